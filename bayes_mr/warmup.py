"""Compile the UKF's filter in a child process while the job's first fits run (``python -m bayes_mr.warmup``).

On an empty kernel cache (a fresh machine) the first least-squares fit
compiles the generic simulator (~40 s of one core) and the first UKF fit the
generic filter (~80 s), one after the other in the job's own process, with
the other core idle. :func:`compile_filter_aside` starts the filter's compile
at once in a child that fits the UKF to a short slice of the job's own
record — the same code path, so the same argument types — and leaves the
machine code in numba's disk cache; the job runs its least-squares fits
meanwhile and waits for the child (:func:`wait`) before its first UKF fit,
which then loads the filter from disk. On a warm cache the child only loads
it (a few seconds). A child that fails changes nothing but the time: the job
compiles the filter itself, as without it, and the child's output is kept in
its log.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import tempfile
import time as _time
from pathlib import Path

import xarray as xr

#: Samples of the record the child fits (enough for every step of a UKF fit; a fraction of a second of work).
SLICE = 400
#: Longest wait for the child [s]; past it the job goes on and compiles the filter itself if it must.
MAX_WAIT_S = 600.0


def compile_filter_aside(record: xr.Dataset, model: str, n_lhs: int, taus, log: Path) -> subprocess.Popen | None:
    """Start a child that fits ``model`` with the UKF (``n_lhs`` priors per τ in ``taus``) to the first
    :data:`SLICE` samples of ``record``, compiling the filter into the disk cache.

    Parameters
    ----------
    record : xarray.Dataset
        The record the job will fit (its slice is pickled to a temporary file the child reads and removes: the
        same dtypes and attributes, so the same compiled signatures).
    model : str
        A model the job fits (any: the filter is compiled for every layout at once).
    n_lhs, taus : int, sequence of float
        The job's UKF settings (the batched filter over more than one prior is what it runs).
    log : pathlib.Path
        The child's output.

    Returns
    -------
    subprocess.Popen or None
        The child (None when the slice could not be written: the job then compiles the filter itself).
    """
    fd, path = tempfile.mkstemp(prefix="bayes_mr_warmup_", suffix=".pkl")
    try:
        with os.fdopen(fd, "wb") as fh:
            pickle.dump(record.isel(time=slice(0, SLICE)).load(), fh)
    except (OSError, pickle.PicklingError, TypeError):
        os.unlink(path)
        return None
    log.parent.mkdir(parents=True, exist_ok=True)
    with open(log, "w") as out:
        return subprocess.Popen([sys.executable, "-m", "bayes_mr.warmup", path, model, str(int(n_lhs)),
                                 *(repr(float(t)) for t in taus)],
                                stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT)


def wait(child: subprocess.Popen | None, timeout: float = MAX_WAIT_S) -> float:
    """Wait for ``child`` (at most ``timeout`` seconds; then it is stopped); seconds waited."""
    if child is None:
        return 0.0
    t0 = _time.perf_counter()
    try:
        child.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        child.kill()
        child.wait()
    return _time.perf_counter() - t0


def main(argv: list[str]) -> int:
    """``argv`` = [pickled slice, model, n_lhs, τ...]: fit, then remove the slice; 0 on success."""
    from .identify import UKF, Identify

    path, model, n_lhs, *taus = argv
    try:
        with open(path, "rb") as fh:
            record = pickle.load(fh)
    finally:
        os.unlink(path)
    t0 = _time.perf_counter()
    Identify(model, UKF(n_lhs=int(n_lhs), taus=tuple(float(t) for t in taus))).fit(record, seed=0, progress=False)
    print(f"bayes_mr.warmup: {model} UKF on {record.sizes['time']} samples in {_time.perf_counter() - t0:.1f} s "
          "(the filter compiled or loaded)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
