"""Load a record: the one place that composes the record layer's steps.

:func:`load` runs, in order,

1. **read** — :func:`bayes_mr.data.read.read_file`: CSV / CSV.gz / netCDF /
   MATLAB / HDF5 (lab column names mapped by ``columns``),
   validated, **units** converted to SI (:mod:`bayes_mr.data.units`), time
   grid and storey mass checked;
2. **derive** — :func:`bayes_mr.data.derive.with_velocity`: a device test
   without a velocity gets one from its displacement;
3. **quality** — :func:`bayes_mr.data.quality.apply_quality`: faults masked
   in ``valid``, inputs repaired, the report in the ``quality`` attribute;
4. **noise floor** (on request) — :func:`bayes_mr.data.noise_floor.noise_floor`:
   ``noise_sd_<channel>`` attributes from a no-input record, a quiet segment or
   differencing, before trimming cuts the quiet parts away;
5. **trim** (on request) — :func:`bayes_mr.data.trim.trim_excited`: the
   excited part only, the report in the ``trim`` attribute.

Each step is a public function of its own module that takes and returns a
record Dataset, for callers that need another order or another step.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Mapping

import xarray as xr

from bayes_mr.data import noise_floor as _noise
from bayes_mr.data.derive import with_velocity
from bayes_mr.data.quality import QualityConfig, apply_quality
from bayes_mr.data.read import read_file
from bayes_mr.data.schema import DEVICE
from bayes_mr.data.trim import trim_excited


def load(
    path: str | os.PathLike,
    *,
    mass: float | None = None,
    units: Mapping[str, str] | Iterable[str] | None = None,
    columns: Mapping[str, str] | Iterable[str] | str | None = None,
    quality: bool | QualityConfig = True,
    trim: bool = False,
    velocity: str | None = "derive",
    noise_floor: bool = False,
    noise_record: xr.Dataset | str | os.PathLike | None = None,
) -> xr.Dataset:
    """Read a test record and prepare it for identification: read → units → derive → quality → noise floor → trim.

    Parameters
    ----------
    path : str or path-like
        ``*.csv``, ``*.csv.gz``, ``*.nc``, ``*.mat`` (v5–v7.3), ``*.h5`` / ``*.hdf5``
        (:func:`bayes_mr.data.read.read_file`); headers are schema names
        (``docs/CONTRACT.md``), optionally with a unit (``displacement [mm]``).
    mass : float, optional
        Storey mass [kg] (structure tests; overrides the file's ``mass``).
    units : mapping or iterable of "column=unit", optional
        Units of columns whose header carries none (e.g. ``{"displacement":
        "cm"}``, or ``["displacement=cm"]`` from ``--units``). A header unit that
        disagrees is an error.
    columns : mapping or "channel=name,..." string(s), optional
        Which file column or variable holds which channel (``{"time": "t"}`` or
        ``"time=t,force=F"``, from ``--columns``).
    quality : bool or QualityConfig
        Quality control with the default or the given thresholds (a netCDF
        record with a quality report keeps its mask, not re-assessed).
    trim : bool
        Trim to the excited part (report in the ``trim`` attribute).
    velocity : {"derive", None}
        Device tests without a ``velocity`` column: derive one from
        displacement by a Savitzky–Golay differentiator (attrs
        ``derived="savgol"``, ``savgol_window``, ``savgol_polyorder``,
        ``bandwidth_hz``), or (None) leave it out.
    noise_floor : bool
        Estimate each channel's measurement-noise SD and store it as
        ``noise_sd_<channel>`` [channel units], with how it was found in the
        ``noise_floor`` attribute (JSON). Off by default: a likelihood then
        estimates it from the record it is given.
    noise_record : xarray.Dataset or path, optional
        A no-input record of the same rig for the noise floor (implies
        ``noise_floor=True``); a path is read without quality control.

    Returns
    -------
    xarray.Dataset
        Record in SI units with ``valid`` and attributes ``kind``, ``fs``,
        ``dt``, ``source``, ``masked`` (and ``mass``, ``quality``,
        ``noise_sd_<channel>``, ``trim`` where they apply).

    Raises
    ------
    RecordError
        A bad file, column, cell or time grid: one line naming file, column, line or
        sample and the remedy (:func:`~bayes_mr.data.read.read_file`).

    Warns
    -----
    UnitWarning
        A channel's magnitude looks like a wrong unit.
    """
    if velocity not in ("derive", None):
        raise ValueError(f"velocity must be 'derive' or None, got {velocity!r}")
    ds = read_file(path, mass=mass, units=units, columns=columns)
    if ds.attrs["kind"] == DEVICE and velocity == "derive":
        ds = with_velocity(ds)
    # a netCDF written after quality control carries its report (a CSV carries no attributes)
    if quality is not False and "quality" not in ds.attrs:
        ds = apply_quality(ds, quality if isinstance(quality, QualityConfig) else QualityConfig())
    if noise_floor or noise_record is not None:
        ds = _with_noise_floor(ds, noise_record)
    if trim:
        ds, report = trim_excited(ds)
        ds.attrs["trim"] = json.dumps(report)
    return ds


def _with_noise_floor(ds: xr.Dataset, noise_record: xr.Dataset | str | os.PathLike | None) -> xr.Dataset:
    """The record with ``noise_sd_<channel>`` and ``noise_floor`` (how each SD was found) attributes."""
    if noise_record is not None and not isinstance(noise_record, xr.Dataset):
        # a no-input run has no storey mass of its own: the record's (or 1 kg) passes the reader's check
        noise_record = read_file(noise_record, mass=ds.attrs.get("mass", 1.0))
    return _noise.with_noise_floor(ds, _noise.noise_floor(ds, noise_record=noise_record))
