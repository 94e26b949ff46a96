"""The walkers an emcee run starts from (:func:`bayes_mr.inference.mcmc.sampler.sample`): drawn inside the prior box."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from bayes_mr.inference.mcmc.moves import jittered_cholesky

LogDensity = Callable[[np.ndarray], np.ndarray]

#: Each redraw of the walkers that fell outside the support narrows their cloud by this factor.
SHRINK = 0.8


def reflect_into(x: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Points x (B, d) mirrored at the box's faces until inside [lower, upper] (coordinates with an infinite
    or empty side are left alone)."""
    lo, hi = np.asarray(lower, float), np.asarray(upper, float)
    w = hi - lo
    ok = np.isfinite(w) & (w > 0)
    y = np.mod(x - lo, 2 * np.where(ok, w, 1.0))
    inside = lo + np.where(y > w, 2 * w - y, y)
    return np.where(ok, inside, x)


def initial_walkers(
    log_prob: LogDensity,
    center: np.ndarray,
    cov: np.ndarray,
    n_walkers: int,
    rng: np.random.Generator,
    *,
    max_rounds: int = 50,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Walkers drawn from N(center, cov), redrawn until the log-density is finite.

    With ``bounds`` (the prior's box) a draw beyond a bound is mirrored back
    into the box: a centre on a bound (an optimum pinned there, common in
    several coordinates at once — spencer on the packaged record) would
    otherwise lose half its draws per such coordinate, 2⁻ᵏ for k of them, and
    the ladder below narrows the cloud only by :data:`SHRINK` per round. A walker
    whose draw still has no finite log-density (the model fails there) is
    drawn again from a cloud narrowed by :data:`SHRINK` per round.

    Returns
    -------
    coords : ndarray (n_walkers, d)
    log_prob : ndarray (n_walkers,)

    Raises
    ------
    RuntimeError
        If after ``max_rounds`` fewer than all walkers have a finite
        log-density (the centre is outside the support, or the model fails
        near it).
    """
    center = np.asarray(center, float)
    d = center.size
    L = jittered_cholesky(cov)
    coords = np.empty((n_walkers, d))
    lp = np.full(n_walkers, -np.inf)
    todo = np.arange(n_walkers)
    for r in range(max_rounds):
        # a cloud that overhangs the prior box (an optimum at its edge) is drawn again, narrower
        x = center + SHRINK**r * rng.standard_normal((todo.size, d)) @ L.T
        if bounds is not None:
            x = reflect_into(x, *bounds)
        val = np.asarray(log_prob(x), float)
        ok = np.isfinite(val)
        coords[todo[ok]] = x[ok]
        lp[todo[ok]] = val[ok]
        todo = todo[~ok]
        if todo.size == 0:
            return coords, lp
    raise RuntimeError(
        f"{todo.size} of {n_walkers} walkers have no finite log-density after {max_rounds} draws around "
        f"the starting point; check that it lies inside the prior box")


def start_walkers(
    log_prob: LogDensity,
    x0_center: np.ndarray,
    x0_cov: np.ndarray,
    n_walkers: int,
    rng: np.random.Generator,
    initial: np.ndarray | None,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Initial walker positions and their log-densities: ``initial`` checked, or drawn around the centre
    (inside ``bounds``, :func:`initial_walkers`).

    Raises
    ------
    ValueError
        If a walker of ``initial`` has no finite log-density.
    """
    if initial is None:
        return initial_walkers(log_prob, x0_center, x0_cov, n_walkers, rng, bounds=bounds)
    coords = np.asarray(initial, float).copy()
    lp0 = np.asarray(log_prob(coords), float)
    if not np.all(np.isfinite(lp0)):
        raise ValueError(f"{int(np.sum(~np.isfinite(lp0)))} initial walkers have no finite log-density")
    return coords, lp0
