"""How much autocorrelated residuals inflate the evidence for an extra parameter.

Under "the effect is absent", the log-likelihood gain of adding the effect's
parameters E to a fitted model is, to second order, ½ sᵀ V_iid⁻¹ s with
s = G_Eᵀ r the score of E, r the standardised residuals and G_E the
sensitivity of the residuals to E *after projecting out the base
parameters* (what the base model cannot already absorb). For independent
residuals Var(s) = V_iid = G_Eᵀ G_E and 2Δℓ ~ χ²_d; for correlated ones
Var(s) = V_HAC and 2Δℓ ~ Σ λ_i χ²_1, λ the eigenvalues of the design effect
V_iid⁻¹ V_HAC (Rao & Scott 1981). :func:`design_effect` returns their mean κ.

V_HAC is estimated *from the model*: the residual auto- and cross-covariances
γ_cc'(k) of the whole record (every sample contributes, so they are well
determined) times the sensitivity's own lag products,

    V_HAC = Σ_{c,c'} Σ_{|k|≤L} w_k γ_cc'(k) Σ_t G_c(t) G_c'(t+k)ᵀ,

with Bartlett weights w_k = 1 − |k|/(L+1). Unlike the Newey–West sandwich of
the score itself, this stays well determined when an effect acts only on a
short stretch of the record (a small-amplitude regime met only while the
motion builds up): there the sandwich sees one or two blocks and can report
no inflation at all, while the residual's correlation is plain from the
rest of the record.
"""

from __future__ import annotations

import numpy as np

from bayes_mr.inference.lsq.refine import Residuals
from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.numerics.stats import hac_bandwidth


def _lagged(a: np.ndarray, b: np.ndarray, lag: int, m: int) -> np.ndarray:
    """Σ_t a(t) b(t+k) for k = −lag..lag (FFT, zero padded to m)."""
    cc = np.fft.irfft(np.conj(np.fft.rfft(a, m)) * np.fft.rfft(b, m), m)
    k = np.arange(-lag, lag + 1)
    return cc[k % m]


def design_effect(lik: OutputError, phi: np.ndarray, sigma: np.ndarray, idx: list[int]) -> tuple[float, np.ndarray]:
    """Mean design effect κ of the parameters ``idx`` at φ (module docstring).

    Parameters
    ----------
    lik : OutputError
    phi : ndarray (p,)
        Optimum in estimation coordinates.
    sigma : ndarray (n_channels,)
        Residual SDs that standardise the residuals.
    idx : list of int
        Positions of the effect's parameters in φ.

    Returns
    -------
    kappa : float
        Mean eigenvalue of V_iid⁻¹ V_HAC (not floored).
    lam : ndarray (d,)
        The eigenvalues.
    """
    rf = Residuals(lik, sigma)
    r = rf(phi)
    J = rf.jacobian(phi, central=True)
    n_c = len(lik.channels)
    n = r.size // n_c
    base = [j for j in range(J.shape[1]) if j not in idx]
    G = J[:, idx]
    if base:
        B = J[:, base]
        G = G - B @ np.linalg.lstsq(B, G, rcond=None)[0]
    return design_effect_of(r.reshape(n, n_c), G.reshape(n, n_c, len(idx)))


def design_effect_of(R: np.ndarray, G: np.ndarray) -> tuple[float, np.ndarray]:
    """Mean design effect κ of sensitivities G against residuals R (module docstring).

    Parameters
    ----------
    R : ndarray, shape (n, c)
        Residuals of c channels (any scale; each channel's covariances are
        estimated from the whole series).
    G : ndarray, shape (n, c, d)
        Sensitivity of each channel's residual to d parameters (already
        orthogonal to whatever the model absorbs).

    Returns
    -------
    kappa : float
        Mean eigenvalue of V_iid⁻¹ V_HAC (1 for white residuals).
    lam : ndarray (d,)
    """
    n, n_c, d = G.shape
    lag = hac_bandwidth(R, max_lag=min(R.shape[0] // 4, 5000))
    m = 2 * n
    w = 1.0 - np.abs(np.arange(-lag, lag + 1)) / (lag + 1)
    v_hac = np.zeros((d, d))
    v_iid = np.zeros((d, d))
    for c in range(n_c):
        rc = R[:, c] - R[:, c].mean()
        v_iid += float(np.mean(rc * rc)) * (G[:, c, :].T @ G[:, c, :])
        for c2 in range(n_c):
            gamma = _lagged(rc, R[:, c2] - R[:, c2].mean(), lag, m) / n
            for a in range(d):
                for b in range(d):
                    v_hac[a, b] += np.sum(w * gamma * _lagged(G[:, c, a], G[:, c2, b], lag, m))
    v_hac = 0.5 * (v_hac + v_hac.T)
    try:
        lam = np.linalg.eigvals(np.linalg.solve(v_iid, v_hac)).real
    except np.linalg.LinAlgError:
        return 1.0, np.ones(d)
    if not np.all(np.isfinite(lam)):
        return 1.0, np.ones(d)
    return float(np.mean(lam)), lam
