"""Measure TMCMC against TI and stepping-stone on the same problems.

Single process, small problems; every route's likelihood evaluations are counted
(:class:`bayes_mr.inference.evidence.tmcmc.Counted`). TI/SS count the β = 1 emcee posterior
(which they need: it is the top rung and fits the reference q) plus the ladder;
the least-squares fit that starts the linear-device and dahl posteriors is not
counted (a few hundred evaluations). One JSON line per (case, seed, route)::

    PYTHONPATH=. python scripts/measure_tmcmc.py gaussian linear dahl --seeds 5 --n 1000

Cases: ``gaussian`` and ``linear`` are the analytic-evidence cases of
``tests/inference/test_evidence.py``; ``dahl`` is a 4 s structure test at 250 Hz
(truth dahl, 1 % output noise), whose ln Z is unknown (routes are compared with
each other); ``bimodal`` is the two-Gaussian mixture of ``tests/inference/test_tmcmc.py``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests")]

from bayes_mr.inference.evidence.routes import stepping_stone, thermodynamic_integration  # noqa: E402
from bayes_mr.inference.evidence.ladder import run_ladder  # noqa: E402
from bayes_mr.inference.mcmc.settings import MCMCSettings  # noqa: E402
from bayes_mr.inference.mcmc.sampler import sample  # noqa: E402
from bayes_mr.inference.mcmc.start import start_from_lsq  # noqa: E402
from bayes_mr.inference.evidence.tmcmc import Counted, TMCMCSettings, run_tmcmc  # noqa: E402

QUICK = dict(progress=False, min_tau_multiple=20.0, rhat_max=1.05, check_every=100)


def problem(case: str):
    """(target, start centre, start covariance, analytic ln Z or None)."""
    if case == "gaussian":
        from inference.test_evidence import gaussian_target

        target, mu, C, log_z = gaussian_target(30.0)
        return target, mu, C, log_z
    if case == "bimodal":
        from inference.test_tmcmc import bimodal_target

        target, modes, C, log_z = bimodal_target()
        return target, modes[0], C, log_z
    from bayes_mr.inference.lsq.least_squares import fit_lsq
    from bayes_mr.likelihood.output_error import OutputError

    if case == "linear":
        from inference.test_evidence import linear_device_problem

        lik, log_z, _ = linear_device_problem()
    else:
        from records import structure_record

        rec, _ = structure_record("dahl", {}, n=1000, fs=250.0, seed=3, rms=0.6, noise=0.01, process=False)
        lik, log_z = OutputError("dahl", rec), None
    center, cov = start_from_lsq(lik, fit_lsq(lik))
    return lik, center, cov, log_z


def ladder_routes(target, center, cov, seed: int) -> list[dict]:
    """TI and SS (reference path) with their counted evaluations; also returns the posterior."""
    counted = Counted(target)
    t0 = time.perf_counter()
    post = sample(counted, center, cov, MCMCSettings(seed=seed, **QUICK))
    n_post = counted.n_evals
    ladder = run_ladder(counted, post, seed=seed)
    wall = time.perf_counter() - t0
    out = []
    for ev in (thermodynamic_integration(ladder), stepping_stone(ladder)):
        out.append({"route": ev.route, "log_z": ev.log_z, "error": ev.total_error, "n_evals": counted.n_evals,
                    "n_evals_posterior": n_post, "wall_s": wall, "converged": ev.converged})
    return out, post


def tmcmc_route(target, post, seed: int, n: int, start: str) -> dict:
    r = run_tmcmc(target, TMCMCSettings(n_particles=n, seed=seed, start=start), posterior=post)
    return {"route": f"tmcmc-{start}", "log_z": r.log_z, "error": r.log_z_error, "naive_error": r.naive_error,
            "n_evals": r.n_evals, "n_evals_evidence": r.n_evals_evidence, "wall_s": r.wall_s, "converged": not r.unhealthy, "n_stages": len(r.stages),
            "n_eves": r.n_eves}


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("cases", nargs="+")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--n", type=int, default=1000, help="TMCMC particles")
    args = ap.parse_args(argv)
    for case in args.cases:
        target, center, cov, truth = problem(case)
        for seed in range(args.seeds):
            rows, post = ladder_routes(target, center, cov, seed)
            rows += [tmcmc_route(target, post, seed, args.n, start) for start in ("prior", "reference")]
            for row in rows:
                row.update(case=case, seed=seed, truth=truth,
                           bias=None if truth is None else row["log_z"] - truth)
                print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
