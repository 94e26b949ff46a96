"""Compile the UKF's filter in a child process while the job's first fits run; declare the posteriors' work.

On an empty kernel cache (a fresh machine) the first least-squares fit
compiles the generic simulator (~40 s of one core) and the first UKF fit the
generic filter (~80 s), one after the other in the job's own process, with
the other core idle. :func:`compile_filter_aside` starts the filter's compile
at once in a child (a spawned :class:`concurrent.futures.ProcessPoolExecutor`
worker) that fits the UKF to a short slice of the job's own record — the same
code path, so the same argument types — and leaves the machine code in
numba's disk cache; the job runs its least-squares fits meanwhile and waits
for the child (:func:`wait`) before its first UKF fit, which then loads the
filter from disk. On a warm cache the child only loads it (a few seconds). A
child that fails changes nothing but the time: the job compiles the filter
itself, as without it, and :func:`wait` returns the child's error.

The job's posteriors each run a model's simulator for hundreds of millions of
sample-steps, on the model's own kernel once it is compiled
(:mod:`bayes_mr._compile.specialise`). Counted as they run, that compile starts
part-way through the posterior's pilot and runs beside it; :func:`expect_posteriors`
declares the pilot's sample-steps up front, so on an empty cache a model whose
pilot alone pays for its kernel starts compiling it at its first
least-squares fit and its posterior has it from the start. On a warm cache
it changes nothing.
"""

from __future__ import annotations

import multiprocessing
import time as _time
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout

import xarray as xr

from bayes_mr._compile.specialise import expect_work
from bayes_mr.models import get_model
from bayes_mr.models.drivers import run_batch

#: Samples of the record the child fits (enough for every step of a UKF fit; a fraction of a second of work).
SLICE = 400
#: Longest wait for the child [s]; past it the job goes on and compiles the filter itself if it must.
MAX_WAIT_S = 600.0


def _fit(record: xr.Dataset, model: str, n_lhs: int, taus: tuple[float, ...]) -> None:
    from bayes_mr.inference.identify import UKF, Identify

    Identify(model, UKF(n_lhs=n_lhs, taus=taus)).fit(record, seed=0, progress=False)


def compile_filter_aside(record: xr.Dataset, model: str, n_lhs: int, taus) -> Future:
    """Start a child that fits ``model`` with the UKF (``n_lhs`` priors per τ in ``taus``) to the first
    :data:`SLICE` samples of ``record``, compiling the filter into the disk cache.

    Parameters
    ----------
    record : xarray.Dataset
        The record the job will fit (its slice goes to the child pickled: the same dtypes and attributes, so the
        same compiled signatures).
    model : str
        A model the job fits (any: the filter is compiled for every layout at once).
    n_lhs, taus : int, sequence of float
        The job's UKF settings (the batched filter over more than one prior is what it runs).

    Returns
    -------
    concurrent.futures.Future
        The child's fit (its executor shuts down when it is done).
    """
    pool = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"))
    fut = pool.submit(_fit, record.isel(time=slice(0, SLICE)).load(), model, int(n_lhs),
                      tuple(float(t) for t in taus))
    pool.shutdown(wait=False)
    return fut


def wait(child: Future, say, timeout: float = MAX_WAIT_S) -> str | None:
    """Wait for ``child`` (at most ``timeout`` seconds) and tell ``say`` how long, or why it failed.

    Returns
    -------
    str or None
        The child's error (None when it compiled or loaded the filter).
    """
    t0 = _time.perf_counter()
    try:
        child.result(timeout=timeout)
        error = None
    except FutureTimeout:
        error = f"not done after {timeout:g} s"
    except Exception as exc:  # noqa: BLE001 — a failed warm-up only costs time: the job compiles the filter itself
        error = f"{type(exc).__name__}: {exc}"
    waited = _time.perf_counter() - t0
    if error is not None:
        say(f"the UKF filter's compile aside failed ({error}); the first UKF fit compiles it")
    elif waited >= 1.0:
        say(f"waited {waited:.0f} s for the UKF filter's compile (bayes_mr.run.warmup; an empty kernel cache)")
    return error


def expect_posteriors(record: xr.Dataset, forms, settings) -> None:
    """Declare the emcee pilots the job will run on ``record`` for each of ``forms``.

    Parameters
    ----------
    record : xarray.Dataset
        The record the posteriors fit (its kind and number of samples).
    forms : sequence of str
        Models whose posteriors the job runs.
    settings : MCMCSettings
        The chains' settings: each pilot runs ``walkers(d)`` walkers for :attr:`pilot_length` steps over every
        sample, d the model's parameter count on this kind of test.
    """
    kind, n = record.attrs["kind"], int(record.sizes["time"])
    for form in forms:
        model = get_model(form)
        expect_work(run_batch, model.layout(kind), n * settings.walkers(len(model.param_names(kind)))
                    * settings.pilot_length)
