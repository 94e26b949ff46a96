# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#   kernelspec:
#     display_name: Python 3 (ipykernel)
#     language: python
#     name: python3
# ---

# %% [markdown]
# # Posterior diagnostics of an emcee fit
#
# One short simulated structure test of a Dahl damper, fitted by least squares, by the emcee
# posterior of the same output-error likelihood and by the thesis's UKF, then checked the way a
# posterior should be checked before anybody believes it:
#
# 1. trace and pair plots (mixing, correlations, shape of the posterior);
# 2. R-hat and effective sample sizes;
# 3. LOO (PSIS) and WAIC from the pointwise log-likelihood;
# 4. coverage of the true parameters (known here, because the record is simulated);
# 5. the UKF against the MCMC posterior (`bm.crosscheck`).
#
# Everything goes through the public face, `import bayes_mr as bm`: every fit is
# `bm.Identify(model, engine).fit(record)` and comes back as ArviZ `InferenceData`, so the
# ArviZ plots and statistics below work on it directly. Everything is small and seeded so the
# notebook runs in about a minute; it is executed by `tests/test_notebooks.py`, and the
# `assert`s below are part of that test.

# %%
import time
import warnings

import matplotlib.pyplot as plt
import numpy as np

import bayes_mr as bm

with warnings.catch_warnings():
    warnings.simplefilter("ignore", FutureWarning)  # "ArviZ is undergoing a major refactor"
    import arviz as az

T_START = time.perf_counter()
SEED = 0
MASS = 50.0  # kg, the thesis's numerical frame (§3.8)
NOISE = 0.01  # measurement noise, fraction of each measured channel's RMS

# %% [markdown]
# ## 1. A short simulated record
#
# Ground motion: band-limited white noise (`bm.make_signal("blwn")`, 1 s at 500 Hz, up to
# 10 Hz). The frame (50 kg) carries a Dahl damper at the model's default parameters, which
# are therefore the truth.
#
# **Noise.** `bm.synthesize(noise=…)` puts the same fraction of noise on the input as process
# noise *and* on the outputs. Process noise makes the residuals of the true model coloured
# (the frame's narrow-band response to it), which an iid Gaussian likelihood does not
# describe. To check the posterior against a likelihood that is right, the record is
# synthesized noise-free and white measurement noise (1 % of RMS) is added to the two measured
# channels here, with its SD stored in the `noise_sd_<channel>` attributes as `bm.synthesize`
# would.

# %%
model = bm.get_model("dahl")
names = list(model.param_names("structure"))
truth = dict(zip(names, model.theta("structure", {})))
signal = bm.make_signal("blwn", duration=1.0, fs=500.0, amplitude=3e-3, fmax=10.0, seed=SEED + 1)
record = bm.synthesize(model, model.theta("structure", {}), signal.time, signal.as_input("structure"), mass=MASS,
                       noise=0.0, seed=SEED, source="dahl-blwn-1s")
rng = np.random.default_rng(SEED + 11)
for channel in ("displacement", "acceleration"):
    clean = record[channel].values
    sd = NOISE * float(np.sqrt(np.mean(clean**2)))
    record[channel] = (record[channel].dims, clean + sd * rng.standard_normal(clean.size), record[channel].attrs)
    record.attrs[f"noise_sd_{channel}"] = sd
record.attrs["noise_fraction"] = NOISE
print("truth:", {n: float(v) for n, v in truth.items()})
print({k: v for k, v in record.attrs.items() if k.startswith("noise_sd")})

# %% [markdown]
# The record, 500 samples: ground acceleration (the input, m/s²), storey displacement (mm)
# and absolute acceleration (m/s²) as measured (grey; the 1 % noise is barely visible), and
# the damper force (N, black), which a structure test does not measure: `bm.synthesize` keeps
# the true one for reference, the likelihood never sees it.

# %%
fig, axes = plt.subplots(4, 1, figsize=(8, 7), sharex=True)
t = record["time"].values
axes[0].plot(t, record["ground_acceleration"], "k", lw=0.8)
axes[0].set_ylabel("ẍ_g [m/s²]")
axes[1].plot(t, 1e3 * record["displacement"], color="0.6", lw=0.8)
axes[1].set_ylabel("x [mm]")
axes[2].plot(t, record["acceleration"], color="0.6", lw=0.8)
axes[2].set_ylabel("ẍ [m/s²]")
axes[3].plot(t, record["force"], "k", lw=0.8)
axes[3].set_ylabel("damper force [N]")
axes[3].set_xlabel("time [s]")
fig.tight_layout()
plt.show()

# %% [markdown]
# ## 2. Least squares, then emcee
#
# Both fit one output-error likelihood (`bm.OutputError`): Gaussian errors on displacement and
# acceleration. The parameters are estimated in the coordinates φ = ln(s·θ) (uniform prior over
# the plausible range = log-uniform in θ); the emcee walkers start from the least-squares
# optimum and sample the two noise SDs too.
#
# The chain stops when the post-burn-in chain is ≥ 20 integrated autocorrelation times long
# **and** every rank-normalised split R-hat (walkers as chains) is below 1.01
# (`bm.MCMCSettings`). `evidence="laplace"` skips the thermodynamic-integration ladder: only
# the posterior is wanted here, not a model comparison.

# %%
lsq = bm.Identify(model, bm.LeastSquares()).fit(record, seed=SEED, progress=False)
settings = bm.MCMCSettings(seed=SEED, progress=False, min_tau_multiple=20.0, rhat_max=1.01, check_every=100)
idata = bm.Identify(model, bm.Emcee(settings=settings, evidence="laplace")).fit(record, seed=SEED, progress=False)
fit_lsq, fit_mcmc = bm.summary_of(lsq), bm.summary_of(idata)
run = fit_mcmc.extra
print(f"emcee: {run['n_steps']} steps × {run['n_walkers']} walkers, burn-in {run['burn']}, thin {run['thin']}, "
      f"{run['stopped']}, {fit_mcmc.wall_s:.1f} s")
print("groups:", ", ".join(idata.groups()))

# %% [markdown]
# Truth, least-squares optimum and posterior mean ± SD of every parameter [SI]: c in N·s/m,
# k in N/m, F_d in N, σ in 1/m. `bm.summary_of` reads the summary every result carries (the
# `fit` keys of the contract).

# %%
print(f"{'':6s} {'truth':>10s} {'lsq':>10s} {'± sd':>8s} {'mcmc':>10s} {'± sd':>8s}")
for n in names:
    print(f"{n:6s} {truth[n]:10.4g} {fit_lsq.params[n]:10.4g} {fit_lsq.params_sd[n]:8.3g} "
          f"{fit_mcmc.params[n]:10.4g} {fit_mcmc.params_sd[n]:8.3g}")

# %% [markdown]
# ## 3. Trace plots
#
# Posterior draws of θ in SI units after burn-in; one line per walker. Left: the marginal
# density of each walker (they should overlap); right: the draws against the draw index (they
# should look like stationary noise with no trends or stuck walkers).

# %%
az.plot_trace(idata, var_names=names, compact=False, figsize=(9, 8))
plt.tight_layout()
plt.show()

# %% [markdown]
# ## 4. Pair plot
#
# Joint posterior of the four parameters (SI units), all walkers pooled, with the true
# values as reference lines. Elongated panels show combinations of parameters the record
# pins down better than the parameters themselves (the correlation matrix below puts numbers
# on them); a banana shape or several modes would be a warning that Gaussian summaries
# (Laplace, the UKF's covariance) are not adequate. The truth should sit inside the bulk of
# every panel. Once the damper has yielded its force is ≈ c·ẋ + k·x ± F_d, so over a few cycles
# a little more stiffness and a little less friction force fit the record almost equally well:
# expect k and F_d to be strongly anti-correlated.

# %%
az.plot_pair(idata, var_names=names, kind="kde", marginals=True,
             reference_values={n: float(v) for n, v in truth.items()}, figsize=(8, 8))
plt.show()
draws = np.column_stack([idata.posterior[n].values.ravel() for n in names])
corr = np.corrcoef(draws, rowvar=False)
print("correlation\n" + "\n".join(f"{n:6s}" + " ".join(f"{v:6.2f}" for v in row) for n, row in zip(names, corr)))

# %% [markdown]
# ## 5. R-hat and effective sample size
#
# Two tables. The package's own diagnostics (group `mcmc_diagnostics`) are computed on the
# **whole post-burn-in chain** in the sampling coordinates, including ln σ of the two
# noise channels: these are the numbers the stopping rule used, and the ones asserted.
# `az.summary` recomputes them on the draws stored in `posterior` (θ in SI, thinned, and mapped
# to least squares' calibrated covariance about the optimum — the result's `uncertainty` says
# so); its R-hat is therefore noisier and its ESS differs.

# %%
diag = idata.mcmc_diagnostics
for c, rhat, ess, tau in zip(diag["coordinate"].values, diag["rhat"].values, diag["ess"].values, diag["tau"].values):
    print(f"{c:20s} R-hat {rhat:.4f}   bulk ESS {ess:7.0f}   τ {tau:5.2f} steps")
print("posterior draws:", fit_mcmc.extra["uncertainty"])

# %%
with warnings.catch_warnings():
    warnings.simplefilter("ignore", FutureWarning)
    summary = az.summary(idata, var_names=names, kind="all")
summary

# %% [markdown]
# The convergence criteria: R-hat < 1.01 for every coordinate and bulk ESS > 400
# (Vehtari et al. 2021: R-hat < 1.01 and ESS > 100 per chain for 4 chains; with a handful of
# walkers the chains are short, so the total is what counts).

# %%
rhat_max = float(diag["rhat"].max())
ess_min = float(diag["ess"].min())
print(f"max R-hat = {rhat_max:.4f}, min bulk ESS = {ess_min:.0f}, converged = {run['converged']}")
assert run["converged"]
assert rhat_max < 1.01, rhat_max
assert ess_min > 400, ess_min

# %% [markdown]
# ## 6. LOO and WAIC
#
# The `log_likelihood` group holds the pointwise log-density of each measured channel
# (`displacement`, `acceleration`) on every valid sample (`obs`), for draws of every walker
# spread evenly over the chain. ArviZ needs one variable per call (`var_name`); the joint
# log-density of a sample (both channels, independent errors) is their sum, added here as `both`.
#
# **`reff`.** Those draws are not the posterior group's draws (which are denser): ArviZ would
# compute the relative efficiency from the posterior's ESS divided by the number of
# log-likelihood draws and get a value ≫ 1. The log-likelihood draws are spaced many
# autocorrelation times apart, so they are close to independent and `reff=1` is passed.
#
# Units: elpd in nats (log-density of the data in SI units, so the absolute level depends
# on the units; only differences between models on the same data mean something). `p_loo`
# is the effective number of parameters: for the joint log-density it should be close to the
# 6 sampled coordinates (4 parameters + 2 noise SDs); the per-channel values share them out.
# Pareto k̂ < 0.7 means the importance sampling is reliable for that sample.

# %%
ll = idata.log_likelihood
ll["both"] = ll["displacement"] + ll["acceleration"]
rows = {}
with warnings.catch_warnings():
    warnings.simplefilter("ignore", FutureWarning)
    for name in ("displacement", "acceleration", "both"):
        loo = az.loo(idata, var_name=name, reff=1.0, pointwise=True)
        waic = az.waic(idata, var_name=name)
        rows[name] = {"elpd_loo": loo.elpd_loo, "se": loo.se, "p_loo": loo.p_loo,
                      "max k̂": float(np.max(loo.pareto_k)), "elpd_waic": waic.elpd_waic, "p_waic": waic.p_waic}
        if name == "both":
            loo_both = loo
print(f"{'':13s}" + "".join(f"{k:>11s}" for k in rows["both"]))
for name, row in rows.items():
    print(f"{name:13s}" + "".join(f"{v:11.2f}" for v in row.values()))

# %% [markdown]
# Pareto k̂ of every sample of the joint log-likelihood (good below 0.7, dashed line).

# %%
az.plot_khat(loo_both, show_hlines=True, figsize=(8, 3))
plt.show()
for name, row in rows.items():
    assert np.isfinite(row["p_loo"]) and np.isfinite(row["elpd_loo"]), (name, row)

# %% [markdown]
# ## 7. Coverage of the true parameters
#
# z = (posterior mean − truth) / posterior SD of every parameter, as the results report them
# (`params`, `params_sd` in SI), for the least-squares Laplace posterior and the emcee one.
# |z| < 3 for every parameter is asserted for both.

# %%
z_truth = {engine: {n: float((fit.params[n] - truth[n]) / fit.params_sd[n]) for n in names}
           for engine, fit in (("lsq", fit_lsq), ("mcmc", fit_mcmc))}
for engine, z in z_truth.items():
    print(f"{engine:5s} z vs truth:", {n: round(v, 2) for n, v in z.items()})
    assert all(abs(v) < 3.0 for v in z.values()), (engine, z)

# %% [markdown]
# ## 8. UKF against MCMC
#
# The thesis's augmented-state UKF on the same record, as `bm.UKF` runs it: 4 Latin-hypercube
# prior means × 3 indices of dispersion (1 %, 10 %, 50 %), the run with the lowest MSE on the
# record kept and refined; its covariance is the filter's own, widened by the filter's offset
# from the likelihood's peak (`peak_offset_sd` says how far, in the filter's SDs).
# `bm.crosscheck(ukf, mcmc)` compares it with the MCMC posterior, parameter by parameter:
# z = (mean_UKF − mean_MCMC)/√(sd_UKF² + sd_MCMC²) (|z| ≤ 3: agreement) and the SD ratio
# sd_UKF/sd_MCMC (≪ 1: an overconfident filter; ≫ 1: one that says less than the record holds).

# %%
ukf = bm.Identify(model, bm.UKF(n_lhs=4, taus=(0.01, 0.1, 0.5))).fit(record, seed=SEED, progress=False)
fit_ukf = bm.summary_of(ukf)
print(f"{fit_ukf.trained} UKF runs finished, {fit_ukf.diverged} diverged; "
      f"selected τ = {fit_ukf.extra['selected_tau']}; {fit_ukf.extra['uncertainty']}")
cross = bm.crosscheck(ukf, idata)
print(f"{'':6s} {'ukf':>10s} {'± sd':>8s} {'mcmc':>10s} {'± sd':>8s} {'z':>6s} {'sd ratio':>9s}")
for n, c in cross.items():
    print(f"{n:6s} {c['ukf']:10.4g} {c['ukf_sd']:8.3g} {c['mcmc']:10.4g} {c['mcmc_sd']:8.3g} {c['z']:6.2f} "
          f"{c['sd_ratio']:9.2f}")

# %% [markdown]
# The same comparison as a figure: mean ± 2 SD of each parameter relative to the truth
# (θ/θ_true, dimensionless) for least squares, MCMC and UKF.

# %%
fig, ax = plt.subplots(figsize=(7, 3))
y = np.arange(len(names))
for shift, (engine, fit), colour in zip((-0.2, 0.0, 0.2), (("lsq", fit_lsq), ("mcmc", fit_mcmc), ("ukf", fit_ukf)),
                                        ("C2", "C0", "C3")):
    m = np.array([fit.params[n] / truth[n] for n in names])
    s = np.array([fit.params_sd[n] / truth[n] for n in names])
    ax.errorbar(m, y + shift, xerr=2 * s, fmt="o", color=colour, label=engine.upper(), capsize=3)
ax.axvline(1.0, color="k", lw=0.8)
ax.set_yticks(y, names)
ax.set_xlabel("θ / θ_true  (mean ± 2 SD)")
ax.legend()
fig.tight_layout()
plt.show()

# %% [markdown]
# The filter agrees with the posterior when every |z| ≤ 3 and its SDs are neither far below
# nor far above the posterior's (asserted: within a factor 3).

# %%
assert set(cross) == set(names), cross
assert all(abs(c["z"]) <= 3.0 for c in cross.values()), cross
assert all(1 / 3 < c["sd_ratio"] < 3 for c in cross.values()), cross

# %% [markdown]
# ## Summary

# %%
print(f"max R-hat {rhat_max:.4f}   min bulk ESS {ess_min:.0f}   "
      f"elpd_loo (both channels) {rows['both']['elpd_loo']:.1f} ± {rows['both']['se']:.1f}, "
      f"p_loo {rows['both']['p_loo']:.2f}")
print("MCMC z vs truth:", {n: round(v, 2) for n, v in z_truth["mcmc"].items()})
print("UKF vs MCMC z:", {n: round(c["z"], 2) for n, c in cross.items()})
print(f"notebook wall time {time.perf_counter() - T_START:.1f} s")
