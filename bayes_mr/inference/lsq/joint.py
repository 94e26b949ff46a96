"""Least squares over several records: the residuals of every record stacked, one Laplace posterior.

The joint likelihood (:class:`~bayes_mr.likelihood.joint.JointLikelihood`) is
a sum over independent records, so its least-squares problem stacks each
record's standardised residual vector (weighted by that record's σ_r,
prewhitened under its own AR orders) and its Jacobian in the shared φ:

1. **start** — the single-record search (:func:`~.least_squares.search`:
   convex sub-fit screening, starts raced on the head) on the record with
   the most valid samples: the starts need the dynamics, which every record
   of one device shares;
2. **refine** on the stacked residuals from that start, with each record's
   noise floor as weights; under the AR model each record's orders are then
   chosen by BIC on its own residual; re-weighted once by each record's
   maximum-likelihood σ_r and refined again;
3. **Laplace** — J = [J_1; …; J_R], the sandwich (JᵀJ)⁻¹ (Σ_r Ω_r) (JᵀJ)⁻¹
   with each record's middle Ω_r its own (Bartlett-weighted HAC, the GLS JᵣᵀJᵣ
   when its whitened residual is white, widened by its input-noise replicas):
   the records are independent, their residuals autocorrelated within a
   record only. The evidence is that of :func:`~.least_squares.laplace` with
   the log-likelihood summed and one Gaussian ln σ integral per record and channel.

A set of one record is that record: :func:`fit_joint` and :func:`laplace_joint`
return :func:`~.least_squares.fit_lsq`'s and :func:`~.least_squares.laplace`'s numbers.
"""

from __future__ import annotations

import math
import time as _time

import numpy as np

from bayes_mr.inference import calibrate
from bayes_mr.inference.lsq import evidence_scale
from bayes_mr.inference.lsq.least_squares import (
    WHITE_P, LSQResult, LSQSettings, ar_terms, fit_lsq, laplace, ml_sd, peak_from, search)
from bayes_mr.inference.lsq.refine import Residuals, refine
from bayes_mr.likelihood.joint import JointLikelihood
from bayes_mr.likelihood.output_error import OutputError

__all__ = ["JointResiduals", "fit_any", "start_offsets", "fit_joint", "laplace_any", "laplace_joint", "peak_any", "peak_joint"]


class JointResiduals:
    """Every record's :class:`~.refine.Residuals` at a shared φ, stacked (and their Jacobians).

    ``sds``: per record, its channels' weights σ_r [channel units]. ``lik``: the joint likelihood whose φ
    is given, when its records' φ are not all of it (per-record offsets,
    :meth:`~bayes_mr.likelihood.joint.JointLikelihood.part_phi`); None: each record reads φ whole.
    """

    def __init__(self, parts: list[OutputError], sds: list[np.ndarray], lik: JointLikelihood | None = None):
        self.each = [Residuals(p, sd) for p, sd in zip(parts, sds)]
        self.lik = lik if lik is not None and lik.record_offsets else None

    def _phi(self, phi, r):
        return phi if self.lik is None else self.lik.part_phi(phi, r)

    def __call__(self, phi):
        return np.concatenate([f(self._phi(phi, r)) for r, f in enumerate(self.each)])

    @property
    def ok(self) -> bool:
        """Every record simulated at the last evaluation (a failed one gives its penalty residuals)."""
        return all(f.last is not None for f in self.each)

    def jacobian(self, phi, central: bool = False):
        if self.lik is None:
            return np.vstack([f.jacobian(phi, central) for f in self.each])
        return np.vstack([self.lik.scatter(f.jacobian(self._phi(phi, r), central), r)
                          for r, f in enumerate(self.each)])


def fit_any(lik, settings: LSQSettings = LSQSettings(), *, progress=None) -> LSQResult:
    """Least squares of a record's likelihood (:func:`fit_lsq`) or of a joint one (:func:`fit_joint`)."""
    if isinstance(lik, JointLikelihood):
        return fit_joint(lik, settings, progress=progress)
    return fit_lsq(lik, settings, progress=progress)


def fit_joint(lik: JointLikelihood, settings: LSQSettings = LSQSettings(), *, progress=None) -> LSQResult:
    """Least-squares fit of a joint likelihood (module docstring); ``sigma`` is every record's σ_r, in x's order."""
    if len(lik.parts) == 1:
        return fit_lsq(lik.parts[0], settings, progress=progress)
    t0 = _time.perf_counter()
    say = progress or (lambda msg: None)
    lead = max(range(len(lik.parts)), key=lambda r: lik.parts[r].n_valid)
    phi, runs = search(lik.parts[lead], settings, say)
    if lik.record_offsets:
        phi = start_offsets(lik, phi, lead)
        runs = [{**run, **{k: _embedded(lik, run[k], lead) for k in ("phi0", "phi")}} for run in runs]
    say(f"starts searched on record {lead}; refining on all {len(lik.parts)} records")
    sds = [p.noise_sd.copy() for p in lik.parts]
    phi = refine(lik, phi, None, settings.max_nfev, residuals=JointResiduals(lik.parts, sds, lik)).x
    for r, part in enumerate(lik.parts):
        if part.residual.kind == "ar" and not part.residual.resolved:
            part.choose_residual_orders(lik.part_phi(phi, r))
    if settings.reweight:
        sds = [ml_sd(p, p.predict(lik.part_phi(phi, r))[0][0]) for r, p in enumerate(lik.parts)]
        phi = refine(lik, phi, None, settings.max_nfev, residuals=JointResiduals(lik.parts, sds, lik)).x
    return laplace_joint(lik, phi, starts=runs, wall_s=_time.perf_counter() - t0,
                         replicas=settings.input_noise_replicas)


def _embedded(lik: JointLikelihood, phi_lead: np.ndarray, lead: int) -> np.ndarray:
    """The lead record's φ as a joint φ: the other records' offsets at 0, where the search left them (it ran on
    the lead record alone)."""
    out = np.zeros(lik.n_params)
    out[lik.index[lead]] = phi_lead
    return out


def start_offsets(lik: JointLikelihood, phi_lead: np.ndarray, lead: int) -> np.ndarray:
    """The joint φ from the lead record's optimum ``phi_lead``: its shared parameters and offset, and every other
    record's offset at its mean force residual there (the least-squares offset of an additive constant)."""
    p = lik.n_params
    phi = np.zeros(p)
    phi[lik.index[lead]] = phi_lead
    coords = lik.par.coords
    for r, part in enumerate(lik.parts):
        if r == lead:
            continue
        at = lik.part_phi(phi, r).copy()
        j = int(np.flatnonzero(lik.index[r] == p - len(lik.parts) + r)[0])
        at[j] = 0.0
        yhat, sim = part.predict(at)
        f0 = float(np.mean((part.y - yhat[0])[part.valid, part.channels.index("force")])) if sim.ok[0] else 0.0
        k = p - len(lik.parts) + r
        phi[k] = np.clip(coords.to_phi(np.full(p, f0))[k], lik.phi_lo[k], lik.phi_hi[k])
    return phi


def _record_terms(part: OutputError, phi: np.ndarray, sampled: bool, replicas: int) -> dict:
    """One record's share of the joint Laplace approximation at φ (record r's own φ, :meth:`~bayes_mr.likelihood.
    joint.JointLikelihood.part_phi`): σ, J, JᵀJ, Ω, ln p, evidence counts; J by that record's φ."""
    yhat, _ = part.predict(phi)
    ar = part.residual.kind == "ar"
    if ar:
        part.choose_residual_orders(phi)
    sigma = ml_sd(part, yhat[0]) if sampled else np.asarray(part.noise_sd, float)
    rf = Residuals(part, sigma)
    r = rf(phi)
    J = rf.jacobian(phi, central=True)
    n_c = int(part.valid.sum())
    out = {"sigma": sigma, "J": J, "JtJ": J.T @ J, "occam": 0.0, "p_white": None, "n_terms": np.full(sigma.size, n_c),
           "n_coef": int(sum(part.residual.orders)) if ar else 0, "input_noise": None}
    if ar:
        out["loglik"], out["occam"], out["n_terms"], out["p_white"] = ar_terms(part, yhat[0], sigma)
    else:
        resid = (part.y - yhat[0])[part.valid]
        out["loglik"] = float(np.sum(-0.5 * (resid / sigma) ** 2 - np.log(sigma) - 0.5 * math.log(2 * math.pi)))
    if ar and out["p_white"] >= WHITE_P:
        out["omega"], out["lag"] = out["JtJ"], 0  # whitened residuals are white: the GLS middle
    else:
        out["omega"], out["lag"] = calibrate.hac_middle(J, r, n_c)
    if replicas > 0 and calibrate.input_noise_sd(part):
        rep, out["input_noise"] = calibrate.replica_middle(part, phi, J, sigma, n=replicas)
        out["omega"] = calibrate.loewner_max(rep, out["omega"])
    return out


def laplace_joint(lik: JointLikelihood, phi: np.ndarray, *, starts=None, wall_s: float = 0.0,
                  replicas: int = calibrate.N_DRAWS) -> LSQResult:
    """Laplace covariance and evidence of a joint likelihood at φ (module docstring, step 3)."""
    if len(lik.parts) == 1:
        return laplace(lik.parts[0], phi, starts=starts, wall_s=wall_s, replicas=replicas)
    sampled = lik.noise == "sampled"
    each = [_record_terms(p, lik.part_phi(phi, r), sampled, replicas) for r, p in enumerate(lik.parts)]
    if lik.record_offsets:  # each record's J and Ω by the joint φ: zero rows and columns at the others' offsets
        for r, e in enumerate(each):
            e["J"] = lik.scatter(e["J"], r)
            e["JtJ"] = e["J"].T @ e["J"]
            S = lik.scatter(np.eye(lik.index[r].size), r)
            e["omega"] = S.T @ e["omega"] @ S
    J = np.vstack([e["J"] for e in each])
    JtJ = sum(e["JtJ"] for e in each)
    cov = calibrate.sandwich(J, sum(e["omega"] for e in each))
    cov_iid = np.linalg.pinv(JtJ)
    sigma = np.concatenate([e["sigma"] for e in each])
    widths = lik.phi_hi - lik.phi_lo
    cov, cov_iid = (calibrate.prior_on_unseen(c, JtJ, widths) for c in (cov, cov_iid))
    log_prior = -float(np.sum(np.log(widths))) + sum(e["occam"] for e in each)
    if sampled:
        log_prior += -float(np.sum(lik.log_sigma_hi - lik.log_sigma_lo)) + 0.5 * sigma.size * math.log(2 * math.pi)
    loglik = float(sum(e["loglik"] for e in each))
    terms = evidence_scale.LaplaceTerms(
        loglik, log_prior, *evidence_scale.volume_terms(JtJ, widths), n_coef=sum(e["n_coef"] for e in each),
        sigma_counts=np.concatenate([np.asarray(e["n_terms"], float) for e in each]) if sampled else None,
        trace_hc=evidence_scale.trace_hc(JtJ, cov))
    cov, cov_iid = (calibrate.within_prior(c, widths) for c in (cov, cov_iid))
    coords = lik.par.coords
    sd_theta = coords.dtheta_dphi(phi) * np.sqrt(np.clip(np.diag(cov), 0, None))
    whites = [e["p_white"] for e in each if e["p_white"] is not None]
    shares = [e["input_noise"] for e in each]
    eiv = None if all(s is None for s in shares) else {
        "n_replicas": replicas,
        "input_share": [v for s in shares for v in (s["input_share"] if s else [0.0] * len(lik.channels))]}
    return LSQResult(
        phi=phi, theta=dict(zip(coords.names, coords.to_theta(phi))), cov_phi=cov, cov_phi_iid=cov_iid,
        sd_theta=dict(zip(coords.names, sd_theta)), sigma=sigma, log_likelihood=loglik,
        log_evidence=float(terms.log_evidence(1.0)), starts=list(starts or []), wall_s=wall_s,
        hac_lag=max(e["lag"] for e in each), whiteness_p=min(whites) if whites else None, input_noise=eiv,
        evidence_terms=terms)


def peak_joint(lik: JointLikelihood, phi0: np.ndarray, max_nfev: int) -> dict:
    """:func:`~.least_squares.peak_from` of a joint likelihood: its local peak downhill from ``phi0``.

    Each record's residuals are weighted by its noise floor, or (``noise="sampled"``) by its
    maximum-likelihood σ_r at ``phi0``; the refinement runs on the stacked residuals.
    """
    if len(lik.parts) == 1:
        return peak_from(lik.parts[0], phi0, max_nfev)
    phi0 = np.asarray(phi0, float)
    sds = [ml_sd(p, p.predict(lik.part_phi(phi0, r))[0][0]) if lik.noise == "sampled"
           else np.asarray(p.noise_sd, float) for r, p in enumerate(lik.parts)]
    fn = JointResiduals(lik.parts, sds, lik)
    r0 = fn(phi0)
    cost0 = 0.5 * float(np.sum(r0**2)) if fn.ok else math.inf
    res = refine(lik, phi0, None, max_nfev, residuals=JointResiduals(lik.parts, sds, lik))
    improved = bool(np.all(np.isfinite(res.x)) and res.cost < cost0)
    phi = res.x if improved else phi0
    return {"phi": phi, "delta": phi - phi0, "nfev": int(res.nfev), "improved": improved}


def peak_any(lik, phi0: np.ndarray, max_nfev: int) -> dict:
    """The likelihood's local peak from ``phi0`` (:func:`peak_joint` or :func:`~.least_squares.peak_from`)."""
    return peak_joint(lik, phi0, max_nfev) if isinstance(lik, JointLikelihood) else peak_from(lik, phi0, max_nfev)


def laplace_any(lik, phi: np.ndarray) -> LSQResult:
    """Laplace covariance and evidence at φ (:func:`laplace_joint` or :func:`~.least_squares.laplace`)."""
    return laplace_joint(lik, phi) if isinstance(lik, JointLikelihood) else laplace(lik, phi)
