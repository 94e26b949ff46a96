"""What makes a posterior slow to sample, read from its chain.

An ensemble chain that does not converge in its budget is rarely short of
speed alone: its integrated time is long because of the posterior's shape in
the sampler's coordinates (φ, the log-scaled parameters, and ln σ). Two shapes
account for the cases met on measured dampers, and both can be read off the
chain without another likelihood evaluation:

* a coordinate the record hardly informs: its draws spread over most of the
  prior's range (spencer's c1b on the packaged damper), so the chain must
  cross the whole box, whose edges cut the proposal;
* a ridge: two coordinates the record fixes only in combination, so their
  draws lie along a line or a curve (the classic Bouc–Wen law's β₁ and γ where
  the loading branch is linear, β₁ + γ ≈ 0; spencer's γ and n).

:func:`chain_geometry` names them, with the coordinates of longest integrated
time, so that a report can say *why* a chain is slow, not only that it is.
The measures are descriptive: the chain is not converged when they matter
most, so the spreads and correlations are those of the draws it has.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: A coordinate whose central 98 % of draws span at least this fraction of its prior range is reported as
#: spread over its prior (the record hardly informs it). A posterior that the record narrows to a tenth of the
#: range spans far less; a flat one spans 0.98.
SPREAD_FRACTION = 0.5
#: Two coordinates whose draws correlate at least this strongly (either sign) are reported as a ridge.
RIDGE_CORRELATION = 0.95
#: At most this many slowest coordinates and ridges are reported.
SHOWN = 3


def chain_geometry(chain: np.ndarray, lower: np.ndarray, upper: np.ndarray, names: Sequence[str],
                   tau: np.ndarray) -> dict:
    """The coordinates of longest integrated time, those spread over their prior, and the ridges of a chain.

    Parameters
    ----------
    chain : ndarray, shape (n_steps, n_walkers, d)
        The chain after burn-in, in the sampler's coordinates.
    lower, upper : ndarray (d,)
        The prior's box in the same coordinates.
    names : sequence of str
        Coordinate names.
    tau : ndarray (d,)
        Integrated autocorrelation time per coordinate [steps].

    Returns
    -------
    dict
        ``slowest``: up to :data:`SHOWN` [name, τ] pairs, longest first; ``spread_over_prior``: {name: fraction
        of the prior's range the central 98 % of draws span} for those at or above :data:`SPREAD_FRACTION`,
        widest first; ``ridges``: up to :data:`SHOWN` [name, name, correlation] triples at or above
        :data:`RIDGE_CORRELATION` in absolute value, strongest first. Empty lists and dict when the chain has
        fewer than two draws.
    """
    x = np.asarray(chain, float).reshape(-1, np.shape(chain)[-1])
    names = list(names)
    tau = np.asarray(tau, float)
    finite = np.isfinite(tau)
    order = np.argsort(-np.where(finite, tau, -np.inf))
    slowest = [[names[j], float(tau[j])] for j in order[:SHOWN] if finite[j]]
    if x.shape[0] < 2:
        return {"slowest": slowest, "spread_over_prior": {}, "ridges": []}
    lo, hi = np.quantile(x, [0.01, 0.99], axis=0)
    width = np.asarray(upper, float) - np.asarray(lower, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        spread = np.where(width > 0, (hi - lo) / width, 0.0)
    spread_over = {names[j]: float(spread[j]) for j in np.argsort(-spread) if spread[j] >= SPREAD_FRACTION}
    sd = x.std(axis=0)
    moving = np.flatnonzero(sd > 0)
    ridges = []
    if moving.size >= 2:
        corr = np.corrcoef(x[:, moving], rowvar=False)
        a, b = np.triu_indices(moving.size, k=1)
        strong = np.flatnonzero(np.abs(corr[a, b]) >= RIDGE_CORRELATION)
        strong = strong[np.argsort(-np.abs(corr[a, b][strong]))][:SHOWN]
        ridges = [[names[moving[a[k]]], names[moving[b[k]]], float(corr[a[k], b[k]])] for k in strong]
    return {"slowest": slowest, "spread_over_prior": spread_over, "ridges": ridges}
