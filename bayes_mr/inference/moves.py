"""Ensemble moves for emcee: the corrected DE snooker update, an independence proposal, the names settings accept."""

from __future__ import annotations

import emcee
import numpy as np

from .proposal import ProposalMap


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
    so that a singular covariance (an unidentified direction) stays drawable.

    A covariance built on a pseudo-inverse can carry eigenvalues a rounding error below zero, more than the
    jitter covers (spencer's least-squares covariance on the packaged damper: Cholesky failed); its
    eigenvalues are then raised to the jitter (the nearest positive-definite matrix in that sense).
    """
    cov = np.atleast_2d(np.asarray(cov, float))
    d = cov.shape[0]
    jitter = 1e-12 * max(float(np.trace(cov)) / d, 1e-300)
    sym = 0.5 * (cov + cov.T)
    try:
        return np.linalg.cholesky(sym + jitter * np.eye(d))
    except np.linalg.LinAlgError:
        w, u = np.linalg.eigh(sym)
        # the diagonal jitter again: the product U diag(w) Uᵀ rounds, and may round a floor-sized eigenvalue away
        return np.linalg.cholesky((u * np.maximum(w, jitter)) @ u.T + jitter * np.eye(d))


class Independence(emcee.moves.MHMove):
    """Independence Metropolis–Hastings from a fixed multivariate t (emcee ``MHMove``).

    Every walker proposes x' ~ q whatever its position, and accepts
    with min(1, p(x') q(x) / (p(x) q(x'))): the chain is exact for any fixed
    q, and when q is close to the target (fitted to a pilot
    chain of it, :func:`bayes_mr.inference.mcmc.sample`) a proposal is accepted often and lands
    anywhere in the posterior, so successive positions are nearly
    independent — an integrated time of a few steps where the local
    differential-evolution moves need tens. Where q is a poor fit (a curved
    valley) it is rejected more often and the ensemble's DE moves carry the
    chain. The t tails (ν = 4) keep the importance ratio p/q bounded where a
    Gaussian q would be lighter tailed than the target.

    q is a t in the coordinates of a :class:`~bayes_mr.inference.proposal.ProposalMap`, fitted to a pilot
    (:func:`~bayes_mr.inference.proposal.fit_proposal`): a coordinate piled against a bound of the prior box in
    log-distance to it, a non-Gaussian marginal mapped onto the normal through its quantiles, a curved ridge
    (a banana: spencer's γ moves with n and n² on the packaged damper) straightened by a shear; q(x) carries
    the map's Jacobian. Measured on spencer's posterior (main job's part A, seed 0, unbudgeted, 56 walkers):
    with the shear the chain converged after 1800 steps (τ 10–15, R-hat < 1.01; acceptance 0.27) where
    without it 2500 steps had not (τ 20–26, 37–43 for γ, β, n; R-hat 1.03; acceptance 0.22); with the
    marginal maps too, τ 7–8 (β 11) and the last adaptation round accepted 0.31, but R-hat < 1.01 held only
    after 2100 steps (β's was the last to pass). With 30 walkers (shear only) τ was 41–62 after 3000 steps:
    the rounds' fits from fewer draws accepted 0.09–0.14.

    Given the box (the map's ``box``), proposals are drawn from q *restricted to it*:
    a draw outside is drawn again (up to :data:`REDRAWS` times). The
    restricted density is q times a constant on the box, and the constant
    cancels from the Hastings ratio, so the chain stays exact; a draw outside
    the prior's box is one the target rejects anyway, so this spends no
    likelihood evaluation on it. Measured on the packaged damper's posteriors
    (20 000 draws of the t fitted to each chain's second half):
    normalized-bouc-wen's put 13 % of its draws outside the box, spencer's 26 %.

    Parameters
    ----------
    mean : ndarray (d,)
        Centre μ of the t, in the map's coordinates y.
    cov : ndarray (d, d)
        Scale matrix Σ of the t, same coordinates.
    pmap : ProposalMap, optional
        x → y and the target's support box (default: y = x, no box).
    df : float
        Degrees of freedom ν.
    """

    def __init__(self, mean, cov, pmap: ProposalMap | None = None, df: float = 4.0):
        self.mean = np.asarray(mean, float)
        d = self.mean.size
        self.chol = jittered_cholesky(cov)
        self.df = float(df)
        self.pmap = pmap or ProposalMap()
        self.box = self.pmap.box
        super().__init__(self._propose, ndim=d)

    def log_density(self, x: np.ndarray) -> np.ndarray:
        """ln q(x) up to a constant, for x of shape (n, d) (in the target's coordinates)."""
        x = np.atleast_2d(x)
        y, log_jac = self.pmap.forward(x)
        z = np.linalg.solve(self.chol, (y - self.mean).T)
        return -0.5 * (self.df + self.mean.size) * np.log1p(np.sum(z * z, axis=0) / self.df) + log_jac

    def _draw(self, n: int, random) -> np.ndarray:
        """n draws of q (target coordinates)."""
        z = random.randn(n, self.mean.size) @ self.chol.T
        w = np.sqrt(random.chisquare(self.df, n) / self.df)
        return self.pmap.inverse(self.mean + z / w[:, None])

    def _outside(self, q: np.ndarray) -> np.ndarray:
        """Indices of the rows of q outside the box."""
        lower, upper = self.box
        return np.flatnonzero(~np.all((q >= lower) & (q <= upper), axis=1))

    def _propose(self, x0, random):
        q = self._draw(x0.shape[0], random)
        if self.box is not None:
            out = self._outside(q)
            for _ in range(REDRAWS):
                if out.size == 0:
                    break
                q[out] = self._draw(out.size, random)
                out = out[self._outside(q[out])]
        return q, self.log_density(x0) - self.log_density(q)


#: Times :class:`Independence` draws again a proposal that fell outside the box before leaving it to be
#: rejected: at an in-box share of 1 %, 20 rounds still place a fifth of the proposals.
REDRAWS = 20


#: Move names accepted in :attr:`MCMCSettings.moves`. ``emcee_snooker`` is emcee 3.1.6's biased
#: DESnookerMove, kept only so the test can show the bias.
MOVES = {
    "de": emcee.moves.DEMove,
    "snooker": Snooker,
    "stretch": emcee.moves.StretchMove,
    "emcee_snooker": emcee.moves.DESnookerMove,
    "independence": Independence,
}
#: Moves built from a fitted proposal (mean, cov[, map]: :func:`~bayes_mr.inference.proposal.fit_proposal`)
#: rather than from nothing.
NEEDS_PROPOSAL = ("independence",)


def local_moves(moves: tuple[tuple[str, float], ...]) -> tuple[tuple[str, float], ...]:
    """``moves`` without those that need a proposal (differential evolution and snooker if none is left)."""
    return tuple(m for m in moves if m[0] not in NEEDS_PROPOSAL) or (("de", 0.8), ("snooker", 0.2))
