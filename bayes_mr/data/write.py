"""Write a record atomically (CSV, CSV.gz, netCDF) with one-line errors.

:func:`write_record` writes to a temporary file in the target directory, then
moves it into place with :func:`os.replace` — nothing is left behind on error.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from bayes_mr.data.checks import CSV_SUFFIXES, NC_SUFFIXES, check_columns, file_suffix, one_line
from bayes_mr.data.schema import STRUCTURE, RecordError, Where, kind_of


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
    suffix = file_suffix(path)
    if suffix not in CSV_SUFFIXES + NC_SUFFIXES:
        raise Where(src).error(f"unknown file type '{suffix or path.name}'", "use .csv, .csv.gz or .nc")
    if not path.parent.is_dir():
        raise Where(src).error("the directory does not exist", "create it first")
    _validate_for_write(ds, src)
    names = [str(v) for v in ds.data_vars if str(v) != "valid"]
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        if suffix in CSV_SUFFIXES:
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
        publish(tmp, path)
    except Exception as exc:  # clean up, then one line (a RecordError passes unchanged)
        if os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(exc, RecordError):
            raise
        raise Where(src).error(f"cannot write ({one_line(exc)})", "check the path and disk space") from None
    return path


def publish(tmp: str, path: Path) -> None:
    """Move a finished temporary file into place, with the permissions a new file gets.

    :func:`tempfile.mkstemp` creates files readable by the owner only.
    """
    mask = os.umask(0)
    os.umask(mask)
    os.chmod(tmp, 0o666 & ~mask)
    os.replace(tmp, path)


def _validate_for_write(ds: xr.Dataset, src: str) -> None:
    if "time" not in ds.coords:
        raise Where(src, "time").error("the record has no time coordinate", "build it with make_record")
    kind = ds.attrs.get("kind", kind_of(list(ds.data_vars)))
    names = [str(v) for v in ds.data_vars if str(v) != "valid"]
    check_columns(["time"] + names, src, label_row=None)
    for name in ["time"] + names:
        values = np.asarray(ds[name].values, dtype=float)
        if not np.isfinite(values).all():
            i = int(np.flatnonzero(~np.isfinite(values))[0])
            raise Where(src, name, i, label="sample").error(
                "NaN or infinite value", "a record holds finite numbers only"
            )
    if kind == STRUCTURE and not ds.attrs.get("mass"):
        raise Where(src).error("a structure record needs its storey mass", "set ds.attrs['mass'] (kg)")


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
