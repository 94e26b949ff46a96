"""Convergence of an ensemble chain: burn-in, integrated times, R-hat, ESS and the verdict.

The rule (see :mod:`bayes_mr.inference.mcmc`): a pilot τ₀ from the second
half of the chain, burn-in ⌈``burn_tau_multiple`` · τ₀⌉ (at most half), and
converged when the chain after burn-in is ``min_tau_multiple`` times its
longest integrated time *and* every coordinate's rank-normalised split R-hat
(walkers as chains) is below ``rhat_max``.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from ..stats import integrated_times


def _quiet_arviz():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        import arviz as az
    return az


def rhat_ess(chain: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rank-normalised split R-hat and bulk ESS per coordinate (walkers as chains).

    Parameters
    ----------
    chain : ndarray, shape (n_steps, n_walkers, d)

    Returns
    -------
    rhat, ess : ndarray (d,)
    """
    az = _quiet_arviz()
    x = np.moveaxis(np.asarray(chain, float), 1, 0)  # (walker, step, d)
    rhat = np.array([float(az.rhat(x[:, :, j], method="rank")) for j in range(x.shape[2])])
    ess = np.array([float(az.ess(x[:, :, j], method="bulk")) for j in range(x.shape[2])])
    return rhat, ess


def convergence_check(chain: np.ndarray, settings) -> dict:
    """Burn-in, τ, R-hat, ESS and the convergence verdict (module docstring rule).

    Parameters
    ----------
    chain : ndarray, shape (n_steps, n_walkers, d)
    settings : MCMCSettings
        Uses ``burn_tau_multiple``, ``min_tau_multiple`` and ``rhat_max``.

    Returns
    -------
    dict with ``burn``, ``tau`` (d,), ``rhat`` (d,), ``ess`` (d,), ``converged``.
    """
    n = chain.shape[0]
    tau0 = float(np.max(integrated_times(chain[n // 2:])))
    burn = n // 2 if not np.isfinite(tau0) else int(min(math.ceil(settings.burn_tau_multiple * tau0), n // 2))
    post = chain[burn:]
    tau = integrated_times(post)
    rhat, ess = rhat_ess(post)
    long_enough = bool(np.all(np.isfinite(tau))) and post.shape[0] >= settings.min_tau_multiple * float(np.max(tau))
    converged = bool(long_enough and np.all(rhat < settings.rhat_max))
    return {"burn": burn, "tau": tau, "rhat": rhat, "ess": ess, "converged": converged}
