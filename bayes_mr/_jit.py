"""The two ways bayes_mr compiles code with numba.

``hot`` is for functions that run per sample or per sub-step (right-hand
sides, RK4, filter steps). They never allocate, so they are compiled without
numba's reference counting (``_nrt=False``): with it, every array argument of
a branchy function is reference-counted with atomic operations on entry and
exit, which measured 7× slower than the physics itself (deriv 103 ns → 14 ns,
one RK4 step 620 ns → 87 ns on this machine). ``driver`` is for the loops
that allocate their buffers once and call the hot functions.

Both use ``error_model="numpy"`` (a division by zero gives inf/nan, which the
callers detect as a diverged run, instead of raising) and cache the machine
code on disk.
"""

from __future__ import annotations

from numba import njit


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
