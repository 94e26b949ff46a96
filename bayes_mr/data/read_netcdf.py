"""Read the columns, mask and attributes of a record netCDF (written by :func:`bayes_mr.data.write_record`).

Errors name the sample (index from 0).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import xarray as xr

from bayes_mr.data import units as _units
from bayes_mr.data.checks import check_columns, check_overrides, one_line
from bayes_mr.data.schema import COMMAND_INTERPS, MIN_SAMPLES, Where

#: Attributes a record gets again from :func:`bayes_mr.data.schema.make_record`, not from the file.
_REBUILT = ("kind", "fs", "dt", "source", "masked")


def read_netcdf(
    path: Path, src: str, overrides: dict[str, str]
) -> tuple[np.ndarray, dict[str, np.ndarray], dict, np.ndarray | None]:
    """Columns of a record netCDF in SI, its extra attributes and its ``valid`` mask.

    Parameters
    ----------
    path : pathlib.Path
        A netCDF file.
    src : str
        The name errors give the file.
    overrides : dict
        Column → unit for variables without a ``units`` attribute (one that
        has one and is also given here is an error).

    Returns
    -------
    time : ndarray, shape (n,)
        Time [s].
    channels : dict
        Channel → values in SI.
    attrs : dict
        The file's attributes except those :func:`make_record` sets (``mass`` as
        a float), and ``_channel_attrs``: channel → its attributes but ``units``.
    valid : ndarray of bool or None
    """
    try:
        with xr.open_dataset(path) as f:
            ds = f.load()
    except Exception as exc:  # noqa: BLE001 — netCDF back-ends raise many types
        raise Where(src).error(
            f"cannot read as netCDF ({one_line(exc)})", "write it with bayes_mr write_record"
        ) from None
    if "time" not in ds.coords and "time" not in ds.variables:
        raise Where(src, "time").error("missing column", "a record needs a time coordinate")
    names = [str(v) for v in ds.data_vars if str(v) != "valid"]
    check_columns(["time"] + names, src, label_row=None)
    check_overrides(overrides, ["time"] + names, src)
    channels = {name: _si_values(ds[name], overrides, src) for name in ["time"] + names}
    time = channels.pop("time")
    if time.size < MIN_SAMPLES:
        raise Where(src).error(f"only {time.size} samples", f"a record needs at least {MIN_SAMPLES} samples")
    valid = np.asarray(ds["valid"].values, bool) if "valid" in ds else None
    attrs = {k: v for k, v in ds.attrs.items() if k not in _REBUILT}
    if "mass" in attrs:
        attrs["mass"] = float(attrs["mass"])
    held = attrs.get("command_interp")
    if held is not None and held not in COMMAND_INTERPS:
        raise Where(src).error(f"attribute command_interp={held!r} is not a reading of the command between samples",
                               "set it to hold (held from sample to sample, as a DAC holds it) or linear, or drop it")
    attrs["_channel_attrs"] = {
        name: {k: v for k, v in ds[name].attrs.items() if k != "units"} for name in names
    }
    return time, channels, attrs, valid


def _si_values(da: xr.DataArray, overrides: dict[str, str], src: str) -> np.ndarray:
    """A variable's finite values in SI, from its ``units`` attribute or the unit option."""
    name = str(da.name)
    values = np.asarray(da.values, dtype=float)
    finite = np.isfinite(values)
    if not finite.all():
        i = int(np.flatnonzero(~finite)[0])
        raise Where(src, name, i, label="sample").error(
            f"{'NaN' if np.isnan(values[i]) else 'infinite'} value",
            "every sample must be a finite number",
        )
    unit = da.attrs.get("units")
    if unit is not None and name in overrides:
        raise Where(src, name).error(
            f"the file says units '{unit}' but units ask for {overrides[name]}", "drop the units option"
        )
    unit = overrides.get(name, unit)
    return values * _units.factor(name, unit, Where(src, name))
