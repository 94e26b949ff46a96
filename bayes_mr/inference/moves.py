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

    A coordinate piled against a bound of the prior box (an effect's
    parameter at "off") has a skewed, exponential-like marginal no symmetric
    q fits; ``edges`` proposes it as u = ln(x − lower) (or ln(upper − x))
    instead, with the Jacobian in q, so its proposals stay inside the box and
    follow the skew (:func:`fit_proposal` decides which, if any).

    A curved ridge (a banana: spencer's γ moves with n and with n² on the
    packaged damper) leaves a linear fit's cross-section skewed, and the
    walkers that land on the side q underweights stay there. ``shear``
    straightens it: q is the t of y = u − B (u − c)², a coordinate minus
    quadratics of others (:func:`fit_shear`), whose Jacobian is 1. Measured on
    spencer's posterior (main job's part A, seed 0, unbudgeted): the chain
    converged after 1800 steps (τ 10–15, R-hat < 1.01; acceptance 0.27) where
    without the shear 2500 steps had not (τ 20–26, 37–43 for γ, β, n; R-hat
    1.03; acceptance 0.22).

    Given the box (``edges``), proposals are drawn from q *restricted to it*:
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
        Centre μ of the t, in the proposal's coordinates (u where ``edges`` transforms).
    cov : ndarray (d, d)
        Scale matrix Σ of the t, same coordinates.
    edges : (ndarray (d,), ndarray (d,), ndarray (d,) of int), optional
        (lower, upper, side): the target's support box, and per coordinate side −1 proposes
        ln(x − lower), +1 ln(upper − x), 0 x itself.
    shear : (ndarray (d,), ndarray (d, d)), optional
        (c, B) of :func:`fit_shear`: the t is of y = u − B (u − c)² (squares elementwise).
    df : float
        Degrees of freedom ν.
    """

    def __init__(self, mean, cov, edges=None, shear=None, df: float = 4.0):
        self.mean = np.asarray(mean, float)
        d = self.mean.size
        self.chol = jittered_cholesky(cov)
        self.df = float(df)
        self.box = None if edges is None else (np.asarray(edges[0], float), np.asarray(edges[1], float))
        self.edges = None if edges is None or not np.any(edges[2]) else tuple(np.asarray(e) for e in edges)
        self.shear = shear
        super().__init__(self._propose, ndim=d)

    def log_density(self, x: np.ndarray) -> np.ndarray:
        """ln q(x) up to a constant, for x of shape (n, d) (in the target's coordinates)."""
        x = np.atleast_2d(x)
        u, log_jac = to_edge_coords(x, self.edges)
        z = np.linalg.solve(self.chol, (sheared(u, self.shear) - self.mean).T)
        return -0.5 * (self.df + self.mean.size) * np.log1p(np.sum(z * z, axis=0) / self.df) + log_jac

    def _draw(self, n: int, random) -> np.ndarray:
        """n draws of q (target coordinates)."""
        z = random.randn(n, self.mean.size) @ self.chol.T
        w = np.sqrt(random.chisquare(self.df, n) / self.df)
        return from_edge_coords(unsheared(self.mean + z / w[:, None], self.shear), self.edges)

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


def to_edge_coords(x: np.ndarray, edges) -> tuple[np.ndarray, np.ndarray]:
    """u of :class:`Independence` (ln of the distance to the edge where side ≠ 0) and ln |du/dx| per row."""
    if edges is None:
        return x, np.zeros(x.shape[0])
    lower, upper, side = edges
    u = np.array(x, float, copy=True)
    gap = np.where(side < 0, x - lower, upper - x)[:, side != 0]
    gap = np.maximum(gap, 1e-300)  # a walker on the bound itself: q finite, the Hastings ratio tiny
    u[:, side != 0] = np.log(gap)
    return u, -np.sum(np.log(gap), axis=1)


def from_edge_coords(u: np.ndarray, edges) -> np.ndarray:
    """x from the proposal coordinates u (inverse of :func:`to_edge_coords`)."""
    if edges is None:
        return u
    lower, upper, side = edges
    x = np.array(u, float, copy=True)
    lo, hi = side < 0, side > 0
    x[:, lo] = lower[lo] + np.exp(u[:, lo])
    x[:, hi] = upper[hi] - np.exp(u[:, hi])
    return x


def sheared(u: np.ndarray, shear) -> np.ndarray:
    """y = u − B (u − c)² of :class:`Independence` (u itself without a shear)."""
    if shear is None:
        return u
    centre, b = shear
    return u - ((u - centre) ** 2) @ b.T


def unsheared(y: np.ndarray, shear) -> np.ndarray:
    """u from y (inverse of :func:`sheared`): a coordinate that drives a shear is never sheared itself, so the
    squares are of y's own columns there."""
    if shear is None:
        return y
    centre, b = shear
    return y + ((y - centre) ** 2) @ b.T


#: A shear term is kept when it raises the mean log-density of the pilot's draws under the fitted Gaussian by at
#: least this (nats per draw; :func:`fit_shear`). Measured: spencer's γ–n term on the packaged damper gains
#: 0.22-0.35 (50-step windows of an unbudgeted chain, 2800 draws); the best spurious terms there, and on a DE
#: pilot of a 12-d Gaussian, 0.02-0.05 (autocorrelated draws: a few hundred effective ones); on 4800 independent
#: Gaussian draws 0.001. A spurious term fitted to a narrow pilot extrapolates as a parabola when the chain spreads.
SHEAR_MIN_GAIN = 0.1


def fit_shear(u: np.ndarray, min_gain: float = SHEAR_MIN_GAIN):
    """(c, B) of the shear y = u − B (u − c)² that straightens a curved pilot u (n, d), or None if no term gains.

    Greedy, best first: the term b·(u_k − c_k)² in coordinate j is scored by the gain it gives the pilot's
    Gaussian fit, −½ ln(1 − ρ²) per draw, with ρ the partial correlation of y_j and (u_k − c_k)² given the other
    columns of y, and b their regression coefficient (both from the precision matrix of [y, (u_k − c_k)²]).
    Replacing y_j by its residual changes only y_j's conditional variance, so that is the whole gain. A
    coordinate that drives a term is never sheared and a sheared one never drives, which keeps the map
    invertible in one step (:func:`unsheared`) and its Jacobian 1.
    """
    u = np.asarray(u, float)
    n, d = u.shape
    centre = u.mean(axis=0)
    sq = (u - centre) ** 2
    b = np.zeros((d, d))
    y = u.copy()
    drives, is_sheared = np.zeros(d, bool), np.zeros(d, bool)
    while True:
        best, term = min_gain, None
        for k in np.flatnonzero(~is_sheared):
            try:
                prec = np.linalg.inv(np.cov(np.column_stack([y, sq[:, k]]), rowvar=False))
            except np.linalg.LinAlgError:  # a coordinate that never moved: nothing to fit
                continue
            for j in np.flatnonzero(~drives):
                if j == k or not prec[j, j] * prec[d, d] > 0.0:
                    continue
                rho2 = prec[j, d] ** 2 / (prec[j, j] * prec[d, d])
                gain = -0.5 * np.log1p(-min(rho2, 1.0 - 1e-12))
                if gain > best:
                    best, term = gain, (j, k, -prec[j, d] / prec[j, j])
        if term is None:
            break
        j, k, coef = term
        b[j, k] += coef
        y[:, j] -= coef * sq[:, k]
        drives[k], is_sheared[j] = True, True
    return (centre, b) if np.any(b) else None


#: A pilot's marginal whose mean is closer than this many of its SDs to a bound of the box may be proposed in
#: log-distance to it (:class:`Independence`), where that fits the pilot better (:func:`fit_proposal`).
#: Measured on normalized-bouc-wen's posterior on the bench's compare record (n's marginal: mean ≈ SD from
#: its bound, skew 2.1): acceptance 0.33 → 0.44, τ 10.4 → 4.9, 1300 → 650 steps, the same means and SDs.
EDGE_SDS = 3.0


def _gaussian_fit(y: np.ndarray) -> float:
    """Mean log-density of the rows of y (n, d) under the Gaussian fitted to them (ML): −½ ln det(2πe Σ)."""
    _, logdet = np.linalg.slogdet(np.atleast_2d(np.cov(y, rowvar=False, bias=True)))
    return -0.5 * (logdet + y.shape[1] * np.log(2.0 * np.pi * np.e))


def fit_proposal(x: np.ndarray, bounds=None) -> tuple:
    """(mean, cov, edges, shear) of :class:`Independence` fitted to pilot draws x (n, d) within the box ``bounds``
    (``edges`` whenever ``bounds`` is given: the box, and the coordinates proposed in log-distance to it, else None;
    ``shear`` of :func:`fit_shear` on those coordinates, or None).

    A coordinate whose pilot mean lies within :data:`EDGE_SDS` SDs of a bound
    is proposed in u = ln(distance to that bound) only where that fits the
    pilot better: the joint Gaussian fitted with that coordinate in u, carried
    back to x with the Jacobian |du/dx| = 1/distance, against the Gaussian
    with it in x, by the mean log-density of the pilot draws (coordinates
    taken greedily, best gain first, each kept if it still gains). Joint, not
    marginal: the marginal of normalized-bouc-wen's n on the bench's compare
    record and of bouc-wen's n on the Bouc–Wen benchmark are alike (mean 1.1
    SDs from the bound, skew 1.4 and 1.1), and both are fitted better in u
    alone; but the benchmark's n moves with β₁ and γ (correlation ±0.98 in x,
    ±0.81 in u), and in u the joint fit loses 2.5 nats per draw — its
    independence move then accepted 0.09 instead of 0.29 (τ 20 against 8,
    measured). The compare record's n gains 0.16 nats: τ ≈ 4 there, 8–10 with n left in x.
    """
    x = np.asarray(x, float)
    edges = None if bounds is None else _fit_edges(x, bounds)
    u = to_edge_coords(x, edges)[0]
    shear = fit_shear(u)
    y = sheared(u, shear)
    return y.mean(axis=0), np.cov(y, rowvar=False), edges, shear


def _fit_edges(x: np.ndarray, bounds) -> tuple:
    """(lower, upper, side) of :func:`fit_proposal`: the coordinates whose log-distance to a bound fits better."""
    lower, upper = (np.asarray(b, float) for b in bounds)
    m, sd = x.mean(axis=0), x.std(axis=0)
    near_lo, near_hi = m - lower < EDGE_SDS * sd, upper - m < EDGE_SDS * sd
    near = np.where(near_lo & (~near_hi | (m - lower <= upper - m)), -1, np.where(near_hi, 1, 0))
    # every near column in log-distance once; a column's mean ln |du/dx| is −mean(u) there
    u_near, _ = to_edge_coords(x, (lower, upper, near))
    mean_log_jac = -u_near.mean(axis=0)
    side = np.zeros_like(near)
    best = _gaussian_fit(x)
    while np.isfinite(best):  # a singular pilot (a coordinate that never moved) moves nothing
        gains = {}
        for j in np.flatnonzero((near != 0) & (side == 0)):
            trial = side != 0
            trial[j] = True
            gains[j] = _gaussian_fit(np.where(trial, u_near, x)) + mean_log_jac[trial].sum() - best
        if not gains or max(gains.values()) <= 0.0:
            break
        j = max(gains, key=gains.get)
        side[j] = near[j]
        best += gains[j]
    return lower, upper, side


#: Move names accepted in :attr:`MCMCSettings.moves`. ``emcee_snooker`` is emcee 3.1.6's biased
#: DESnookerMove, kept only so the test can show the bias.
MOVES = {
    "de": emcee.moves.DEMove,
    "snooker": Snooker,
    "stretch": emcee.moves.StretchMove,
    "emcee_snooker": emcee.moves.DESnookerMove,
    "independence": Independence,
}
#: Moves built from a fitted proposal (mean, cov[, edges[, shear]]: :func:`fit_proposal`) rather than from nothing.
NEEDS_PROPOSAL = ("independence",)


def local_moves(moves: tuple[tuple[str, float], ...]) -> tuple[tuple[str, float], ...]:
    """``moves`` without those that need a proposal (differential evolution and snooker if none is left)."""
    return tuple(m for m in moves if m[0] not in NEEDS_PROPOSAL) or (("de", 0.8), ("snooker", 0.2))
