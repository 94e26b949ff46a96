"""Packaged earthquake ground-motion records (thesis signals II, III and IV).

Two public records ship, gzip-compressed and otherwise unchanged, in
``resources/`` (provenance and checksums in ``resources/GROUND_MOTIONS.md``):

* ``"elcentro"`` — 1940 Imperial Valley, El Centro, N–S component: two
  columns, time [s] and ground acceleration [g], 0.02 s step, 2688 samples,
  peak 0.349 g. The thesis's signal II (numerical study, §3.8.1) and signal III
  (experiment, Table 5.1) use this record.
* ``"loma-prieta"`` — 1989 Loma Prieta, Corralitos, component 000, in the PEER
  NGA-West ``.AT2`` format: 4 header lines (the fourth holds ``NPTS`` and
  ``DT``), then acceleration [g], 5 values per line; 7995 samples at 0.005 s.
  It stands in for the thesis's Kobe record (signal IV), which is not available.

:func:`load_ground_motion` returns time [s] and acceleration [m/s²]; the two
readers, :func:`read_two_column` and :func:`read_peer_at2`, also take any file
in the same formats (plain or ``.gz``).
"""

from __future__ import annotations

import gzip
import re
from importlib import resources
from os import PathLike
from pathlib import Path

import numpy as np

#: Standard gravity [m/s²]: the records are in units of g.
STANDARD_GRAVITY = 9.80665

#: Packaged record name → (file in ``resources/``, format, description).
GROUND_MOTIONS: dict[str, tuple[str, str, str]] = {
    "elcentro": (
        "elcentro_1940_ns.dat.gz",
        "two-column",
        "1940 Imperial Valley (El Centro) N-S, 0.02 s, 53.74 s, PGA 0.349 g",
    ),
    "loma-prieta": (
        "RSN753_LOMAP_CLS000.AT2.gz",
        "peer-at2",
        "1989 Loma Prieta, Corralitos 000 (PEER RSN753), 0.005 s, 39.97 s, stands in for Kobe",
    ),
}

# Relative tolerance on the spacing of a two-column file's time stamps: the
# El Centro file carries 8 significant digits, so anything looser than this
# is a real gap or a duplicated row, not rounding.
_SPACING_RTOL = 1e-6

_FLOAT = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[EeDd][-+]?\d+)?"
_FLOAT_RE = re.compile(_FLOAT)
_HEADER_RE = re.compile(
    r"NPTS\s*=\s*(\d+)\s*,?\s*DT\s*=\s*(" + _FLOAT + r")\s*(SEC|S)?\b", re.IGNORECASE
)


class GroundMotionFormatError(ValueError):
    """A ground-motion file does not have the expected layout (the message says where)."""


def ground_motion_names() -> dict[str, str]:
    """Packaged records: name → one-line description."""
    return {name: desc for name, (_, _, desc) in GROUND_MOTIONS.items()}


def load_ground_motion(name: str) -> tuple[np.ndarray, np.ndarray]:
    """Load a packaged earthquake record in SI units.

    Parameters
    ----------
    name : {"elcentro", "loma-prieta"}
        Record name (see :data:`GROUND_MOTIONS`).

    Returns
    -------
    t : ndarray, shape (n,)
        Time [s], uniform, starting at 0.
    ag : ndarray, shape (n,)
        Ground acceleration [m/s²] (the file's g × :data:`STANDARD_GRAVITY`).

    Raises
    ------
    ValueError
        Unknown name (the message lists the valid ones).
    GroundMotionFormatError
        The packaged file is damaged.
    """
    if name not in GROUND_MOTIONS:
        raise ValueError(
            f"unknown ground motion {name!r}; valid names: {', '.join(GROUND_MOTIONS)}"
        )
    filename, fmt, _ = GROUND_MOTIONS[name]
    ref = resources.files("bayes_mr.data").joinpath("resources", filename)
    with resources.as_file(ref) as path:
        reader = read_two_column if fmt == "two-column" else read_peer_at2
        return reader(path)


def _read_lines(path: str | PathLike) -> tuple[str, list[str]]:
    path = Path(path)
    opener = gzip.open if path.suffix == ".gz" else open
    try:
        with opener(path, "rt", encoding="ascii", errors="strict", newline=None) as fh:
            return path.name, fh.read().splitlines()
    except UnicodeDecodeError as err:
        raise GroundMotionFormatError(f"{path.name}: not an ASCII text file ({err})") from None


def _parse_float(token: str, where: str) -> float:
    try:
        # Fortran writers may use a D exponent (1.0D-03).
        return float(token.replace("D", "E").replace("d", "e"))
    except ValueError:
        raise GroundMotionFormatError(f"{where}: {token!r} is not a number") from None


def read_two_column(path: str | PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a two-column record: time [s], acceleration [g] (whitespace separated).

    Blank lines are skipped; every other line must hold exactly two finite
    numbers, and the time stamps must be uniformly spaced and increasing.

    Parameters
    ----------
    path : path-like
        Plain text or ``.gz`` file.

    Returns
    -------
    t : ndarray, shape (n,)
        Time [s], shifted so that ``t[0] = 0`` (a record starting later is
        re-referenced to its first sample).
    ag : ndarray, shape (n,)
        Ground acceleration [m/s²].

    Raises
    ------
    GroundMotionFormatError
        A line without exactly two numbers, a non-finite value, non-uniform or
        non-increasing time, or fewer than 2 samples.
    """
    fname, lines = _read_lines(path)
    t_list: list[float] = []
    a_list: list[float] = []
    for lineno, line in enumerate(lines, start=1):
        tokens = line.replace(",", " ").split()
        if not tokens:
            continue
        where = f"{fname}, line {lineno}"
        if len(tokens) != 2:
            raise GroundMotionFormatError(
                f"{where}: expected 2 columns (time [s], acceleration [g]), found {len(tokens)}"
            )
        t_list.append(_parse_float(tokens[0], where))
        a_list.append(_parse_float(tokens[1], where))
    t = np.asarray(t_list)
    ag_g = np.asarray(a_list)
    if t.size < 2:
        raise GroundMotionFormatError(f"{fname}: fewer than 2 samples")
    bad = ~(np.isfinite(t) & np.isfinite(ag_g))
    if bad.any():
        raise GroundMotionFormatError(f"{fname}, data row {int(np.argmax(bad)) + 1}: non-finite value")
    steps = np.diff(t)
    # The end-to-end span gives the step without the rounding of single stamps.
    dt = float((t[-1] - t[0]) / (t.size - 1))
    off = np.abs(steps - dt) > _SPACING_RTOL * max(abs(dt), 1e-300)
    if dt <= 0 or off.any():
        row = int(np.argmax(off)) + 2 if off.any() else 2
        raise GroundMotionFormatError(
            f"{fname}, data row {row}: time is not uniformly increasing (median step {dt:g} s)"
        )
    # Rebuild time from the step: the file's stamps are rounded decimals.
    t_uniform = np.arange(t.size) * dt
    return t_uniform, ag_g * STANDARD_GRAVITY


def read_peer_at2(path: str | PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a PEER NGA ``.AT2`` acceleration file.

    Layout: line 1–2 free text, line 3 must say the series is in units of G,
    line 4 holds ``NPTS= n, DT= dt SEC``; then the ``n`` values, 5 per line
    (the last line may hold fewer). Values are read by pattern, so fixed-width
    fields that touch (``-.1E-02-.2E-02``) are still split correctly.

    Parameters
    ----------
    path : path-like
        The ``.AT2`` file, plain or gzip-compressed (``.gz``).

    Returns
    -------
    t : ndarray, shape (NPTS,)
        Time [s], ``k · DT`` for k = 0 … NPTS − 1.
    ag : ndarray, shape (NPTS,)
        Ground acceleration [m/s²].

    Raises
    ------
    GroundMotionFormatError
        Missing header, units other than g, ``NPTS``/``DT`` unreadable or not
        positive, a line with more than 5 values or with text between values,
        a short line before the last, a value count different from ``NPTS``,
        or a non-finite value.
    """
    fname, lines = _read_lines(path)
    if len(lines) < 5:
        raise GroundMotionFormatError(f"{fname}: too short for a PEER AT2 file (4 header lines + data)")
    if not re.search(r"\bG\b", lines[2].upper()) or "ACCEL" not in lines[2].upper():
        raise GroundMotionFormatError(
            f"{fname}, line 3: expected 'ACCELERATION TIME SERIES IN UNITS OF G', found {lines[2].strip()!r}"
        )
    match = _HEADER_RE.search(lines[3])
    if match is None:
        raise GroundMotionFormatError(
            f"{fname}, line 4: expected 'NPTS= n, DT= dt SEC', found {lines[3].strip()!r}"
        )
    npts = int(match.group(1))
    dt = _parse_float(match.group(2), f"{fname}, line 4")
    if npts < 2 or not np.isfinite(dt) or dt <= 0:
        raise GroundMotionFormatError(f"{fname}, line 4: NPTS={npts}, DT={dt} are not usable")

    values: list[float] = []
    data_lines = [(i, line) for i, line in enumerate(lines[4:], start=5) if line.strip()]
    for pos, (lineno, line) in enumerate(data_lines):
        where = f"{fname}, line {lineno}"
        tokens = _FLOAT_RE.findall(line)
        if _FLOAT_RE.sub("", line).strip():
            raise GroundMotionFormatError(f"{where}: unexpected text {line.strip()!r}")
        if len(tokens) > 5 or (len(tokens) < 5 and pos != len(data_lines) - 1):
            raise GroundMotionFormatError(f"{where}: expected 5 values per line, found {len(tokens)}")
        values.extend(_parse_float(tok, where) for tok in tokens)
    if len(values) != npts:
        raise GroundMotionFormatError(f"{fname}: header says NPTS={npts} but the file holds {len(values)} values")
    ag_g = np.asarray(values)
    if not np.isfinite(ag_g).all():
        raise GroundMotionFormatError(f"{fname}: non-finite acceleration value")
    return np.arange(npts) * dt, ag_g * STANDARD_GRAVITY
