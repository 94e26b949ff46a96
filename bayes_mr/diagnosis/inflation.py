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
    if len(getattr(lik, "parts", ())) > 1:
        return _joint_design_effect(lik, phi, sigma, idx)
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


def _joint_design_effect(lik, phi: np.ndarray, sigma: np.ndarray, idx: list[int]) -> tuple[float, np.ndarray]:
    """κ of a likelihood summed over independent records (:class:`~bayes_mr.likelihood.joint.JointLikelihood`).

    The effect's sensitivities are made orthogonal to the shared base parameters over all records at once (the
    base absorbs what it can of every record together); the iid and HAC covariances are each record's own,
    summed — residuals are autocorrelated within a record, independent between records. ``sigma`` is every
    record's σ_r in the joint order (R·C,).
    """
    n_c = len(lik.channels)
    rs, js = [], []
    for k, part in enumerate(lik.parts):
        rf = Residuals(part, np.asarray(sigma, float)[k * n_c:(k + 1) * n_c])
        own = lik.part_phi(phi, k)  # the shared parameters and (with record offsets) this record's offset
        rs.append(rf(own))
        js.append(lik.scatter(rf.jacobian(own, central=True), k))
    J = np.vstack(js)
    base = [j for j in range(J.shape[1]) if j not in idx]
    G = J[:, idx]
    if base:
        B = J[:, base]
        G = G - B @ np.linalg.lstsq(B, G, rcond=None)[0]
    v_iid, v_hac, lo = np.zeros((len(idx), len(idx))), np.zeros((len(idx), len(idx))), 0
    for r in rs:
        n = r.size // n_c
        a, b = covariances(r.reshape(n, n_c), G[lo:lo + r.size].reshape(n, n_c, len(idx)))
        v_iid, v_hac, lo = v_iid + a, v_hac + b, lo + r.size
    return _mean_eigenvalue(v_iid, v_hac)


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
    return _mean_eigenvalue(*covariances(R, G))


def covariances(R: np.ndarray, G: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(V_iid, V_HAC), each (d, d): the covariances of the score Σ_t G_t r_t, white and Bartlett-weighted.

    Both are scaled by the record's length n (a sum over independent records adds them)."""
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
    return v_iid, 0.5 * (v_hac + v_hac.T)


def _mean_eigenvalue(v_iid: np.ndarray, v_hac: np.ndarray) -> tuple[float, np.ndarray]:
    """Mean eigenvalue of V_iid⁻¹ V_HAC and the eigenvalues (1 each where they cannot be had)."""
    d = v_iid.shape[0]
    try:
        lam = np.linalg.eigvals(np.linalg.solve(v_iid, v_hac)).real
    except np.linalg.LinAlgError:
        return 1.0, np.ones(d)
    if not np.all(np.isfinite(lam)):
        return 1.0, np.ones(d)
    return float(np.mean(lam)), lam
