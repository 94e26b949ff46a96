"""The independence proposal's coordinates: where a multivariate t fits a posterior, and fitting it there.

:class:`~bayes_mr.inference.mcmc.moves.Independence` proposes from a t in coordinates y = map(x) and evaluates
q(x) = t(y) |dy/dx|. The map, fitted to a pilot's draws (:func:`fit_proposal`), is three steps, each taken only
where it fits the pilot's draws better (mean log-density of the joint Gaussian, Jacobian included):

1. **edges** — a coordinate piled against a bound of the prior box: u = ln(distance to the bound);
2. **margins** — a coordinate with a non-Gaussian marginal (a plateau of a weakly informed parameter, a long
   tail): v = a monotone piecewise-linear map of its pilot quantiles onto the normal's (:func:`fit_margins`);
3. **shear** — a curved ridge: y = v − B (v − c)², a coordinate minus quadratics of others (Jacobian 1,
   :func:`fit_shear`).

Any fixed map keeps the independence chain exact; the map only decides how often it accepts.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import stats

#: A pilot's marginal whose mean is closer than this many of its SDs to a bound of the box may be proposed in
#: log-distance to it (:class:`ProposalMap`), where that fits the pilot better (:func:`fit_proposal`).
#: On normalized-bouc-wen's posterior on the bench's compare record (``bayes-mr bench``; n's marginal: mean ≈ SD
#: from its bound, skew 2.1): acceptance 0.33 → 0.44, τ 10.4 → 4.9, the same means and SDs
#: (``tests/inference/test_mcmc.py`` checks the choice on targets piled at a bound).
EDGE_SDS = 3.0


def _gaussian_fit(y: np.ndarray) -> float:
    """Mean log-density of the rows of y (n, d) under the Gaussian fitted to them (ML): −½ ln det(2πe Σ)."""
    _, logdet = np.linalg.slogdet(np.atleast_2d(np.cov(y, rowvar=False, bias=True)))
    return -0.5 * (logdet + y.shape[1] * np.log(2.0 * np.pi * np.e))


def to_edge_coords(x: np.ndarray, edges) -> tuple[np.ndarray, np.ndarray]:
    """u of :class:`ProposalMap` (ln of the distance to the edge where side ≠ 0) and ln |du/dx| per row."""
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


@dataclass(frozen=True)
class ProposalMap:
    """x → y of the independence proposal (module docstring); the identity when nothing is set.

    Attributes
    ----------
    box : (ndarray (d,), ndarray (d,)), optional
        The target's support (lower, upper): proposals are drawn inside it.
    side : ndarray (d,) of int, optional
        Per coordinate −1 proposes ln(x − lower), +1 ln(upper − x), 0 x itself.
    margins : dict of int to ndarray
        Coordinate → its pilot quantiles at :data:`MARGIN_PROBS` (after ``side``): the knots of its map.
    shear : (ndarray (d,), ndarray (d, d)), optional
        (c, B) of :func:`fit_shear`.
    """

    box: tuple | None = None
    side: np.ndarray | None = None
    margins: dict = field(default_factory=dict)
    shear: tuple | None = None

    def forward(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(y, ln |dy/dx|) of the rows of x (n, d)."""
        u, log_jac = to_edge_coords(np.atleast_2d(x), self._edges())
        if self.margins:
            u = np.array(u, float, copy=True)
            for j, knots in self.margins.items():
                u[:, j], lj = margin_forward(u[:, j], knots)
                log_jac = log_jac + lj
        return sheared(u, self.shear), log_jac

    def inverse(self, y: np.ndarray) -> np.ndarray:
        """x of the rows of y (inverse of :meth:`forward`)."""
        u = unsheared(np.atleast_2d(y), self.shear)
        if self.margins:
            u = np.array(u, float, copy=True)
            for j, knots in self.margins.items():
                u[:, j] = margin_inverse(u[:, j], knots)
        return from_edge_coords(u, self._edges())

    def _edges(self):
        if self.side is None or not np.any(self.side):
            return None
        return (*self.box, self.side)


#: Probabilities of the knots of a marginal map (:func:`fit_margins`): the pilot's quantiles there are mapped
#: onto the standard normal's, linearly between knots and beyond the outer ones.
MARGIN_PROBS = np.array([0.01, 0.05, 0.15, 0.3, 0.5, 0.7, 0.85, 0.95, 0.99])
_MARGIN_Z = stats.norm.ppf(MARGIN_PROBS)
#: A marginal map is kept when it raises the pilot's joint Gaussian fit (Jacobian included) by at least this
#: (nats per draw). On spencer's posterior of the packaged damper β (a long tail) gains 0.32-0.52 and the
#: plateaus against the prior's lower bound 0.08-0.13, 500 independent Gaussian draws at most 0.011
#: (``tests/inference/test_proposal_margins.py``: a plateau and a tail mapped, a Gaussian left alone).
MARGIN_MIN_GAIN = 0.05


def margin_forward(col: np.ndarray, knots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(v, ln dv/du) of one coordinate under the piecewise-linear map of ``knots`` onto :data:`MARGIN_PROBS`'s
    normal quantiles (the outer segments extended)."""
    i = np.clip(np.searchsorted(knots, col) - 1, 0, knots.size - 2)
    slope = (_MARGIN_Z[i + 1] - _MARGIN_Z[i]) / (knots[i + 1] - knots[i])
    return _MARGIN_Z[i] + slope * (col - knots[i]), np.log(slope)


def margin_inverse(v: np.ndarray, knots: np.ndarray) -> np.ndarray:
    """u of :func:`margin_forward`'s v."""
    i = np.clip(np.searchsorted(_MARGIN_Z, v) - 1, 0, knots.size - 2)
    return knots[i] + (v - _MARGIN_Z[i]) * (knots[i + 1] - knots[i]) / (_MARGIN_Z[i + 1] - _MARGIN_Z[i])


def fit_margins(u: np.ndarray, min_gain: float = MARGIN_MIN_GAIN) -> dict:
    """Coordinate → knots of the marginal maps that fit the draws u (n, d) better, taken greedily, best first,
    each kept if the joint Gaussian's mean log-density plus the mean ln dv/du gains ``min_gain`` or more."""
    u = np.asarray(u, float)
    candidates = {}
    for j in range(u.shape[1]):
        knots = np.quantile(u[:, j], MARGIN_PROBS)
        if np.all(np.diff(knots) > 0.0):  # a coordinate that barely moved has no map
            candidates[j] = (knots, *margin_forward(u[:, j], knots))
    chosen, v, fit = {}, u.copy(), _gaussian_fit(u)  # fit: of v, without the chosen maps' Jacobians
    while np.isfinite(fit) and candidates:
        gains = {}
        for j, (knots, vj, lj) in candidates.items():
            trial = v.copy()
            trial[:, j] = vj
            gains[j] = _gaussian_fit(trial) + lj.mean() - fit
        j = max(gains, key=gains.get)
        if gains[j] < min_gain:
            break
        knots, v[:, j], _ = candidates.pop(j)
        chosen[j] = knots
        fit = _gaussian_fit(v)
    return chosen


def sheared(u: np.ndarray, shear) -> np.ndarray:
    """y = u − B (u − c)² of :class:`ProposalMap` (u itself without a shear)."""
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
#: least this (nats per draw; :func:`fit_shear`): spencer's γ–n term on the packaged damper gains 0.22-0.35, the
#: best spurious terms of autocorrelated pilots 0.02-0.05 (``tests/inference/test_shear.py``: the banana's
#: parabola found, nothing in a Gaussian). A spurious term fitted to a narrow pilot extrapolates as a parabola
#: when the chain spreads.
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
    d = u.shape[1]
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


def fit_proposal(x: np.ndarray, bounds=None) -> tuple:
    """(mean, cov, map) of :class:`~bayes_mr.inference.mcmc.moves.Independence` fitted to pilot draws x (n, d) within
    the box ``bounds``: its t's centre and scale in the coordinates of the :class:`ProposalMap` (edges where
    ``bounds`` is given, then :func:`fit_margins`, then :func:`fit_shear`).

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
    independence move then accepts 0.09 instead of 0.29 (τ 20 against 8).
    The compare record's n gains 0.16 nats: τ ≈ 4 there, 8–10 with n left in x.
    """
    x = np.asarray(x, float)
    box = None if bounds is None else tuple(np.asarray(b, float) for b in bounds)
    side = None if bounds is None else _fit_edges(x, box)
    u = ProposalMap(box=box, side=side).forward(x)[0]
    margins = fit_margins(u)
    u = ProposalMap(margins=margins).forward(u)[0]
    pmap = ProposalMap(box=box, side=side, margins=margins, shear=fit_shear(u))
    y = sheared(u, pmap.shear)
    return y.mean(axis=0), np.cov(y, rowvar=False), pmap


def _fit_edges(x: np.ndarray, bounds) -> np.ndarray:
    """``side`` of :func:`fit_proposal` (:class:`ProposalMap`): the coordinates whose log-distance to a bound
    fits better."""
    lower, upper = bounds
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
    return side
