"""Least squares: recovery from noise-free and noisy data, convex starts, Laplace evidence."""

import math

import numpy as np
import pytest

from bayes_mr.data.schema import make_record
from bayes_mr.inference.lsq import LinearSubfit, LSQSettings, fit_lsq, linear_names
from bayes_mr.likelihood import OutputError
from bayes_mr.models import get_model
from bayes_mr.simulate import simulate
from records import device_inputs, structure_record

STRUCTURE_CASES = [
    ("dahl", {}),
    ("normalized-bouc-wen", {}),
    ("lugre", {}),
    ("bouc-wen", {"c": 100.0, "k": 2e4, "beta1": 2e5, "gamma": 1e5, "n": 2.0}),
]


def spencer_record(noise, seed=0, n=3000):
    """A damper like Spencer's prototype (published parameters × 0.7…1.4) on a device test at 3 kHz."""
    model = get_model("spencer")
    inputs = device_inputs(0.006, n=n, fs=3000.0, seed=seed)
    theta = model.theta("device")
    factors = np.random.default_rng(seed + 100).uniform(0.7, 1.4, theta.size)
    factors[model.param_names("device").index("A")] = 1.0
    theta = theta * factors
    force = simulate(model, inputs, theta)["force"]
    rng = np.random.default_rng(seed + 7)
    sd = max(noise * force.std(), 1e-9)
    rec = make_record(
        np.arange(inputs.n) * inputs.dt,
        dict(displacement=inputs.rows[:, 0], velocity=inputs.rows[:, 1], voltage=inputs.rows[:, 2],
             force=force + noise * force.std() * rng.standard_normal(inputs.n)),
        source="spencer-test", attrs=dict(noise_sd_force=sd),
    )
    free = [i for i, n in enumerate(model.param_names("device")) if n != "A"]
    return rec, theta[free]


@pytest.mark.parametrize("name,values", STRUCTURE_CASES, ids=[c[0] for c in STRUCTURE_CASES])
def test_noise_free_structure_recovery(name, values):
    rec, theta = structure_record(name, values, n=6000, seed=3, rms=0.6, noise=1e-12, process=False)
    res = fit_lsq(OutputError(name, rec, noise="fixed"))
    est = np.array([res.theta[n] for n in get_model(name).free_names("structure")])
    assert np.abs(est / theta - 1).max() < 1e-4


def test_noise_free_spencer_recovery_with_A_fixed():
    """α, A, β, γ share one redundant scale (Ma et al. 2004): A is held at 301, the rest recovered."""
    rec, theta = spencer_record(noise=0.0)
    lik = OutputError("spencer", rec, noise="fixed")
    assert "A" not in lik.par.names
    res = fit_lsq(lik, LSQSettings(n_candidates=32, n_starts=3))
    est = np.array([res.theta[n] for n in lik.par.names])
    assert np.abs(est / theta - 1).max() < 1e-4


@pytest.mark.parametrize("name,values", STRUCTURE_CASES, ids=[c[0] for c in STRUCTURE_CASES])
def test_noisy_structure_recovery_within_reported_uncertainty(name, values):
    """1 % RMS measurement noise on displacement and acceleration."""
    rec, theta = structure_record(name, values, n=10000, seed=3, rms=0.6, noise=0.01, process=False)
    res = fit_lsq(OutputError(name, rec))
    names = get_model(name).free_names("structure")
    est = np.array([res.theta[n] for n in names])
    sd = np.array([res.sd_theta[n] for n in names])
    assert np.all(np.abs(est - theta) <= 3 * sd), dict(zip(names, ((est - theta) / sd).round(2)))
    assert np.all(sd / theta < 0.05)  # and the uncertainty is not trivially wide


def test_noisy_spencer_recovery_within_reported_uncertainty():
    rec, theta = spencer_record(noise=0.01, seed=1, n=6000)
    lik = OutputError("spencer", rec)
    res = fit_lsq(lik, LSQSettings(n_candidates=32, n_starts=3))
    est = np.array([res.theta[n] for n in lik.par.names])
    sd = np.array([res.sd_theta[n] for n in lik.par.names])
    assert np.all(np.abs(est - theta) <= 3 * sd), dict(zip(lik.par.names, ((est - theta) / sd).round(2)))


def test_convex_subfit_recovers_linear_parameters_given_the_nonlinear_ones():
    rec, theta = structure_record("lugre", {}, n=6000, seed=3, rms=0.6, noise=0.01, process=False)
    lik = OutputError("lugre", rec)
    assert linear_names(lik) == ("c", "k", "beta", "epsilon")
    sub = LinearSubfit(lik)
    phi = lik.par.coords.to_phi(theta)
    start = phi.copy()
    start[:4] = lik.phi_lo[:4]  # forget the linear parameters
    fitted, cost = sub.solve(start)
    got = lik.par.coords.to_theta(fitted)
    assert np.abs(got[[1, 2]] / theta[[1, 2]] - 1).max() < 0.01  # k, β well determined by the force
    assert cost < 1.0  # N²: force noise only


def test_laplace_evidence_equals_analytic_evidence_on_linear_gaussian_model():
    """LuGre with α → 0 and only c, k free is linear in (c, k): the Laplace evidence is exact.

    With uniform priors wide enough not to cut the likelihood, the evidence
    of y = A θ + e, e ~ N(0, σ²I) is ∫ N(y; Aθ, σ²I) dθ / V over the box.
    """
    values = dict(beta=5e3, epsilon=30.0, alpha=1e-300)
    rec, theta = structure_record("lugre", {**values, "c": 100.0, "k": 2e4}, n=3000, seed=5, rms=0.6,
                                  noise=0.01, process=False)
    ranges = {"c": (50.0, 200.0), "k": (1e4, 4e4)}
    lik = OutputError("lugre", rec, fixed=values, ranges=ranges, noise="fixed")
    # make the problem exactly linear in θ (not φ): fit in θ by ordinary least squares
    sim0 = lik.predict(lik.par.coords.to_phi(np.array([100.0, 2e4])))[0][0]
    res = fit_lsq(lik)
    # analytic: y = y(θ) is linear in θ = (c, k); columns by exact differences
    th0 = np.array([100.0, 2e4])
    cols = []
    for j in range(2):
        e = th0.copy()
        e[j] *= 1.01
        cols.append((lik.predict(lik.par.coords.to_phi(e))[0][0] - sim0) / (0.01 * th0[j]))
    sd = lik.noise_sd
    A = np.stack([(c[lik.valid] / sd).ravel() for c in cols], axis=1)
    b = ((lik.y[lik.valid] - sim0[lik.valid]) / sd).ravel()
    AtA = A.T @ A
    dth = np.linalg.solve(AtA, A.T @ b)
    rss = float(np.sum((b - A @ dth) ** 2))
    n = b.size
    log_norm = -float(np.sum(np.log(np.broadcast_to(sd, lik.y[lik.valid].shape)))) - 0.5 * n * math.log(2 * math.pi)
    # ∫ exp(−½‖b − A δ‖²) dδ = exp(−½ rss) (2π)^{d/2} |AᵀA|^{−1/2}; prior density in θ is 1/V_θ,
    # but the package's prior is uniform in φ = ln(sθ): p(θ) = 1/(θ · Δφ) per parameter.
    theta_hat = th0 + dth
    log_prior_theta = -float(np.sum(np.log(theta_hat) + np.log(lik.phi_hi - lik.phi_lo)))
    log_z = log_norm - 0.5 * rss + math.log(2 * math.pi) - 0.5 * np.linalg.slogdet(AtA)[1] + log_prior_theta
    assert res.log_evidence == pytest.approx(log_z, abs=0.05)
