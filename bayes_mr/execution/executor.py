"""Grids of independent jobs, in this process or on an executor (a Dask cluster, a process pool).

>>> from bayes_mr.execution.executor import open_executor, run_jobs
>>> with open_executor(workers=2) as ex:                                  # doctest: +SKIP
...     outcomes = run_jobs(pow, [(2, 10), (3, 5)], executor=ex)
>>> [o.value for o in outcomes]                                           # doctest: +SKIP
[1024, 243]

An *executor* is anything with ``.submit(fn, *args)`` returning futures with
``.result()``: a :class:`concurrent.futures.Executor` or a
``dask.distributed.Client`` (which spreads the jobs over a cluster).
``compare``'s models × engines, diagnose's candidate effects and the UKF
training chunks all go through this one interface:

* each job is a module-level function with picklable arguments (it is
  shipped to another process, possibly another machine);
* results come back in the order the jobs were given, whatever order they
  finish in, so nothing downstream (seeds, tables, selection) depends on
  completion order — the same numbers as in process;
* progress is reported as each job finishes;
* a job that raises is an :class:`Outcome` with its error, never the end of
  the grid;
* Ctrl-C (KeyboardInterrupt) cancels the jobs that have not started and is
  raised again; a job already running on a worker cannot be stopped from
  here and its result is dropped.

A process pool must start its workers with ``spawn`` (or ``forkserver``):
``ProcessPoolExecutor(n, mp_context=multiprocessing.get_context("spawn"))``.
A forked child of a process whose compiled kernels have run (GNU OpenMP) is
terminated, and every job it held becomes a row with its error.

On an executor each job runs with one numba thread: the executor's workers are
the parallelism, and the compiled kernels would otherwise start one thread per
core in every worker. Thread counts do not change any result (every batched
kernel computes its members independently).

In one process, :func:`local_threads` is a pool of threads, one per numba
thread, for grids whose jobs are least-squares fits (diagnose's candidate
effects, the starts of a search): a fit's simulations release the GIL, and a
fit alone leaves a core idle through its Python steps and its one-member
simulations (measured on the bench's diagnose, 30 s at 1 kHz: 18.5 s in
turn, 13.4 s on two threads with the costliest candidates first, the same
result). ``cost`` (:func:`run_jobs`) submits the costliest jobs first, so the
last to finish is not a long one started late.
"""

from __future__ import annotations

import contextlib
import logging
import time as _time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass


@dataclass(frozen=True)
class Outcome:
    """What one job gave.

    Attributes
    ----------
    index : int
        Position of the job in the list given to :func:`run_jobs`.
    value : object
        The job's return value (None if it failed).
    error : str or None
        ``"ExceptionType: message"`` of a job that raised.
    wall_s : float
        Seconds from submission (in process: from its start) to its result.
    """

    index: int
    value: object = None
    error: str | None = None
    wall_s: float = 0.0

    @property
    def ok(self) -> bool:
        return self.error is None


def is_dask(executor) -> bool:
    """Whether ``executor`` is a ``dask.distributed.Client`` (it can scatter data to its workers)."""
    return executor is not None and hasattr(executor, "scatter") and hasattr(executor, "gather")


def share(executor, obj):
    """``obj`` as jobs on ``executor`` should receive it.

    A dask Client gets it scattered to every worker once (a future that the
    workers resolve to the object, so a record or a fitted base model is not
    shipped again with every job); any other executor, or none, the object
    itself (a process pool pickles it with each job).
    """
    if is_dask(executor):
        # a fresh key each time: a content-hashed key that an earlier grid has just released can be
        # forgotten by the scheduler while this grid's jobs wait for it ("Could not find data")
        return executor.scatter(obj, broadcast=True, hash=False)
    return obj


def is_done(fut) -> bool:
    """Whether a future has finished (futures without ``done()`` count as not finished)."""
    done = getattr(fut, "done", None)
    return bool(done()) if callable(done) else False


def cancel(futures) -> None:
    """Cancel every future that has not finished (those that cannot be cancelled are left to run)."""
    for fut in futures:
        if not is_done(fut):
            stop = getattr(fut, "cancel", None)
            if callable(stop):
                stop()


def submit(executor, fn: Callable, *args):
    """``executor.submit(fn, *args)``; on dask as an impure task, so equal jobs are not merged into one."""
    if is_dask(executor):
        return executor.submit(fn, *args, pure=False)
    return executor.submit(fn, *args)


def call_single_threaded(fn: Callable, *args):
    """``fn(*args)`` with numba's parallel kernels on one thread in this thread (a job on an executor)."""
    import numba

    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        return fn(*args)
    finally:
        numba.set_num_threads(before)


def _error(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"


def _ident(fut):
    """A future's identity across the objects that stand for it (dask: its key)."""
    return getattr(fut, "key", None) or id(fut)


def _completed(executor, futures: list) -> Iterator:
    """The futures in the order they finish (in submission order for an executor of unknown kind)."""
    import concurrent.futures as cf

    if is_dask(executor):
        from distributed import as_completed

        return iter(as_completed(futures))
    if all(isinstance(f, cf.Future) for f in futures):
        return cf.as_completed(futures)
    return iter(futures)


def run_jobs(
    fn: Callable,
    jobs: Sequence[tuple],
    *,
    executor=None,
    on_start: Callable[[int], None] | None = None,
    on_done: Callable[[Outcome], None] | None = None,
    cost: Sequence[float] | None = None,
) -> list[Outcome]:
    """Call ``fn(*args)`` for every ``args`` of ``jobs``, in process or on ``executor``.

    Parameters
    ----------
    fn : callable
        A module-level function (picklable by reference).
    jobs : sequence of tuple
        The positional arguments of each call (picklable; on dask, futures
        from :func:`share` stand for scattered data).
    executor : object, optional
        ``.submit(fn, *args) -> future`` (module docstring); None runs the
        jobs one after another here.
    on_start : callable, optional
        Called with a job's index when it starts (in process) or is
        submitted (executor).
    on_done : callable, optional
        Called with each :class:`Outcome` as its job finishes.
    cost : sequence of float, optional
        Expected relative cost of each job: on an executor the costliest are submitted first (ties in the
        order given); the outcomes keep the order of ``jobs``. In process the jobs run in the order given.

    Returns
    -------
    list of Outcome
        One per job, in the order of ``jobs``.
    """
    start = on_start or (lambda i: None)
    done = on_done or (lambda o: None)
    if executor is None:
        outcomes = []
        for i, args in enumerate(jobs):
            start(i)
            t0 = _time.perf_counter()
            try:
                o = Outcome(i, fn(*args), wall_s=_time.perf_counter() - t0)
            except Exception as exc:  # one failed job is a result, not the end of the grid
                o = Outcome(i, error=_error(exc), wall_s=_time.perf_counter() - t0)
            done(o)
            outcomes.append(o)
        return outcomes
    order = list(range(len(jobs))) if cost is None else sorted(range(len(jobs)), key=lambda i: -float(cost[i]))
    return _run_on(executor, fn, jobs, start, done, order)


def _run_on(executor, fn: Callable, jobs: Sequence[tuple], start, done, order: list[int]) -> list[Outcome]:
    """:func:`run_jobs` on an executor: submit all (in ``order``), collect as they finish, cancel the rest on
    Ctrl-C."""
    t0 = _time.perf_counter()
    futures: list = []
    index: dict = {}
    try:
        for i in order:
            futures.append(submit(executor, call_single_threaded, fn, *jobs[i]))
            index[_ident(futures[-1])] = i
            start(i)
        outcomes: dict[int, Outcome] = {}
        for fut in _completed(executor, futures):
            i = index[_ident(fut)]
            try:
                o = Outcome(i, fut.result(), wall_s=_time.perf_counter() - t0)
            except Exception as exc:  # raised by the job, or the worker running it was lost
                o = Outcome(i, error=_error(exc), wall_s=_time.perf_counter() - t0)
            outcomes[i] = o
            done(o)
    except BaseException:  # Ctrl-C or a failing callback: nothing more is to run
        cancel(futures)
        raise
    return [outcomes[i] for i in range(len(futures))]


#: numba threading layers that run parallel kernels called from several threads at once (``workqueue`` aborts).
THREADSAFE_LAYERS = ("omp", "tbb")


@contextlib.contextmanager
def local_threads(given=None) -> Iterator[object]:
    """``given`` if not None, else a pool of threads in this process, one per numba thread, closed after.

    None (jobs in turn) where that would not run jobs side by side: one numba thread here (a job on an
    executor, or a one-core machine), or a threading layer not known to take concurrent calls (``workqueue``).
    Each job runs its kernels on one thread (:func:`call_single_threaded`); results are those of the jobs in
    turn. On Ctrl-C the jobs not started are cancelled and the running ones (a fit each) finish first.
    """
    if given is not None:
        yield given
        return
    import numba
    from concurrent.futures import ThreadPoolExecutor

    n = numba.get_num_threads()  # starts numba's threading layer, so the next line can name it
    if n < 2 or numba.threading_layer() not in THREADSAFE_LAYERS:
        yield None
        return
    pool = ThreadPoolExecutor(n, thread_name_prefix="bayes_mr")
    try:
        yield pool
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def side_by_side(fn: Callable, jobs: Sequence[tuple]) -> list:
    """``[fn(*args) for args in jobs]``, the calls side by side on :func:`local_threads` where there can be.

    For the few independent refinements of one fit (a search's starts): results in the order of ``jobs``; a call
    that raises raises here (the first in that order; calls not started yet are cancelled, running ones finish).
    """
    with local_threads() as pool:
        if pool is None:
            return [fn(*args) for args in jobs]
        return list(pool.map(lambda args: call_single_threaded(fn, *args), jobs))


@contextlib.contextmanager
def job_executor(given=None) -> Iterator[object]:
    """The executor a job's own sub-jobs should use: ``given``, else its Dask cluster, else None.

    A job running as a task on a Dask worker (a ``compare`` fit on
    ``--scheduler``/``--workers``) gets a client of that cluster
    (``distributed.worker_client``: the task leaves its worker's thread pool
    while it waits, so its sub-jobs — an evidence ladder's rungs — run on the
    cluster's free workers, this one included). Anywhere else (in process, a
    process pool) it is ``given``, None by default: the sub-jobs then run in
    the job's own process. Sub-jobs give the same numbers wherever they run.
    """
    if given is not None:
        yield given
        return
    try:
        from distributed import get_worker, worker_client

        get_worker()
    except (ImportError, ValueError):  # not on a Dask worker
        yield None
        return
    with worker_client() as client:
        yield client


@contextlib.contextmanager
def open_executor(scheduler: str | None = None, workers: int | None = None) -> Iterator[object]:
    """The executor of ``--scheduler ADDRESS`` / ``--workers N``, closed after.

    Parameters
    ----------
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://HOST:8786``): a Client
        connected to it (the cluster itself is left running).
    workers : int, optional
        Start a ``LocalCluster`` of this many worker processes, one thread
        each, for the duration of the block.

    Yields
    ------
    dask.distributed.Client or None
        None when neither is given (jobs run in this process).
    """
    if scheduler and workers:
        raise ValueError("give --scheduler ADDRESS (a running cluster) or --workers N (a local one), not both")
    if not scheduler and workers is None:
        yield None
        return
    from distributed import Client, LocalCluster

    if scheduler:
        with Client(scheduler) as client:
            yield client
        return
    if workers < 1:
        raise ValueError(f"--workers must be ≥ 1, got {workers}")
    # dashboard on a free port: two commands on one machine do not fight over 8787; only errors are logged
    # (a worker slow to exit at close is killed with a warning that says nothing about the results)
    with LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True, dashboard_address=":0",
                      silence_logs=logging.ERROR) as cluster:
        with Client(cluster) as client:
            yield client
