"""Residual models of the output-error likelihood: independent (iid) or autoregressive (AR(p)) errors.

Not to be confused with :mod:`bayes_mr.numerics.synthetic_noise`, which *generates*
noise for simulated records; this module *models* the residual y − ŷ(θ).

The residual of a dynamic model is not white: model error and the response
to noise on the measured input are smooth in time. Per output channel c the
AR(p_c) model writes the residual e_t as

    e_t = Σ_{k=1..p} a_k e_{t−k} + ε_t,   ε_t ~ N(0, σ_c²) independent,

and the likelihood is the *conditional* one (Box & Jenkins): the first p
samples of every contiguous run of valid samples are conditioned on, the
others contribute ln N(w_t; 0, σ_c²) of the prewhitened residual
w_t = e_t − Σ a_k e_{t−k}. The recursion restarts after every masked gap,
so a masked sample is never used as a lag. It costs O(N·p) per channel.

The AR coefficients a are *profiled*: for given residuals the conditional
maximum-likelihood a is the least-squares regression of e_t on its lags, a
p × p solve per channel (p ≤ :data:`MAX_ORDER`), so each likelihood call
re-estimates them for its own θ. Profiling rather than sampling keeps the
sampler's dimension and the estimators' interfaces unchanged, costs less than
the simulation, and with thousands of samples the coefficients are known to
~1/√N, far better than θ; the Laplace evidence adds their Occam factor
(:func:`coefficient_log_occam`), the thermodynamic and stepping-stone routes
(which integrate the profiled density) do not.

The order p_c is chosen per record and channel by BIC on the residual of a
first iid fit (:func:`select_orders`); p = 0 is the iid case.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal as _signal
from scipy import stats as _stats

from bayes_mr.numerics.stats import autocorrelation

LOG_2PI = float(np.log(2 * np.pi))
#: Highest AR order BIC may choose.
MAX_ORDER = 5
#: Lags of the Ljung–Box test of a whitened residual.
LJUNG_BOX_LAGS = 20
#: Half-width of the uniform prior on each AR coefficient (the Laplace evidence's Occam factor).
COEF_PRIOR_HALF_WIDTH = 1.0


@dataclass(frozen=True)
class ResidualModel:
    """Which residual model a likelihood uses.

    Attributes
    ----------
    kind : {"iid", "ar"}
    orders : tuple of int, optional
        AR order of each output channel (``kind="ar"``); None until chosen
        (:func:`select_orders` on the residual of a first iid fit).
    max_order : int
        Highest order considered.
    """

    kind: str = "iid"
    orders: tuple[int, ...] | None = None
    max_order: int = MAX_ORDER

    def __post_init__(self):
        if self.kind not in ("iid", "ar"):
            raise ValueError(f"noise model must be 'iid' or 'ar', got {self.kind!r}")

    @property
    def resolved(self) -> bool:
        """True when the density is defined (iid, or AR with its orders chosen)."""
        return self.kind == "iid" or self.orders is not None

    def order_of(self, n_channels: int) -> tuple[int, ...]:
        """Orders per channel (zeros for iid and for AR before the orders are chosen)."""
        return tuple(self.orders) if self.orders is not None else (0,) * n_channels

    def label(self) -> str:
        """``iid``, or ``ar(p=…)`` with one order per channel (``ar`` while not chosen)."""
        if self.kind == "iid":
            return "iid"
        return "ar" if self.orders is None else "ar(p=" + ",".join(str(p) for p in self.orders) + ")"


def usable(valid: np.ndarray, p: int) -> np.ndarray:
    """Samples whose p previous samples are all valid (the conditional likelihood's terms), shape (N,).

    The first p samples of every contiguous run of valid samples are conditioned on.
    """
    valid = np.asarray(valid, bool)
    out = valid.copy()
    for k in range(1, p + 1):
        out[k:] &= valid[:-k]
        out[:k] = False
    return out


def _lags(e: np.ndarray, p: int) -> np.ndarray:
    """Lagged copies of e (B, N): shape (B, N, p), entry [..., t, k] = e[t − k − 1] (0 before the start)."""
    out = np.zeros(e.shape + (p,))
    for k in range(p):
        out[:, k + 1:, k] = e[:, : e.shape[1] - k - 1]
    return out


def profile(e: np.ndarray, valid: np.ndarray, p: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Conditional-ML AR(p) coefficients of each residual series and its prewhitened residual.

    Parameters
    ----------
    e : ndarray, shape (B, N)
        Residual series [channel units]; values at invalid samples are ignored.
    valid : ndarray of bool, shape (N,)
    p : int
        AR order (0: w = e).

    Returns
    -------
    w : ndarray (B, N)
        Prewhitened residual e_t − Σ a_k e_{t−k}, zero where not :func:`usable`.
    a : ndarray (B, p)
        AR coefficients.
    gram : ndarray (B, p, p)
        Σ_t X_t X_tᵀ of the lag regressors over the usable samples [units²].
    use : ndarray of bool (N,)
        The usable samples.
    """
    e = np.where(np.asarray(valid, bool)[None], np.atleast_2d(np.asarray(e, float)), 0.0)
    use = usable(valid, p)
    if p == 0:
        return np.where(use[None], e, 0.0), np.zeros((e.shape[0], 0)), np.zeros((e.shape[0], 0, 0)), use
    X = _lags(e, p)[:, use, :]
    target = e[:, use]
    gram = np.einsum("btk,btl->bkl", X, X)
    rhs = np.einsum("btk,bt->bk", X, target)
    # a vanishing residual (a noise-free fit) has a singular Gram matrix: a tiny ridge keeps a finite
    ridge = 1e-12 * np.maximum(np.trace(gram, axis1=1, axis2=2), 1e-300)[:, None, None] * np.eye(p)
    a = np.linalg.solve(gram + ridge, rhs[..., None])[..., 0]
    w = np.zeros_like(e)
    w[:, use] = target - np.einsum("btk,bk->bt", X, a)
    return w, a, gram, use


def select_order(e: np.ndarray, valid: np.ndarray, max_order: int = MAX_ORDER) -> int:
    """AR order of a residual series (N,) by the Bayesian information criterion.

    Every order is fitted on the same samples (those usable at ``max_order``),
    so the criteria compare like with like: BIC_p = n ln(RSS_p / n) + p ln n.
    """
    common = usable(valid, max_order)
    n = int(common.sum())
    if n <= 2 * max_order + 2:
        return 0
    bic = []
    for p in range(max_order + 1):
        w, _, _, _ = profile(np.asarray(e, float)[None], valid, p)
        rss = float(np.sum(w[0, common] ** 2))
        bic.append(n * np.log(max(rss, 1e-300) / n) + p * np.log(n))
    return int(np.argmin(bic))


def select_orders(resid: np.ndarray, valid: np.ndarray, max_order: int = MAX_ORDER) -> tuple[int, ...]:
    """:func:`select_order` of each channel of a residual (N, C) [channel units]."""
    return tuple(select_order(resid[:, c], valid, max_order) for c in range(resid.shape[1]))


def whiten(resid: np.ndarray, valid: np.ndarray, orders: tuple[int, ...]) -> tuple[np.ndarray, list[np.ndarray]]:
    """Prewhitened residual of each channel with profiled AR coefficients.

    Parameters
    ----------
    resid : ndarray, shape (B, N, C)
        Residuals y − ŷ [channel units].
    valid : ndarray of bool (N,)
    orders : tuple of int
        AR order per channel.

    Returns
    -------
    w : ndarray (B, N, C)
        Prewhitened residuals, zero at samples that are conditioned on or invalid.
    coefs : list of ndarray
        AR coefficients of each channel, shape (B, p_c).
    """
    w = np.zeros(resid.shape)
    coefs = []
    for c, p in enumerate(orders):
        w[:, :, c], a, _, _ = profile(resid[:, :, c], valid, p)
        coefs.append(a)
    return w, coefs


def counts(valid: np.ndarray, orders: tuple[int, ...]) -> np.ndarray:
    """Number of terms of the conditional likelihood of each channel, shape (C,)."""
    return np.array([int(usable(valid, p).sum()) for p in orders])


def log_density(resid: np.ndarray, sigma: np.ndarray, valid: np.ndarray, orders: tuple[int, ...], *,
                pointwise: bool = False):
    """Conditional AR log-density of residuals (B, N, C) with innovation SDs ``sigma`` (B, C).

    Returns the total (B,) and, with ``pointwise``, the per-sample terms
    (B, N, C) (zero at samples conditioned on or invalid).
    """
    w, _ = whiten(resid, valid, orders)
    use = np.stack([usable(valid, p) for p in orders], axis=-1)  # (N, C)
    z = w / sigma[:, None, :]
    terms = np.where(use[None], -0.5 * z * z - np.log(sigma)[:, None, :] - 0.5 * LOG_2PI, 0.0)
    total = terms.sum(axis=(1, 2))
    return (total, terms) if pointwise else total


def integrated_time(coef: np.ndarray, n: int) -> float:
    """Integrated autocorrelation time τ = S(0)/γ₀ of a fitted AR process [samples].

    S(0) = σ²/(1 − Σa)² is the spectral density at zero frequency and γ₀ =
    σ² Σ ψ_j² the variance (ψ the impulse response of 1/(1 − Σ a_k z^k),
    over ``n`` samples); for AR(1), τ = (1 + a)/(1 − a). A non-stationary
    fit (a root on or inside the unit circle) gets τ = n.
    """
    coef = np.asarray(coef, float)
    if coef.size == 0:
        return 1.0
    roots = np.roots(np.r_[1.0, -coef])
    if np.any(np.abs(roots) >= 1.0):
        return float(n)
    impulse = np.zeros(max(n, 2))
    impulse[0] = 1.0
    psi = _signal.lfilter([1.0], np.r_[1.0, -coef], impulse)
    return float(min(1.0 / ((1.0 - coef.sum()) ** 2 * np.sum(psi**2)), n))


def effective_samples(coefs: list[np.ndarray], n: np.ndarray) -> np.ndarray:
    """Effective number of independent samples N_c/τ_c of each channel (τ from the fitted AR)."""
    return np.array([max(n_c / integrated_time(a, int(n_c)), 1.0) for a, n_c in zip(coefs, n)])


def ljung_box(w: np.ndarray, n_coef: int, lags: int = LJUNG_BOX_LAGS) -> float:
    """Ljung–Box p-value of the whiteness of a series (n,), with ``n_coef`` fitted AR coefficients.

    Q = n(n+2) Σ_{k≤h} ρ_k²/(n−k) against χ² with h − n_coef degrees of freedom.
    """
    w = np.asarray(w, float)
    n = w.size
    h = min(lags, n - 1)
    rho = autocorrelation(w, h)[1:]
    q = n * (n + 2) * float(np.sum(rho**2 / (n - np.arange(1, h + 1))))
    return float(_stats.chi2.sf(q, max(h - n_coef, 1)))


def coefficient_log_occam(resid: np.ndarray, valid: np.ndarray, orders: tuple[int, ...],
                          sigma: np.ndarray) -> float:
    """Laplace factor of the profiled AR coefficients in the evidence [nats].

    Σ_c [½ p_c ln 2π − ½ ln|G_c/σ_c²| − p_c ln(2 h)]: the Gaussian integral of
    each channel's coefficients (Hessian G_c/σ_c², G_c the Gram matrix of the
    lag regressors) under a uniform prior of half-width h =
    :data:`COEF_PRIOR_HALF_WIDTH` on each coefficient. Zero for iid.

    Parameters
    ----------
    resid : ndarray (N, C)
        Residual at the optimum [channel units].
    sigma : ndarray (C,)
        Innovation SDs [channel units].
    """
    out = 0.0
    for c, p in enumerate(orders):
        if p == 0:
            continue
        _, _, gram, _ = profile(resid[None, :, c], valid, p)
        _, logdet = np.linalg.slogdet(gram[0] / sigma[c] ** 2)
        out += 0.5 * p * LOG_2PI - 0.5 * logdet - p * np.log(2 * COEF_PRIOR_HALF_WIDTH)
    return float(out)


def describe(resid: np.ndarray, valid: np.ndarray, model: ResidualModel, channels: tuple[str, ...]) -> dict:
    """What a fit JSON says about its residual model, from the residual (N, C) of its point estimate.

    Returns
    -------
    dict
        ``noise_model`` (:meth:`ResidualModel.label`), ``n_eff`` (channel →
        effective number of independent samples) and, under AR, ``ar_coef``
        (channel → coefficients). Under AR, n_eff = N_c/τ_c with τ_c the
        integrated autocorrelation time of the fitted AR process
        (:func:`integrated_time`); under iid, where the model assumes τ = 1,
        N_c/τ_c with τ_c of the residual itself (:func:`bayes_mr.numerics.stats.integrated_time`),
        so a reader sees how far the assumption is off.
    """
    from bayes_mr.numerics.stats import integrated_time as residual_time

    resid = np.where(np.asarray(valid, bool)[:, None], resid, 0.0)
    out: dict = {"noise_model": model.label()}
    if model.kind == "ar" and model.orders is not None:
        _, coefs = whiten(resid[None], valid, model.orders)
        n = counts(valid, model.orders)
        coefs = [a[0] for a in coefs]
        out["n_eff"] = dict(zip(channels, effective_samples(coefs, n)))
        out["ar_coef"] = {c: a.tolist() for c, a in zip(channels, coefs)}
    else:
        v = np.asarray(valid, bool)
        out["n_eff"] = {c: v.sum() / residual_time(resid[v, j]) for j, c in enumerate(channels)}
    return out


def apply_filter(resid: np.ndarray, valid: np.ndarray, orders: tuple[int, ...],
                 coefs: list[np.ndarray]) -> np.ndarray:
    """Prewhiten residuals (B, N, C) with *given* AR coefficients (one (p_c,) array per channel).

    The linear map :func:`whiten` applies with the coefficients it profiles,
    held fixed: what a perturbation of the residual (a noise replica) becomes
    in the likelihood's whitened coordinates. Zero where not :func:`usable`.
    """
    e = np.where(np.asarray(valid, bool)[None, :, None], np.asarray(resid, float), 0.0)
    out = np.zeros(e.shape)
    for c, p in enumerate(orders):
        use = usable(valid, p)
        w = e[:, :, c].copy()
        for k in range(p):
            w[:, k + 1:] -= coefs[c][k] * e[:, : e.shape[1] - k - 1, c]
        out[:, :, c] = np.where(use[None], w, 0.0)
    return out
