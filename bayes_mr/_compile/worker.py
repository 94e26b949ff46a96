"""Child process that compiles one specialised kernel into the disk cache (``python -m bayes_mr._compile.worker``),
and the ready markers it leaves.

Started by :func:`bayes_mr._compile.specialise._start_background` with the generated
module's path, the kernel's name, a file holding the argument types (pickled,
hex), the marker to write when numba has saved the machine code (the parent
runs a slower kernel until that marker exists) and, optionally, how many
steps to lower its own CPU priority (``nice``) before compiling. The parent
claims the compile first (:func:`claim`), so that processes sharing a cache
start one child per kernel, not one each.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import pickle
import socket
import sys
import tempfile
import time
from pathlib import Path

import numba

_markers: dict[tuple, Path] = {}


def _write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file in the same directory and a rename."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.stem, suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _load(path: Path):
    """The generated module at ``path`` (imported once per process)."""
    name = f"bayes_mr_kernels_{path.stem}"
    mod = sys.modules.get(name)
    if mod is None:
        spec = importlib.util.spec_from_file_location(name, path)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        sys.modules[name] = mod
    return mod


def ready_path(path: Path, argtypes: tuple) -> Path:
    """Marker written once the kernel at ``path`` is compiled into the disk cache for ``argtypes``; its name hashes
    numba's cache directory (keyed on the package's sources, :mod:`bayes_mr._compile.jit`) so that after an edit an old
    marker cannot make ``auto`` compile in the calling process (a compare's UKF row would take minutes, not seconds)."""
    key = (path, argtypes, numba.config.CACHE_DIR)
    marker = _markers.get(key)  # memoised: every kernel call asks
    if marker is None:
        h = hashlib.sha256((repr(argtypes) + str(numba.config.CACHE_DIR)).encode()).hexdigest()[:12]
        marker = _markers[key] = path.with_name(f"{path.stem}.{h}.ready")
    return marker


def mark_ready(marker: Path, name: str, argtypes: tuple) -> None:
    """Write ``marker``: kernel ``name`` is in numba's disk cache for ``argtypes``."""
    _write_atomic(marker, f"{name} {argtypes!r}\n")


#: A claim older than this [s] is taken over whoever made it (a compile at the lowest priority on a busy machine
#: can take 13 min; a claimant on another host, or one whose process id was reused, cannot be checked otherwise).
CLAIM_STALE_S = 3600.0


def claim_path(marker: Path) -> Path:
    """The file a process holds while a child compiles the kernel of ``marker`` (:func:`claim`)."""
    return marker.with_suffix(".claim")


def _alive(text: str) -> bool:
    """Whether the claim ``text`` ("host pid time") names a process that may still be compiling."""
    try:
        host, pid, since = text.split()
        pid, since = int(pid), float(since)
    except ValueError:
        return False  # a claim being written or a damaged one: taken over
    if time.time() - since > CLAIM_STALE_S:
        return False
    if host != socket.gethostname():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, another user's
        pass
    return True


def claim(marker: Path, pid: int | None = None) -> bool:
    """Claim the compile of ``marker``'s kernel for process ``pid`` (default this one) across processes.

    False when another live process holds the claim (it is compiling that kernel: on a cluster sharing one cache,
    or in pytest's or Dask's workers, one compile instead of one per process). A claim whose process has ended
    without removing it (killed) or that is older than :data:`CLAIM_STALE_S` is taken over. The compiling child
    removes the claim when it is done, whether it succeeded or not (:func:`main`).
    """
    path = claim_path(marker)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = f"{socket.gethostname()} {os.getpid() if pid is None else pid} {time.time()!r}\n"
    for _ in range(2):
        try:
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:
            try:
                held = path.read_text()
            except FileNotFoundError:
                continue  # released meanwhile: try again
            if _alive(held):
                return False
            path.unlink(missing_ok=True)  # stale: take it over
            continue
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
        return True
    return False


def hand_over(marker: Path, pid: int) -> None:
    """Name the compiling child ``pid`` in the claim this process made for it (its liveness is what counts)."""
    _write_atomic(claim_path(marker), f"{socket.gethostname()} {pid} {time.time()!r}\n")


def idle_class() -> bool:
    """Move this process to the idle scheduling class (Linux ``SCHED_IDLE``), where it has one; whether it did.

    Below every ``nice`` level: a thread of the job (or of its stages beside the posteriors, at ``nice`` 19,
    :mod:`bayes_mr.run.aside`) that wakes takes the core at once, so a compile for a later run never delays a
    parallel batch of this one.
    """
    try:
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
    except (AttributeError, OSError):
        return False
    return True


def main(argv: list[str]) -> int:
    """Compile ``argv`` = [module path, kernel name, types file, marker, (nice)]; 0 on success."""
    path, name, types_file, marker = argv[:4]
    if len(argv) > 4 and int(argv[4]) > 0:
        os.nice(int(argv[4]))  # compile on the cores the parent leaves idle
        idle_class()
    try:
        argtypes = pickle.loads(bytes.fromhex(Path(types_file).read_text()))
        fn = getattr(_load(Path(path)), name)
        fn.compile(argtypes)  # a cached dispatcher saves the overload to numba's cache here
        mark_ready(Path(marker), name, argtypes)
    finally:
        claim_path(Path(marker)).unlink(missing_ok=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
