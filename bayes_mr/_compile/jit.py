"""The two ways bayes_mr compiles code with numba.

``hot`` is for functions that run per sample or per sub-step (right-hand
sides, RK4, filter steps). They never allocate, so they are compiled without
numba's reference counting (``_nrt=False``): with it, every array argument of
a branchy function is reference-counted with atomic operations on entry and
exit, which is 7× slower than the physics itself (deriv 103 ns → 14 ns, one
RK4 step 620 ns → 87 ns on one core). ``driver`` is for the loops
that allocate their buffers once and call the hot functions.

Both use ``error_model="numpy"`` (a division by zero gives inf/nan, which the
callers detect as a diverged run, instead of raising) and cache the machine
code on disk.

Where: numba checks a cached function against its *own* file only, so
machine code of :mod:`bayes_mr.models.drivers` inlined from an edited
:mod:`bayes_mr.models.kernel` would be loaded stale, and the old physics
would run silently. The cache therefore
lives in a directory named by a hash of the code of every source file of the package
that compiles code (``$NUMBA_CACHE_DIR``, else ``$BAYES_MR_CACHE/numba`` or
``~/.cache/bayes_mr/numba``, then ``<hash>/``): an edit of any of them
starts a fresh cache, an unchanged install reuses its own. The hash is of the
code alone (:func:`code_of`): editing a docstring or a comment recompiles
nothing, where it would otherwise cost every kernel's compile again (the full
specialised ones take ten minutes or more each, :mod:`bayes_mr._compile.specialise`).
"""

from __future__ import annotations

import ast
import hashlib
import os
from pathlib import Path

import numba
from numba import njit

from bayes_mr._compile.threads import limit_blas, passive_wait

#: Text that marks a source file as compiling code (its edits change the cache key).
_MARKERS = (b"@hot", b"@driver", b"njit(")


def code_of(source: bytes) -> bytes:
    """The code of a Python source, without its docstrings and comments: its syntax tree, dumped.

    Two sources with the same code give the same bytes, whatever their prose or layout (a docstring is not
    code here: no kernel reads ``__doc__``); any other change gives other bytes.
    """
    tree = ast.parse(source)
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if (isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and body
                and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant)
                and isinstance(body[0].value.value, str)):
            node.body = body[1:] or [ast.Pass()]
    return ast.dump(tree).encode()


def _source_key(root: Path | None = None) -> str:
    """Hash of the compiling source files (names and code, :func:`code_of`) under ``root`` (default: this
    package)."""
    h = hashlib.sha256()
    root = Path(__file__).resolve().parents[1] if root is None else Path(root)
    for f in sorted(root.rglob("*.py")):
        data = f.read_bytes()
        if any(m in data for m in _MARKERS):
            h.update(str(f.relative_to(root)).encode())
            h.update(code_of(data))
    return h.hexdigest()[:16]


def _configure_cache() -> None:
    """Point numba's on-disk cache at a directory keyed by :func:`_source_key` (before any function compiles)."""
    base = os.environ.get("NUMBA_CACHE_DIR") or os.path.join(
        os.environ.get("BAYES_MR_CACHE") or os.path.join(
            os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "bayes_mr"),
        "numba")
    numba.config.CACHE_DIR = os.path.join(base, _source_key())


_configure_cache()
passive_wait()  # numba's OpenMP threads sleep between batches instead of spinning (bayes_mr._compile.threads)
limit_blas()  # numba's threads do the parallel work; BLAS's own pool would compete with them (bayes_mr._compile.threads)


def hot(fn=None, **options):
    """Compile a non-allocating hot-path function."""
    opts = dict(cache=True, error_model="numpy", _nrt=False)
    opts.update(options)
    return njit(**opts)(fn) if fn is not None else njit(**opts)


def driver(fn=None, **options):
    """Compile an allocating driver loop."""
    opts = dict(cache=True, error_model="numpy")
    opts.update(options)
    return njit(**opts)(fn) if fn is not None else njit(**opts)
