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
# One short simulated structure test of a Dahl damper, fitted by least squares and by the
# emcee posterior of the same output-error likelihood (`bayes_mr.likelihood.output_error.OutputError`),
# then checked the way a posterior should be checked before anybody believes it:
#
# 1. trace and pair plots (mixing, correlations, shape of the posterior);
# 2. R-hat and effective sample sizes;
# 3. LOO (PSIS) and WAIC from the pointwise log-likelihood;
# 4. coverage of the true parameters (known here, because the record is simulated);
# 5. the UKF against the MCMC posterior (`bayes_mr.inference.ukf.crosscheck.ukf_vs_mcmc`).
#
# Everything is small and seeded so the notebook runs in about a minute; it is executed by
# `tests/test_notebooks.py`, and the `assert`s below are part of that test.

# %%
import time
import warnings

import matplotlib.pyplot as plt
import numba
import numpy as np
import pandas as pd

with warnings.catch_warnings():
    warnings.simplefilter("ignore", FutureWarning)  # "ArviZ is undergoing a major refactor"
    import arviz as az

from bayes_mr.inference.ukf import filter as ukf
from bayes_mr.inference.ukf import kernel as K
from bayes_mr.inference.ukf.crosscheck import ukf_vs_mcmc
from bayes_mr.inference.lsq.least_squares import fit_lsq
from bayes_mr.inference.mcmc.settings import MCMCSettings
from bayes_mr.inference.mcmc.sampler import fit_mcmc
from bayes_mr.inference.mcmc_posterior import mcmc_posterior
from bayes_mr.inference.results import build
from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.models import get_model
from bayes_mr.signals import make_signal
from bayes_mr.simulation.simulate import synthesize

# The batches here are small (12 walkers × 500 samples per call): numba's threads cost more in
# start-up and synchronisation than they save (MCMC 32 s on one thread against 66 s on two, on a
# shared 2-core machine). The results do not depend on the thread count.
numba.set_num_threads(1)

T_START = time.perf_counter()
SEED = 0
MASS = 50.0  # kg, the thesis's numerical frame (§3.8)
NOISE = 0.01  # measurement noise, fraction of each measured channel's RMS

# %% [markdown]
# ## 1. A short simulated record
#
# Ground motion: band-limited white noise (`make_signal("blwn")`, 1 s at 500 Hz, up to
# 10 Hz). The frame (50 kg) carries a Dahl damper at the model's default parameters, which
# are therefore the truth.
#
# **Noise.** `synthesize(noise=…)` puts the same fraction of noise on the input as process
# noise *and* on the outputs. Process noise makes the residuals of the true model coloured
# (the frame's narrow-band response to it), which the iid Gaussian likelihood does not
# describe — the posterior is then too narrow and misses the truth by several SD
# (see the comment above `CANDIDATES` in `tests/test_evidence.py`). `synthesize` has no
# measurement-only option, so the record is synthesized noise-free and white measurement
# noise (1 % of RMS) is added to the two measured channels here, with its SD stored in the
# `noise_sd_<channel>` attributes as `synthesize` would.

# %%
model = get_model("dahl")
theta_true = model.theta("structure", {})
signal = make_signal("blwn", duration=1.0, fs=500.0, amplitude=3e-3, fmax=10.0, seed=SEED + 1)
record = synthesize(model, theta_true, signal.time, signal.as_input("structure"), mass=MASS,
                    noise=0.0, seed=SEED, source="dahl-blwn-1s")
rng = np.random.default_rng(SEED + 11)
for channel in ("displacement", "acceleration"):
    clean = record[channel].values
    sd = NOISE * float(np.sqrt(np.mean(clean**2)))
    record[channel] = (record[channel].dims, clean + sd * rng.standard_normal(clean.size), record[channel].attrs)
    record.attrs[f"noise_sd_{channel}"] = sd
record.attrs["noise_fraction"] = NOISE
print(dict(zip(model.param_names("structure"), theta_true)))
print({k: v for k, v in record.attrs.items() if k.startswith("noise_sd")})

# %% [markdown]
# The record, 500 samples: ground acceleration (the input, m/s²), storey displacement (mm)
# and absolute acceleration (m/s²) as measured (grey; the 1 % noise is barely visible), and
# the damper force (N, black), which a structure test does not measure: `synthesize` keeps
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
# Both use one `OutputError` likelihood: Gaussian errors on displacement and acceleration
# with their SDs sampled (coordinates `sigma_displacement`, `sigma_acceleration` hold ln σ).
# The parameters are sampled in the estimation coordinates φ = ln(s·θ) (uniform prior over the
# plausible range = log-uniform in θ). The walkers start from the least-squares optimum.
#
# The run stops when the post-burn-in chain is ≥ 20 integrated autocorrelation times long
# (emcee's advice is 50; the R-hat rule is the binding one here) **and** every rank-normalised
# split R-hat (walkers as chains) is below 1.01.

# %%
lik = OutputError(model, record)
phi_true = lik.par.coords.to_phi(theta_true[lik.par.free_idx])
lsq = fit_lsq(lik)
settings = MCMCSettings(seed=SEED, progress=False, min_tau_multiple=20.0, rhat_max=1.01, check_every=100)
post = fit_mcmc(lik, lsq=lsq, settings=settings)
# pointwise log-likelihood on 40 draws of each walker (960 draws) for LOO / WAIC
idata = build(lik, mcmc_posterior(lik, post, lsq, n_ll_draws=40 * post.n_walkers))
print(f"emcee: {post.n_steps} steps × {post.n_walkers} walkers, burn-in {post.burn}, thin {post.thin}, "
      f"converged={post.converged}, {post.wall_s:.1f} s")
print("free parameters:", lik.par.names, " sampled noise SDs:", lik.names[lik.n_params:])

# %%
table = pd.DataFrame({
    "truth": theta_true[lik.par.free_idx],
    "lsq": [lsq.theta[n] for n in lik.par.names],
    "mcmc mean": idata.posterior[list(lik.par.names)].mean().to_array().values,
    "mcmc sd": idata.posterior[list(lik.par.names)].std().to_array().values,
    "unit": lik.par.coords.units,
}, index=list(lik.par.names))
table

# %% [markdown]
# ## 3. Trace plots
#
# Posterior draws of θ in SI units (c in N·s/m, k in N/m, F_d in N, σ in 1/m) after burn-in,
# thinned by ≈ τ/2; one line per walker. Left: the marginal density of each walker (they
# should overlap); right: the draws against the draw index (they should look like
# stationary noise with no trends or stuck walkers).

# %%
az.plot_trace(idata, var_names=list(lik.par.names), compact=False, figsize=(9, 8))
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
# every panel. Here the strongest is k with F_d (correlation ≈ −0.95 with seed 0): once the
# damper has yielded its force is ≈ c·ẋ + k·x ± F_d, and over a few cycles a little more
# stiffness and a little less friction force fit the record almost equally well.

# %%
az.plot_pair(idata, var_names=list(lik.par.names), kind="kde", marginals=True,
             reference_values=dict(zip(lik.par.names, theta_true[lik.par.free_idx])),
             figsize=(8, 8))
plt.show()
pd.DataFrame(np.corrcoef(post.chain[post.burn:, :, :lik.n_params].reshape(-1, lik.n_params), rowvar=False),
             index=list(lik.par.names), columns=list(lik.par.names)).round(2)

# %% [markdown]
# ## 5. R-hat and effective sample size
#
# Two tables. The package's own diagnostics (group `mcmc_diagnostics`) are computed on the
# **whole post-burn-in chain** in the sampling coordinates, including ln σ of the two
# noise channels: these are the numbers the stopping rule used, and the ones asserted.
# `az.summary` recomputes them on the **thinned** draws stored in `posterior` (θ in SI); its
# ESS is therefore smaller (fewer, less correlated draws), and its R-hat is noisier.

# %%
diag = idata.mcmc_diagnostics
diag_table = pd.DataFrame({"rhat": diag["rhat"].values, "ess_bulk": diag["ess"].values,
                           "tau [steps]": diag["tau"].values}, index=diag["coordinate"].values)
diag_table

# %%
with warnings.catch_warnings():
    warnings.simplefilter("ignore", FutureWarning)
    summary = az.summary(idata, var_names=list(lik.par.names), kind="all")
summary

# %% [markdown]
# The convergence criteria: R-hat < 1.01 for every coordinate and bulk ESS > 400
# (Vehtari et al. 2021: R-hat < 1.01 and ESS > 100 per chain for 4 chains; with 24 walkers
# the chains are short, so the total is what counts).

# %%
rhat_max = float(diag["rhat"].max())
ess_min = float(diag["ess"].min())
print(f"max R-hat = {rhat_max:.4f}, min bulk ESS = {ess_min:.0f}, converged = {post.converged}")
assert post.converged
assert rhat_max < 1.01, rhat_max
assert ess_min > 400, ess_min

# %% [markdown]
# ## 6. LOO and WAIC
#
# The `log_likelihood` group holds the pointwise log-density of each measured channel
# (`displacement`, `acceleration`) on every valid sample (`obs`), for 40 draws of each walker
# spread evenly over the thinned chain. ArviZ needs one variable per call (`var_name`); the
# joint log-density of a sample (both channels, independent errors) is their sum, added
# here as `both`.
#
# **`reff`.** Those 40 draws per walker are not the posterior group's draws (which are
# denser): ArviZ would compute the relative efficiency from the posterior's ESS divided by
# the number of log-likelihood draws and get a value ≫ 1. The log-likelihood draws are
# spaced many autocorrelation times apart, so they are close to independent and `reff=1`
# is passed explicitly.
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
                      "max k̂": float(np.max(loo.pareto_k)), "elpd_waic": waic.elpd_waic,
                      "p_waic": waic.p_waic}
        if name == "both":
            loo_both = loo
ic_table = pd.DataFrame(rows).T
ic_table

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
# z = (posterior mean − truth) / posterior SD, in the sampling coordinates φ (where the
# posterior is close to Gaussian), from the whole post-burn-in chain. |z| < 3 for every
# parameter is asserted.

# %%
p = lik.n_params
mean_phi = post.mean()[:p]
sd_phi = np.sqrt(np.diag(post.cov()))[:p]
z_truth = (mean_phi - phi_true) / sd_phi
print(dict(zip(lik.par.names, z_truth.round(2))))
assert np.all(np.abs(z_truth) < 3.0), dict(zip(lik.par.names, z_truth))

# %% [markdown]
# ## 8. UKF against MCMC
#
# The thesis's augmented-state UKF on the same record: 4 Latin-hypercube prior means × 3
# indices of dispersion (1 %, 10 %, 50 %), the run with the highest innovation
# log-likelihood kept. Its final Gaussian on φ is compared with the MCMC posterior:
# z = (mean_UKF − mean_MCMC)/√(sd_UKF² + sd_MCMC²) and the SD ratio sd_UKF/sd_MCMC,
# in φ and in θ [SI].
#
# **Not asserted: on this record the UKF does not agree with the posterior.** With seed 0
# the best filter's final means are 6–28 % from the truth while its SDs are about as small
# as the posterior's (SD ratio 0.8–1.3): |z| ≈ 24–52 for every parameter — an overconfident
# filter, while the MCMC covers the truth (section 7). This is the known behaviour on short
# records: `tests/test_evidence.py::test_ukf_and_mcmc_means_agree_on_the_25_s_record` finds
# |z| < 3 only on the 25 s thesis-length record (and is marked slow), far too long for this
# notebook. The z-scores are shown so the disagreement is visible, not hidden; this is the
# cross-check doing its job (flagging the UKF), not a failure of the sampler.

# %%
problem = ukf.make_problem(OutputError(model, record))
priors = ukf.lhs_priors(problem.coords, n_lhs=4, taus=(0.01, 0.1, 0.5), seed=SEED)
runs = ukf.run_priors(problem, priors)
ok = runs["info"][:, K.I_STATUS] == K.OK
best = int(np.argmax(np.where(ok, runs["info"][:, K.I_LOGLIK], -np.inf)))
ns = len(problem.p0_states)
print(f"{int(ok.sum())}/{len(priors)} UKF runs finished; best: LHS {priors[best].lhs}, "
      f"τ = {priors[best].tau}, innovation log-likelihood {runs['info'][best, K.I_LOGLIK]:.1f}")
cross = ukf_vs_mcmc(runs["mean"][best, ns:], runs["cov"][best, ns:, ns:], post.chain[post.burn:],
                    coords=problem.coords)
cross_table = cross[["mean_ukf_theta", "sd_ukf_theta", "mean_mcmc_theta", "sd_mcmc_theta",
                     "z_theta", "sd_ratio_theta", "z_phi", "sd_ratio_phi"]].to_dataframe()
cross_table

# %% [markdown]
# The same comparison as a figure: posterior mean ± 2 SD of each parameter relative to the
# truth (θ/θ_true, dimensionless) for MCMC and UKF.

# %%
fig, ax = plt.subplots(figsize=(7, 3))
names = list(problem.coords.names)
truth = theta_true[lik.par.free_idx]
y = np.arange(len(names))
for shift, engine, colour in ((-0.12, "mcmc", "C0"), (0.12, "ukf", "C3")):
    m = cross[f"mean_{engine}_theta"].values / truth
    s = cross[f"sd_{engine}_theta"].values / truth
    ax.errorbar(m, y + shift, xerr=2 * s, fmt="o", color=colour, label=engine.upper(), capsize=3)
ax.axvline(1.0, color="k", lw=0.8)
ax.set_yticks(y, names)
ax.set_xlabel("θ / θ_true  (mean ± 2 SD)")
ax.legend()
fig.tight_layout()
plt.show()

# %% [markdown]
# ## Summary

# %%
print(f"max R-hat {rhat_max:.4f}   min bulk ESS {ess_min:.0f}   "
      f"elpd_loo (both channels) {rows['both']['elpd_loo']:.1f} ± {rows['both']['se']:.1f}, "
      f"p_loo {rows['both']['p_loo']:.2f}")
print("MCMC z vs truth:", dict(zip(lik.par.names, z_truth.round(2))))
print("UKF vs MCMC z (θ):", dict(zip(names, cross["z_theta"].values.round(2))))
print("UKF vs MCMC z (φ):", dict(zip(names, cross["z_phi"].values.round(2))))
print(f"notebook wall time {time.perf_counter() - T_START:.1f} s")
