"""Cross-check of UKF estimates against the MCMC posterior of the same model and record.

The UKF's final Gaussian on φ (the estimation coordinates) and the emcee
posterior are two estimates of one posterior. Per parameter:

* ``z`` = (mean_ukf − mean_mcmc) / √(sd_ukf² + sd_mcmc²): the difference of
  the means in units of their combined standard deviation (|z| ≤ 3 is
  agreement);
* ``sd_ratio`` = sd_ukf / sd_mcmc: whether the filter's covariance is as wide
  as the posterior (the filter's parameter random walk widens it; a ratio ≪ 1
  is an overconfident filter).

Both in φ, where the UKF is Gaussian, and in θ [SI], where the UKF's
moments are those of its Gaussian on φ mapped through θ = e^φ/s (log-normal
moments, exact) and the MCMC moments are taken over the mapped draws.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from bayes_mr.models.params import Coordinates


def _ukf_theta_moments(mean: np.ndarray, var: np.ndarray, coords: Coordinates) -> tuple[np.ndarray, np.ndarray]:
    """Mean and SD of θ when φ ~ N(mean, var) per coordinate (log-normal for log parameters)."""
    m_log = np.exp(mean + 0.5 * var) / coords.scale
    sd_log = m_log * np.sqrt(np.expm1(var))
    m_lin = mean / coords.scale
    sd_lin = np.sqrt(var) / coords.scale
    # θ = sinh(φ)/s: E sinh φ = sinh μ e^{v/2}, E sinh² φ = (cosh 2μ e^{2v} − 1)/2
    m_asinh = np.sinh(mean) * np.exp(0.5 * var) / coords.scale
    e2 = 0.5 * (np.cosh(2 * mean) * np.exp(2 * var) - 1.0) / coords.scale**2
    sd_asinh = np.sqrt(np.clip(e2 - m_asinh**2, 0.0, None))
    mean_th = np.where(coords.log, m_log, np.where(coords.asinh, m_asinh, m_lin))
    return mean_th, np.where(coords.log, sd_log, np.where(coords.asinh, sd_asinh, sd_lin))


def ukf_vs_mcmc(
    ukf_mean_phi: np.ndarray,
    ukf_cov_phi: np.ndarray,
    mcmc_chain_phi: np.ndarray,
    *,
    coords: Coordinates | None = None,
    names: tuple[str, ...] | None = None,
) -> xr.Dataset:
    """z-scores and SD ratios of UKF against MCMC, per parameter.

    Parameters
    ----------
    ukf_mean_phi : ndarray (p,)
        UKF final mean of φ.
    ukf_cov_phi : ndarray (p, p)
        UKF final covariance of φ.
    mcmc_chain_phi : ndarray (..., d)
        MCMC draws (post burn-in) with φ in the first p coordinates (any
        further coordinates, e.g. ln σ_c, are ignored); any leading shape.
    coords : Coordinates, optional
        Maps φ → θ; without it only the φ comparison is returned.
    names : tuple of str, optional
        Parameter names (default ``coords.names`` or p0, p1, …).

    Returns
    -------
    xarray.Dataset
        dim ``param``; variables ``mean_ukf_phi``, ``sd_ukf_phi``,
        ``mean_mcmc_phi``, ``sd_mcmc_phi``, ``z_phi``, ``sd_ratio_phi`` and,
        with ``coords``, the same with suffix ``_theta`` [SI].
    """
    mean = np.asarray(ukf_mean_phi, float)
    p = mean.size
    cov = np.asarray(ukf_cov_phi, float).reshape(p, p)
    draws = np.asarray(mcmc_chain_phi, float)
    draws = draws.reshape(-1, draws.shape[-1])[:, :p]
    if draws.shape[1] != p:
        raise ValueError(f"MCMC draws have {draws.shape[1]} coordinates, the UKF {p} parameters")
    if names is None:
        names = coords.names if coords is not None else tuple(f"p{j}" for j in range(p))
    var = np.clip(np.diag(cov), 0.0, None)

    def block(m_u, s_u, m_m, s_m, suffix):
        return {
            f"mean_ukf_{suffix}": ("param", m_u),
            f"sd_ukf_{suffix}": ("param", s_u),
            f"mean_mcmc_{suffix}": ("param", m_m),
            f"sd_mcmc_{suffix}": ("param", s_m),
            f"z_{suffix}": ("param", (m_u - m_m) / np.sqrt(s_u**2 + s_m**2)),
            f"sd_ratio_{suffix}": ("param", s_u / s_m),
        }

    data = block(mean, np.sqrt(var), draws.mean(axis=0), draws.std(axis=0, ddof=1), "phi")
    if coords is not None:
        th = coords.to_theta(draws)
        m_u, s_u = _ukf_theta_moments(mean, var, coords)
        data.update(block(m_u, s_u, th.mean(axis=0), th.std(axis=0, ddof=1), "theta"))
    ds = xr.Dataset(data, coords={"param": list(names)})
    ds.attrs["description"] = ("z = (mean_ukf − mean_mcmc)/√(sd_ukf² + sd_mcmc²); "
                               "sd_ratio = sd_ukf/sd_mcmc; φ = estimation coordinates, θ = SI")
    ds.attrs["n_mcmc_draws"] = int(draws.shape[0])
    return ds
