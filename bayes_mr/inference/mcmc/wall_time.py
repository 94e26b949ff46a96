"""Will an emcee posterior fit its wall-time budget? One timed ensemble evaluation, projected.

A posterior with a budget (``MCMCSettings.max_seconds``) that cannot meet the
package's rule (≥ 50 τ, R-hat < 1.01) in it ends as a chain flagged "NOT
converged": minutes spent on a result the report must then discount.
:func:`check_budget` times one evaluation of the whole ensemble at the
starting point (the least-squares optimum, where the simulation's sub-steps
are those the chain will meet) and projects it over the pilot and the fewest
steps a chain proper has met the rule in; when that exceeds the budget it
raises :class:`OverBudget` with the numbers, so the caller can say which
posterior was not run and why instead of running it to its time limit.
"""

from __future__ import annotations

import time as _time

import numpy as np

#: Steps of the chain proper (after the pilot) the projection counts: the fewest the rule has held in. With the
#: pilot-fitted independence move alone on 8 walkers and a check every 50 steps, the main job's posteriors on the
#: packaged damper's part A (1 kHz) need dahl 250, lugre 300, normalized-bouc-wen 400, bouc-wen 650 and spencer
#: 850 steps (``bayes-mr run``'s report lists each chain's steps).
MIN_CHAIN_STEPS = 250


class OverBudget(RuntimeError):
    """A posterior not started: its projected wall time exceeds its budget (the message has the numbers)."""


def over_budget(error: str | None) -> str | None:
    """The reason of a job's error (``"ExceptionType: message"``, :class:`bayes_mr.execution.executor.Outcome`) if it is
    an :class:`OverBudget` (a posterior deliberately not run, not a failure), else None."""
    prefix = f"{OverBudget.__name__}: "
    return error[len(prefix):] if error and error.startswith(prefix) else None


#: Timed ensemble evaluations of :func:`check_budget` (the fastest is the step's cost).
TIMED_CALLS = 3


def check_budget(log_prob, center: np.ndarray, n_walkers: int, pilot_steps: int, max_seconds: float,
                 chain_walkers: int | None = None) -> float:
    """Seconds of one ensemble step at ``center``; raise :class:`OverBudget` if the run cannot fit.

    The ensemble is evaluated once untimed, then :data:`TIMED_CALLS` times, and the fastest call is the step's
    cost: the first may compile the walkers' batched kernel (a fresh machine, or a kernel the least-squares fit
    did not use), which the chain pays once, not at every step; and one timed call carries whatever else the
    machine did in that half second, which on a busy machine can double it and refuse a posterior that fits.

    Parameters
    ----------
    log_prob : callable
        The vectorised log-density ``f(X (B, d)) -> (B,)`` the chain will sample.
    center : ndarray (d,)
        Where the walkers start (inside the support).
    n_walkers : int
        Walkers of the ensemble (one step evaluates each once).
    pilot_steps : int
        Fewest steps before the chain proper: the pilot and one adaptation round
        (``MCMCSettings.pilot_length``; 0 if none).
    max_seconds : float
        The chain's wall-time budget [s].
    chain_walkers : int, optional
        Walkers of the chain proper when fewer than the pilot's (``MCMCSettings.walkers_after_pilot``): its
        steps cost that share of the timed ensemble's (one evaluation per walker).

    Returns
    -------
    float
        Measured seconds of one ensemble evaluation.

    Raises
    ------
    OverBudget
        When (``pilot_steps`` + :data:`MIN_CHAIN_STEPS`) steps at that cost exceed ``max_seconds``.
    """
    x = np.repeat(np.atleast_2d(np.asarray(center, float)), n_walkers, axis=0)
    log_prob(x)  # may compile the batched kernel: not a step's cost
    step = np.inf
    for _ in range(TIMED_CALLS):
        t0 = _time.perf_counter()
        log_prob(x)
        step = min(step, _time.perf_counter() - t0)
    chain_step = step * (chain_walkers or n_walkers) / n_walkers
    projected = step * pilot_steps + chain_step * MIN_CHAIN_STEPS
    if projected > max_seconds:
        chain = "" if chain_walkers in (None, n_walkers) else f" of {chain_walkers} walkers"
        raise OverBudget(
            f"one step of its {n_walkers} walkers costs {step:.2g} s at the least-squares optimum, so the pilot "
            f"({pilot_steps} steps) and the fewest steps a chain has met the rule in ({MIN_CHAIN_STEPS}{chain}) would "
            f"take ~{projected:.0f} s, more than the {max_seconds:.3g} s its budget leaves it: not run")
    return step
