"""Read the columns of a record CSV (plain or gzip) in SI units, and input-only CSVs.

A record CSV has a header row of schema names, each optionally with a unit in
brackets (``displacement [mm]``, see :mod:`bayes_mr.data.units`), then one
line per sample; a trailing comma on every line and blank lines at the end are
tolerated. Errors name the line (header = line 1).
"""

from __future__ import annotations

import os
import re
import warnings
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np
import pandas as pd

from bayes_mr.data import units as _units
from bayes_mr.data.checks import CSV_SUFFIXES, check_columns, check_overrides, check_time, file_suffix, one_line
from bayes_mr.data.schema import MIN_SAMPLES, OUTPUTS, Where, kind_of


def read_csv(
    path: Path, src: str, overrides: dict[str, str], inputs_only: bool = False, columns: dict[str, str] | None = None
) -> tuple[np.ndarray, dict[str, np.ndarray], dict, None]:
    """Columns of a record CSV, converted to SI.

    Parameters
    ----------
    path : pathlib.Path
    src : str
        File name for messages.
    overrides : dict
        Column → unit for columns whose header carries none (:func:`bayes_mr.data.units.parse_unit_options`).
    inputs_only : bool
        An input file: only the driving channel is required.
    columns : dict, optional
        Channel → header name (without its unit) for headers that are not schema names.

    Returns
    -------
    time : ndarray, shape (n,)
        Time stamps [s] as written (not yet checked for uniformity).
    channels : dict
        Channel → values in SI.
    attrs : dict
        Empty (a CSV carries no attributes).
    valid : None
        A CSV carries no mask.
    """
    df = _drop_padding(_parse(path, src))
    names, file_units = _header(df, src, columns or {})
    present = list(names.values())
    check_columns(present, src, label_row=1, inputs_only=inputs_only)
    check_overrides(overrides, present, src)
    time = None
    channels: dict[str, np.ndarray] = {}
    first_bad: tuple[int, str, str] | None = None
    for header, name in names.items():
        values, bad = _numbers(df[header])
        if bad is not None:
            # the earliest bad line is reported after every column is read; a unit error raises at once
            if first_bad is None or bad[0] < first_bad[0]:
                first_bad = (bad[0], name, bad[1])
            continue
        f = _si_factor(name, file_units[name], overrides, src)
        values = values * f if f != 1.0 else values
        if name == "time":
            time = values
        else:
            channels[name] = values
    if first_bad is not None:
        i, name, problem = first_bad
        raise Where(src, name, i + 2).error(problem, "every cell must be a finite number; fix or remove the line")
    if len(df) < MIN_SAMPLES:
        raise Where(src).error(f"only {len(df)} samples", f"a record needs at least {MIN_SAMPLES} samples")
    return time, channels, {}, None


def _parse(path: Path, src: str) -> pd.DataFrame:
    """The file as a frame of strings; parser, gzip and decoding failures become one line."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", pd.errors.ParserWarning)
            return pd.read_csv(
                path,
                dtype=str,
                keep_default_na=False,
                skip_blank_lines=False,
                index_col=False,
                compression="infer",
                encoding="utf-8-sig",
            )
    except pd.errors.EmptyDataError:
        raise Where(src).error("the file is empty", "a record needs a header row and data rows") from None
    except pd.errors.ParserError as exc:
        m = re.search(r"Expected (\d+) fields in line (\d+), saw (\d+)", str(exc))
        if m:
            raise Where(src, row=int(m.group(2))).error(
                f"{m.group(3)} fields where the header has {m.group(1)}", "fix the row or the header"
            ) from None
        raise Where(src).error(
            f"cannot parse as CSV ({one_line(exc)})", "write a comma-separated file with a header row"
        ) from None
    except Exception as exc:  # noqa: BLE001 — gzip (zlib.error, BadGzipFile), decoding, permissions
        raise Where(src).error(
            f"cannot read the file ({one_line(exc)})", "check that it is a readable (gzip) CSV"
        ) from None


def _drop_padding(df: pd.DataFrame) -> pd.DataFrame:
    """Without the empty column a trailing comma makes, and without trailing blank lines."""
    for col in list(df.columns):
        if str(col).startswith("Unnamed:") and (df[col].str.strip() == "").all():
            df = df.drop(columns=col)
    blank = (df.apply(lambda c: c.str.strip()) == "").all(axis=1).to_numpy()
    n_rows = len(df)
    while n_rows and blank[n_rows - 1]:
        n_rows -= 1
    return df.iloc[:n_rows]


def _header(
    df: pd.DataFrame, src: str, columns: dict[str, str]
) -> tuple[dict[str, str], dict[str, str | None]]:
    """Header → schema name (through the ``columns`` mapping), and schema name → unit in brackets (None if none)."""
    names: dict[str, str] = {}
    file_units: dict[str, str | None] = {}
    channel_of = {var: name for name, var in columns.items()}
    found = set()
    for col in df.columns:
        header = str(col)
        if header.startswith("Unnamed:"):
            raise Where(src, row=1).error("a column has no name", "give every column a header")
        name, unit = _units.split_header(header)
        if name in channel_of:
            found.add(name)
            name = channel_of[name]
        elif name in columns:  # a schema-named column the mapping replaced by another
            continue
        if name in names.values():
            raise Where(src, name, 1).error("duplicate column", "keep one column per channel")
        names[header] = name
        file_units[name] = unit
    for name, var in columns.items():
        if var not in found:
            raise Where(src, name, 1).error(f"no column '{var}' in the header", "check --columns")
    return names, file_units


def _numbers(raw: pd.Series) -> tuple[np.ndarray | None, tuple[int, str] | None]:
    """A column's values, or None and (first bad row index, what is wrong there)."""
    try:
        values = raw.to_numpy(dtype=float)
    except ValueError:
        numeric = pd.to_numeric(raw.str.strip(), errors="coerce").to_numpy(dtype=float)
        text = raw.str.strip().str.lower()
        bad = np.isnan(numeric) & ~text.isin(["nan", "+nan", "-nan"]).to_numpy()
        i = int(np.flatnonzero(bad)[0])
        cell = raw.iloc[i].strip()
        return None, (i, "empty cell" if cell == "" else f"non-numeric value '{cell[:30]}'")
    finite = np.isfinite(values)
    if not finite.all():
        i = int(np.flatnonzero(~finite)[0])
        return None, (i, f"{'NaN' if np.isnan(values[i]) else 'infinite'} value")
    return values, None


def _si_factor(name: str, unit: str | None, overrides: dict[str, str], src: str) -> float:
    """Factor to SI of a column: its header unit, or the unit option (which must agree with the header)."""
    if name in overrides:
        if unit is not None and _units.factor(name, unit, Where(src, name)) != _units.factor(
            name, overrides[name], Where(src, name)
        ):
            raise Where(src, name, 1).error(
                f"the header says [{unit}] but units ask for {overrides[name]}",
                "drop one of the two",
            )
        unit = overrides[name]
    where = Where(src, name) if name in overrides else Where(src, name, 1)
    return _units.factor(name, unit, where)


def read_inputs(
    path: str | os.PathLike, *, units: Mapping[str, str] | Iterable[str] | None = None
) -> tuple[str, np.ndarray, dict[str, np.ndarray]]:
    """Read an input-only CSV for ``bayes-mr simulate --input``.

    The file has ``time`` and ``ground_acceleration`` (structure test) or
    ``displacement`` (device test; optional ``velocity``), optionally
    ``voltage``; units in brackets or ``units=`` as for :func:`bayes_mr.data.load`.

    Returns
    -------
    kind : {"structure", "device"}
    time : ndarray, shape (n,)
        Uniform time [s].
    channels : dict
        Input channels in SI.

    Raises
    ------
    RecordError
        As :func:`bayes_mr.data.load`.
    """
    path = Path(path)
    src = str(path)
    if not path.exists():
        raise Where(src).error("file not found", "check the path")
    if file_suffix(path) not in CSV_SUFFIXES:
        raise Where(src).error("inputs must be a CSV file", "write time and ground_acceleration (or displacement) as CSV")
    time, channels, _, _ = read_csv(path, src, _units.parse_unit_options(units), inputs_only=True)
    kind = kind_of(channels, src)
    measured = OUTPUTS[kind] + ("force",)
    outputs = [c for c in channels if c in measured]
    if outputs:
        raise Where(src, outputs[0], 1).error("an input file holds inputs only", "drop the measured outputs")
    time, _ = check_time(time, src, "line")
    return kind, time, channels
