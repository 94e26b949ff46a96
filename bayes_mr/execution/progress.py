"""Progress on a terminal: one-line messages and progress bars (stderr only).

Every long command reports through these two, so ``progress=False`` (tests,
libraries) is silent and a terminal sees the same style everywhere.
"""

from __future__ import annotations

import sys
import time as _time
from typing import Callable


def say(progress: bool | Callable[[str], None] | None, *, clock: bool = False) -> Callable[[str], None]:
    """A message sink from a ``progress`` argument.

    Parameters
    ----------
    progress : bool, callable or None
        A callable is used as is; True prints to stderr; False/None is silent.
    clock : bool
        Prefix each message with the seconds since this call.
    """
    if callable(progress):
        return progress
    if not progress:
        return lambda msg: None
    if clock:
        t0 = _time.perf_counter()
        return lambda msg: print(f"[{_time.perf_counter() - t0:6.0f} s] {msg}", file=sys.stderr, flush=True)
    return lambda msg: print(f"  … {msg}", file=sys.stderr, flush=True)


def on_terminal(enabled: bool | None) -> bool:
    """Whether to show progress: ``enabled`` if given, else whether stderr is a terminal."""
    return sys.stderr.isatty() if enabled is None else bool(enabled) and sys.stderr.isatty()


def bar(total: int, desc: str, *, unit: str = "it", enabled: bool | None = None, initial: int = 0):
    """A tqdm progress bar on stderr, disabled unless :func:`on_terminal` says so."""
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, desc=desc, unit=unit, file=sys.stderr,
                disable=not on_terminal(enabled), dynamic_ncols=True, leave=False)
