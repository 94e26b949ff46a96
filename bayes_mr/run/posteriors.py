"""The main job's emcee posteriors: one pool of work, the selected form's posterior first.

A posterior costs minutes where a least-squares fit costs seconds, and the
forms' costs differ several-fold (on the packaged damper at 1 kHz one
simulation of part A takes ~66 000 integrator steps for spencer, ~19 000 for
dahl, and spencer's ensemble has 56 walkers to dahl's 20;
``scripts/measure_posterior_work.py``). A budget per
posterior either starves the expensive selected form or spends the whole job
on forms the evidence has already ranked far below it. So the main job fits
every form by least squares and the UKF first — the Laplace evidence of the
least-squares fits selects — and then runs the posteriors in the order the
evidence ranks the forms, the selected one first, each with what the earlier
ones left of :attr:`bayes_mr.run.plan.Budget.mcmc_pool`.

The pool is counted in work, never in seconds, so the same record and seed give
the same posteriors on a quiet machine and a busy one: each log-density
evaluation (one walker, one step) is charged its form's price
(:func:`evaluation_price`, the integrator steps of one simulation at the
least-squares optimum), so a spencer evaluation weighs what it costs against a
dahl one, on any machine and thread count. A posterior that cannot hold its
pilot and shortest chain in what is left is not started, and one whose own
integrated time projects the rule (≥ 50 τ, R-hat < 1.01) past it stops there
(:mod:`bayes_mr.inference.mcmc.budget`,
:func:`bayes_mr.inference.mcmc.convergence.projection`); the report names both,
with the numbers. The wall clock is only a safety cap
(:attr:`~bayes_mr.run.plan.Budget.mcmc_pool_cap_s`): a posterior it stops or
does not start is reported as a machine limit, not a result.
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from bayes_mr.execution.executor import Outcome, local_threads, run_jobs
from bayes_mr.selection.fit_jobs import (
    FIT_ERRORS, error_row, free_parameters, least_squares, lsq_mcmc_job, row_message, unit_results,
)
from bayes_mr.inference.identify import Emcee, LeastSquares
from bayes_mr.inference.mcmc.budget import cap_message, over_budget, seconds_text
from bayes_mr.inference.mcmc.settings import MCMCSettings
from bayes_mr.models.integrate import steps

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


#: Significant figures of an evaluation's price: the schedule's count is the same on every machine and thread
#: count, and rounding it keeps a kernel's last-bit difference at a sub-step bound from moving a budget decision.
PRICE_FIGURES = 3


def evaluation_price(lik, res) -> int:
    """What one log-density evaluation of ``lik`` is charged [integrator steps]: the RK4 sub-steps and Rosenbrock
    steps of one simulation of its record at the least-squares optimum ``res`` the chain starts from
    (:attr:`bayes_mr.simulation.simulate.Simulation.schedule`), to :data:`PRICE_FIGURES` significant figures.

    Fixed by the record and that fit, whatever the machine: the simulation is what an evaluation costs, and its
    sub-steps are set by the model's stiffness at the parameters, which near the posterior's bulk are those of
    the optimum.
    """
    n_steps = int(steps(lik.simulate(np.atleast_2d(res.phi)).schedule[0]).sum())
    return max(1, int(float(f"{n_steps:.{PRICE_FIGURES}g}")))


def pool_spent(pool: float, work: dict[str, dict]) -> str:
    """Why a posterior was not started: the pool cannot pay one evaluation (the forms that spent it, with their
    integrator steps)."""
    spent = "".join(f", {m} {w['integrator_steps']:.3g}" for m, w in work.items() if w["integrator_steps"])
    return f"the posteriors' pool of {pool:.3g} integrator steps is spent ({spent[2:] or 'nothing yet'}): not run"


def cap_spent(pool_cap_s: float, work: dict[str, dict]) -> str:
    """Why a posterior was not started: the posteriors' wall-time cap is spent (the forms that spent it)."""
    spent = ", ".join(f"{m} {seconds_text(w['wall_s'])} s" for m, w in work.items())
    return (f"not run: the posteriors' wall-time cap of {seconds_text(pool_cap_s)} s is spent "
            f"({spent or 'nothing yet'}): a machine limit, not a result")


def posterior_settings(mcmc: MCMCSettings, seed: int, evaluations: int | None, cap_s: float | None) -> MCMCSettings:
    """A posterior's settings: ``mcmc`` with the seed, no bar, the work budget the pool leaves it (``evaluations``,
    at most ``mcmc.max_evaluations``) and the wall-time cap (``cap_s``, at most ``mcmc.max_seconds``)."""
    def least(a, b):
        return b if a is None else a if b is None else min(a, b)

    return replace(mcmc, seed=seed, progress=False, max_evaluations=least(mcmc.max_evaluations, evaluations),
                   max_seconds=least(mcmc.max_seconds, cap_s))


def run_posteriors(part_a, part_b, order: list[str], budget: Budget, *, seed: int, fitted: dict,
                   say) -> tuple[dict[str, tuple[dict, object]], dict[str, str], dict[str, dict]]:
    """Each form's emcee posterior in ``order``, sharing ``budget.mcmc_pool`` (work) under ``budget.mcmc_pool_cap_s``.

    Each chain starts from the form's least-squares fit of the first pass (``fitted``, :func:`least_squares_pass`),
    as :func:`bayes_mr.selection.comparison.compare` runs a model's ``lsq`` and ``mcmc`` rows from one fit; a form without
    one is fitted first (and fails as its ``lsq`` row did). Without a pool each posterior has
    ``budget.mcmc.max_evaluations`` alone; with one, at most that and what the earlier posteriors left, at its
    form's :func:`evaluation_price`.

    Parameters
    ----------
    part_a, part_b : xarray.Dataset
        Training and validation records.
    order : list of str
        :func:`posterior_order`.
    budget : Budget
        Uses ``mcmc``, ``mcmc_pool``, ``mcmc_pool_cap_s``, ``evidence`` and ``noise``.
    seed : int
    fitted : dict
        Form → (likelihood, LSQResult) on ``part_a`` (:func:`least_squares_pass`).
    say : callable

    Returns
    -------
    fits : dict
        Form → (``mcmc`` row, InferenceData or None) of every posterior started (or failed).
    skipped : dict
        Form → why no posterior was run (:class:`bayes_mr.inference.mcmc.budget.OverBudget`'s reason, the pool
        spent, or the wall-time cap spent).
    work : dict
        Form → what its posterior spent and under which limits (:func:`_work_entry`).
    """
    pool, pool_cap = budget.mcmc_pool, budget.mcmc_pool_cap_s
    fits, skipped, work = {}, {}, {}
    for form in order:
        spent, wall = sum(w["integrator_steps"] for w in work.values()), sum(w["wall_s"] for w in work.values())
        left = None if pool is None else pool - spent
        if pool_cap is not None and wall >= pool_cap:
            skipped[form] = cap_spent(pool_cap, work)
            work[form] = _work_entry(None, 0, left, 0.0, 0.0, skipped[form])
            say(f"{form} × mcmc: {skipped[form]}")
            continue
        t0 = _time.perf_counter()
        try:
            lik, res = fitted.get(form) or least_squares(form, LeastSquares(settings=Emcee.lsq_settings(seed)),
                                                         part_a, budget.noise)
            price = evaluation_price(lik, res)
        except FIT_ERRORS as exc:
            fits[form] = (error_row(form, "mcmc", exc, _time.perf_counter() - t0), None)
            work[form] = _work_entry(None, 0, left, _time.perf_counter() - t0, None, None)
            say(row_message(form, "mcmc", fits[form][0]))
            continue
        if left is not None and left < price:
            skipped[form] = pool_spent(pool, work)
            work[form] = _work_entry(price, 0, left, _time.perf_counter() - t0, None, None)
            say(f"{form} × mcmc: {skipped[form]}")
            continue
        cap = None if pool_cap is None else pool_cap - wall
        settings = posterior_settings(budget.mcmc, seed, None if left is None else int(left // price), cap)
        say(f"{form} × mcmc …")
        row, idata = lsq_mcmc_job(form, None, Emcee(settings=settings, evidence=budget.evidence), part_a, part_b,
                                  seed, False, budget.noise, fitted=(lik, res))[-1]
        capped = row.get("stopped") == "max_seconds"
        work[form] = _work_entry(price, int(row.get("evaluations") or 0), left, _time.perf_counter() - t0,
                                 settings.max_seconds, cap_message(settings.max_seconds, pool_cap) if capped else None)
        say(row_message(form, "mcmc", row))
        why = over_budget(row.get("error"))
        if why:  # not a failure: a posterior the work budget could not converge, not started (budget.py)
            skipped[form] = why if left is None else (
                f"{why} (the pool has {left:.3g} of its {pool:.3g} integrator steps left, {price} an evaluation)")
        else:
            fits[form] = (row, idata)
    return fits, skipped, work


def _work_entry(price: int | None, evaluations: int, left: float | None, wall_s: float, cap_s: float | None,
                machine_limit: str | None) -> dict:
    """One form's line of ``summary.json``'s ``posterior_work``: ``evaluations`` (walker-steps of pilot, rounds and
    chain), ``steps_per_evaluation`` (:func:`evaluation_price`), ``integrator_steps`` (their product: what the pool
    was charged), ``pool_left`` (integrator steps the pool had before it), ``wall_s``, ``wall_cap_s`` (the cap it
    ran under) and ``machine_limit`` (what the wall-time cap did to it, or None)."""
    return {"evaluations": evaluations, "steps_per_evaluation": price,
            "integrator_steps": evaluations * (price or 0), "pool_left": left, "wall_s": wall_s,
            "wall_cap_s": cap_s, "machine_limit": machine_limit}
