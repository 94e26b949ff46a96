"""The main job's emcee posteriors: one pool of seconds, the selected form's posterior first.

A posterior costs minutes where a least-squares fit costs seconds, and the
forms' costs differ by tens (on the packaged damper at 1 kHz one ensemble
step of spencer's 56 walkers takes ~0.35 s, of dahl's ~0.01 s). A budget per
posterior either starves the expensive selected form or spends the whole job
on forms the evidence has already ranked far below it. So the main job fits
every form by least squares and the UKF first — the Laplace evidence of the
least-squares fits selects — and then runs the posteriors in the order the
evidence ranks the forms, the selected one first, each with what the earlier
ones left of :attr:`bayes_mr.mainjob.Budget.mcmc_pool_s` as its wall-time
budget. A posterior whose measured step cost projects past what is left is
not started, and one whose own integrated time projects the rule (≥ 50 τ,
R-hat < 1.01) past it stops there (:mod:`bayes_mr.inference.budget`,
:func:`bayes_mr.inference.convergence.projection`); the report names both,
with the numbers.
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import replace
from typing import TYPE_CHECKING

from .comparison import compare, row_of
from .identify import Emcee, LeastSquares
from .inference.budget import over_budget

if TYPE_CHECKING:
    from .mainjob import Budget


def posterior_order(forms, selected: str | None, bayes_factors: dict[str, float]) -> list[str]:
    """The forms in the order their posteriors run: the selected one, then by evidence (smallest ln BF against
    the selected first), forms without an evidence last, ties in the order given.

    Parameters
    ----------
    forms : sequence of str
    selected : str or None
    bayes_factors : dict
        Model → ln Z(selected) − ln Z(model) [nats] (:func:`bayes_mr.comparison.choose`).
    """
    def key(item):
        i, m = item
        bf = bayes_factors.get(m)
        finite = bf is not None and math.isfinite(float(bf))
        return (m != selected, not finite, float(bf) if finite else 0.0, i)

    return [m for _, m in sorted(enumerate(forms), key=key)]


def pool_spent(pool_s: float, used: dict[str, float], lsq_s: float) -> str:
    """Why a posterior was not started: what is left of the pool (after the forms that spent it, with their
    seconds) does not cover the least-squares fit its chain starts from."""
    left = max(pool_s - sum(used.values()), 0.0)
    spent = "".join(f", {m} {s:.0f} s" for m, s in used.items())
    return (f"the {left:.0f} s left of the posteriors' pool of {pool_s:g} s (spent: {spent[2:] or 'nothing yet'}) do "
            f"not cover the least-squares fit its chain starts from ({lsq_s:.0f} s): not run")


def run_posteriors(part_a, part_b, order: list[str], budget: Budget, *, seed: int, lsq_s: dict[str, float],
                   say) -> tuple[dict[str, tuple[dict, object]], dict[str, str]]:
    """Each form's emcee posterior in ``order``, sharing ``budget.mcmc_pool_s``.

    Each runs as :func:`bayes_mr.comparison.compare` runs a model's ``lsq`` and ``mcmc`` rows (one least-squares
    fit, the chain from its optimum: the same least squares as the comparison's ``lsq`` row, so its seconds
    ``lsq_s[form]`` are held back from the chain's budget). Without a pool each posterior has
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
    lsq_s : dict
        Form → seconds of its least-squares fit in the comparison.
    say : callable

    Returns
    -------
    fits : dict
        Form → (``mcmc`` row, InferenceData or None) of every posterior started (or failed).
    skipped : dict
        Form → why no posterior was run (:class:`bayes_mr.inference.budget.OverBudget`'s reason, or the pool
        spent).
    """
    pool = budget.mcmc_pool_s
    cap = budget.mcmc.max_seconds
    fits, skipped, used = {}, {}, {}
    for form in order:
        left = math.inf if pool is None else pool - sum(used.values()) - lsq_s.get(form, 0.0)
        if left <= 0:
            skipped[form] = pool_spent(pool, used, lsq_s.get(form, 0.0))
            say(f"{form} × mcmc: {skipped[form]}")
            continue
        seconds = min(left, cap if cap is not None else math.inf)
        settings = replace(budget.mcmc, seed=seed, progress=False,
                           max_seconds=None if math.isinf(seconds) else seconds)
        estimators = {"lsq": LeastSquares(), "mcmc": Emcee(settings=settings, evidence=budget.evidence)}
        t0 = _time.perf_counter()
        out = compare(part_a, [form], engines=("lsq", "mcmc"), validate=part_b, seed=seed, progress=say,
                      estimators=estimators, noise=budget.noise)
        used[form] = _time.perf_counter() - t0
        row = row_of(out["rows"], form, "mcmc") or next(r for r in out["rows"] if r["engine"] == "mcmc")
        why = over_budget(row.get("error"))
        if why:  # not a failure: a posterior the budget could not converge, not started (budget.py)
            skipped[form] = why
        else:
            fits[form] = (row, out["idata"].get((form, "mcmc")))
    return fits, skipped
