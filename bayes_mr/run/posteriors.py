"""The main job's emcee posteriors: one pool of seconds, the selected form's posterior first.

A posterior costs minutes where a least-squares fit costs seconds, and the
forms' costs differ by tens (on the packaged damper at 1 kHz one ensemble
step of spencer's 56 walkers takes ~0.35 s, of dahl's ~0.01 s). A budget per
posterior either starves the expensive selected form or spends the whole job
on forms the evidence has already ranked far below it. So the main job fits
every form by least squares and the UKF first — the Laplace evidence of the
least-squares fits selects — and then runs the posteriors in the order the
evidence ranks the forms, the selected one first, each with what the earlier
ones left of :attr:`bayes_mr.run.plan.Budget.mcmc_pool_s` as its wall-time
budget. A posterior whose measured step cost projects past what is left is
not started, and one whose own integrated time projects the rule (≥ 50 τ,
R-hat < 1.01) past it stops there (:mod:`bayes_mr.inference.mcmc.wall_time`,
:func:`bayes_mr.inference.mcmc.convergence.projection`); the report names both,
with the numbers.
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import replace
from typing import TYPE_CHECKING

from bayes_mr.execution.executor import Outcome, local_threads, run_jobs
from bayes_mr.selection.fit_jobs import (
    FIT_ERRORS, error_row, free_parameters, least_squares, lsq_mcmc_job, row_message, unit_results,
)
from bayes_mr.inference.identify import Emcee, LeastSquares
from bayes_mr.inference.mcmc.wall_time import over_budget

if TYPE_CHECKING:
    from bayes_mr.run.plan import Budget


def posterior_order(forms, selected: str | None, bayes_factors: dict[str, float]) -> list[str]:
    """The forms in the order their posteriors run: the selected one, then by evidence (smallest ln BF against
    the selected first), forms without an evidence last, ties in the order given.

    Parameters
    ----------
    forms : sequence of str
    selected : str or None
    bayes_factors : dict
        Model → ln Z(selected) − ln Z(model) [nats] (:func:`bayes_mr.selection.comparison.choose`).
    """
    def key(item):
        i, m = item
        bf = bayes_factors.get(m)
        finite = bf is not None and math.isfinite(float(bf))
        return (m != selected, not finite, float(bf) if finite else 0.0, i)

    return [m for _, m in sorted(enumerate(forms), key=key)]


def least_squares_pass(part_a, part_b, forms, *, seed: int, noise: str, say) -> tuple[list[dict], dict, dict]:
    """Every form's least-squares fit on ``part_a``, validated on ``part_b``: the comparison's ``lsq`` rows, and the
    fit each form's chain starts from (:func:`run_posteriors`), made once for both.

    The fit is the one the chain would make (:meth:`~bayes_mr.inference.identify.Emcee.lsq_settings` of ``seed``), so the
    rows are those :func:`bayes_mr.selection.comparison.compare` gives for ``lsq`` and the posteriors those it gives for
    ``mcmc`` (:func:`bayes_mr.selection.fit_jobs.lsq_mcmc_job`).

    Returns
    -------
    rows : list of dict
        One ``lsq`` row per form, in order (``error`` where the fit failed).
    idata : dict
        (form, ``"lsq"``) → InferenceData of the fits that succeeded.
    fitted : dict
        Form → (likelihood, :class:`~bayes_mr.inference.lsq.least_squares.LSQResult`) of the fits that succeeded.
    """
    lsq = LeastSquares(settings=Emcee.lsq_settings(seed))
    rows, idata, fitted, n_done = [None] * len(forms), {}, {}, [0]

    def finished(o: Outcome) -> None:
        form = forms[o.index]
        # a job that raised past its own FIT_ERRORS: the grid's error row for that outcome (fit_jobs.unit_results)
        fit, row, data = o.value if o.ok else (None, unit_results(o, form, ["lsq"])[0][1], None)
        rows[o.index] = row
        if fit is not None:
            fitted[form] = fit
        if data is not None:
            idata[(form, "lsq")] = data
        n_done[0] += 1
        say(f"{row_message(form, 'lsq', row)} [{n_done[0]}/{len(forms)}]")

    # the forms side by side on this process's threads, the costliest first (same fits as in turn, executor.py)
    with local_threads() as pool:
        if pool is not None:
            say(f"{', '.join(forms)} × lsq, side by side …")
        run_jobs(form_least_squares, [(form, lsq, part_a, part_b, seed, noise) for form in forms], executor=pool,
                 on_start=lambda i: None if pool is not None else say(f"{forms[i]} × lsq …"), on_done=finished,
                 cost=[free_parameters(form, part_a) for form in forms])
    return rows, idata, fitted


def form_least_squares(form: str, lsq, part_a, part_b, seed: int, noise: str) -> tuple[tuple | None, dict, object]:
    """One form's least-squares fit on ``part_a`` and its ``lsq`` row validated on ``part_b`` (a job of
    :func:`least_squares_pass`): (fit or None, row, InferenceData or None); a fit that fails is a row with its error."""
    t0 = _time.perf_counter()
    try:
        fit = least_squares(form, lsq, part_a, noise)
    except FIT_ERRORS as exc:
        return None, error_row(form, "lsq", exc, _time.perf_counter() - t0), None
    [(row, data)] = lsq_mcmc_job(form, lsq, None, part_a, part_b, seed, False, noise, fitted=fit)
    return fit, row, data


def pool_spent(pool_s: float, used: dict[str, float]) -> str:
    """Why a posterior was not started: nothing is left of the pool (the forms that spent it, with their seconds)."""
    spent = "".join(f", {m} {s:.0f} s" for m, s in used.items())
    return f"the posteriors' pool of {pool_s:g} s is spent ({spent[2:] or 'nothing yet'}): not run"


def run_posteriors(part_a, part_b, order: list[str], budget: Budget, *, seed: int, fitted: dict,
                   say) -> tuple[dict[str, tuple[dict, object]], dict[str, str]]:
    """Each form's emcee posterior in ``order``, sharing ``budget.mcmc_pool_s``.

    Each chain starts from the form's least-squares fit of the first pass (``fitted``, :func:`least_squares_pass`),
    as :func:`bayes_mr.selection.comparison.compare` runs a model's ``lsq`` and ``mcmc`` rows from one fit; a form without
    one is fitted first (and fails as its ``lsq`` row did). Without a pool each posterior has
    ``budget.mcmc.max_seconds`` alone; with one, at most that and what the earlier posteriors left.

    Parameters
    ----------
    part_a, part_b : xarray.Dataset
        Training and validation records.
    order : list of str
        :func:`posterior_order`.
    budget : Budget
        Uses ``mcmc``, ``mcmc_pool_s``, ``evidence`` and ``noise``.
    seed : int
    fitted : dict
        Form → (likelihood, LSQResult) on ``part_a`` (:func:`least_squares_pass`).
    say : callable

    Returns
    -------
    fits : dict
        Form → (``mcmc`` row, InferenceData or None) of every posterior started (or failed).
    skipped : dict
        Form → why no posterior was run (:class:`bayes_mr.inference.mcmc.wall_time.OverBudget`'s reason, or the pool
        spent).
    """
    pool = budget.mcmc_pool_s
    cap = budget.mcmc.max_seconds
    fits, skipped, used = {}, {}, {}
    for form in order:
        left = math.inf if pool is None else pool - sum(used.values())
        if left <= 0:
            skipped[form] = pool_spent(pool, used)
            say(f"{form} × mcmc: {skipped[form]}")
            continue
        seconds = min(left, cap if cap is not None else math.inf)
        settings = replace(budget.mcmc, seed=seed, progress=False,
                           max_seconds=None if math.isinf(seconds) else seconds)
        mcmc = Emcee(settings=settings, evidence=budget.evidence)
        lsq = None if form in fitted else LeastSquares(settings=Emcee.lsq_settings(seed))
        say(f"{form} × mcmc …")
        t0 = _time.perf_counter()
        row, idata = lsq_mcmc_job(form, lsq, mcmc, part_a, part_b, seed, False, budget.noise,
                                  fitted=fitted.get(form))[-1]
        used[form] = _time.perf_counter() - t0
        say(row_message(form, "mcmc", row))
        why = over_budget(row.get("error"))
        if why:  # not a failure: a posterior the budget could not converge, not started (budget.py)
            skipped[form] = why
        else:
            fits[form] = (row, idata)
    return fits, skipped
