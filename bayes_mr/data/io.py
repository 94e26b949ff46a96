"""Read and write test records (CSV, CSV.gz, netCDF) with one-line errors.

:func:`read_record` turns a file into a record in the package schema
(:mod:`bayes_mr.data.schema`): it validates the file (every problem is a
one-line :class:`~bayes_mr.data.schema.RecordError` naming the file, the
column and the line, and what to do), converts units to SI
(:mod:`bayes_mr.data.units`), derives a velocity for device tests that have
none (:func:`bayes_mr.data.derive.smooth_velocity`), runs quality control
(:mod:`bayes_mr.data.quality`) and, on request, trims the record to its
excited part (:func:`bayes_mr.data.noise.trim_excited`).

:func:`write_record` writes a record atomically: to a temporary file in the
target directory, then :func:`os.replace` — nothing is left behind on error.
"""

from __future__ import annotations

import json
import os
import re
import tempfile
import warnings
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from . import units as _units
from .derive import smooth_velocity
from .noise import trim_excited
from .quality import QualityConfig, apply_quality
from .schema import (
    DEVICE,
    MIN_SAMPLES,
    OPTIONAL,
    REQUIRED,
    STRUCTURE,
    UNITS,
    RecordError,
    Where,
    kind_of,
    make_record,
)

#: Time stamps within this fraction of a sample interval of a uniform grid are
#: kept as they are (float round-off of ``i * dt``).
TIME_EXACT = 1e-6
#: Time stamps within this fraction of a sample interval of a uniform grid are
#: accepted and the grid is rebuilt as ``t0 + i * dt`` (stamps rounded to a few
#: decimals in the file); farther off is a non-uniform time error.
TIME_JITTER = 1e-2

_CSV_SUFFIXES = (".csv", ".csv.gz")
_NC_SUFFIXES = (".nc", ".nc4", ".netcdf")


@dataclass(frozen=True)
class _At(Where):
    """A :class:`Where` that names a file line (CSV) or a sample (netCDF) instead of a row."""

    label: str = "line"

    def error(self, problem: str, remedy: str) -> RecordError:
        parts = [self.source]
        if self.column is not None:
            parts.append(f"column '{self.column}'")
        if self.row is not None:
            parts.append(f"{self.label} {self.row}")
        msg = f"{', '.join(parts)}: {problem} — {remedy}"
        return RecordError(" ".join(msg.split()))  # always one line


def _suffix(path: Path) -> str:
    name = path.name.lower()
    for s in _CSV_SUFFIXES[::-1] + _NC_SUFFIXES:
        if name.endswith(s):
            return s
    return path.suffix.lower()


# ------------------------------------------------------------------ reading


def read_record(
    path: str | os.PathLike,
    *,
    mass: float | None = None,
    units: Mapping[str, str] | Iterable[str] | None = None,
    quality: bool | QualityConfig = True,
    trim: bool = False,
    velocity: str | None = "derive",
) -> xr.Dataset:
    """Read a test record from CSV (plain or gzip) or netCDF into the package schema.

    Parameters
    ----------
    path : str or path-like
        ``*.csv``, ``*.csv.gz`` (header row, comma separated; a trailing comma
        on every line is tolerated) or ``*.nc`` written by :func:`write_record`.
        Column headers are schema names, optionally with a unit in brackets
        (``displacement [mm]``); see :mod:`bayes_mr.data.units`.
    mass : float, optional
        Storey mass [kg] for a structure test; overrides a netCDF ``mass``
        attribute. Required for structure tests if the file carries none.
    units : mapping or iterable of "column=unit", optional
        Units of columns whose header carries none (e.g. ``{"displacement":
        "cm"}``, or ``["displacement=cm"]`` from ``--units``). A header unit that
        disagrees is an error.
    quality : bool or QualityConfig
        Run quality control (:func:`bayes_mr.data.quality.apply_quality`) with
        the default or the given thresholds. A netCDF record that already
        carries a quality report keeps its mask and is not re-assessed.
    trim : bool
        Trim to the excited part (:func:`bayes_mr.data.noise.trim_excited`);
        the report is stored in the ``trim`` attribute.
    velocity : {"derive", None}
        Device tests without a ``velocity`` column: derive one from
        displacement by a Savitzky–Golay differentiator (attrs
        ``derived="savgol"``, ``savgol_window``, ``savgol_polyorder``,
        ``bandwidth_hz``), or (None) leave it out.

    Returns
    -------
    xarray.Dataset
        Record in SI units with ``valid`` and attributes ``kind``, ``fs``,
        ``dt``, ``source``, ``masked`` (and ``mass``, ``quality``, ``trim``
        where they apply).

    Raises
    ------
    RecordError
        One line naming file, column and line (CSV; header = line 1) or sample
        (netCDF), and the remedy.

    Warns
    -----
    UnitWarning
        A channel's magnitude looks like a wrong unit.

    Notes
    -----
    Time must increase at every line. Stamps within :data:`TIME_EXACT` (1e-6)
    of a step from the uniform grid ``t0 + i·dt`` are float round-off and kept;
    within :data:`TIME_JITTER` (1 %) they were rounded in the file (e.g. to
    µs) and the grid is rebuilt by least squares (attribute ``time_rebuilt``);
    a step off by more than 2 % (a lost sample, a clock slip) is an error at
    its line.
    """
    if velocity not in ("derive", None):
        raise ValueError(f"velocity must be 'derive' or None, got {velocity!r}")
    path = Path(path)
    src = str(path)
    if not path.exists():
        raise _At(src).error("file not found", "check the path")
    if path.is_dir():
        raise _At(src).error("is a directory, not a record", "give a .csv, .csv.gz or .nc file")
    suffix = _suffix(path)
    overrides = _units.parse_unit_options(units)
    if suffix in _CSV_SUFFIXES:
        time, channels, attrs, valid = _read_csv(path, src, overrides)
        label = "line"
    elif suffix in _NC_SUFFIXES:
        time, channels, attrs, valid = _read_netcdf(path, src, overrides)
        label = "sample"
    else:
        raise _At(src).error(f"unknown file type '{suffix or path.name}'", "use .csv, .csv.gz or .nc")

    kind = kind_of(channels)
    time, rebuilt = _check_time(time, src, label)
    if rebuilt:
        attrs["time_rebuilt"] = "time stamps rounded in the file; rebuilt as t0 + i*dt"
    dt = (time[-1] - time[0]) / (time.size - 1)
    _units.check_plausible(channels, src, fs=1.0 / dt)

    if mass is not None:
        attrs["mass"] = float(mass)
    m = attrs.pop("mass", None)
    if kind == STRUCTURE and (m is None or not np.isfinite(m) or m <= 0):
        raise _At(src).error(
            "a structure test needs the storey mass", "pass --mass KG (or a netCDF 'mass' attribute)"
        )
    if kind == DEVICE and velocity == "derive" and "velocity" not in channels:
        v, info = smooth_velocity(channels["displacement"], dt, return_info=True)
        channels["velocity"] = v
        derived = {
            "derived": "savgol",
            "savgol_window": info["window"],
            "savgol_polyorder": info["polyorder"],
            "bandwidth_hz": info["bandwidth_hz"],
            "description": "Savitzky-Golay derivative of displacement (bayes_mr.data.derive.smooth_velocity)",
        }
    else:
        derived = None
    channel_attrs = attrs.pop("_channel_attrs", {})
    ds = make_record(time, channels, kind=kind, mass=m if kind == STRUCTURE else None, source=src, valid=valid)
    for name, a in channel_attrs.items():
        if name in ds:
            ds[name].attrs.update(a)
    if derived is not None:
        ds["velocity"].attrs.update(derived)
    if kind == DEVICE and m is not None:
        ds.attrs["mass"] = float(m)
    for key, value in attrs.items():
        ds.attrs.setdefault(key, value)
    ds.attrs["masked"] = int((~ds["valid"].values).sum())

    if quality is not False and not ("quality" in ds.attrs and suffix in _NC_SUFFIXES):
        cfg = quality if isinstance(quality, QualityConfig) else QualityConfig()
        ds = apply_quality(ds, cfg)
    if trim:
        ds, report = trim_excited(ds)
        ds.attrs["trim"] = json.dumps(report)
    return ds


def read_inputs(
    path: str | os.PathLike, *, units: Mapping[str, str] | Iterable[str] | None = None
) -> tuple[str, np.ndarray, dict[str, np.ndarray]]:
    """Read an input-only CSV for ``bayes-mr simulate --input``.

    The file has ``time`` and ``ground_acceleration`` (structure test) or
    ``displacement`` (device test; optional ``velocity``), optionally
    ``voltage``; units in brackets or ``units=`` as for :func:`read_record`.

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
        As :func:`read_record`.
    """
    path = Path(path)
    src = str(path)
    if not path.exists():
        raise _At(src).error("file not found", "check the path")
    if _suffix(path) not in _CSV_SUFFIXES:
        raise _At(src).error("inputs must be a CSV file", "write time and ground_acceleration (or displacement) as CSV")
    time, channels, _, _ = _read_csv(path, src, _units.parse_unit_options(units), inputs_only=True)
    kind = kind_of(channels)
    measured = ("displacement", "acceleration", "force") if kind == STRUCTURE else ("force",)
    outputs = [c for c in channels if c in measured]
    if outputs:
        raise _At(src, outputs[0], 1).error("an input file holds inputs only", "drop the measured outputs")
    time, _ = _check_time(time, src, "line")
    return kind, time, channels


def _read_csv(path: Path, src: str, overrides: dict[str, str], inputs_only: bool = False):
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", pd.errors.ParserWarning)
            df = pd.read_csv(
                path,
                dtype=str,
                keep_default_na=False,
                skip_blank_lines=False,
                index_col=False,
                compression="infer",
                encoding="utf-8-sig",
            )
    except pd.errors.EmptyDataError:
        raise _At(src).error("the file is empty", "a record needs a header row and data rows") from None
    except pd.errors.ParserError as exc:
        m = re.search(r"Expected (\d+) fields in line (\d+), saw (\d+)", str(exc))
        if m:
            raise _At(src, row=int(m.group(2))).error(
                f"{m.group(3)} fields where the header has {m.group(1)}", "fix the row or the header"
            ) from None
        raise _At(src).error(
            f"cannot parse as CSV ({_one_line(exc)})", "write a comma-separated file with a header row"
        ) from None
    except Exception as exc:  # noqa: BLE001 — gzip (zlib.error, BadGzipFile), decoding, permissions
        raise _At(src).error(
            f"cannot read the file ({_one_line(exc)})", "check that it is a readable (gzip) CSV"
        ) from None

    # a trailing comma on every line makes an unnamed, empty last column
    for col in list(df.columns):
        if str(col).startswith("Unnamed:") and (df[col].str.strip() == "").all():
            df = df.drop(columns=col)
    # trailing blank lines at the end of the file
    blank = (df.apply(lambda c: c.str.strip()) == "").all(axis=1).to_numpy()
    n_rows = len(df)
    while n_rows and blank[n_rows - 1]:
        n_rows -= 1
    df = df.iloc[:n_rows]

    names: dict[str, str] = {}
    file_units: dict[str, str | None] = {}
    for col in df.columns:
        header = str(col)
        if header.startswith("Unnamed:"):
            raise _At(src, row=1).error("a column has no name", "give every column a header")
        name, unit = _units.split_header(header)
        if name in names.values():
            raise _At(src, name, 1).error("duplicate column", "keep one column per channel")
        names[header] = name
        file_units[name] = unit
    present = list(names.values())
    _check_columns(present, src, label_row=1, inputs_only=inputs_only)
    _check_overrides(overrides, present, src)

    time = None
    channels: dict[str, np.ndarray] = {}
    first_bad: tuple[int, str, str] | None = None
    for header, name in names.items():
        raw = df[header]
        try:
            values = raw.to_numpy(dtype=float)
        except ValueError:
            numeric = pd.to_numeric(raw.str.strip(), errors="coerce").to_numpy(dtype=float)
            text = raw.str.strip().str.lower()
            bad = np.isnan(numeric) & ~text.isin(["nan", "+nan", "-nan"]).to_numpy()
            i = int(np.flatnonzero(bad)[0])
            cell = raw.iloc[i].strip()
            problem = "empty cell" if cell == "" else f"non-numeric value '{cell[:30]}'"
            if first_bad is None or i < first_bad[0]:
                first_bad = (i, name, problem)
            continue
        finite = np.isfinite(values)
        if not finite.all():
            i = int(np.flatnonzero(~finite)[0])
            problem = f"{'NaN' if np.isnan(values[i]) else 'infinite'} value"
            if first_bad is None or i < first_bad[0]:
                first_bad = (i, name, problem)
            continue
        unit = file_units[name]
        if name in overrides:
            if unit is not None and _units.factor(name, unit, _At(src, name)) != _units.factor(
                name, overrides[name], _At(src, name)
            ):
                raise _At(src, name, 1).error(
                    f"the header says [{unit}] but units ask for {overrides[name]}",
                    "drop one of the two",
                )
            unit = overrides[name]
        where = _At(src, name) if name in overrides else _At(src, name, 1)
        f = _units.factor(name, unit, where)
        values = values * f if f != 1.0 else values
        if name == "time":
            time = values
        else:
            channels[name] = values
    if first_bad is not None:
        i, name, problem = first_bad
        raise _At(src, name, i + 2).error(problem, "every cell must be a finite number; fix or remove the line")
    if len(df) < MIN_SAMPLES:
        raise _At(src).error(f"only {len(df)} samples", f"a record needs at least {MIN_SAMPLES} samples")
    return time, channels, {}, None


def _read_netcdf(path: Path, src: str, overrides: dict[str, str]):
    try:
        with xr.open_dataset(path) as f:
            ds = f.load()
    except Exception as exc:  # noqa: BLE001 — netCDF back-ends raise many types
        raise _At(src).error(
            f"cannot read as netCDF ({_one_line(exc)})", "write it with bayes_mr write_record"
        ) from None
    if "time" not in ds.coords and "time" not in ds.variables:
        raise _At(src, "time").error("missing column", "a record needs a time coordinate")
    names = [str(v) for v in ds.data_vars if str(v) != "valid"]
    _check_columns(["time"] + names, src, label_row=None)
    _check_overrides(overrides, ["time"] + names, src)
    channels: dict[str, np.ndarray] = {}
    time = None
    for name in ["time"] + names:
        da = ds[name]
        values = np.asarray(da.values, dtype=float)
        finite = np.isfinite(values)
        if not finite.all():
            i = int(np.flatnonzero(~finite)[0])
            raise _At(src, name, i, label="sample").error(
                f"{'NaN' if np.isnan(values[i]) else 'infinite'} value",
                "every sample must be a finite number",
            )
        unit = da.attrs.get("units")
        if unit is not None and name in overrides:
            raise _At(src, name).error(
                f"the file says units '{unit}' but units ask for {overrides[name]}", "drop the units option"
            )
        unit = overrides.get(name, unit)
        values = values * _units.factor(name, unit, _At(src, name))
        if name == "time":
            time = values
        else:
            channels[name] = values
    if time.size < MIN_SAMPLES:
        raise _At(src).error(f"only {time.size} samples", f"a record needs at least {MIN_SAMPLES} samples")
    valid = np.asarray(ds["valid"].values, bool) if "valid" in ds else None
    attrs = {k: v for k, v in ds.attrs.items() if k not in ("kind", "fs", "dt", "source", "masked")}
    if "mass" in attrs:
        attrs["mass"] = float(attrs["mass"])
    attrs["_channel_attrs"] = {
        name: {k: v for k, v in ds[name].attrs.items() if k != "units"} for name in names
    }
    return time, channels, attrs, valid


def _check_columns(present: list[str], src: str, label_row: int | None, inputs_only: bool = False) -> None:
    kind = kind_of(present)
    valid = ("time",) + REQUIRED[kind] + OPTIONAL[kind]
    for name in present:
        if name not in valid:
            raise _At(src, name, label_row).error(
                f"unknown column for a {kind} test", f"valid columns: {', '.join(valid)}"
            )
    required = REQUIRED[kind][:1] if inputs_only else REQUIRED[kind]
    for name in ("time",) + required:
        if name not in present:
            raise _At(src, name).error(
                f"missing column for a {kind} test",
                f"a {kind} test needs columns {', '.join(('time',) + REQUIRED[kind])}",
            )


def _check_overrides(overrides: dict[str, str], present: list[str], src: str) -> None:
    for name in overrides:
        if name not in UNITS:
            raise _At(src, name).error("units given for an unknown column", f"columns: {', '.join(UNITS)}")
        if name not in present:
            raise _At(src, name).error("units given for a column the file does not have", "drop that units option")


def _check_time(t: np.ndarray, src: str, label: str) -> tuple[np.ndarray, bool]:
    """Check that time increases uniformly; return it (rebuilt if rounded) and whether rebuilt.

    Row numbers in messages: CSV line = index + 2 (header is line 1); netCDF sample = index.
    """
    offset = 2 if label == "line" else 0
    steps = np.diff(t)
    bad = np.flatnonzero(steps <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise _At(src, "time", i + offset, label=label).error(
            f"time does not increase ({t[i - 1]:.9g} then {t[i]:.9g})", "sort the record or remove repeated lines"
        )
    dt = (t[-1] - t[0]) / (t.size - 1)
    # local test first: it names the first bad step, whatever happens later
    off = np.abs(steps - dt) > 2 * TIME_JITTER * dt
    if off.any():
        i = int(np.flatnonzero(off)[0]) + 1
        raise _At(src, "time", i + offset, label=label).error(
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
    raise _At(src, "time", i + offset, label=label).error(
        f"time drifts off a uniform grid by {dev[i]:.3g} s here", "resample to a uniform grid"
    )


def _publish(tmp: str, path: Path) -> None:
    """Move a finished temporary file into place, with the permissions a new file gets.

    :func:`tempfile.mkstemp` creates files readable by the owner only.
    """
    mask = os.umask(0)
    os.umask(mask)
    os.chmod(tmp, 0o666 & ~mask)
    os.replace(tmp, path)


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())[:200] or type(exc).__name__


# ------------------------------------------------------------------ writing


def write_record(ds: xr.Dataset, path: str | os.PathLike) -> Path:
    """Write a record atomically to ``.csv``, ``.csv.gz`` or ``.nc``.

    CSV: columns ``time`` then the channels, schema names in SI (no unit
    brackets), full float precision (shortest round-trip repr); attributes
    and the ``valid`` mask are not stored. netCDF: every variable including
    ``valid`` and the attributes (``kind``, ``mass``, ``quality``, …).
    The file appears only when complete: it is written to a temporary file
    in the target directory and moved into place with :func:`os.replace`.

    Parameters
    ----------
    ds : xarray.Dataset
        Record in the package schema.
    path : str or path-like

    Returns
    -------
    pathlib.Path
        The path written.

    Raises
    ------
    RecordError
        Unknown suffix, a missing directory, a record that breaks the schema,
        or a write failure; nothing is written.
    """
    path = Path(path)
    src = str(path)
    suffix = _suffix(path)
    if suffix not in _CSV_SUFFIXES + _NC_SUFFIXES:
        raise _At(src).error(f"unknown file type '{suffix or path.name}'", "use .csv, .csv.gz or .nc")
    if not path.parent.is_dir():
        raise _At(src).error("the directory does not exist", "create it first")
    _validate_for_write(ds, src)
    names = [str(v) for v in ds.data_vars if str(v) != "valid"]
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        if suffix in _CSV_SUFFIXES:
            frame = pd.DataFrame({"time": ds["time"].values.astype(float)})
            for name in names:
                frame[name] = ds[name].values.astype(float)
            frame.to_csv(tmp, index=False, compression="gzip" if suffix == ".csv.gz" else None)
        else:
            out = ds.copy()
            out.attrs = _netcdf_attrs(ds.attrs)
            for name in out.variables:
                out[name].attrs = _netcdf_attrs(out[name].attrs)
            out.to_netcdf(tmp)
        _publish(tmp, path)
    except Exception as exc:  # clean up, then one line (a RecordError passes unchanged)
        if os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(exc, RecordError):
            raise
        raise _At(src).error(f"cannot write ({_one_line(exc)})", "check the path and disk space") from None
    return path


def _validate_for_write(ds: xr.Dataset, src: str) -> None:
    if "time" not in ds.coords:
        raise _At(src, "time").error("the record has no time coordinate", "build it with make_record")
    kind = ds.attrs.get("kind", kind_of(list(ds.data_vars)))
    names = [str(v) for v in ds.data_vars if str(v) != "valid"]
    _check_columns(["time"] + names, src, label_row=None)
    for name in ["time"] + names:
        values = np.asarray(ds[name].values, dtype=float)
        if not np.isfinite(values).all():
            i = int(np.flatnonzero(~np.isfinite(values))[0])
            raise _At(src, name, i, label="sample").error("NaN or infinite value", "a record holds finite numbers only")
    if kind == STRUCTURE and not ds.attrs.get("mass"):
        raise _At(src).error("a structure record needs its storey mass", "set ds.attrs['mass'] (kg)")


def _netcdf_attrs(attrs: Mapping) -> dict:
    """netCDF attributes must be numbers, strings or arrays: convert or drop the rest."""
    out = {}
    for k, v in attrs.items():
        if v is None:
            continue
        if isinstance(v, (bool, np.bool_)):
            out[k] = int(v)
        elif isinstance(v, (dict, list, tuple)) and not all(isinstance(e, (int, float)) for e in v):
            out[k] = json.dumps(v)
        else:
            out[k] = v
    return out
