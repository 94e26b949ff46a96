"""Bayes factors under model error: the magnitude-adjusted Laplace evidence.

The evidence of :func:`bayes_mr.inference.lsq.least_squares.laplace` is that of the working
likelihood (iid, or AR by BIC per channel). When the model is wrong the
residual is smooth in time, and between two wrong forms ln Z₁ − ln Z₂ ≈
(N/2)·ln(SSR₂/SSR₁) grows with the number of samples N — with the *sampling
rate* at a fixed record length — instead of with the information the record
holds. ``studies/bayes_factor_rate.py`` measures it (structure tests, 3 s, 2 %
noise on input and outputs, a hidden effect): under ``iid`` the raw |ln BF| of
dahl against normalized Bouc–Wen grows ×17 from 250 Hz to 4 kHz, the calibrated
one below ×1.04 (medians of 8 records); under ``ar`` the raw one does not grow
but wanders (its sign changes with the rate on 2 of 8 records).

The calibrated covariance C of the estimate (the sandwich of
:mod:`.calibrate`, which includes the residual's autocorrelation and the
model's response to input noise) says how much the record really determines
φ. The magnitude adjustment of a misspecified or composite likelihood (Pauli,
Racugno & Ventura 2011; Ribatet, Cooley & Davison 2012) raises the likelihood
to the power

    k = p / tr(H C),   H = JᵀJ (the working likelihood's Gauss–Newton information),

so that the adjusted posterior's curvature k·H matches C⁻¹ on average over
the p directions (k = 1 when the working likelihood is right: C = H⁻¹). Its
Laplace evidence is

    ln Z_k = k ln L̂ + ln π(φ̂) + Σ_i min(½ ln 2π − ½ ln(k λ_i), ln w_i) + [σ, AR terms at curvature × k],

the package's own Laplace evidence (box-bounded volume, σ and AR-coefficient
Laplace factors) with every curvature multiplied by k; at k = 1 it is the raw
evidence exactly (:class:`LaplaceTerms` is what ``lsq.laplace`` computes its
ln Z from).

**One k per comparison.** Each model gets its own k, but a Bayes factor
must not use two: k₁ ln L̂₁ − k₂ ln L̂₂ depends on the units of the data
(ln L̂ of a density shifts by −N ln a when the channel is rescaled by a, and
the shift cancels only when both are multiplied by the same k). ``compare``
therefore evaluates every model at the pooled scale
k̄ = Σ_m p_m / Σ_m tr(H_m C_m) (:func:`common_scale`): the same
information-per-nat factor for every candidate on the record, the mean of
the models' own curvature ratios weighted by their dimension.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

LOG_2PI = math.log(2.0 * math.pi)


def volume_terms(JtJ: np.ndarray, widths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(eigenvalues λ_i of JᵀJ, ln of the prior box's extent w_i along each eigenvector).

    ``widths``: the box widths hi − lo in φ. See :func:`log_volume`.
    """
    eig, vec = np.linalg.eigh(JtJ)
    return eig, np.log(np.abs(vec).T @ np.asarray(widths, float))


def log_volume(eig: np.ndarray, box: np.ndarray, k: float = 1.0) -> float:
    """ln of the Laplace posterior volume of curvature k·JᵀJ, each direction bounded by the prior box.

    The Laplace evidence multiplies the likelihood's peak by the volume
    (2π)^{d/2} |k JᵀJ|^{-1/2} = Π_i √(2π) σ_i over the eigen-directions v_i
    of JᵀJ (σ_i = (k λ_i)^{-1/2}). A direction the data cannot see has
    λ_i → 0 and an unbounded σ_i, yet the prior is uniform on a box: the
    likelihood cannot be integrated over more than the box's extent along v_i,
    w_i = Σ_j |v_ij| (hi_j − lo_j). Each direction therefore contributes
    min(√(2π) σ_i, w_i), so an unidentified parameter gains nothing (its ln w
    cancels its prior's −ln w).
    """
    with np.errstate(divide="ignore"):
        gauss = 0.5 * LOG_2PI - 0.5 * np.log(np.clip(k * np.asarray(eig, float), 0.0, None))
    return float(np.sum(np.minimum(gauss, np.asarray(box, float))))


@dataclass(frozen=True)
class LaplaceTerms:
    """The pieces of a Laplace evidence, so that it can be evaluated for the likelihood raised to a power k.

    Attributes
    ----------
    log_likelihood : float
        ln p(y | φ̂, σ̂) of the working likelihood [nats].
    log_prior : float
        Everything that does not scale with k: ln π(φ̂), the σ prior and its
        ½ c ln 2π, the AR coefficients' Laplace factor at k = 1 [nats].
    eig, box : ndarray (p,)
        Eigenvalues of JᵀJ and the ln box extents along its eigenvectors (:func:`volume_terms`).
    n_coef : int
        AR coefficients integrated out (their factor changes by −½ n_coef ln k).
    sigma_counts : ndarray (c,) or None
        Terms N_c of each channel's ln σ_c curvature 2 N_c (None: σ held fixed).
    trace_hc : float
        tr(JᵀJ C) with C the reported (calibrated) covariance of φ.
    """

    log_likelihood: float
    log_prior: float
    eig: np.ndarray
    box: np.ndarray
    n_coef: int = 0
    sigma_counts: np.ndarray | None = None
    trace_hc: float = float("nan")

    @property
    def n_params(self) -> int:
        """Dimension p of φ."""
        return int(np.asarray(self.eig).size)

    @property
    def scale(self) -> float:
        """This model's own k = min(1, p / tr(H C)) (1 when C = H⁻¹; NaN when the trace is unknown).

        Capped at 1: the adjustment only ever tempers the working likelihood (a
        sandwich narrower than H⁻¹ is its estimate's noise, not extra information).
        """
        t = float(self.trace_hc)
        return min(1.0, self.n_params / t) if math.isfinite(t) and t > 0 else float("nan")

    def log_evidence(self, k: float = 1.0) -> float:
        """Laplace ln Z of the working likelihood raised to the power ``k`` [nats] (k = 1: the raw evidence)."""
        log_z = k * self.log_likelihood + self.log_prior + log_volume(self.eig, self.box, k)
        if k != 1.0:
            log_z -= 0.5 * self.n_coef * math.log(k)
        if self.sigma_counts is not None:
            log_z -= 0.5 * float(np.sum(np.log(2.0 * k * np.asarray(self.sigma_counts, float))))
        return float(log_z)

    def to_dict(self) -> dict:
        """JSON-ready form (the fit JSON's ``evidence_calibration``)."""
        return {"log_likelihood": float(self.log_likelihood), "log_prior": float(self.log_prior),
                "eig": [float(v) for v in self.eig], "box": [float(v) for v in self.box],
                "n_coef": int(self.n_coef), "trace_hc": float(self.trace_hc),
                "sigma_counts": None if self.sigma_counts is None else [float(v) for v in self.sigma_counts]}

    @classmethod
    def from_dict(cls, d: dict) -> "LaplaceTerms":
        """Inverse of :meth:`to_dict`."""
        counts = d.get("sigma_counts")
        return cls(float(d["log_likelihood"]), float(d["log_prior"]), np.asarray(d["eig"], float),
                   np.asarray(d["box"], float), int(d.get("n_coef", 0)),
                   None if counts is None else np.asarray(counts, float), float(d.get("trace_hc", math.nan)))


def trace_hc(JtJ: np.ndarray, cov: np.ndarray) -> float:
    """tr(JᵀJ C): p when C = (JᵀJ)⁻¹, larger when C is wider than the working likelihood's curvature says."""
    return float(np.sum(JtJ * cov.T))


def calibration_info(terms: LaplaceTerms | None) -> dict:
    """The fit JSON's ``evidence_scale`` (own k), ``log_evidence_calibrated`` (at it) and ``evidence_calibration``."""
    if terms is None or not math.isfinite(terms.scale):
        return {}
    return {"evidence_scale": terms.scale, "log_evidence_calibrated": terms.log_evidence(terms.scale),
            "evidence_calibration": terms.to_dict()}


def common_scale(terms: list[LaplaceTerms]) -> float:
    """The pooled k̄ = min(1, Σ p_m / Σ tr(H_m C_m)) of the models of one comparison (module docstring)."""
    p = sum(t.n_params for t in terms)
    tr = sum(float(t.trace_hc) for t in terms)
    return min(1.0, p / tr) if tr > 0 and math.isfinite(tr) else float("nan")


def at_common_scale(terms: dict[str, LaplaceTerms]) -> tuple[float, dict[str, float]] | None:
    """k̄ of :func:`common_scale` and each model's ln Z_k̄ [nats] (name → value); None when k̄ is not finite."""
    k = common_scale(list(terms.values()))
    if not math.isfinite(k):
        return None
    return k, {m: t.log_evidence(k) for m, t in terms.items()}
