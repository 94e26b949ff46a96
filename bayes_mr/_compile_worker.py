"""Child process that compiles one specialised kernel into the disk cache (``python -m bayes_mr._compile_worker``),
and the ready markers it leaves.

Started by :func:`bayes_mr._specialise._start_background` with the generated
module's path, the kernel's name, a file holding the argument types (pickled,
hex), the marker to write when numba has saved the machine code (the parent
runs a slower kernel until that marker exists) and, optionally, how many
steps to lower its own CPU priority (``nice``) before compiling.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import pickle
import sys
import tempfile
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
    numba's cache directory (keyed on the package's sources, :mod:`bayes_mr._jit`) so that after an edit an old
    marker cannot make ``auto`` compile in the calling process (it did: a compare's UKF row took 173 s, not 4)."""
    key = (path, argtypes, numba.config.CACHE_DIR)
    marker = _markers.get(key)  # memoised: every kernel call asks
    if marker is None:
        h = hashlib.sha256((repr(argtypes) + str(numba.config.CACHE_DIR)).encode()).hexdigest()[:12]
        marker = _markers[key] = path.with_name(f"{path.stem}.{h}.ready")
    return marker


def mark_ready(marker: Path, name: str, argtypes: tuple) -> None:
    """Write ``marker``: kernel ``name`` is in numba's disk cache for ``argtypes``."""
    _write_atomic(marker, f"{name} {argtypes!r}\n")


def main(argv: list[str]) -> int:
    """Compile ``argv`` = [module path, kernel name, types file, marker, (nice)]; 0 on success."""
    path, name, types_file, marker = argv[:4]
    if len(argv) > 4 and int(argv[4]) > 0:
        os.nice(int(argv[4]))  # compile on the cores the parent leaves idle
    argtypes = pickle.loads(bytes.fromhex(Path(types_file).read_text()))
    fn = getattr(_load(Path(path)), name)
    fn.compile(argtypes)  # a cached dispatcher saves the overload to numba's cache here
    mark_ready(Path(marker), name, argtypes)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
