"""Compiled kernels specialised to one model layout, cached on disk.

The generic kernels (:mod:`bayes_mr.models.kernel`, the drivers, the UKF) read the model's int64 *layout* at
run time, so one compiled kernel serves every ``FORM+EFFECT`` combination but branches on the layout at every
sub-step. :func:`specialised` returns the same kernel with the layout fixed: a generated module (one per
layout and kernel) holds the layout as a global tuple and a wrapper that passes it on to the generic kernel.
numba types a global tuple of ints as a tuple of *literal* ints, and every compiled function it reaches is
compiled again for that literal type — the layout becomes a compile-time constant there, and LLVM folds away
the branches of the effects the model does not have. The physics stays in one place: a new effect added to
the generic kernel is specialised with no change here.

Compiling one takes ten minutes or more of a core and 5–6 GB of memory (the full kernel of a structure test,
measured with two compiles sharing two cores: spencer 608 s, normalized-bouc-wen 675 s, lugre 681 s, bouc-wen 839 s,
dahl 856 s; ``bayes-mr bench`` times dahl's alone as ``compile_s``), so ``auto`` never waits for it: it starts the
compile in a child process
(:mod:`bayes_mr._compile.worker`) and runs the generic kernel until the child marks the machine code ready
on disk (:class:`_Auto`).

Nearly all of that is the physics inlined at numba-IR level (:data:`INLINE`): the same kernel with the layout
constant and nothing inlined there, the *quick* kernel (:data:`QUICK_INLINE`), compiles in a small fraction of it.
The full kernel is 1.4–5× faster per sample than the generic one (dahl the most, spencer the least: ``bayes-mr
bench``'s ``simulate_ns_per_step``, :mod:`bayes_mr.bench.kernels`, docs/performance.md), the quick one between the
two. So once a layout's work pays, ``auto`` compiles both: the quick kernel at once, and the
full one at the lowest CPU priority (:data:`BACKGROUND_NICE`), on the cores the job leaves idle: it runs where it
is ready (in a later process, or later in a long one) and never takes a core from the job that asked for it: at
the job's own priority, on an empty cache and 2 cores, the full compile doubles the time of ``make run``'s
spencer posterior — for a kernel no faster than the quick one on that model.

Between the two sits the *inlined* kernel (:func:`inlined`): the generic kernel with the per-sub-step
physics inlined (:data:`INLINE`) but the layout still read at run time. One compile serves every model, so
``auto`` starts it much sooner (:data:`INLINED_WORK`) and runs it until a model's specialised kernel is
ready. The generic kernel itself stays as it is: the reference the others are tested against, and quick to
compile for the test suite.

Cache. The generated modules live in ``$BAYES_MR_CACHE/kernels`` (default ``~/.cache/bayes_mr/kernels``);
numba caches their machine code next to them (``__pycache__``), so a fresh machine compiles each model once
and a later process loads it from disk. A module's name hashes the layout, the kernel and the code of
every module the kernel reaches, so editing the physics gives new modules instead of stale machine code
(numba itself only checks the caller's file). Files are written to a temporary name and renamed, so
concurrent processes (pytest workers, Dask) never see a partial file; two processes compiling the same
kernel at once both succeed, and numba's own index writes are atomic too. A background compile is claimed by
the first process that starts it (``*.claim``, :func:`bayes_mr._compile.worker.claim`): processes sharing a
cache start one child per kernel, not one each (a full compile takes over ten minutes and several GB of memory:
one per process would multiply both).
"""

from __future__ import annotations

import hashlib
import inspect
import os
import pickle
import subprocess
import sys
import threading
import types
from contextlib import contextmanager
from pathlib import Path

import numba
import numpy as np
from numba import njit, typeof
from numba.core.typing.typeof import Purpose

from bayes_mr._compile.jit import code_of
from bayes_mr._compile.worker import _load, _write_atomic, claim, hand_over, mark_ready, ready_path

#: Environment variable naming the cache directory (generated kernels in its ``kernels`` subdirectory).
CACHE_ENV = "BAYES_MR_CACHE"
#: Environment variable choosing the kernels: ``auto`` (default), ``specialised`` or ``generic``.
KERNELS_ENV = "BAYES_MR_KERNELS"
#: ``auto``: background compiles of a layout's quick and full specialised kernels start once this many sample-steps
#: (samples × parameter sets) have been asked of it in the process; one already compiled on disk for the call's
#: argument types runs at once. The quick one costs ~20 s of one core and saves 80-260 ns per sample-step on the
#: generic kernel (module docstring): it pays back within the process after ~1e8-2.5e8 steps and at once in later
#: ones (the disk cache), so both start at 2e8 — an emcee posterior or a 100-prior UKF training, not a
#: least-squares fit or one of diagnose's dozens of candidate refits. The full one (10–15 min) uses idle cores only.
AUTO_WORK = 2e8
#: ``auto``: the background compile of the inlined kernel (:func:`inlined`, every layout) starts once this many
#: sample-steps have been asked of the generic kernel in the process, over all layouts. About 6 minutes of a core
#: once per machine, it takes the generic step 1.2–1.8× faster for every model (``simulate_ns_per_step``): a
#: diagnose — dozens of layouts, none worth its own compile — pays.
INLINED_WORK = 2e7
#: Kernels ``auto`` gives the inlined tier: the simulator's (measured above). A UKF job is either too short to
#: pay for any compile or long enough for its model's specialised kernel (``AUTO_WORK``), and the filter's
#: sigma-point arithmetic gains from inlining only with the sizes constant (:data:`INLINE`).
INLINED_TIER = ("run_batch",)

#: Compiled functions inlined into their callers in the specialised and inlined kernels (the per-sub-step physics):
#: 1.5-2.4x on the dahl structure step with the layout constant (1.3x without). ``advance`` calls ``deriv`` from one
#: site for all four RK4 stages, so it is inlined once (a fifth of the compile time, ~220 s -> 47 s); so does the UKF's
#: ``advance_points``, which replaces ``advance`` in the filter's step (not a second inlined copy there). The UKF's
#: sigma-point arithmetic (:mod:`.inference.unscented_kernel`) is inlined so the filter's sizes are constants in its
#: loops (a dahl filter run on signal I 2.27 -> 1.68–1.82 µs per sample).
INLINE = ("deriv", "deriv_pow", "forces", "rate", "substeps", "advance", "advance_points", "point_powers", "observe",
          "cholesky", "sigma_points", "moments", "sigma_thetas")
#: Inlined in the *quick* kernel of a layout: nothing beyond what the source inlines (module docstring).
QUICK_INLINE: tuple[str, ...] = ()
#: CPU priority (``nice`` increment) of the background compile of a layout's full specialised kernel; the quick
#: and the inlined kernels compile at the caller's priority.
BACKGROUND_NICE = 19
#: Inlined as well in a kernel specialised to one layout: the simulator's loop, into ``models.drivers.run_one``,
#: whose one scratch array then keeps RK4's stages in registers (dahl structure step 31.8 -> 25.4 ns; in the
#: inlined kernel, layout unknown, 47 -> 249 ns, so not there). The UKF's loop the same way: no gain.
INLINE_SPECIALISED = ("_integrate",)

_loaded: dict[tuple, object] = {}
_lock = threading.RLock()
_work: dict[tuple, float] = {}
_paths: dict[tuple, Path] = {}
_started: set[Path] = set()


def cache_dir() -> Path:
    """Directory of the generated kernel modules: ``$BAYES_MR_CACHE/kernels`` or ``~/.cache/bayes_mr/kernels``."""
    root = os.environ.get(CACHE_ENV) or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "bayes_mr")
    return Path(root) / "kernels"


def _is_dispatcher(obj) -> bool:
    return hasattr(obj, "py_func") and hasattr(obj, "targetoptions")


def _callees(py) -> list[tuple[str, object]]:
    """(global name, dispatcher) of the compiled functions ``py`` refers to."""
    out = []
    for name in py.__code__.co_names:
        g = py.__globals__.get(name)
        if _is_dispatcher(g):
            out.append((name, g))
    return out


def _reached_files(dispatcher) -> list[str]:
    """Source files of every compiled function reachable from ``dispatcher`` through module globals."""
    seen_fn: set[int] = set()
    files: set[str] = set()
    todo = [dispatcher]
    while todo:
        d = todo.pop()
        if id(d) in seen_fn:
            continue
        seen_fn.add(id(d))
        files.add(inspect.getsourcefile(d.py_func))
        todo.extend(g for _, g in _callees(d.py_func))
    return sorted(files)


def private_chain(dispatcher, inline: tuple[str, ...] = INLINE):
    """A private, uncached copy of ``dispatcher`` and of every compiled function it reaches.

    Same code objects, so the same physics; but the copies resolve their
    callees among the copies, are never written to (or read from) the
    generic kernels' on-disk caches — whose index numba keys on the caller's
    file alone, so a specialisation cached there would outlive an edit of
    the physics — and the functions named in ``inline`` are inlined at
    numba-IR level, so that the whole step sits in one LLVM function where
    the constant layout folds and the states stay in registers. The
    generated module's wrapper is the only cached artefact.
    """
    memo: dict[int, object] = {}

    def copy(d):
        if id(d) in memo:
            return memo[id(d)]
        py = d.py_func
        glob = dict(py.__globals__)
        fn = types.FunctionType(py.__code__, glob, py.__name__, py.__defaults__, py.__closure__)
        fn.__qualname__ = py.__qualname__
        fn.__doc__ = py.__doc__
        opts = {k: v for k, v in d.targetoptions.items() if k not in ("nopython", "boundscheck")}
        if py.__name__ in inline:
            opts["inline"] = "always"
        new = njit(**opts)(fn)
        memo[id(d)] = new
        for name, g in _callees(py):
            glob[name] = copy(g)
        return new

    return copy(dispatcher)


def _fingerprint(dispatcher) -> str:
    """Hash of the code of every file the kernel reaches (changes when the physics does, not with its prose:
    :func:`~bayes_mr._compile.jit.code_of`)."""
    h = hashlib.sha256()
    for f in _reached_files(dispatcher):
        h.update(f.encode())
        h.update(code_of(Path(f).read_bytes()))
    return h.hexdigest()


def _source(dispatcher, lay: tuple[int, ...] | None, inline: tuple[str, ...]) -> str:
    """Text of the generated module: the layout as a global tuple (none for the inlined kernel, ``lay`` None)
    and a wrapper with the generic signature."""
    py = dispatcher.py_func
    sig = inspect.signature(py).parameters
    params = list(sig)
    if params[0] != "lay":
        raise ValueError(f"{py.__name__}: the layout must be the first argument to specialise on it")
    opts = {k: v for k, v in dispatcher.targetoptions.items() if k == "nogil"}
    opt_text = ", ".join(f"{k}={v!r}" for k, v in sorted(opts.items()))
    args = ", ".join(str(p) for p in sig.values())  # defaults kept (e.g. the drivers' every=1)
    call = ", ".join(["LAY" if lay is not None else "lay"] + params[1:])
    what = "for one layout" if lay is not None else "with the physics inlined, any layout"
    return (
        f'"""Generated by bayes_mr._compile.specialise: {py.__module__}.{py.__name__} {what}. Do not edit."""\n'
        f"from bayes_mr._compile.jit import driver\n"
        f"from bayes_mr._compile.specialise import private_chain\n"
        f"from {py.__module__} import {py.__name__}\n\n"
        f"_generic = private_chain({py.__name__}, inline={tuple(inline)!r})\n"
        + (f"LAY = {tuple(int(v) for v in lay)!r}\n" if lay is not None else "")
        + f"\n\n@driver({opt_text})\n"
        f"def {py.__name__}({args}):\n"
        + ("    # ``lay`` is ignored: the layout is the constant LAY\n" if lay is not None else "")
        + "    return _generic(" + call + ")\n"
    )


def _lay_tuple(lay) -> tuple[int, ...] | None:
    return None if lay is None else tuple(int(v) for v in np.asarray(lay).ravel())


def _inline_for(lay_t: tuple[int, ...] | None, inline: tuple[str, ...] | None) -> tuple[str, ...]:
    """``inline``, or by default :data:`INLINE` (the inlined kernel) and :data:`INLINE_SPECIALISED` too (one layout)."""
    if inline is not None:
        return tuple(inline)
    return INLINE if lay_t is None else INLINE + INLINE_SPECIALISED


def module_path(dispatcher, lay, inline: tuple[str, ...] | None = None) -> Path:
    """Path of the generated module specialising ``dispatcher`` to layout ``lay`` (None: the inlined kernel)."""
    lay_t = _lay_tuple(lay)
    inline = _inline_for(lay_t, inline)
    text = _source(dispatcher, lay_t, inline)
    key = hashlib.sha256((_fingerprint(dispatcher) + text).encode()).hexdigest()[:20]
    return cache_dir() / f"k_{dispatcher.py_func.__name__}_{'any_' if lay_t is None else ''}{key}.py"


def _path(dispatcher, lay_t: tuple[int, ...] | None, inline: tuple[str, ...]) -> Path:
    """:func:`module_path`, memoised (hashing the kernel's sources reads files); ``inline`` as resolved by
    :func:`_inline_for`."""
    key = (id(dispatcher), lay_t, inline)
    with _lock:
        path = _paths.get(key)
        if path is None:
            path = _paths[key] = module_path(dispatcher, lay_t, inline)
    return path


def _generated(dispatcher, lay_t: tuple[int, ...] | None, inline: tuple[str, ...]) -> Path:
    """Path of the generated module, written if missing (``inline`` resolved, as for :func:`_path`)."""
    path = _path(dispatcher, lay_t, inline)
    if not path.exists():
        _write_atomic(path, _source(dispatcher, lay_t, inline))
    return path


def specialised(dispatcher, lay, inline: tuple[str, ...] | None = None):
    """``dispatcher`` (a compiled kernel whose first argument is the layout) with ``lay`` fixed.

    Parameters
    ----------
    dispatcher : numba dispatcher
        A generic kernel, e.g. :func:`bayes_mr.models.drivers.run_batch`.
    lay : int array
        The model's layout (:meth:`bayes_mr.models.Model.layout`).
    inline : tuple of str
        Names of the compiled functions inlined into their callers (default
        :data:`INLINE` and :data:`INLINE_SPECIALISED`, or :data:`INLINE` alone when ``lay`` is None; fewer
        compile faster and run slower).

    Returns
    -------
    numba dispatcher
        Same signature as ``dispatcher``; its ``lay`` argument is ignored. It
        compiles on its first call (or loads its machine code from the cache).
    """
    lay_t = _lay_tuple(lay)
    inline = _inline_for(lay_t, inline)
    key = (id(dispatcher), lay_t, inline)
    fn = _loaded.get(key)
    if fn is None:
        path = _generated(dispatcher, lay_t, inline)
        with _lock:
            fn = _loaded[key] = getattr(_load(path), dispatcher.py_func.__name__)
    return fn


def inlined(dispatcher, inline: tuple[str, ...] | None = None):
    """``dispatcher`` with the functions named in ``inline`` inlined, the layout still an argument.

    The same physics as the generic kernel (the same numbers; tested), about
    twice as fast per sub-step, and one compile for every model. Compiles on
    its first call or loads from the cache, like :func:`specialised`.
    """
    return specialised(dispatcher, None, inline)


def _start_background(dispatcher, lay_t: tuple[int, ...] | None, argtypes: tuple,
                      inline: tuple[str, ...] | None = None, nice: int = 0) -> None:
    """Compile the specialised kernel (``lay_t`` None: the inlined one; ``inline`` as for :func:`specialised`)
    for ``argtypes`` in another process (once per kernel and types among the processes sharing the cache: the
    first claims it, :func:`~bayes_mr._compile.worker.claim`), ``nice`` steps below this one's priority.

    The child (:mod:`bayes_mr._compile.worker`) writes numba's cache and then
    the :func:`ready_path` marker; its stderr goes to ``<module>.log``. It is
    in the caller's process group, so an interrupt stops it with the caller;
    a caller that ends normally leaves it to finish for the next process.
    """
    path = _generated(dispatcher, lay_t, _inline_for(lay_t, inline))
    marker = ready_path(path, argtypes)
    with _lock:
        if marker in _started:
            return
        _started.add(marker)
    if not claim(marker):  # another process's child is compiling it
        return
    types_file = marker.with_suffix(".types")
    _write_atomic(types_file, pickle.dumps(argtypes).hex())
    # the child must write where this process reads: numba's cache directory as configured here
    env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(numba.config.CACHE_DIR).parent))
    with open(path.with_suffix(".log"), "a") as log:
        child = subprocess.Popen([sys.executable, "-m", "bayes_mr._compile.worker", str(path),
                                  dispatcher.py_func.__name__, str(types_file), str(marker), str(int(nice))],
                                 stdin=subprocess.DEVNULL, stdout=log, stderr=log, env=env)
    hand_over(marker, child.pid)


class _Auto:
    """A kernel that runs the generic code until a faster twin is compiled, in the background.

    Called like the generic kernel. On each call it types the arguments and
    runs the fastest kernel ready on disk for those types: the model's full
    specialised kernel, else its quick one (:data:`QUICK_INLINE`), else the
    inlined one (:func:`inlined`, any model), else the generic kernel (loading
    one costs milliseconds). Once the work asked of the layout has passed
    :data:`AUTO_WORK` (``pays``) it starts background compiles of the quick
    kernel and, at :data:`BACKGROUND_NICE`, of the full one; short of that,
    once the work asked of the kernel over all layouts has passed
    :data:`INLINED_WORK` (``pays_inlined``), of the inlined one — so a long
    job speeds up part-way instead of stopping for a compile. ``eager`` (the
    ``specialised`` or ``inlined`` choice) runs that kernel, compiled in this
    process if need be, and marks it ready for later ``auto`` calls.
    """

    __slots__ = ("dispatcher", "lay", "pays", "pays_inlined", "eager")

    def __init__(self, dispatcher, lay_t: tuple[int, ...], pays: bool, pays_inlined: bool = False,
                 eager: str | None = None):
        self.dispatcher, self.lay, self.eager = dispatcher, lay_t, eager
        self.pays, self.pays_inlined = pays, pays_inlined

    def __call__(self, *args):
        argtypes = tuple(typeof(a, Purpose.argument) for a in args)
        d = self.dispatcher
        if self.eager:
            lay = self.lay if self.eager == "specialised" else None
            out = specialised(d, lay)(*args)
            marker = ready_path(_path(d, lay, _inline_for(lay, None)), argtypes)
            if not marker.exists():
                mark_ready(marker, d.py_func.__name__, argtypes)
            return out
        # fastest first: (layout, inlined functions) of the full, the quick and the any-layout kernel
        full, quick, _ = tiers = ((self.lay, _inline_for(self.lay, None)), (self.lay, QUICK_INLINE),
                                  (None, _inline_for(None, None)))
        best = next((t for t in tiers if ready_path(_path(d, *t), argtypes).exists()), None)
        if self.pays and best is not full:
            _start_background(d, self.lay, argtypes, nice=BACKGROUND_NICE)
            if best is not quick:
                _start_background(d, self.lay, argtypes, inline=QUICK_INLINE)
        elif self.pays_inlined and best is None:
            _start_background(d, None, argtypes)
        return d(*args) if best is None else specialised(d, *best)(*args)


def expect_work(dispatcher, lay, work: float) -> None:
    """Count ``work`` sample-steps this process will ask of ``dispatcher`` for layout ``lay`` before it asks them.

    For a job that knows it will run a long fit of a model (the main job's posteriors): under ``auto`` the next
    call for that layout starts the background compiles the work pays for (:data:`AUTO_WORK`) at once, and the
    fit then has its model's own kernel from its start, not from part-way through.
    """
    key = (id(dispatcher), _lay_tuple(lay))
    with _lock:
        _work[key] = _work.get(key, 0.0) + float(work)


@contextmanager
def compiled_here(mode: str = "specialised"):
    """Under ``auto``, compile the block's kernels in this process and mark them ready (``mode``).

    For warm-up calls outside a timing (the bench): later ``auto`` calls with
    the same argument types then run the ``specialised`` (or ``inlined``)
    kernels from the start. ``generic``, ``inlined`` and ``specialised`` are
    left as they are.
    """
    before = os.environ.get(KERNELS_ENV)
    if (before or "auto").strip().lower() == "auto":
        os.environ[KERNELS_ENV] = mode
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(KERNELS_ENV, None)
        else:
            os.environ[KERNELS_ENV] = before


#: The values of ``$BAYES_MR_KERNELS``.
CHOICES = ("auto", "specialised", "inlined", "generic")


def kernel(dispatcher, lay, work: float = 0.0):
    """The kernel to run for layout ``lay``: specialised, inlined or generic, by ``$BAYES_MR_KERNELS``.

    All give the same numbers (the specialised kernel is the generic code
    with the layout constant, the inlined one the generic code with the
    physics inlined). ``generic`` needs no compilation per model (the test
    suite uses it); ``specialised`` and ``inlined`` always run that kernel,
    compiled in the calling process if need be (and mark it ready for
    ``auto``); ``auto`` (default) runs the fastest one compiled on disk for
    the call's argument types — full specialised, quick specialised
    (:data:`QUICK_INLINE`), inlined, generic — and starts background
    compiles once the work pays (:data:`AUTO_WORK`; :data:`INLINED_WORK` for
    the kernels of :data:`INLINED_TIER`; :class:`_Auto`).

    Parameters
    ----------
    dispatcher : numba dispatcher
        A generic kernel whose first argument is the layout.
    lay : int array
        The model's layout.
    work : float
        Sample-steps this call will run (samples × parameter sets), counted
        towards :data:`AUTO_WORK` (this layout) and :data:`INLINED_WORK` (any layout).
    """
    choice = os.environ.get(KERNELS_ENV, "auto").strip().lower()
    if choice == "generic":
        return dispatcher
    if choice not in CHOICES:
        raise ValueError(f"{KERNELS_ENV}={choice!r}: give one of {', '.join(repr(c) for c in CHOICES)}")
    lay_t = _lay_tuple(lay)
    if choice != "auto":
        return _Auto(dispatcher, lay_t, False, eager=choice)
    key, key_any = (id(dispatcher), lay_t), (id(dispatcher), None)
    with _lock:
        for k in (key, key_any):
            _work[k] = _work.get(k, 0.0) + float(work)
        pays = _work[key] >= AUTO_WORK
        pays_inlined = _work[key_any] >= INLINED_WORK and dispatcher.py_func.__name__ in INLINED_TIER
    return _Auto(dispatcher, lay_t, pays, pays_inlined)
