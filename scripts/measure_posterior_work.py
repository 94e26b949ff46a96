"""Measure the work of the main job's emcee posteriors, unbudgeted: what ``FULL.mcmc_pool`` is derived from.

Prepares the packaged record as ``make run`` does (:data:`bayes_mr.run.plan.FULL`), fits every form's least squares
on part A (the first pass's fits, :func:`bayes_mr.run.posteriors.least_squares_pass`) and runs each form's
posterior from it with FULL's settings but no pool and no cap, so each ends by its own rules. Each posterior's
log-density evaluations (walker-steps of pilot, rounds and chain) and their price
(:func:`bayes_mr.run.posteriors.evaluation_price`) are fixed by the record and the seed, so they are what ``make
run`` spends on any machine wherever the pool does not bind. One JSON object on stdout::

    PYTHONPATH=. python scripts/measure_posterior_work.py --seed 0 > work.json

The UKF, the diagnosis and the other stages of ``make run`` are not run (they do not draw on the pool).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace

from bayes_mr.run.plan import FULL
from bayes_mr.run.posteriors import least_squares_pass, run_posteriors
from bayes_mr.run.records import prepare


def measure(seed: int = 0, forms: tuple[str, ...] | None = None) -> dict:
    """Per form: ``evaluations``, ``steps_per_evaluation``, ``integrator_steps``, the chain's ``n_steps`` and
    ``n_walkers``, ``pilot_steps``, ``adapt_acceptance``, ``converged``, ``stopped`` and ``wall_s``; and their
    ``total_integrator_steps``."""
    def say(msg):
        print(msg, file=sys.stderr, flush=True)

    budget = replace(FULL, mcmc_pool=None, mcmc_pool_cap_s=None, forms=forms or FULL.forms)
    _, part_a, _, info = prepare(budget)
    t0 = time.perf_counter()
    _, _, fitted = least_squares_pass(part_a, None, list(budget.forms), seed=seed, noise=budget.noise, say=say)
    lsq_s = time.perf_counter() - t0
    fits, skipped, work = run_posteriors(part_a, None, list(budget.forms), budget, seed=seed, fitted=fitted, say=say)
    out = {"seed": seed, "samples": info["samples"], "fs": info["fs"], "lsq_s": lsq_s, "skipped": skipped,
           "forms": {}}
    for form, w in work.items():
        row = fits.get(form, ({}, None))[0]
        out["forms"][form] = {**{k: w[k] for k in ("evaluations", "steps_per_evaluation", "integrator_steps",
                                                   "wall_s")},
                              **{k: row.get(k) for k in ("n_steps", "n_walkers", "pilot_steps", "adapt_acceptance",
                                                         "converged", "stopped", "error")}}
    out["total_integrator_steps"] = sum(w["integrator_steps"] for w in work.values())
    return out


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--forms", default=None, help="comma-separated forms (default: FULL's)")
    a = p.parse_args()
    print(json.dumps(measure(a.seed, tuple(a.forms.split(",")) if a.forms else None), indent=1))
