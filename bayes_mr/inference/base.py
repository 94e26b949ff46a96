"""The estimator protocol: every engine turns one likelihood into one :class:`Posterior`.

An estimator is a small frozen object with a ``name`` and

    fit(likelihood, *, seed, progress) -> Posterior

where ``likelihood`` is the :class:`~bayes_mr.likelihood.output_error.OutputError` binding
of (model, record, noise model) that every engine shares. The
:class:`Posterior` holds what only the engine knows — its draws, the point it
stands behind, its evidence and diagnostics — and nothing that can be
derived from the likelihood: scores, pointwise log-likelihood, predictive
draws and the JSON summary are built from it by one function,
:func:`bayes_mr.inference.results.build`. Adding an engine touches ``inference/`` only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np
import xarray as xr

if TYPE_CHECKING:  # the likelihood is the layer below; imported for annotations only
    from bayes_mr.likelihood.output_error import OutputError


@dataclass
class Posterior:
    """What an estimator found, in the likelihood's coordinates.

    Attributes
    ----------
    engine : str
        Engine name (``lsq``, ``mcmc``, ``ukf``).
    draws : ndarray, shape (chain, draw, p)
        Posterior draws of the free parameters θ [SI].
    point : ndarray, shape (p,)
        The parameter set the engine stands behind (optimum, maximum a
        posteriori, selected run) [SI]; its prediction is what is scored.
    x_draws : ndarray, shape (n, ndim)
        Draws in the likelihood's coordinates x = [φ, ln σ_c] (the noise part
        only when the likelihood samples σ), best first: the first few
        become the pointwise log-likelihood and the predictive draws.
    x_chain : tuple of int, optional
        (chains, draws per chain) of ``x_draws`` when it is a (chain, draw)
        grid (MCMC); None for independent draws.
    pp_draws : ndarray, shape (m, ndim), optional
        Draws the predictive simulations are evenly taken from (default: the
        first rows of ``x_draws``).
    ll_time_index : ndarray of int, optional
        Samples the pointwise log-likelihood is stored on (default: evenly
        spaced valid samples).
    log_evidence : float or None
        ln p(y | model) by the engine's route.
    lp : ndarray, shape (chain, draw), optional
        Log posterior of each draw.
    params_sd_ddof : int
        Degrees of freedom of the reported SD (1 for a chain, 0 for exact draws).
    simulation : dict
        Keyword arguments of :func:`bayes_mr.simulation.simulate.simulate` the engine
        used (sub-step control), so scores replay its simulation.
    info : dict
        Engine-specific JSON keys added to the ``fit`` summary.
    sample_stats, groups, attrs : dict
        Engine-specific ``sample_stats`` variables, extra InferenceData groups
        and posterior attributes.
    sample_stats_attrs : dict
        Attributes of the ``sample_stats`` group (convergence diagnostics).
    trained, diverged : int or None
        Completed / failed UKF runs.
    wall_s : float
        Wall time of the engine [s].
    """

    engine: str
    draws: np.ndarray
    point: np.ndarray
    x_draws: np.ndarray
    x_chain: tuple[int, int] | None = None
    pp_draws: np.ndarray | None = None
    ll_time_index: np.ndarray | None = None
    log_evidence: float | None = None
    lp: np.ndarray | None = None
    params_sd_ddof: int = 0
    simulation: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)
    sample_stats: dict = field(default_factory=dict)
    sample_stats_attrs: dict = field(default_factory=dict)
    groups: dict[str, xr.Dataset] = field(default_factory=dict)
    attrs: dict = field(default_factory=dict)
    trained: int | None = None
    diverged: int | None = None
    wall_s: float = 0.0


@runtime_checkable
class Estimator(Protocol):
    """An engine: ``fit(likelihood, *, seed, progress) -> Posterior``."""

    name: str

    def fit(self, likelihood: "OutputError", *, seed: int = 0, progress: bool = True) -> Posterior:
        """Estimate the parameters of ``likelihood``'s model from its record."""
        ...


def laplace_draws(phi: np.ndarray, cov: np.ndarray, lower: np.ndarray, upper: np.ndarray, n: int,
                  rng: np.random.Generator, *, max_rounds: int = 50) -> tuple[np.ndarray, int]:
    """Draws of φ from the Gaussian N(phi, cov) truncated to the prior box [lower, upper].

    The prior is uniform on the box, so the Laplace posterior is the Gaussian
    restricted to it. Draws outside are rejected and drawn again (never
    clipped: clipping piles mass on the bounds and biases the mean). Where the
    box holds almost none of the Gaussian's mass (an optimum in a corner with a
    huge SD), the draws still missing after ``max_rounds`` rounds are clipped,
    and their number is returned so the result can say so.

    Returns
    -------
    draws : ndarray, shape (n, p)
    n_clipped : int
        Draws that had to be clipped (0 when truncation succeeded).
    """
    kept: list[np.ndarray] = []
    need = n
    for r in range(max_rounds):
        # the first round draws exactly n (the whole answer when the box holds the Gaussian), later ones extra
        batch = rng.multivariate_normal(phi, cov, size=need if r == 0 else max(2 * need, 64), method="eigh")
        inside = batch[np.all((batch >= lower) & (batch <= upper), axis=1)][:need]
        kept.append(inside)
        need -= inside.shape[0]
        if need == 0:
            break
    if need:
        kept.append(np.clip(rng.multivariate_normal(phi, cov, size=need, method="eigh"), lower, upper))
    return np.concatenate(kept), need


def even_indices(n_have: int, n_want: int) -> np.ndarray:
    """``min(n_want, n_have)`` evenly spaced indices into ``range(n_have)`` (sorted, unique)."""
    return np.unique(np.linspace(0, n_have - 1, min(n_want, n_have)).round().astype(int))
