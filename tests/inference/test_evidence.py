"""Evidence routes against analytic evidences (each within its own reported error)."""

import math

import numpy as np
import pytest

from bayes_mr.data.schema import make_record
from bayes_mr.inference.ukf import filter as ukf
from bayes_mr.inference.ukf import kernel as K
from bayes_mr.inference.ukf.crosscheck import ukf_vs_mcmc
from bayes_mr.inference.evidence.routes import (
    Evidence, laplace_evidence, select_route, stepping_stone, thermodynamic_integration,
)
from bayes_mr.inference.evidence.ladder import BoxTarget, run_ladder
from bayes_mr.inference.lsq.least_squares import fit_lsq
from bayes_mr.inference.mcmc.settings import MCMCSettings
from bayes_mr.inference.mcmc.sampler import fit_mcmc, sample
from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.models import get_model
from bayes_mr.simulation.simulate import simulate
from records import device_inputs, structure_record


def within(ev: Evidence, truth: float, k: float = 3.0) -> bool:
    return abs(ev.log_z - truth) <= k * ev.total_error


# --- a Gaussian likelihood in a uniform prior box ------------------------------------

def gaussian_target(half_width: float, seed: int = 2, d: int = 4):
    """ln L = c₀ − ½(x−μ)ᵀC⁻¹(x−μ) on the box μ ± half_width·SD; Z = e^c₀ (2π)^{d/2}|C|^{1/2} / V."""
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((d, d))
    C = A @ A.T / d + 0.2 * np.eye(d)
    mu = rng.standard_normal(d)
    P = np.linalg.inv(C)
    c0 = -123.4
    sd = np.sqrt(np.diag(C))
    lo, hi = mu - half_width * sd, mu + 1.1 * half_width * sd

    def loglike(X):
        r = np.atleast_2d(X) - mu
        return c0 - 0.5 * np.einsum("bi,ij,bj->b", r, P, r)

    # the box holds all but < 1e-40 of the Gaussian's mass at these widths: no truncation term
    log_z = c0 + 0.5 * d * math.log(2 * math.pi) + 0.5 * np.linalg.slogdet(C)[1] - np.sum(np.log(hi - lo))
    return BoxTarget(loglike, lo, hi), mu, C, log_z


@pytest.fixture(scope="module")
def gaussian_case():
    target, mu, C, log_z = gaussian_target(30.0)
    post = sample(target, mu, C, MCMCSettings(seed=1, progress=False))
    return target, post, log_z


def test_reference_path_ti_and_stepping_stone_match_the_analytic_evidence(gaussian_case):
    target, post, log_z = gaussian_case
    ladder = run_ladder(target, post, path="reference", seed=5)
    ti, ss = thermodynamic_integration(ladder), stepping_stone(ladder)
    for ev in (ti, ss):
        assert within(ev, log_z), (ev.route, ev.log_z - log_z, ev.total_error)
        assert ev.total_error < 0.01  # and the error bar is not trivially wide
    assert ti.ladder_error < ti.mc_error  # a Gaussian reference makes the integrand nearly flat


def test_reference_rungs_on_an_executor_give_the_in_process_ladder(gaussian_case):
    """The reference path's rungs are independent jobs: on a pool they give the same chains, bit for bit."""
    from concurrent.futures import ThreadPoolExecutor

    target, post, _ = gaussian_case
    betas = np.array([0.0, 0.1, 0.4, 1.0])
    here = run_ladder(target, post, betas=betas, seed=3)
    with ThreadPoolExecutor(2) as pool:
        there = run_ladder(target, post, betas=betas, seed=3, executor=pool)
    for a, b in zip(here.chains[1:-1], there.chains[1:-1]):
        np.testing.assert_array_equal(a.chain, b.chain)
    assert thermodynamic_integration(here).log_z == thermodynamic_integration(there).log_z


def test_a_checkpointed_ladder_resumes_to_the_same_evidence(gaussian_case, tmp_path):
    """Every temperature is a group of one HDF5 file; rerunning with resume=True redoes nothing."""
    from dataclasses import replace as _replace

    from bayes_mr.inference.evidence.ladder import LADDER_SETTINGS

    target, post, _ = gaussian_case
    settings = _replace(LADDER_SETTINGS, backend=tmp_path / "ladder.h5")
    betas = np.array([0.0, 0.3, 0.7, 1.0])  # short: emcee's HDF5 backend reopens the file every step
    first = thermodynamic_integration(run_ladder(target, post, betas=betas, seed=9, settings=settings))
    again = run_ladder(target, post, betas=betas, seed=9, settings=_replace(settings, resume=True))
    assert thermodynamic_integration(again).log_z == first.log_z
    assert all(c.wall_s < 1.0 for c in again.chains[1:-1])


def test_power_posterior_ti_matches_the_analytic_evidence_with_its_ladder_error(gaussian_case):
    """Prior path, β_k = (k/20)⁵: the ladder error is the larger part and is reported as such."""
    target, post, log_z = gaussian_case
    ladder = run_ladder(target, post, path="prior", seed=6)
    ti = thermodynamic_integration(ladder)
    assert within(ti, log_z), (ti.log_z - log_z, ti.mc_error, ti.ladder_error)
    assert ti.ladder_error > ti.mc_error
    assert ti.total_error < 0.6
    # the plain trapezoid is biased low on this ladder (the integrand is convex in β): over twelve ladder seeds it
    # missed by −0.20 to −0.56 (mean −0.40) against an MC error of 0.11–0.14, so its miss in units of the MC
    # error (1.6–4.8) is no fixed bound, and neither is its sign in one run: the rungs' short chains start from
    # the posterior's last walkers, and from another posterior chain (the independence move's t₂₀ with a t₄
    # share) four ladder seeds missed by +0.04 to −0.41. What holds is that the correction moves the estimate
    # up by more than the MC error
    assert ti.log_z - ti.details["trapezoid"] > ti.mc_error


def test_select_prefers_ti_then_laplace():
    lap = Evidence("laplace", -10.0, 0.0, float("nan"), float("nan"))
    ti = Evidence("ti", -11.0, 0.1, 0.01, 0.1)
    ss = Evidence("ss", -11.05, 0.1, 0.0, 0.1)
    assert select_route({"laplace": lap, "ti": ti, "ss": ss}) is ti
    assert select_route({"laplace": lap, "ss": ss}) is lap
    with pytest.raises(ValueError):
        select_route({"ss": ss})


# --- a linear-Gaussian OutputError: every route, Laplace included ------------------------

def linear_device_problem(n=600, noise=0.01, seed=1):
    """LuGre device test with ε, α fixed: the force is exactly linear in (c, k, β).

    Returns the likelihood and the analytic evidence. With the package's
    prior (uniform in φ = ln(sθ), i.e. density Π 1/(θ_j Δφ_j) in θ) the
    evidence is L̂ (2π)^{3/2} |AᵀA/σ²|^{−1/2} E[Π 1/(θ_j Δφ_j)] with the
    expectation over the Gaussian posterior of θ, taken to second order
    (the third-order term is < 1e-5 here).
    """
    model = get_model("lugre")
    inputs = device_inputs(0.006, n=n, fs=1000.0, seed=0, voltage=False)
    values = {"c": 2000.0, "k": 500.0, "beta": 3e5, "epsilon": 500.0, "alpha": 1000.0}
    theta = model.theta("device", values)
    force = simulate(model, inputs, theta)["force"]
    sd = noise * force.std()
    rng = np.random.default_rng(seed)
    rec = make_record(np.arange(n) * inputs.dt,
                      {"displacement": inputs.rows[:, 0], "velocity": inputs.rows[:, 1],
                           "force": force + sd * rng.standard_normal(n)},
                      source="linear-lugre", attrs={"noise_sd_force": sd, "input_interp": "linear"})
    lik = OutputError("lugre", rec, fixed={"epsilon": 500.0, "alpha": 1000.0}, noise="fixed")
    names = model.param_names("device")
    free = [names.index(p) for p in lik.par.names]
    base = theta.copy()
    base[free] = 0.0
    f0 = simulate(model, inputs, base)["force"]
    cols = []
    for j in free:
        e = base.copy()
        e[j] = 1.0
        cols.append(simulate(model, inputs, e)["force"] - f0)
    A = np.column_stack(cols) / sd
    b = (lik.y[:, 0] - f0) / sd
    AtA = A.T @ A
    th = np.linalg.solve(AtA, A.T @ b)
    cov = np.linalg.inv(AtA)
    rss = float(np.sum((b - A @ th) ** 2))
    second = 1 + np.sum(np.diag(cov) / th**2) + sum(
        cov[i, j] / (th[i] * th[j]) for i in range(3) for j in range(i + 1, 3))
    log_z = (-n * math.log(sd) - 0.5 * n * math.log(2 * math.pi) - 0.5 * rss + 1.5 * math.log(2 * math.pi)
             - 0.5 * np.linalg.slogdet(AtA)[1] - np.sum(np.log(th * (lik.phi_hi - lik.phi_lo)))
             + math.log(second))
    return lik, log_z, math.log(second)


def test_every_route_matches_the_analytic_evidence_of_a_linear_output_error_model():
    """Laplace exact up to the prior density's curvature (which it ignores); TI and SS within their errors."""
    lik, log_z, curvature = linear_device_problem()
    lsq = fit_lsq(lik)
    lap = laplace_evidence(lsq)
    assert abs(lap.log_z - (log_z - curvature)) < 1e-3  # Laplace misses exactly the prior's curvature term
    # the posterior only fits the reference and is the top rung: 20 τ is plenty
    post = fit_mcmc(lik, lsq=lsq, settings=MCMCSettings(seed=0, progress=False, min_tau_multiple=20.0,
                                                         rhat_max=1.05, check_every=100))
    ladder = run_ladder(lik, post, seed=1)
    for ev in (thermodynamic_integration(ladder), stepping_stone(ladder)):
        assert within(ev, log_z), (ev.route, ev.log_z - log_z, ev.total_error)
        # the sampling routes resolve what Laplace misses: its deficit is > 2 of their standard errors
        assert ev.total_error < curvature / 2


# --- the thesis's numerical study (§3.8): truth dahl, 1 % noise ---------------------------------
#
# Measurement noise only (``process=False``): with the thesis's 1 % input noise the residuals hold
# the frame's narrow-band response to it, which the iid likelihood (and an AR(1) one: lag-1
# autocorrelation 0.01–0.02) does not model; the posterior is then ~2.3× too narrow and misses the
# truth by up to 6 SD (measured on 25 s). That is a likelihood question, not a sampler one, so these
# tests use data the likelihood describes.
#
# Fast (default): 2 s; the selection's posteriors stop at 20 τ (they only fit the reference and
# are the top rung of the ladder). Slow: 25 s, every posterior to 50 τ and R-hat < 1.01.


CANDIDATES = ("dahl", "normalized-bouc-wen", "lugre")
FULL = MCMCSettings(seed=0, progress=False)
QUICK = MCMCSettings(seed=0, progress=False, min_tau_multiple=20.0, rhat_max=1.05, check_every=100)


def study(n: int, settings: dict) -> dict:
    """Every candidate fitted to one dahl record: LSQ, emcee posterior, reference-path TI and SS."""
    rec, theta = structure_record("dahl", {}, n=n, seed=3, rms=0.6, noise=0.01, process=False)
    out = {"record": rec, "theta": theta}
    for name in CANDIDATES:
        lik = OutputError(name, rec)
        lsq = fit_lsq(lik)
        post = fit_mcmc(lik, lsq=lsq, settings=settings[name])
        ladder = run_ladder(lik, post, seed=1)
        out[name] = {"lik": lik, "lsq": lsq, "post": post, "ti": thermodynamic_integration(ladder),
                         "ss": stepping_stone(ladder), "laplace": laplace_evidence(lsq)}
    return out


@pytest.fixture(scope="module", params=[
    pytest.param((2000, {"dahl": FULL, "normalized-bouc-wen": QUICK, "lugre": QUICK}), id="2s"),
    pytest.param((25000, dict.fromkeys(CANDIDATES, FULL)), id="25s", marks=pytest.mark.slow),
])
def numerical_study(request):
    return study(*request.param)


def test_mcmc_posterior_covers_the_true_parameters(numerical_study):
    fit = numerical_study["dahl"]
    lik, post = fit["lik"], fit["post"]
    assert post.converged and np.all(post.rhat < 1.01)
    p = lik.n_params
    mean, sd = post.mean()[:p], np.sqrt(np.diag(post.cov()))[:p]
    z = (mean - lik.par.coords.to_phi(numerical_study["theta"])) / sd
    assert np.all(np.abs(z) < 3.0), dict(zip(lik.par.names, z.round(2)))


def test_evidence_selects_dahl(numerical_study):
    """TI (the selecting route) ranks dahl first; SS on the same samples agrees within errors.

    Over normalized Bouc–Wen (which contains dahl at n = σ = 1) by more than
    3 nats. Over LuGre (which contains dahl as ε → 0, the lower end of its
    ε prior) only by ≈ 0.7–2.4 nats at 2–10 s, not growing with the record
    (measured): the log-uniform ε prior keeps its mass near the Dahl limit,
    so the Occam penalty stays at about ln(prior width / posterior width of
    ln ε) ≈ 1.5 nats, plus 0.5 for LuGre's wider β box.
    """
    fits = {name: numerical_study[name] for name in CANDIDATES}
    for name, f in fits.items():
        ti, ss = f["ti"], f["ss"]
        assert ti.total_error < 0.1, name
        assert abs(ti.log_z - ss.log_z) < 3 * math.hypot(ti.total_error, ss.total_error), name
    ln_z = {name: f["ti"].log_z for name, f in fits.items()}
    assert ln_z["dahl"] - ln_z["normalized-bouc-wen"] > 3.0
    assert ln_z["dahl"] - ln_z["lugre"] > 0.3


@pytest.mark.slow
def test_ukf_and_mcmc_means_agree_on_the_25_s_record(numerical_study):
    """The thesis's UKF (best of 18 LHS × τ priors by innovation evidence) against the emcee posterior.

    25 s only: on 2–10 s records the UKF's final mean of ``c`` wanders up to
    27 of its own SDs from the truth (measured; its covariance is held at a
    floor by the parameter random walk), while the MCMC covers the truth at
    every length — the crosscheck then flags the UKF, as it should.
    """
    if numerical_study["record"].sizes["time"] < 25000:
        pytest.skip("the UKF agrees with the posterior only on the thesis-length record")
    fit = numerical_study["dahl"]
    problem = ukf.make_problem(OutputError("dahl", numerical_study["record"]))
    priors = ukf.lhs_priors(problem.coords, n_lhs=6, taus=(0.01, 0.1, 0.5), seed=0)
    out = ukf.run_priors(problem, priors)
    ok = out["info"][:, K.I_STATUS] == K.OK
    best = int(np.argmax(np.where(ok, out["info"][:, K.I_LOGLIK], -np.inf)))
    ns = len(problem.p0_states)
    post = fit["post"]
    ds = ukf_vs_mcmc(out["mean"][best, ns:], out["cov"][best, ns:, ns:], post.chain[post.burn:],
                     coords=problem.coords)
    assert np.all(np.abs(ds["z_phi"].values) < 3.0), ds["z_phi"].values
    assert np.all(np.abs(ds["z_theta"].values) < 3.0), ds["z_theta"].values


def test_a_ladder_rung_that_did_not_converge_is_named_and_its_evidence_refused(gaussian_case):
    """Rungs stopped far short of their ≥ N τ rule: TI and SS carry their β, and compare will not select on them."""
    from dataclasses import replace as _replace

    from bayes_mr.selection.comparison import _select
    from bayes_mr.inference.evidence.ladder import LADDER_SETTINGS

    target, post, *_ = gaussian_case
    short = _replace(LADDER_SETTINGS, max_steps=60, check_every=30, min_tau_multiple=50.0)
    betas = np.array([0.0, 0.1, 0.5, 1.0])
    ladder = run_ladder(target, post, betas=betas, seed=3, settings=short)
    ti, ss = thermodynamic_integration(ladder), stepping_stone(ladder)
    assert set(ti.unconverged) <= {0.1, 0.5} and ti.unconverged and not ti.converged
    assert ss.unconverged == ti.unconverged and ti.to_dict()["converged"] is False
    rows = [{"model": "a", "engine": "mcmc", "log_evidence": ti.log_z, "evidence_route": "ti",
             "evidence_routes": {"ti": ti.to_dict()}},
            {"model": "b", "engine": "mcmc", "log_evidence": ti.log_z - 5.0, "evidence_route": "ti",
             "evidence_routes": {"ti": {**ti.to_dict(), "converged": True, "unconverged_betas": []}}}]
    selected, factors, verdict = _select(rows, "mcmc", "ti", force=False)
    assert selected is None and "refused" in verdict and "a: rungs β = " in verdict["refused"]
    assert factors["b"] == pytest.approx(5.0)
    selected, _, verdict = _select(rows, "mcmc", "ti", force=True)
    assert selected == "a" and verdict["forced"] is True and list(verdict["unconverged"]) == ["a"]
