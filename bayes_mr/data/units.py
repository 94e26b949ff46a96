"""Units of lab files: parse, convert to SI, and warn when magnitudes look wrong.

A column header may carry its unit in brackets (``displacement [mm]``,
``force [kN]``, ``ground_acceleration [g]``, ``time [ms]``), or the caller
passes a mapping (``units={"displacement": "cm"}``; on the command line
``--units displacement=cm``). A header without a unit is taken to be in SI
(the package schema, :data:`bayes_mr.data.schema.UNITS`). The package never
guesses a unit: an unknown unit is an error, and after conversion
:func:`check_plausible` warns (:class:`UnitWarning`) when a channel's
magnitude is implausible for a lab test of a damper or a small frame, which
usually means a wrong or missing unit.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Iterable, Mapping

import numpy as np

from bayes_mr.data.schema import Where

#: Standard gravity [m/s²] (the ``g`` unit).
G0 = 9.80665
_INCH = 0.0254
_LBF = 4.4482216152605

#: Accepted units per physical quantity → factor to SI.  Matching ignores case
#: (``KN`` = ``kN``); no two units of one quantity differ only by case.
ACCEPTED: dict[str, dict[str, float]] = {
    "length": {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "in": _INCH},
    "velocity": {"m/s": 1.0, "cm/s": 1e-2, "mm/s": 1e-3, "in/s": _INCH},
    "acceleration": {
        "m/s^2": 1.0, "m/s2": 1.0, "m/s²": 1.0,
        "g": G0,
        "cm/s^2": 1e-2, "cm/s2": 1e-2, "cm/s²": 1e-2,
        "mm/s^2": 1e-3, "mm/s2": 1e-3, "mm/s²": 1e-3,
    },
    "force": {"N": 1.0, "kN": 1e3, "lbf": _LBF, "kip": 1e3 * _LBF},
    "voltage": {"V": 1.0, "mV": 1e-3},
    "current": {"A": 1.0, "mA": 1e-3},
    "time": {"s": 1.0, "ms": 1e-3},
}

#: Physical quantity of every schema column.
QUANTITY: dict[str, str] = {
    "time": "time",
    "displacement": "length",
    "velocity": "velocity",
    "ground_acceleration": "acceleration",
    "acceleration": "acceleration",
    "force": "force",
    "applied_force": "force",
    "voltage": "voltage",
    "current": "current",
}

#: Plausible peak |value| in SI per channel: (low, high, hint below, hint above).
#: Outside the range :func:`check_plausible` warns.  The ranges bracket what a
#: lab test of an MR damper or a small frame on a shake table can produce, so a
#: factor 10-1000 unit slip lands outside them:
#:
#: * displacement: 10 µm .. 1 m (damper strokes and storey drifts are mm to cm;
#:   > 1 m is a file in mm or cm read as m);
#: * velocity: 10 µm/s .. 10 m/s;
#: * ground / storey acceleration: 0.05 .. 100 m/s² (0.005 g .. 10 g; a peak
#:   below 0.05 m/s² is a file in g read as m/s²; above 100 m/s² a file in
#:   cm/s² or mm/s²);
#: * force: 0.01 N .. 1 MN (below 0.01 N a file in kN read as N; lab MR dampers
#:   stay well under 1 MN, so more is N labelled kN);
#: * voltage: up to 100 V (damper drivers take 0-10 V; more is mV read as V).
PLAUSIBLE: dict[str, tuple[float | None, float | None, str, str]] = {
    "displacement": (1e-5, 1.0, "values labelled as mm or cm that are in m", "mm or cm"),
    "velocity": (1e-5, 10.0, "values labelled as mm/s or cm/s that are in m/s", "mm/s or cm/s"),
    "ground_acceleration": (0.05, 100.0, "g", "cm/s^2 or mm/s^2"),
    "acceleration": (0.05, 100.0, "g", "cm/s^2 or mm/s^2"),
    "force": (1e-2, 1e6, "kN", "values labelled as kN that are in N"),
    "applied_force": (1e-2, 1e6, "kN", "values labelled as kN that are in N"),
    "voltage": (None, 100.0, "", "mV"),
    # MR damper drivers give 0-3 A; more than 50 A is a file in mA read as A
    "current": (None, 50.0, "", "mA"),
}
_SUGGEST_LOW = {"ground_acceleration": "g", "acceleration": "g", "force": "kN", "applied_force": "kN"}
_SUGGEST_HIGH = {
    "displacement": "mm", "velocity": "mm/s", "ground_acceleration": "cm/s^2",
    "acceleration": "cm/s^2", "voltage": "mV", "current": "mA",
}
#: Plausible sampling rates [Hz]; outside, the time column is likely in ms or µs.
FS_RANGE = (10.0, 1e6)

_HEADER = re.compile(r"^\s*([^\[\]]*?)\s*(?:\[\s*([^\[\]]*?)\s*\])?\s*$")


class UnitWarning(UserWarning):
    """A channel's magnitude looks like a wrong or missing unit (the data are still read)."""


def split_header(header: str) -> tuple[str, str | None]:
    """Split ``"force [kN]"`` into ``("force", "kN")``; no brackets → unit None.

    Parameters
    ----------
    header : str
        A column header.

    Returns
    -------
    name, unit : str, str or None
    """
    m = _HEADER.match(header)
    if m is None:  # unbalanced brackets: let the caller report the whole header
        return header.strip(), None
    name, unit = m.group(1), m.group(2)
    return name, (unit if unit else None)


def accepted(column: str) -> list[str]:
    """Accepted unit names for a schema column (e.g. ``["m", "cm", "mm", "in"]``)."""
    return list(ACCEPTED[QUANTITY[column]])


def factor(column: str, unit: str | None, where: Where) -> float:
    """Factor that converts ``column`` from ``unit`` to SI.

    Parameters
    ----------
    column : str
        Schema column name (a key of :data:`QUANTITY`).
    unit : str or None
        Unit as written in the file or given by the user; None means SI.
    where : Where
        File (and column) for the error message.

    Returns
    -------
    float

    Raises
    ------
    RecordError
        The unit is not one the package knows for this column.
    """
    if unit is None:
        return 1.0
    table = ACCEPTED[QUANTITY[column]]
    for name, f in table.items():
        if name.lower() == unit.strip().lower():
            return f
    raise where.error(
        f"unknown unit '{unit}'",
        f"accepted units for {column}: {', '.join(table)}",
    )


def parse_unit_options(options: Iterable[str] | Mapping[str, str] | None) -> dict[str, str]:
    """Unit overrides from ``["displacement=cm", "force=kN"]`` (the CLI's ``--units``) or a mapping.

    Raises
    ------
    ValueError
        An option is not of the form ``column=unit``.
    """
    if options is None:
        return {}
    if isinstance(options, Mapping):
        return {str(k).strip(): str(v).strip() for k, v in options.items()}
    out: dict[str, str] = {}
    for opt in options:
        name, sep, unit = opt.partition("=")
        if not sep or not name.strip() or not unit.strip():
            raise ValueError(f"--units {opt!r}: expected COLUMN=UNIT, e.g. displacement=cm")
        out[name.strip()] = unit.strip()
    return out


def check_plausible(channels: Mapping[str, np.ndarray], source: str, fs: float | None = None) -> list[str]:
    """Warn (:class:`UnitWarning`) for every channel whose magnitude looks like a wrong unit.

    The test is on the peak ``max |x|`` of each channel in SI against
    :data:`PLAUSIBLE`, and on the sampling rate against :data:`FS_RANGE`.
    An all-zero channel is not a unit problem and is skipped.

    Parameters
    ----------
    channels : mapping
        Column → values in SI, shape (n,).
    source : str
        File name for the message.
    fs : float, optional
        Sampling rate [Hz].

    Returns
    -------
    list of str
        The warning messages issued (empty when all looks plausible).
    """
    issued: list[str] = []

    def warn(msg: str) -> None:
        issued.append(msg)
        warnings.warn(msg, UnitWarning, stacklevel=3)

    for name, values in channels.items():
        if name not in PLAUSIBLE:
            continue
        x = np.asarray(values, float)
        x = x[np.isfinite(x)]
        peak = float(np.max(np.abs(x))) if x.size else 0.0
        if peak == 0.0:
            continue
        low, high, below, above = PLAUSIBLE[name]
        si = ACCEPTED[QUANTITY[name]]
        si_unit = next(iter(si))
        if low is not None and peak < low:
            hint = (
                f"looks like {below}; pass --units {name}={_SUGGEST_LOW[name]}"
                if name in _SUGGEST_LOW
                else f"looks like {below}; check the column's unit"
            )
            warn(f"{source}, column '{name}': peak {peak:.3g} {si_unit} is below {low:g} {si_unit} — {hint}")
        if high is not None and peak > high:
            hint = (
                f"looks like {above}; pass --units {name}={_SUGGEST_HIGH[name]}"
                if name in _SUGGEST_HIGH
                else f"looks like {above}; check the column's unit"
            )
            warn(f"{source}, column '{name}': peak {peak:.3g} {si_unit} is above {high:g} {si_unit} — {hint}")
    if fs is not None and np.isfinite(fs):
        if fs < FS_RANGE[0]:
            warn(
                f"{source}, column 'time': sampling rate {fs:.3g} Hz is below {FS_RANGE[0]:g} Hz — "
                "looks like ms; pass --units time=ms"
            )
        elif fs > FS_RANGE[1]:
            warn(
                f"{source}, column 'time': sampling rate {fs:.3g} Hz is above {FS_RANGE[1]:g} Hz — "
                "time looks like it is not in s (labelled ms but in s?); check the time unit"
            )
    return issued
