"""Statistics used across the package, each computed in one place.

* :func:`autocorrelation` — sample autocorrelation of a series (FFT);
* :func:`integrated_time` / :func:`integrated_times` — integrated
  autocorrelation time of a series, and of every coordinate of an ensemble
  chain (emcee's estimator, Sokal's window);
* :func:`hac_bandwidth` — the Bartlett bandwidth of a HAC (sandwich)
  covariance;
* :func:`robust_sd` — the standard deviation from the median absolute
  deviation.

This module is the bottom layer: it imports numpy and emcee only.
"""

from __future__ import annotations

import emcee
import numpy as np

#: MAD → standard deviation for Gaussian data (1/Φ⁻¹(3/4)).
MAD_TO_SD = 1.4826
#: Bartlett bandwidth of a HAC covariance, at least this fraction of the record.
HAC_FRACTION = 1 / 20
#: Autocorrelation below which residual correlation counts as died out.
RHO_SMALL = 0.05


def robust_sd(x: np.ndarray, axis: int | None = None) -> np.ndarray | float:
    """Standard deviation from the median absolute deviation, 1.4826 · MAD(x).

    Parameters
    ----------
    x : array_like
    axis : int, optional
        Axis along which to compute (default: the whole array).
    """
    x = np.asarray(x, float)
    med = np.median(x, axis=axis, keepdims=axis is not None)
    out = MAD_TO_SD * np.median(np.abs(x - med), axis=axis)
    return float(out) if axis is None else out


def autocorrelation(r: np.ndarray, max_lag: int) -> np.ndarray:
    """Sample autocorrelation ρ_0..ρ_max_lag of ``r`` (n,) (FFT, biased estimator).

    A constant series has ρ ≡ 0.
    """
    r = np.asarray(r, float) - np.mean(r)
    n = r.size
    max_lag = min(max_lag, n - 1)
    f = np.fft.rfft(r, 2 * n)
    acov = np.fft.irfft(f * np.conj(f))[: max_lag + 1]
    return acov / acov[0] if acov[0] > 0 else np.zeros(max_lag + 1)


def integrated_time(r: np.ndarray, c: float = 5.0) -> float:
    """Integrated autocorrelation time τ = 1 + 2 Σ_k ρ_k of a series [samples].

    Sokal's adaptive window (the smallest M with M ≥ c τ(M)) on the
    autocorrelation up to min(n/4, 20000) lags. τ is the factor by which
    correlation inflates the variance of a mean over an independent one; at
    least 1.
    """
    r = np.asarray(r, float)
    rho = autocorrelation(r, max_lag=min(r.size // 4, 20000))
    tau = 2.0 * np.cumsum(rho) - 1.0
    m = np.arange(tau.size)
    window = np.flatnonzero(m >= c * tau)
    tau_hat = tau[window[0]] if window.size else tau[-1]
    return float(max(tau_hat, 1.0))


def integrated_times(chain: np.ndarray) -> np.ndarray:
    """Integrated autocorrelation time of each coordinate of an ensemble chain [steps].

    ``chain`` has shape (n_steps, n_walkers, d); emcee's estimator (walkers
    averaged, Sokal's window, never raises). A walker that never moved has no
    autocorrelation function; it is left out of its coordinate's average (if
    no walker moved, τ = ∞: nothing is converged).
    """
    chain = np.asarray(chain, float)
    if chain.shape[0] < 2:
        return np.full(chain.shape[-1], np.inf)
    moving = np.ptp(chain, axis=0) > 0  # (n_walkers, d)
    if moving.all():
        return np.atleast_1d(emcee.autocorr.integrated_time(chain, tol=0, quiet=True))
    tau = np.full(chain.shape[-1], np.inf)
    for j in range(chain.shape[-1]):
        if moving[:, j].any():
            tau[j] = float(emcee.autocorr.integrated_time(chain[:, moving[:, j], j][:, :, None], tol=0,
                                                          quiet=True)[0])
    return tau


def hac_bandwidth(r: np.ndarray, max_lag: int) -> int:
    """Bartlett bandwidth [samples] of a HAC covariance for residuals r (n, c).

    The lag where the pooled autocorrelation of the channels first falls
    below :data:`RHO_SMALL`, but at least :data:`HAC_FRACTION` of the record
    and at most ``max_lag``. A bandwidth from the autocorrelation alone is too
    short: a small but long-lived correlation (a structure's response to
    process noise, a few % of the residual at each lag) is coherent with the
    parameter sensitivities and inflates the variance of the score several
    times; 1/20 of the record spans many periods of any mode the record can
    identify and leaves ~20 blocks for the estimate.
    """
    r = np.asarray(r, float)
    r = r - r.mean(axis=0)
    n = r.shape[0]
    f = np.fft.rfft(r, 2 * n, axis=0)
    acf = np.fft.irfft(f * np.conj(f), axis=0)[: max_lag + 1].sum(axis=1)
    acf = acf / acf[0] if acf[0] > 0 else acf
    below = np.flatnonzero(np.abs(acf) < RHO_SMALL)
    from_acf = int(below[0]) if below.size else max_lag
    return int(min(max_lag, max(from_acf, round(HAC_FRACTION * n), 1)))
