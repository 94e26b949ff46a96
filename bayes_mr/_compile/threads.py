"""One BLAS thread: bayes_mr's parallel work is numba's and the executor's, not OpenBLAS's.

The package runs its batches in parallel with numba (``prange`` over
parameter sets, walkers and priors, on numba's OpenMP pool) and spreads jobs
over processes (:mod:`bayes_mr.execution.executor`). Its BLAS calls are small and
interleaved with those batches: the SVD of a tall Jacobian with a few
columns in every trust-region step of least squares, p × p Hessians and
covariances. On those, OpenBLAS's own thread pool is a loss twice over on
2 cores: the SVD of a 60000 × 6 Jacobian takes 5.0 ms on two OpenBLAS
threads and 2.7 ms on one, and the pool's threads, spinning between calls,
hold the cores numba's next batch needs (``diagnose`` of the 30-s, 1-kHz
record of ``bayes-mr bench``: 42 s → 16 s wall, 84 s → 32 s of CPU, same
result).

So the compute layer (:mod:`bayes_mr._compile.jit`, imported by everything that
simulates) limits every BLAS library loaded in the process to one thread
when it is imported, through threadpoolctl. ``$BAYES_MR_BLAS_THREADS`` sets
another number (e.g. for a notebook that also does large dense algebra);
``0`` leaves BLAS alone.

numba's own pool (the GNU OpenMP layer here) has the same habit: after each
parallel batch its threads spin, waiting for the next, and between batches
the job runs Python (emcee's bookkeeping, least squares' trust-region
steps) for most of its time. On 2 cores a loop of short batches with
Python between them holds 2.0 cores where its work needs 1.23, and in
``make run`` a kernel compiling beside the job at low priority gets no
core at all.
:func:`passive_wait` sets ``OMP_WAIT_POLICY=PASSIVE`` (sleeping threads)
unless the environment says otherwise — before numba starts its pool,
which reads it once.
"""

from __future__ import annotations

import os

#: The environment variable that overrides the limit (an integer; 0: no limit).
ENV = "BAYES_MR_BLAS_THREADS"


def blas_threads() -> int:
    """The BLAS thread limit to apply: ``$BAYES_MR_BLAS_THREADS``, else 1 (0 means none).

    Raises
    ------
    ValueError
        If the variable is set to something that is not a non-negative integer.
    """
    raw = os.environ.get(ENV, "").strip()
    if not raw:
        return 1
    if not (raw.isascii() and raw.isdigit()):
        raise ValueError(f"${ENV}={raw!r}: expected a non-negative integer (threads per BLAS library; "
                         "0 leaves BLAS's own setting alone)")
    return int(raw)


#: The OpenMP variable :func:`passive_wait` sets, and its value.
OMP_WAIT = ("OMP_WAIT_POLICY", "PASSIVE")


def passive_wait() -> None:
    """Let numba's OpenMP threads sleep between parallel batches (``OMP_WAIT_POLICY=PASSIVE``), unless
    ``$OMP_WAIT_POLICY`` is set already.

    It takes effect only if numba's thread pool has not started in this
    process (the OpenMP runtime reads the variable when it loads); spawned
    child processes inherit it.
    """
    os.environ.setdefault(*OMP_WAIT)


def limit_blas() -> None:
    """Limit the BLAS libraries loaded in this process (numpy's and scipy's) to :func:`blas_threads` threads.

    scipy's own OpenBLAS is loaded with :mod:`scipy.linalg`, which is imported
    first so that the limit reaches it too.
    """
    n = blas_threads()
    if n == 0:
        return
    import scipy.linalg  # noqa: F401  (loads scipy's BLAS, so that the limit below applies to it)
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=n, user_api="blas")
