"""Where an emcee run starts: its seeds, the initial walkers, and the cloud they are drawn from.

A run's ``seed`` becomes a :class:`numpy.random.SeedSequence` with two children: one seeds the Generator that
draws the initial walkers, the other the ``RandomState`` of emcee's moves (whose state the checkpoint stores,
:mod:`.chain`), so a resumed run continues the same random stream. The walkers are drawn from a Gaussian cloud
around a centre — for the package's posterior the least-squares optimum with its HAC covariance, widened
(:func:`start_from_lsq`) — mirrored into the prior box and redrawn, narrower, where the log-density is not finite.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from bayes_mr.inference.mcmc.moves import jittered_cholesky
from bayes_mr.numerics.synthetic_noise import as_seed_sequence

LogDensity = Callable[[np.ndarray], np.ndarray]


# --- seeds -----------------------------------------------------------------------


def run_seeds(seed) -> tuple[np.random.Generator, dict, str]:
    """The Generator of the initial walkers, emcee's RandomState state, and the seed's entropy.

    Parameters
    ----------
    seed : int or SeedSequence

    Returns
    -------
    init_rng : numpy.random.Generator
        Draws the initial walkers.
    move_state : dict
        State of the legacy ``RandomState`` emcee's moves draw from (we set
        its state, never the global one).
    entropy : str
        The seed's entropy, with the spawn key of a spawned child (a child
        shares its parent's entropy: the spawn key tells them apart).
    """
    seq = as_seed_sequence(seed)
    init_seq, move_seq = seq.spawn(2)
    rs = np.random.RandomState(np.random.MT19937(move_seq))
    entropy = str(seq.entropy) + ("/" + "-".join(map(str, seq.spawn_key)) if seq.spawn_key else "")
    return np.random.default_rng(init_seq), rs.get_state(), entropy


def seed_of(entropy: str) -> np.random.SeedSequence:
    """The SeedSequence a :func:`run_seeds` entropy string names (``"ENTROPY"`` or ``"ENTROPY/K1-K2…"``)."""
    ent, _, key = str(entropy).partition("/")
    return np.random.SeedSequence(int(ent), spawn_key=tuple(int(k) for k in key.split("-") if k))


def child_seed(seed, key: int) -> np.random.SeedSequence:
    """The child of ``seed`` with spawn key ``key`` appended (not one ``SeedSequence.spawn`` gives)."""
    seq = as_seed_sequence(seed)
    return np.random.SeedSequence(seq.entropy, spawn_key=seq.spawn_key + (key,))


# --- the initial walkers -----------------------------------------------------------

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


# --- the package's posterior: the least-squares optimum -------------------------------

#: Standard deviations of the LSQ (HAC) covariance are widened by this factor for the walker cloud:
#: a cloud a little wider than the posterior contracts in a few τ; a narrower one expands slowly.
INIT_INFLATION = 1.5


def start_from_lsq(lik, lsq) -> tuple[np.ndarray, np.ndarray]:
    """Centre and covariance of the initial walkers from a least-squares fit.

    The centre is (φ̂, ln σ̂); the covariance is the HAC sandwich of φ̂ (wider
    than the iid posterior when residuals are autocorrelated — a safe start)
    and, for ln σ_c, 1/(2 N_c) (the curvature of the Gaussian likelihood in
    ln σ), both widened by :data:`INIT_INFLATION`; the cloud is centred inside
    the prior box.

    Parameters
    ----------
    lik : OutputError
    lsq : LSQResult

    Returns
    -------
    center : ndarray (ndim,)
    cov : ndarray (ndim, ndim)
    """
    p = lik.n_params
    center = np.array(lsq.phi, float)
    cov_phi = np.array(lsq.cov_phi, float)
    if not np.all(np.isfinite(cov_phi)) or np.any(np.diag(cov_phi) <= 0):
        cov_phi = np.array(lsq.cov_phi_iid, float)
    blocks = [cov_phi]
    if lik.noise == "sampled":
        center = np.concatenate([center, np.log(lsq.sigma)])
        blocks.append(np.eye(lik.ndim - p) / (2.0 * lik.n_valid))
    cov = np.zeros((lik.ndim, lik.ndim))
    cov[:p, :p] = blocks[0]
    if len(blocks) > 1:
        cov[p:, p:] = blocks[1]
    cov *= INIT_INFLATION**2
    lo, hi = lik.lower, lik.upper
    center = np.clip(center, lo + 1e-6 * (hi - lo), hi - 1e-6 * (hi - lo))
    return center, cov
