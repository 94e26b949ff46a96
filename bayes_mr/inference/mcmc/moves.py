"""Ensemble moves for emcee: the corrected DE snooker update, an independence proposal, the names settings accept."""

from __future__ import annotations

import emcee
import numpy as np
from scipy.special import gammaln, logsumexp

from bayes_mr.inference.mcmc.proposal import ProposalMap


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


#: Degrees of freedom ν of :class:`Independence`'s main t (:class:`~bayes_mr.inference.mcmc.settings.MCMCSettings`'s
#: ``proposal_df``). The scale matrix is the draws' covariance whatever ν, so a t with small ν is wider than
#: them (covariance Σ·ν/(ν − 2): twice at ν = 4) and spends proposals in the tails. On the main job's posteriors
#: of the packaged damper's part A a proposal fitted to a converged chain's draws accepts, at ν = 4 and 20,
#: 0.41 and 0.60 of the time on spencer's, 0.44 and 0.51 on bouc-wen's, 0.61 and 0.80 on normalized-bouc-wen's,
#: and its chains need fewer steps. A light-tailed q alone sticks where the target's tails outrun it (the banana
#: of ``tests/inference/test_shear.py``), hence the defensive t₄ share below (Hesterberg 1995), which bounds the
#: weights p/q where p's tails outrun t₂₀'s: Pareto k 1/4 against 17/20 for a t₃ target
#: (``tests/inference/test_proposal_tails.py``).
PROPOSAL_DF = 20.0
#: Share and ν of the heavy-tailed component mixed into :class:`Independence`'s q
#: (``MCMCSettings.defensive_share``): q = 0.8 t₂₀ + 0.2 t₄ bounds p/q by p/(0.2 t₄) wherever the target's
#: tails outrun t₂₀. On spencer's converged draws it costs little (acceptance 0.61 → 0.56 against t₂₀ alone,
#: 0.41 with t₄ alone); with a share of 0.1 the banana of ``tests/inference/test_shear.py`` needs 10 450 steps
#: on seed 5.
DEFENSIVE_SHARE = 0.2
DEFENSIVE_DF = 4.0


class Independence(emcee.moves.MHMove):
    """Independence Metropolis–Hastings from a fixed mixture of two multivariate t (emcee ``MHMove``).

    Every walker proposes x' ~ q whatever its position, and accepts
    with min(1, p(x') q(x) / (p(x) q(x'))): the chain is exact for any fixed
    q, and when q is close to the target (fitted to a pilot
    chain of it, :mod:`bayes_mr.inference.mcmc.adapt`) a proposal is accepted often and lands
    anywhere in the posterior, so successive positions are nearly
    independent — an integrated time of a few steps where the local
    differential-evolution moves need tens. Where q is a poor fit (a curved
    valley) it is rejected more often; in the adaptation rounds the ensemble's DE moves carry the
    walkers there, and the next q is fitted to them. q is a mixture of a t with ν = :data:`PROPOSAL_DF` and a defensive t₄ (:data:`DEFENSIVE_SHARE`
    of it) of the same centre and scale: the t₂₀ accepts more often than a heavy-tailed t, the t₄ keeps
    the importance ratio p/q bounded where the target's tails outrun t₂₀ (measured at the constants).

    q is that mixture in the coordinates of a :class:`~bayes_mr.inference.mcmc.proposal.ProposalMap`, fitted to a pilot
    (:func:`~bayes_mr.inference.mcmc.proposal.fit_proposal`): a coordinate piled against a bound of the prior box in
    log-distance to it, a non-Gaussian marginal mapped onto the normal through its quantiles, a curved ridge
    (a banana: spencer's γ moves with n and n² on the packaged damper) straightened by a shear; q(x) carries
    the map's Jacobian. On spencer's posterior (the main job's part A) the shear took τ from 20–26 to 10–15
    and the marginal maps to 7–8 (``tests/inference/test_shear.py`` and
    ``tests/inference/test_proposal_margins.py`` test each on a target made for it).

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
    defensive : float
        Share ε of the defensive component (ν = :data:`DEFENSIVE_DF`, same centre, scale and map): q is
        (1 − ε) t_ν + ε t₄, so p/q ≤ p/(ε t₄) wherever the target's tails outrun t_ν (0: t_ν alone).
    """

    def __init__(self, mean, cov, pmap: ProposalMap | None = None, df: float = PROPOSAL_DF,
                 defensive: float = DEFENSIVE_SHARE):
        self.mean = np.asarray(mean, float)
        d = self.mean.size
        self.chol = jittered_cholesky(cov)
        if not 0.0 <= defensive < 1.0:
            raise ValueError(f"the defensive share must be in [0, 1), got {defensive}")
        # (share, ν) of each component of the mixture: the main t first
        self.components = ((1.0 - defensive, float(df)),) + (((defensive, DEFENSIVE_DF),) if defensive else ())
        self.pmap = pmap or ProposalMap()
        self.box = self.pmap.box
        #: ln p(x′) − ln q(x′) of the proposals so far, one array per step (finite ones only)
        self.log_weights: list[np.ndarray] = []
        super().__init__(self._propose, ndim=d)

    def log_density(self, x: np.ndarray) -> np.ndarray:
        """ln q(x) up to a constant, for x of shape (n, d) (in the target's coordinates)."""
        x = np.atleast_2d(x)
        y, log_jac = self.pmap.forward(x)
        z = np.linalg.solve(self.chol, (y - self.mean).T)
        q = np.sum(z * z, axis=0)
        d = self.mean.size
        # each component's normalised ln density less the common ln|Σ|/2 (their ratio is what the mixture needs)
        terms = [np.log(share) + gammaln(0.5 * (nu + d)) - gammaln(0.5 * nu) - 0.5 * d * np.log(nu * np.pi)
                 - 0.5 * (nu + d) * np.log1p(q / nu) for share, nu in self.components]
        return logsumexp(terms, axis=0) + log_jac

    def _draw(self, n: int, random) -> np.ndarray:
        """n draws of q (target coordinates)."""
        z = random.randn(n, self.mean.size) @ self.chol.T
        nu = np.full(n, self.components[0][1])
        if len(self.components) == 2:  # one defensive component at most (__init__)
            share, nu_defensive = self.components[1]
            nu[random.rand(n) < share] = nu_defensive
        w = np.sqrt(random.chisquare(nu) / nu)
        return self.pmap.inverse(self.mean + z / w[:, None])

    def _outside(self, q: np.ndarray) -> np.ndarray:
        """Indices of the rows of q outside the box."""
        lower, upper = self.box
        return np.flatnonzero(~np.all((q >= lower) & (q <= upper), axis=1))

    def propose(self, model, state):
        """emcee's Metropolis–Hastings step, recording ln p(x′) − ln q(x′) of every proposal x′ in
        :attr:`log_weights` (importance weights of draws of q: :func:`~bayes_mr.inference.mcmc.convergence.tail_index`
        tells from them whether q bounds p/q)."""
        def recording(coords):
            lp, blobs = model.compute_log_prob_fn(coords)
            inside = np.isfinite(lp)  # a proposal the target rejects outright carries no weight
            self.log_weights.append(lp[inside] - self._log_q[inside])
            return lp, blobs

        return super().propose(model._replace(compute_log_prob_fn=recording), state)

    def _propose(self, x0, random):
        q = self._draw(x0.shape[0], random)
        if self.box is not None:
            out = self._outside(q)
            for _ in range(REDRAWS):
                if out.size == 0:
                    break
                q[out] = self._draw(out.size, random)
                out = out[self._outside(q[out])]
        self._log_q = self.log_density(q)
        return q, self.log_density(x0) - self._log_q


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
#: Moves built from a fitted proposal (mean, cov[, map]: :func:`~bayes_mr.inference.mcmc.proposal.fit_proposal`)
#: rather than from nothing.
NEEDS_PROPOSAL = ("independence",)


def local_moves(moves: tuple[tuple[str, float], ...]) -> tuple[tuple[str, float], ...]:
    """``moves`` without those that need a proposal (differential evolution and snooker if none is left)."""
    return tuple(m for m in moves if m[0] not in NEEDS_PROPOSAL) or (("de", 0.8), ("snooker", 0.2))
