"""Least-squares baseline: output-error fit, Laplace covariance and evidence.

1. **Starting values by a convex sub-fit** of the parameters the force is
   linear in, given the nonlinear ones (:mod:`.subfit`): Latin-hypercube
   candidates of the nonlinear parameters are screened this way and the best
   become starts.
2. **Output-error least squares** (``scipy.optimize.least_squares``, trust
   region reflective, bounded by the plausible box) on the simulation
   residuals in the estimation coordinates φ, from each start; residuals are
   weighted by the noise SD of each channel, then re-weighted once by the
   residual RMS (the maximum-likelihood σ_c when σ is unknown). On a long
   record (more than ``head_samples`` samples) steps 1–2 run on the record's
   head and the starts race (successive halving): each gets an eighth of
   ``max_nfev``, the better half continues with twice the budget, and so on
   until one is left, which is refined on the whole record. The search among
   starts needs the dynamics, not every period of a stationary test, and a
   ranking after a few evaluations is unreliable (a start still far from its
   optimum may be in the right basin), so starts are dropped gradually; the
   estimate, its covariance and evidence are still the whole record's.
   While racing, simulations get at most ``search_substeps`` RK4
   sub-steps per sample interval, and a candidate or start whose simulation
   saturates that cap on more than :data:`~.subfit.STIFF_FRACTION` of the intervals is rejected as a start (its dynamics
   are far faster than the sampling resolves; simulating it with the kernel's 400 sub-steps costs 30–90 s per
   evaluation on the Bouc–Wen benchmark). Only the final refinement simulates with the full sub-step range.
3. **Laplace approximation** at the optimum: Cov(φ) = (JᵀJ)⁻¹ with J the
   Jacobian of the σ̂-standardised residuals (exact from the forward
   sensitivities where the model has them, else central differences on a
   replayed sub-step schedule; :class:`~bayes_mr.inference.lsq.refine.Residuals`). Residuals of a dynamic model are
   autocorrelated (process noise, model error), and (JᵀJ)⁻¹ then understates
   the uncertainty many times over; the reported covariance is the
   heteroskedasticity-and-autocorrelation-consistent sandwich
   (JᵀJ)⁻¹ Ω (JᵀJ)⁻¹ with a Bartlett-weighted Ω (Newey & West 1987) whose
   bandwidth is where the residual autocorrelation dies out. When the
   record's input is measured with noise, the sandwich's middle is widened,
   direction by direction, to that of replicas of the model's response to the
   input noise (errors in variables, :mod:`.calibrate`): a Bartlett middle
   with a bandwidth the record can afford misses most of it. The evidence is
   ln Z ≈ ln p(y|φ̂,σ̂) + ln p(φ̂) + ln p(σ̂) + ½(d+c) ln 2π + ½ ln|Σ_φ| − ½ Σ_c ln(2 N_c),
   with the same priors as :class:`~bayes_mr.likelihood.output_error.OutputError`. Its terms
   (:class:`~bayes_mr.inference.lsq.evidence_scale.LaplaceTerms`) also give the calibrated
   evidence of the likelihood raised to k = p / tr(JᵀJ Cov(φ)) (:mod:`.evidence_scale`).
4. **Under the AR residual model** (``OutputError(..., residual="ar")``,
   :mod:`bayes_mr.likelihood.noise_model`) steps 1–2 are the first, iid fit; its
   residual chooses each channel's AR order (BIC), and the re-weighted
   refinement minimises the *prewhitened* residuals with profiled AR
   coefficients — generalised least squares, the maximum of the conditional
   AR likelihood. When the Ljung–Box test finds every channel's whitened
   residual white (p ≥ :data:`WHITE_P`), Cov(φ) is the GLS (JᵀJ)⁻¹ of the
   whitened residuals, with no sandwich; otherwise the HAC sandwich of the
   whitened residuals. The evidence adds the AR coefficients' Laplace factor
   (:func:`~bayes_mr.likelihood.noise_model.coefficient_log_occam`) and counts N_c as
   the conditional likelihood's terms.
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import dataclass, field

import numpy as np

from bayes_mr.likelihood import noise_model
from bayes_mr.execution.executor import side_by_side
from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.inference import calibrate
from bayes_mr.inference.lsq import evidence_scale
from bayes_mr.inference.calibrate import hac_covariance
from bayes_mr.inference.lsq.memo import simulated
from bayes_mr.inference.lsq.refine import Residuals, refine, standardised
from bayes_mr.inference.lsq.subfit import screen

__all__ = ["LSQResult", "LSQSettings", "WHITE_P", "fit_lsq", "laplace", "ml_sd", "peak_from", "posterior_log_volume",
           "search"]

#: Ljung–Box p-value above which a whitened residual counts as white (no HAC sandwich needed).
WHITE_P = 0.01


@dataclass(frozen=True)
class LSQSettings:
    """Least-squares settings.

    Attributes
    ----------
    n_candidates : int
        Latin-hypercube candidates of the nonlinear parameters screened by the
        convex sub-fit.
    n_starts : int
        Best candidates refined by nonlinear least squares.
    max_nfev : int
        Most residual evaluations per start.
    seed : int
        Seed of the candidates.
    reweight : bool
        Re-weight channels by their residual RMS after the first fit.
    head_samples : int or None
        Records longer than this search among starts on their first
        ``head_samples`` samples and refine the best on the whole record
        (None: every start on the whole record).
    search_substeps : int or None
        Most RK4 sub-steps per sample interval while a long record's starts
        are screened and raced on its head; a parameter set saturating it on
        more than :data:`~.subfit.STIFF_FRACTION` of the intervals is rejected as a
        start (None: the kernel's own maximum, nothing rejected).
    input_noise_replicas : int
        Replicas of the response to the input's noise in the covariance's
        middle (:mod:`.calibrate`); 0 keeps the HAC/GLS covariance alone.
    exact_jacobian : bool
        Jacobians from the forward sensitivities where the model has them
        (:class:`~bayes_mr.inference.lsq.refine.Residuals`: one run instead of
        p + 1, and exact); False: finite differences everywhere.
    """

    n_candidates: int = 48
    n_starts: int = 4
    max_nfev: int = 200
    seed: int = 0
    reweight: bool = True
    head_samples: int | None = 8192
    search_substeps: int | None = 32
    input_noise_replicas: int = calibrate.N_DRAWS
    exact_jacobian: bool = True


@dataclass
class LSQResult:
    """Outcome of :func:`fit_lsq`.

    Attributes
    ----------
    phi : ndarray (p,)
        Optimum in estimation coordinates.
    theta : dict
        Optimum, name → value [SI] (free parameters).
    cov_phi : ndarray (p, p)
        Covariance of φ (autocorrelation-consistent sandwich; with noise on
        the record's input, its middle widened by the input-noise replicas).
    cov_phi_iid : ndarray (p, p)
        (JᵀJ)⁻¹: the covariance if residuals were independent.
    sd_theta : dict
        Delta-method standard deviations [SI].
    sigma : ndarray (n_channels,)
        Residual RMS per measured channel (ML noise SD).
    log_likelihood, log_evidence : float
        At the optimum, and the Laplace evidence.
    starts : list of dict
        Each start: initial φ, final φ, cost, nfev, status.
    input_noise : dict or None
        :func:`.calibrate.replica_middle`'s info when the input's noise
        entered the covariance (``input_share`` per channel, ``n_replicas``).
    evidence_terms : LaplaceTerms or None
        The pieces of ``log_evidence`` (:mod:`.evidence_scale`), for the
        magnitude-adjusted (calibrated) evidence.
    """

    phi: np.ndarray
    theta: dict[str, float]
    cov_phi: np.ndarray
    cov_phi_iid: np.ndarray
    sd_theta: dict[str, float]
    sigma: np.ndarray
    log_likelihood: float
    log_evidence: float
    starts: list[dict] = field(default_factory=list)
    wall_s: float = 0.0
    hac_lag: int = 0
    whiteness_p: float | None = None
    input_noise: dict | None = None
    evidence_terms: evidence_scale.LaplaceTerms | None = None


# --- nonlinear least squares -----------------------------------------------------------


def peak_from(lik: OutputError, phi0: np.ndarray, max_nfev: int) -> dict:
    """The likelihood's local peak reached downhill from ``phi0`` (bounded trust-region least squares).

    How far another estimator's answer (the UKF's) lies from the output-error
    likelihood's own optimum. Residuals are weighted by the record's noise SDs,
    or (``noise="sampled"``) by their maximum-likelihood values at ``phi0``.

    Returns
    -------
    dict
        ``phi`` the peak [φ], ``delta`` = phi − phi0 [φ], ``nfev`` the model
        evaluations used and ``improved`` (False: no lower cost was found and
        delta is zero).
    """
    phi0 = np.asarray(phi0, float)
    yhat, sim = lik.predict(phi0)  # one simulation for σ and the starting cost
    sd = ml_sd(lik, yhat[0]) if lik.noise == "sampled" else np.asarray(lik.noise_sd, float)
    r0 = standardised(lik, yhat[0], sd)
    cost0 = 0.5 * float(np.sum(r0**2)) if sim.ok[0] and np.all(np.isfinite(r0)) else math.inf
    res = refine(lik, phi0, sd, max_nfev)
    improved = bool(np.all(np.isfinite(res.x)) and res.cost < cost0)
    phi = res.x if improved else phi0
    return {"phi": phi, "delta": phi - phi0, "nfev": int(res.nfev), "improved": improved}


def fit_lsq(lik: OutputError, settings: LSQSettings = LSQSettings(), *, progress=None) -> LSQResult:
    """Least-squares fit of ``lik``'s model to its record (see module docstring).

    Parameters
    ----------
    lik : OutputError
        Model and record (its ``noise_sd`` weights the first pass).
    settings : LSQSettings
    progress : callable, optional
        Called with a short text after each stage.

    Returns
    -------
    LSQResult
    """
    t0 = _time.perf_counter()
    say = progress or (lambda msg: None)
    phi, runs = search(lik, settings, say)
    sd = lik.noise_sd.copy()
    if lik.residual.kind == "ar" and not lik.residual.resolved:
        say(f"AR orders {lik.choose_residual_orders(phi)} (BIC on the iid fit's residual)")
    if settings.reweight:
        yhat, _ = simulated(lik, phi)
        sd = ml_sd(lik, yhat[0])
        res = refine(lik, phi, sd, settings.max_nfev, exact=settings.exact_jacobian)
        phi = res.x
    return laplace(lik, phi, starts=runs, wall_s=_time.perf_counter() - t0,
                   replicas=settings.input_noise_replicas, exact=settings.exact_jacobian)


def search(lik: OutputError, settings: LSQSettings, say) -> tuple[np.ndarray, list[dict]]:
    """Steps 1–2 of the module docstring: the best start refined with the first-pass weights, and every start.

    On a record longer than ``settings.head_samples`` the starts race on its head and the winner is
    refined on the whole record. ``say`` is called with a short text after each stage.
    """
    n = lik.y.shape[0]
    if settings.head_samples is None or n <= settings.head_samples:
        runs = _search(lik, settings, say, settings.max_nfev)
        return min(runs, key=lambda r: r["cost"])["phi"], runs
    # the starts race on the head (an eighth of the evaluations each, then the better half twice as many, …)
    head = _head(lik, settings.head_samples)
    runs = _search(head, settings, say, max(settings.max_nfev // 8, 1), race=True)
    phi = refine(lik, min(runs, key=lambda r: r["cost"])["phi"], lik.noise_sd.copy(), settings.max_nfev,
                 exact=settings.exact_jacobian).x
    say(f"best start (raced on the first {settings.head_samples} samples) refined on all {n}")
    return phi, runs


def _head(lik: OutputError, n: int) -> OutputError:
    """The same likelihood (coordinates, noise, fixed parameters) on the first ``n`` samples of the record."""
    rec = lik.record.isel(time=slice(0, n))
    return OutputError(lik.model, rec, ranges=lik.ranges, fixed=lik.fixed, noise=lik.noise,
                       noise_sd=lik.noise_sd, scales=lik.scales)


def _search(lik: OutputError, settings: LSQSettings, say, max_nfev: int, race: bool = False) -> list[dict]:
    """Steps 1–2 of the module docstring: screen candidates, refine the best ``n_starts``; one dict per start.

    ``race``: successive halving — every start gets ``max_nfev`` evaluations,
    the better half continues with twice as many, until one start is left.
    Otherwise every start gets ``max_nfev`` once.
    """
    # the cost cap matters where evaluations are expensive: the race on a long record's head (a short record
    # keeps the kernel's own sub-step range, so its starts are what they always were)
    cap = settings.search_substeps if race else None
    starts = screen(lik, settings.n_candidates, settings.n_starts, settings.seed, cap)
    say(f"screened {settings.n_candidates + 1} candidates")
    runs = [{"start": i + 1, "phi0": phi0, "phi": phi0, "cost": np.inf, "nfev": 0, "status": 0, "message": ""}
            for i, phi0 in enumerate(starts)]
    alive, budget = list(runs), max_nfev
    while alive:  # the starts side by side (independent refinements: the same numbers as in turn)
        done = side_by_side(refine, [(lik, run["phi"], lik.noise_sd.copy(), budget, cap, None, settings.exact_jacobian)
                                     for run in alive])
        for run, res in zip(alive, done):
            run.update(phi=res.x, cost=float(res.cost), nfev=run["nfev"] + int(res.nfev), status=int(res.status),
                       message=str(res.message))
            say(f"start {run['start']}/{len(runs)}: cost {res.cost:.4g} after {run['nfev']} evaluations")
        if not race or len(alive) == 1:
            break
        alive = sorted(alive, key=lambda r: r["cost"])[: (len(alive) + 1) // 2]
        budget *= 2
    return runs


def ml_sd(lik: OutputError, yhat: np.ndarray) -> np.ndarray:
    """Maximum-likelihood σ_c at a prediction (N, C): the residual RMS, under AR the innovation RMS.

    Floored at 1e-12 of each channel's SD, so that a perfect fit still weights its residuals."""
    if lik.residual.kind == "iid":
        sd = np.sqrt(np.mean((lik.y - yhat)[lik.valid] ** 2, axis=0))
    else:
        white = lik.whiten(np.where(lik.valid[:, None], lik.y - yhat, 0.0))
        sd = np.sqrt(np.sum(white**2, axis=0) / noise_model.counts(lik.valid, lik.residual.orders))
    return np.maximum(sd, 1e-12 * np.std(lik.y[lik.valid], axis=0))


def ar_terms(lik: OutputError, yhat: np.ndarray, sigma: np.ndarray) -> tuple[float, float, np.ndarray, float]:
    """Under the AR model: (ln p(y|φ̂,σ̂), the AR coefficients' Laplace factor, the terms per channel,
    the smallest Ljung–Box p-value of the channels' whitened residuals)."""
    orders = lik.residual.orders
    full = np.where(lik.valid[:, None], lik.y - yhat, 0.0)
    white = lik.whiten(full)
    loglik = float(lik.log_density(yhat[None], sigma[None], np.array([True]))[0])
    occam = noise_model.coefficient_log_occam(full, lik.valid, orders, sigma)
    p_white = min(noise_model.ljung_box(white[noise_model.usable(lik.valid, p), c], p)
                  for c, p in enumerate(orders))
    return loglik, occam, noise_model.counts(lik.valid, orders), p_white


def posterior_log_volume(JtJ: np.ndarray, widths: np.ndarray) -> float:
    """ln of the Laplace posterior volume, each direction bounded by the prior box
    (:func:`bayes_mr.inference.lsq.evidence_scale.log_volume`: an unidentified parameter gains nothing).

    Parameters
    ----------
    JtJ : ndarray, shape (d, d)
        Gauss–Newton information of the standardised residuals in φ.
    widths : ndarray, shape (d,)
        Prior box widths hi − lo in φ.
    """
    return evidence_scale.log_volume(*evidence_scale.volume_terms(JtJ, widths))


def laplace(lik: OutputError, phi: np.ndarray, *, starts=None, wall_s: float = 0.0,
            replicas: int = calibrate.N_DRAWS, exact: bool = True) -> LSQResult:
    """Laplace covariance and evidence of ``lik`` at φ (an optimum); GLS under the AR model.

    J is exact where the model has sensitivities (``exact``, :class:`~bayes_mr.inference.lsq.refine.Residuals`),
    else central differences.

    When the record's input carries noise, the covariance's middle is the
    larger (direction by direction) of the HAC/GLS one and that of ``replicas``
    replicas of the model's response to the input noise (:mod:`.calibrate`).
    """
    yhat, _ = simulated(lik, phi)
    resid = (lik.y - yhat[0])[lik.valid]
    n_c = resid.shape[0]
    sampled = lik.noise == "sampled"
    ar = lik.residual.kind == "ar"
    if ar:
        lik.choose_residual_orders(phi)
    # sampled: σ_c at its maximum-likelihood value, the residual (under AR: innovation) RMS
    sigma = ml_sd(lik, yhat[0]) if sampled else np.asarray(lik.noise_sd, float)
    rf = Residuals(lik, sigma, exact=exact)
    r = rf(phi)
    J = rf.jacobian(phi, central=True)
    JtJ = J.T @ J
    cov_iid = np.linalg.pinv(JtJ)
    p_white, occam, n_terms = None, 0.0, np.full(sigma.size, n_c)
    if ar:
        loglik, occam, n_terms, p_white = ar_terms(lik, yhat[0], sigma)
    else:
        loglik = float(np.sum(-0.5 * (resid / sigma) ** 2 - np.log(sigma) - 0.5 * math.log(2 * math.pi)))
    if ar and p_white >= WHITE_P:
        cov, lag = cov_iid, 0  # the AR model whitened the residual: GLS needs no sandwich
    else:
        cov, lag = hac_covariance(J, r, n_c)
    cov, eiv = _with_input_noise(lik, phi, J, sigma, cov, replicas)
    widths = lik.phi_hi - lik.phi_lo
    cov, cov_iid = (calibrate.prior_on_unseen(c, JtJ, widths) for c in (cov, cov_iid))
    log_prior = -float(np.sum(np.log(widths))) + occam
    if sampled:
        # log-uniform σ prior, and the Gaussian integral over ln σ_c (curvature 2 N_c at the optimum)
        log_prior += -float(np.sum(lik.log_sigma_hi - lik.log_sigma_lo)) + 0.5 * sigma.size * math.log(2 * math.pi)
    terms = evidence_scale.LaplaceTerms(
        loglik, log_prior, *evidence_scale.volume_terms(JtJ, widths),
        n_coef=int(sum(lik.residual.orders)) if ar else 0,
        sigma_counts=np.asarray(n_terms, float) if sampled else None, trace_hc=evidence_scale.trace_hc(JtJ, cov))
    cov, cov_iid = (calibrate.within_prior(c, widths) for c in (cov, cov_iid))  # reported: no wider than the box
    log_z = terms.log_evidence(1.0)
    coords = lik.par.coords
    sd_phi = np.sqrt(np.clip(np.diag(cov), 0, None))
    sd_theta = coords.dtheta_dphi(phi) * sd_phi
    return LSQResult(
        phi=phi,
        theta=dict(zip(coords.names, coords.to_theta(phi))),
        cov_phi=cov,
        cov_phi_iid=cov_iid,
        sd_theta=dict(zip(coords.names, sd_theta)),
        sigma=sigma,
        log_likelihood=loglik,
        log_evidence=float(log_z),
        starts=list(starts or []),
        wall_s=wall_s,
        hac_lag=lag,
        whiteness_p=p_white,
        input_noise=eiv,
        evidence_terms=terms,
    )


def _with_input_noise(lik: OutputError, phi, J, sigma, cov, replicas: int) -> tuple[np.ndarray, dict | None]:
    """``cov`` with the input-noise replicas' middle where that is larger (:mod:`.calibrate`)."""
    if replicas <= 0 or not calibrate.input_noise_sd(lik):
        return cov, None
    omega, info = calibrate.replica_middle(lik, phi, J, sigma, n=replicas)
    B = J.T @ J
    return calibrate.sandwich(J, calibrate.loewner_max(omega, B @ cov @ B)), info
