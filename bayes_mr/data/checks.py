"""Checks shared by the record readers and the writer: file type, columns, unit options, time grid.

Every failure is a one-line :class:`~bayes_mr.data.schema.RecordError` naming
the file, the column and the line (CSV; header = line 1) or sample (netCDF),
and the remedy.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bayes_mr.data.schema import OPTIONAL, REQUIRED, UNITS, Where, kind_of

#: Time stamps within this fraction of a sample interval of a uniform grid are
#: kept as they are (float round-off of ``i * dt``).
TIME_EXACT = 1e-6
#: Time stamps within this fraction of a sample interval of a uniform grid are
#: accepted and the grid is rebuilt as ``t0 + i * dt`` (stamps rounded to a few
#: decimals in the file); farther off is a non-uniform time error.
TIME_JITTER = 1e-2

CSV_SUFFIXES = (".csv", ".csv.gz")
NC_SUFFIXES = (".nc", ".nc4", ".netcdf")


def file_suffix(path: Path) -> str:
    """The record type of a path: one of :data:`CSV_SUFFIXES` or :data:`NC_SUFFIXES`, else its suffix."""
    name = path.name.lower()
    for s in CSV_SUFFIXES[::-1] + NC_SUFFIXES:
        if name.endswith(s):
            return s
    return path.suffix.lower()


def one_line(exc: BaseException) -> str:
    """An exception's message on one line (at most 200 characters), else its type's name."""
    return " ".join(str(exc).split())[:200] or type(exc).__name__


def check_columns(present: list[str], src: str, label_row: int | None, inputs_only: bool = False) -> None:
    """Every column is known for the test's kind and every required one is there.

    Parameters
    ----------
    present : list of str
        Column names, ``time`` included.
    src : str
        File name for messages.
    label_row : int, optional
        Line of the header (CSV: 1) for messages about an unknown column.
    inputs_only : bool
        An input file (``bayes-mr simulate --input``): only the driving channel is required.
    """
    kind = kind_of(present, src)
    valid = ("time",) + REQUIRED[kind] + OPTIONAL[kind]
    for name in present:
        if name not in valid:
            raise Where(src, name, label_row).error(
                f"unknown column for a {kind} test", f"valid columns: {', '.join(valid)}"
            )
    required = REQUIRED[kind][:1] if inputs_only else REQUIRED[kind]
    for name in ("time",) + required:
        if name not in present:
            raise Where(src, name).error(
                f"missing column for a {kind} test",
                f"a {kind} test needs columns {', '.join(('time',) + REQUIRED[kind])}",
            )


def check_overrides(overrides: dict[str, str], present: list[str], src: str) -> None:
    """Unit options name only schema columns that the file has."""
    for name in overrides:
        if name not in UNITS:
            raise Where(src, name).error("units given for an unknown column", f"columns: {', '.join(UNITS)}")
        if name not in present:
            raise Where(src, name).error("units given for a column the file does not have", "drop that units option")


def check_time(t: np.ndarray, src: str, label: str) -> tuple[np.ndarray, bool]:
    """Check that time increases uniformly; return it (rebuilt if rounded) and whether rebuilt.

    Parameters
    ----------
    t : ndarray, shape (n,)
        Time stamps [s].
    src : str
        File name for messages.
    label : {"line", "sample"}
        Row numbers in messages: CSV line = index + 2 (header is line 1); netCDF sample = index.

    Returns
    -------
    time : ndarray, shape (n,)
        ``t``, or the uniform grid fitted to it [s].
    rebuilt : bool
    """
    offset = 2 if label == "line" else 0
    steps = np.diff(t)
    bad = np.flatnonzero(steps <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise Where(src, "time", i + offset, label=label).error(
            f"time does not increase ({t[i - 1]:.9g} then {t[i]:.9g})", "sort the record or remove repeated lines"
        )
    dt = (t[-1] - t[0]) / (t.size - 1)
    # local test first: it names the first bad step, whatever happens later
    off = np.abs(steps - dt) > 2 * TIME_JITTER * dt
    if off.any():
        i = int(np.flatnonzero(off)[0]) + 1
        raise Where(src, "time", i + offset, label=label).error(
            f"non-uniform time (step {steps[i - 1]:.6g} s, the record's step is {dt:.6g} s)",
            "resample to a uniform grid (bayes_mr.data.derive.resample) or fill the gap",
        )
    grid = t[0] + np.arange(t.size) * dt
    dev = np.abs(t - grid)
    if dev.max() <= TIME_EXACT * dt:
        return t, False
    if dev.max() <= TIME_JITTER * dt:
        # least-squares step through the first stamp: rounding of the last
        # stamp alone would bias dt by (rounding)/(duration)
        i = np.arange(t.size, dtype=float)
        step = float(np.dot(i, t - t[0]) / np.dot(i, i))
        return t[0] + i * step, True
    i = int(np.flatnonzero(dev > TIME_JITTER * dt)[0])
    raise Where(src, "time", i + offset, label=label).error(
        f"time drifts off a uniform grid by {dev[i]:.3g} s here", "resample to a uniform grid"
    )
