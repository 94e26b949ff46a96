"""Bench figures of the compiled kernels: generic, inlined and specialised per model, and their compile time.

Kept apart from :mod:`bayes_mr.bench.benchmark` (which calls :func:`kernel_bench`) so
the kernel figures live next to nothing else:

* ``simulate_ns_per_step`` — ``{form: {"generic": ns, "inlined": ns, "specialised": ns}}``:
  one parameter set, one thread, a structure test on the first 10 s of
  thesis signal I (4096 Hz), wall time per sample, best of a few runs. The
  inlined kernel is what ``auto`` runs for a model with no specialised
  kernel compiled yet (:func:`bayes_mr._compile.specialise.inlined`).
* ``kernel_speedup`` — generic over specialised for the dahl structure step,
  same run; ``inlined_speedup`` — generic over inlined, same step.
* ``simulate_stiff_corners`` — ``{form: {...}}`` for ``dahl`` and ``bouc-wen``: the stiffest tenth of 100 draws
  from the prior box (those whose plain RK4 run needs the most sub-steps), a structure test on the first 10 s
  of thesis signal I, one thread: ns per sample, RK4 sub-steps per interval and the share of intervals at the
  sub-step cap, at caps 400 and 1600, with the hysteretic state held on its loading branch (the simulator as
  it runs) and without (``hold_branch=False``: every interval integrated, the code path before the hold).
  Where the law is solved exactly the cost does not grow with the cap and no interval reaches it.
* ``compile_s`` — ``{"cold": s, "warm": s}``: a fresh process simulating dahl
  with an empty kernel cache (compiles), then a second one with that cache
  (loads the machine code from disk); import time excluded.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time as _time
from contextlib import contextmanager
from functools import partial
from pathlib import Path

import numpy as np

from bayes_mr._compile.specialise import CACHE_ENV, inlined, specialised
from bayes_mr.models import get_model
from bayes_mr.models.drivers import run_batch
from bayes_mr.signals import thesis_signal

#: The five forms timed for ``simulate_ns_per_step``.
FORMS = ("normalized-bouc-wen", "dahl", "lugre", "bouc-wen", "spencer")

_COLD_SCRIPT = """
import time
import numpy as np
from bayes_mr._compile.specialise import specialised
from bayes_mr.models import get_model
from bayes_mr.models.drivers import run_batch
m = get_model("dahl")
lay, cst = m.layout("structure"), m.constants(50.0)
P = np.atleast_2d(m.theta("structure", {}))
rows = np.zeros((100, 3)); rows[:, 0] = np.sin(np.arange(100) * 0.05)
out = np.empty((1, 100, 4)); sched = np.zeros((1, 99), np.int64); failed = np.empty(1, np.int64)
t0 = time.perf_counter()
specialised(run_batch, lay)(lay, cst, P, 1e-3, rows, out, sched, False, failed)
print(time.perf_counter() - t0)
"""


def _best_ns(fn, args, n_steps: int, repeats: int) -> float:
    """Best wall time of ``fn(*args)`` over ``repeats`` calls, in ns per step (compiled before timing)."""
    fn(*args)
    best = np.inf
    for _ in range(repeats):
        t0 = _time.perf_counter()
        fn(*args)
        best = min(best, _time.perf_counter() - t0)
    return best / n_steps * 1e9


@contextmanager
def _one_thread():
    """numba on one thread inside the block (a per-sample time of one run, not of the thread pool)."""
    import numba

    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(threads)


def simulate_ns_per_step(forms=FORMS, duration: float = 10.0, repeats: int = 5) -> dict:
    """ns per sample of the generic, inlined and specialised simulator, per form (structure test, one thread)."""
    sig = thesis_signal("I")
    n = min(sig.time.size, int(round(duration / (sig.time[1] - sig.time[0]))) + 1)
    rows = np.zeros((n, 3))
    rows[:, 0] = sig.as_input("structure")["ground_acceleration"][:n]
    dt = float(sig.time[1] - sig.time[0])
    out = {}
    with _one_thread():
        for form in forms:
            m = get_model(form)
            lay, cst = m.layout("structure"), m.constants(50.0)
            P = np.atleast_2d(m.theta("structure", {}))
            buf = (np.empty((1, n, 4)), np.zeros((1, n - 1), np.int64), np.empty(1, np.int64))
            args = (lay, cst, P, dt, rows, buf[0], buf[1], False, buf[2])
            out[form] = {"generic": _best_ns(run_batch, args, n - 1, repeats),
                         "inlined": _best_ns(inlined(run_batch), args, n - 1, repeats),
                         "specialised": _best_ns(specialised(run_batch, lay), args, n - 1, repeats)}
    return out


#: The forms, the caps and the share of the draws ``simulate_stiff_corners`` times (module docstring).
STIFF_FORMS, STIFF_CAPS, STIFF_SHARE = ("dahl", "bouc-wen"), (400, 1600), 0.1


def stiff_corners(forms=STIFF_FORMS, duration: float = 10.0, draws: int = 100, repeats: int = 3,
                  seed: int = 0) -> dict:
    """``simulate_stiff_corners`` (module docstring): the cost of the stiffest prior draws, by sub-step cap."""
    from scipy.stats import qmc

    from bayes_mr.likelihood.output_error import OutputError
    from bayes_mr.models.integrate import steps
    from bayes_mr.simulation.simulate import synthesize

    sig = thesis_signal("I")
    n = min(sig.time.size, int(round(duration / (sig.time[1] - sig.time[0]))) + 1)
    inputs = {k: v[:n] for k, v in sig.as_input("structure").items()}
    out = {}
    with _one_thread():
        for form in forms:
            m = get_model(form)
            rec = synthesize(m, m.theta("structure", {}), sig.time[:n], inputs, mass=50.0, seed=seed,
                             source="bench: stiff corners")
            lik = OutputError(m, rec)
            u = qmc.LatinHypercube(d=len(lik.phi_lo), seed=seed).random(draws)
            phi = lik.phi_lo + u * (lik.phi_hi - lik.phi_lo)
            plain = lik.simulate(phi, hold_branch=False, n_max=max(STIFF_CAPS))
            load = np.where(plain.ok, steps(plain.schedule).mean(axis=1), -1.0)
            stiff = phi[np.argsort(load)[::-1][:max(1, int(round(STIFF_SHARE * draws)))]]
            rows = {}
            for hold in (True, False):
                for cap in STIFF_CAPS:
                    run = partial(lik.simulate, hold_branch=hold, n_max=cap)
                    sim = run(stiff)
                    k = steps(sim.schedule)
                    rows[f"{'held' if hold else 'rk4'}_{cap}"] = {
                        "ns_per_sample": _best_ns(run, (stiff,), stiff.shape[0] * (n - 1), repeats),
                        "substeps_per_interval": float(k.mean()), "share_at_cap": float(np.mean(k >= cap)),
                        "completed": int(sim.ok.sum())}
            out[form] = {"draws": draws, "timed": int(stiff.shape[0]), **rows}
    return out


def compile_seconds() -> dict:
    """Cold (empty cache, compiles) and warm (loads from disk) first call of the dahl kernel, each in a fresh process."""
    root = Path(__file__).resolve().parents[2]  # the source tree that holds bayes_mr/
    with tempfile.TemporaryDirectory(prefix="bayes_mr_bench_") as tmp:
        env = {**os.environ, CACHE_ENV: tmp, "PYTHONPATH": os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")])}
        times = {}
        for label in ("cold", "warm"):
            res = subprocess.run([sys.executable, "-c", _COLD_SCRIPT], env=env, capture_output=True, text=True,
                                 check=True)
            times[label] = float(res.stdout.split()[-1])
    return times


def kernel_bench() -> dict:
    """``simulate_ns_per_step``, ``kernel_speedup``, ``inlined_speedup`` (dahl) and ``compile_s`` (module docstring)."""
    ns = simulate_ns_per_step()
    return {"simulate_ns_per_step": ns,
            "kernel_speedup": ns["dahl"]["generic"] / ns["dahl"]["specialised"],
            "inlined_speedup": ns["dahl"]["generic"] / ns["dahl"]["inlined"],
            "simulate_stiff_corners": stiff_corners(), "compile_s": compile_seconds()}
