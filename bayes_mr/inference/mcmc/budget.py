"""Will an emcee posterior fit its work budget? The pilot, one adaptation round and the shortest chain, counted.

A posterior's work budget (``MCMCSettings.max_evaluations``) is counted in log-density evaluations: every step of
an ensemble evaluates each of its walkers once, so a run of ``n`` steps on ``w`` walkers costs ``n·w`` of them
(walker-steps; the starting ensemble's one evaluation per part is not counted). That count is fixed by the
settings, the seed and the record, so what a budget lets a posterior compute is the same on any machine, busy or
quiet; the wall clock is only a safety cap (``MCMCSettings.max_seconds``), and when it acts the result says so.

A posterior that cannot meet the package's rule (≥ 50 τ, R-hat < 1.01) in its budget ends as a chain flagged
"NOT converged": work spent on a result the report must then discount. :func:`check_budget` counts the
evaluations of the pilot, one adaptation round and the fewest steps a chain proper has met the rule in; when
they exceed the budget it raises :class:`OverBudget` with the numbers, so the caller can say which posterior was
not run and why instead of running it to its limit.
"""

from __future__ import annotations

#: Steps of the chain proper (after the pilot) the count reserves: the fewest the rule has held in. With the
#: pilot-fitted independence move alone on 8 walkers and a check every 50 steps, the main job's posteriors on the
#: packaged damper's part A (1 kHz) need dahl 250, normalized-bouc-wen 250, lugre 400, bouc-wen 450 and spencer
#: 600 steps (``scripts/measure_posterior_work.py``, seed 0; ``bayes-mr run``'s report lists each chain's steps).
MIN_CHAIN_STEPS = 250


class OverBudget(RuntimeError):
    """A posterior not started: its projected work exceeds its budget (the message has the numbers)."""


def over_budget(error: str | None) -> str | None:
    """The reason of a job's error (``"ExceptionType: message"``, :class:`bayes_mr.execution.executor.Outcome`) if it is
    an :class:`OverBudget` (a posterior deliberately not run, not a failure), else None."""
    prefix = f"{OverBudget.__name__}: "
    return error[len(prefix):] if error and error.startswith(prefix) else None


def check_budget(n_walkers: int, pilot_steps: int, max_evaluations: int, chain_walkers: int | None = None) -> int:
    """Log-density evaluations the run needs at least; raise :class:`OverBudget` if they exceed ``max_evaluations``.

    Parameters
    ----------
    n_walkers : int
        Walkers of the ensemble of the pilot and the adaptation rounds (of the chain when there is no pilot).
    pilot_steps : int
        Fewest steps before the chain proper: the pilot and one adaptation round
        (``MCMCSettings.pilot_length``; 0 if none).
    max_evaluations : int
        The run's work budget [log-density evaluations].
    chain_walkers : int, optional
        Walkers of the chain proper when fewer than the pilot's (``MCMCSettings.walkers_after_pilot``).

    Returns
    -------
    int
        ``pilot_steps · n_walkers + MIN_CHAIN_STEPS · chain_walkers`` [evaluations].

    Raises
    ------
    OverBudget
        When that exceeds ``max_evaluations``.
    """
    chain_walkers = chain_walkers or n_walkers
    pilot, chain = pilot_steps * n_walkers, MIN_CHAIN_STEPS * chain_walkers
    if pilot + chain > max_evaluations:
        raise OverBudget(
            f"its pilot and first adaptation round ({pilot_steps} steps × {n_walkers} walkers) and the fewest steps a "
            f"chain has met the rule in ({MIN_CHAIN_STEPS} × {chain_walkers} walkers) need {pilot + chain} "
            f"log-density evaluations, more than the {max_evaluations} its work budget leaves it: not run")
    return pilot + chain


def seconds_text(s: float) -> str:
    """Seconds as the reports write them: whole ones, two figures below ten (a test's cap of 0.001 s)."""
    return f"{s:.0f}" if s >= 10 else f"{s:.2g}"


def cap_message(cap_s: float | None, pool_cap_s: float | None = None) -> str:
    """What a chain the wall-time cap stopped says: a machine limit, not a work-budget outcome (``cap_s`` the cap it
    ran under, None if unknown; ``pool_cap_s`` the cap of the posteriors it shared, if any)."""
    of = "" if cap_s is None else f" of {seconds_text(cap_s)} s"
    share = "" if pool_cap_s is None else f" (what the posteriors' {seconds_text(pool_cap_s)} s cap left it)"
    return f"stopped by the wall-time cap{of}{share}: a machine limit, not a result"
