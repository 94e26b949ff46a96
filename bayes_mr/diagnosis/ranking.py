"""Which effect explains the record: passing candidates ranked by what they explain, and ties said as such.

Significance (:func:`.screen.passes`: the κ-corrected score over the threshold, and a lower error) decides
*whether* an effect is there. It does not say *which* of two passing effects explains the record: each
score is divided by the candidate's own design effect κ, an estimate that moves with the fit, so two
scores are not on one scale. Candidates that pass are ranked by Δℓ, the log-likelihood each adds to the
same base on the same record — the order one common inflation factor for the whole round gives, since
dividing every Δℓ by the same κ keeps their order. A candidate that removes 90 % of the residual ranks
above one that removes 13 %, whatever their κ. Candidates that do not pass follow, by score.

Two passing candidates A (ranked first) and B are *ambiguous* when the record cannot tell which explains
more. With d_t the difference of their pointwise log-densities at sample t, D = Σ_t d_t = Δℓ_A − Δℓ_B is
compared with its standard deviation √(N · LRV(d)), LRV the long-run variance of d_t (Bartlett weights,
the bandwidth of :func:`~bayes_mr.numerics.stats.hac_bandwidth`): Vuong's (1989) test for non-nested
models, with the autocorrelation of a dynamic model's residuals in the variance (Newey & West 1987).
B is ambiguous with A when D < :data:`Z_AMBIGUOUS` · SD.
"""

from __future__ import annotations

import math

import numpy as np

from bayes_mr.diagnosis.fits import Fit
from bayes_mr.diagnosis.screen import THRESHOLD, Candidate, passes
from bayes_mr.numerics.stats import hac_bandwidth

#: Standard deviations of D within which two passing candidates are reported as ambiguous (two-sided 95 %).
Z_AMBIGUOUS = 1.96

#: Largest HAC bandwidth, as a share of the record.
MAX_LAG_SHARE = 0.1


def rank(candidates: list[Candidate], threshold: float = THRESHOLD) -> list[Candidate]:
    """``candidates`` best first: those that pass by Δℓ (module docstring), then the others by score."""
    passing = [c for c in candidates if passes(c, threshold)]
    rest = [c for c in candidates if not passes(c, threshold)]
    passing.sort(key=lambda c: -c.delta_loglik)
    rest.sort(key=lambda c: -c.score if math.isfinite(c.score) else math.inf)
    return passing + rest


def pointwise(fit: Fit) -> np.ndarray:
    """ln p(y_t | θ̂) of each valid sample of ``fit``'s record, summed over channels (n_valid,)."""
    lik = fit.lik
    yhat = np.stack([fit.predicted[c] for c in lik.channels], axis=-1)[None]
    sigma = np.asarray(fit.result.sigma, float)[None]
    _, terms = lik.log_density(yhat, sigma, np.array([True]), pointwise=True)
    return terms[0].sum(axis=1)[lik.valid]


def long_run_variance(d: np.ndarray) -> float:
    """Bartlett long-run variance of the series ``d`` (the variance of its mean times its length)."""
    d = np.asarray(d, float) - float(np.mean(d))
    n = d.size
    lag = hac_bandwidth(d[:, None], max(1, int(MAX_LAG_SHARE * n)))
    f = np.fft.rfft(d, 2 * n)
    acov = np.fft.irfft(f * np.conj(f))[: lag + 1] / n
    w = 1.0 - np.arange(1, lag + 1) / (lag + 1.0)
    return float(max(acov[0] + 2.0 * np.sum(w * acov[1:]), 0.0))


def compare_fits(a: Fit, b: Fit) -> dict:
    """D = ln L(a) − ln L(b) over the same samples, its SD and D/SD (module docstring)."""
    d = pointwise(a) - pointwise(b)
    if d.size == 0 or not np.all(np.isfinite(d)):
        return {"difference": None, "sd": None, "z": None}
    total = float(np.sum(d))
    sd = math.sqrt(d.size * long_run_variance(d))
    z = total / sd if sd > 0 else (math.inf if total > 0 else 0.0)
    return {"difference": total, "sd": sd, "z": z}


def ambiguous(cause: Candidate, candidates: list[Candidate], threshold: float = THRESHOLD) -> list[dict]:
    """The passing candidates the record cannot tell from ``cause``, each with the test of
    :func:`compare_fits` (``cause`` against it); empty when the cause stands alone."""
    out = []
    for c in candidates:
        if c.name == cause.name and c.channel == cause.channel or not passes(c, threshold):
            continue
        test = compare_fits(cause.fit, c.fit)
        if test["z"] is not None and test["z"] < Z_AMBIGUOUS:
            out.append({"name": c.name, "candidate": c, **test})
    return out
