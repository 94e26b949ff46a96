"""Read a record file (CSV, CSV.gz, netCDF, MATLAB, HDF5) into the package schema: the first step of :func:`bayes_mr.data.load`.

:func:`read_file` validates the file (every problem is a one-line
:class:`~bayes_mr.data.schema.RecordError` naming the file, the column and the
line, and what to do), converts units to SI (:mod:`bayes_mr.data.units`),
checks the time grid and the storey mass, and warns when a magnitude looks
like a wrong unit. It derives nothing and assesses nothing: those are the
later steps of :func:`bayes_mr.data.load`.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from pathlib import Path

import xarray as xr

from bayes_mr.data import units as _units
from bayes_mr.data.checks import CSV_SUFFIXES, NC_SUFFIXES, check_time, file_suffix
from bayes_mr.data.read_arrays import ARRAY_SUFFIXES, parse_columns, read_arrays
from bayes_mr.data.read_csv import read_csv
from bayes_mr.data.read_netcdf import read_netcdf
from bayes_mr.data.schema import DEVICE, Where, check_mass, kind_of, make_record


def read_file(
    path: str | os.PathLike,
    *,
    mass: float | None = None,
    units: Mapping[str, str] | Iterable[str] | None = None,
    columns: Mapping[str, str] | Iterable[str] | str | None = None,
) -> xr.Dataset:
    """Read a test record from CSV (plain or gzip), netCDF, MATLAB ``.mat`` or HDF5, in SI units.

    Parameters
    ----------
    path : str or path-like
        ``*.csv``, ``*.csv.gz`` (header row, comma separated; a trailing comma
        on every line is tolerated) or ``*.nc`` written by
        :func:`bayes_mr.data.write_record`. Column headers are schema names,
        optionally with a unit in brackets (``displacement [mm]``).
    mass : float, optional
        Storey mass [kg]; overrides a netCDF ``mass`` attribute. Required for
        structure tests if the file carries none.
    units : mapping or iterable of "column=unit", optional
        Units of columns whose header carries none (``{"displacement": "cm"}``
        or ``["displacement=cm"]``). A header unit that disagrees is an error.
    columns : mapping or "channel=name,..." string(s), optional
        Which file column (CSV header without its unit, MATLAB / HDF5
        variable) holds which channel, e.g. ``{"time": "t", "force": "F"}``
        (:func:`~bayes_mr.data.read_arrays.parse_columns`). Not for netCDF.

    Returns
    -------
    xarray.Dataset
        Record with the file's channels and ``valid`` (a netCDF's mask, else
        all True); attributes ``kind``, ``fs`` [Hz], ``dt`` [s], ``source``,
        ``masked``, ``mass`` [kg] where given, ``time_rebuilt`` where the
        stamps were rounded, and a netCDF's other attributes.

    Raises
    ------
    RecordError
        One line naming file, column and line (CSV; header = line 1) or sample
        (netCDF, MATLAB, HDF5: index from 0), and the remedy.

    Warns
    -----
    UnitWarning
        A channel's magnitude looks like a wrong unit.
    """
    path = Path(path)
    src = str(path)
    if not path.exists():
        raise Where(src).error("file not found", "check the path")
    if path.is_dir():
        raise Where(src).error("is a directory, not a record", "give a .csv, .csv.gz or .nc file")
    suffix = file_suffix(path)
    time, channels, attrs, valid = _read_columns(path, src, _units.parse_unit_options(units), parse_columns(columns))
    label = "line" if suffix in CSV_SUFFIXES else "sample"

    kind = kind_of(channels, src)
    time, rebuilt = check_time(time, src, label)
    if rebuilt:
        attrs["time_rebuilt"] = "time stamps rounded in the file; rebuilt as t0 + i*dt"
    dt = (time[-1] - time[0]) / (time.size - 1)
    _units.check_plausible(channels, src, fs=1.0 / dt)

    m = _storey_mass(attrs, mass, kind, src)
    channel_attrs = attrs.pop("_channel_attrs", {})
    ds = make_record(time, channels, kind=kind, mass=m if kind != DEVICE else None, source=src, valid=valid)
    for name, a in channel_attrs.items():
        if name in ds:
            ds[name].attrs.update(a)
    if kind == DEVICE and m is not None:
        ds.attrs["mass"] = float(m)
    for key, value in attrs.items():
        ds.attrs.setdefault(key, value)
    ds.attrs["masked"] = int((~ds["valid"].values).sum())
    return ds


def _read_columns(path: Path, src: str, overrides: dict[str, str], mapping: dict[str, str]) -> tuple:
    """(time, channels in SI, attrs, valid or None) by the file's type."""
    suffix = file_suffix(path)
    if suffix in CSV_SUFFIXES:
        return read_csv(path, src, overrides, columns=mapping)
    if suffix in NC_SUFFIXES:
        if mapping:
            raise Where(src).error("a column mapping is for CSV, MATLAB and HDF5 files",
                                   "a netCDF record already uses schema names; drop --columns")
        return read_netcdf(path, src, overrides)
    if suffix in ARRAY_SUFFIXES:
        return read_arrays(path, src, overrides, mapping)
    raise Where(src).error(f"unknown file type '{suffix or path.name}'", "use .csv, .csv.gz, .nc, .mat, .h5 or .hdf5")


def _storey_mass(attrs: dict, mass: float | None, kind: str, src: str) -> float | None:
    """The mass [kg] to record (the argument over the file's), taken out of ``attrs``; required for a structure."""
    if mass is not None:
        attrs["mass"] = float(mass)
    m = attrs.pop("mass", None)
    check_mass(kind, m, src)
    return m
