"""Ensemble moves for emcee: the corrected DE snooker update, an independence proposal, the names settings accept."""

from __future__ import annotations

import emcee
import numpy as np


class Snooker(emcee.moves.DESnookerMove):
    """DE snooker update (ter Braak & Vrugt 2008) with emcee 3.1.6's two errors fixed.

    emcee 3.1.6 projects on ``(s − z)/√|s − z|`` instead of the unit vector
    and uses ½(d − 1) in the Hastings factor; its chain is not stationary at
    the target (on a 4-d Gaussian it under-disperses, E[χ²] 15 MCSE low —
    ``tests/test_mcmc.py``). Fixed upstream after 3.1.6 (dfm/emcee#531);
    this is the corrected proposal, so the pinned emcee can stay.
    """

    def get_proposal(self, s, c, random):
        ns, ndim = s.shape
        q = np.empty_like(s)
        log_factor = np.empty(ns)
        for i in range(ns):
            w = np.array([c[j][random.randint(len(c[j]))] for j in range(3)])
            random.shuffle(w)
            z, z1, z2 = w
            delta = s[i] - z
            norm = np.linalg.norm(delta)
            u = delta / norm
            q[i] = s[i] + u * self.gammas * (np.dot(u, z1) - np.dot(u, z2))
            log_factor[i] = (ndim - 1.0) * (np.log(np.linalg.norm(q[i] - z)) - np.log(norm))
        return q, log_factor


def jittered_cholesky(cov) -> np.ndarray:
    """Lower Cholesky factor of the symmetrised ``cov`` with a 1e-12 relative jitter on the diagonal,
    so that a singular covariance (an unidentified direction) stays drawable."""
    cov = np.atleast_2d(np.asarray(cov, float))
    d = cov.shape[0]
    jitter = 1e-12 * max(float(np.trace(cov)) / d, 1e-300)
    return np.linalg.cholesky(0.5 * (cov + cov.T) + jitter * np.eye(d))


class Independence(emcee.moves.MHMove):
    """Independence Metropolis–Hastings from a fixed multivariate t (emcee ``MHMove``).

    Every walker proposes x' ~ t_ν(μ, Σ) whatever its position, and accepts
    with min(1, p(x') q(x) / (p(x) q(x'))): the chain is exact for any fixed
    q, and when q is close to the target (a Gaussian fitted to a pilot
    chain of it, :func:`bayes_mr.inference.mcmc.sample`) a proposal is accepted often and lands
    anywhere in the posterior, so successive positions are nearly
    independent — an integrated time of a few steps where the local
    differential-evolution moves need tens. Where q is a poor fit (a curved
    valley, a posterior piled against a bound) it is rejected more often
    and the ensemble's DE moves carry the chain. The t tails (ν = 4) keep
    the importance ratio p/q bounded where a Gaussian q would be lighter
    tailed than the target.

    Parameters
    ----------
    mean : ndarray (d,)
        Centre μ of the proposal (e.g. a pilot chain's mean).
    cov : ndarray (d, d)
        Scale matrix Σ (e.g. that chain's covariance).
    df : float
        Degrees of freedom ν.
    """

    def __init__(self, mean, cov, df: float = 4.0):
        self.mean = np.asarray(mean, float)
        d = self.mean.size
        self.chol = jittered_cholesky(cov)
        self.df = float(df)
        super().__init__(self._propose, ndim=d)

    def log_density(self, x: np.ndarray) -> np.ndarray:
        """ln q(x) up to a constant, for x of shape (n, d)."""
        u = np.linalg.solve(self.chol, (np.atleast_2d(x) - self.mean).T)
        return -0.5 * (self.df + self.mean.size) * np.log1p(np.sum(u * u, axis=0) / self.df)

    def _propose(self, x0, random):
        n, d = x0.shape
        z = random.randn(n, d) @ self.chol.T
        w = np.sqrt(random.chisquare(self.df, n) / self.df)
        q = self.mean + z / w[:, None]
        return q, self.log_density(x0) - self.log_density(q)


#: Move names accepted in :attr:`MCMCSettings.moves`. ``emcee_snooker`` is emcee 3.1.6's biased
#: DESnookerMove, kept only so the test can show the bias.
MOVES = {
    "de": emcee.moves.DEMove,
    "snooker": Snooker,
    "stretch": emcee.moves.StretchMove,
    "emcee_snooker": emcee.moves.DESnookerMove,
    "independence": Independence,
}
#: Moves built from a proposal Gaussian (mean, cov) rather than from nothing.
NEEDS_PROPOSAL = ("independence",)


def local_moves(moves: tuple[tuple[str, float], ...]) -> tuple[tuple[str, float], ...]:
    """``moves`` without those that need a proposal (differential evolution and snooker if none is left)."""
    return tuple(m for m in moves if m[0] not in NEEDS_PROPOSAL) or (("de", 0.8), ("snooker", 0.2))
