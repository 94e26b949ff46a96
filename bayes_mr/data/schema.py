"""The one record schema every source is read into.

A *record* is an :class:`xarray.Dataset` with one dimension, ``time``, and
these conventions (SI units throughout, see ``docs/CONTRACT.md`` "Records"):

* coordinate ``time`` [s], uniformly sampled, first sample = start of the test;
* data variables, float64 on ``time``, each with an ``attrs["units"]``:

  - structure test: ``ground_acceleration`` (input), ``displacement``,
    ``acceleration`` (absolute storey acceleration); optional ``force`` and
    ``voltage``;
  - device test: ``displacement`` (input), ``force`` (output); optional
    ``velocity`` and ``voltage``;

* ``valid`` (bool on ``time``): False for samples that quality control masked;
  every likelihood, filter update and metric uses only valid samples;
* attributes: ``kind`` (``"structure"`` or ``"device"``), ``fs`` [Hz],
  ``dt`` [s], ``source`` (file or generator), ``mass`` [kg] (structure
  tests), ``masked`` (number of invalid samples), and optional noise
  standard deviations ``noise_sd_<channel>`` in the channel's units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr

STRUCTURE = "structure"
DEVICE = "device"

#: SI unit of every channel the package knows.
UNITS: dict[str, str] = {
    "time": "s",
    "ground_acceleration": "m/s^2",
    "displacement": "m",
    "acceleration": "m/s^2",
    "velocity": "m/s",
    "force": "N",
    "voltage": "V",
}

REQUIRED: dict[str, tuple[str, ...]] = {
    STRUCTURE: ("ground_acceleration", "displacement", "acceleration"),
    DEVICE: ("displacement", "force"),
}
OPTIONAL: dict[str, tuple[str, ...]] = {
    STRUCTURE: ("force", "voltage"),
    DEVICE: ("velocity", "voltage"),
}
#: Channels a model is scored on (the measured outputs of the UKF / likelihood).
OUTPUTS: dict[str, tuple[str, ...]] = {
    STRUCTURE: ("displacement", "acceleration"),
    DEVICE: ("force",),
}

#: Fewest samples a record may have (the filters and metrics need a few hundred).
MIN_SAMPLES = 300


class RecordError(ValueError):
    """Bad input: the message is one line naming file, column, row and the remedy."""


def kind_of(columns) -> str:
    """Kind of test from its column names (``ground_acceleration`` → structure)."""
    return STRUCTURE if "ground_acceleration" in columns else DEVICE


@dataclass(frozen=True)
class Where:
    """Where a problem is: used to build one-line error messages.

    Attributes
    ----------
    source : str
        File name or generator.
    column : str, optional
        Column (channel) name.
    row : int, optional
        Position: a file line (CSV, header = line 1) or a sample index (netCDF).
    label : str
        Word the message puts before ``row``: ``"line"`` or ``"sample"``.
    """

    source: str
    column: str | None = None
    row: int | None = None
    label: str = "line"

    def error(self, problem: str, remedy: str) -> RecordError:
        """A :class:`RecordError` ``"source, column 'c', line n: problem — remedy"`` on one line."""
        parts = [self.source]
        if self.column is not None:
            parts.append(f"column '{self.column}'")
        if self.row is not None:
            parts.append(f"{self.label} {self.row}")
        msg = f"{', '.join(parts)}: {problem} — {remedy}"
        return RecordError(" ".join(msg.split()))  # always one line


def make_record(
    time: np.ndarray,
    channels: dict[str, np.ndarray],
    *,
    kind: str | None = None,
    mass: float | None = None,
    source: str = "memory",
    valid: np.ndarray | None = None,
    attrs: dict | None = None,
) -> xr.Dataset:
    """Build a record in the package schema (no file I/O, light checks).

    Parameters
    ----------
    time : array, shape (n,)
        Sample times [s], uniformly spaced.
    channels : dict
        Channel name → array of shape (n,), in SI units (see :data:`UNITS`).
    kind : {"structure", "device"}, optional
        Defaults to the kind read from the channel names.
    mass : float, optional
        Storey mass [kg]; required for a structure test.
    source : str
        Where the data came from (file name or generator).
    valid : bool array, shape (n,), optional
        Sample mask (True = usable). Defaults to all True.
    attrs : dict, optional
        Extra attributes (noise levels, provenance, quality report).

    Returns
    -------
    xarray.Dataset
    """
    time = np.asarray(time, dtype=float)
    kind = kind or kind_of(channels)
    where = Where(source)
    for name in REQUIRED[kind]:
        if name not in channels:
            raise Where(source, name).error(
                f"missing column for a {kind} test",
                f"a {kind} test needs columns time, {', '.join(REQUIRED[kind])}",
            )
    for name in channels:
        if name not in UNITS:
            known = ", ".join(REQUIRED[kind] + OPTIONAL[kind])
            raise Where(source, name).error("unknown column", f"valid columns: time, {known}")
    if kind == STRUCTURE and (mass is None or not np.isfinite(mass) or mass <= 0):
        raise where.error("a structure test needs the storey mass", "pass --mass KG (or a netCDF 'mass' attribute)")
    if time.size < MIN_SAMPLES:
        raise where.error(
            f"only {time.size} samples", f"a record needs at least {MIN_SAMPLES} samples"
        )
    dt = float(np.median(np.diff(time)))
    data_vars = {
        name: ("time", np.asarray(values, dtype=float), {"units": UNITS[name]})
        for name, values in channels.items()
    }
    valid = np.ones(time.size, bool) if valid is None else np.asarray(valid, bool)
    data_vars["valid"] = ("time", valid, {"description": "False where quality control masked the sample"})
    ds = xr.Dataset(data_vars, coords={"time": ("time", time, {"units": "s"})})
    ds.attrs.update(
        kind=kind,
        fs=1.0 / dt,
        dt=dt,
        source=source,
        masked=int((~valid).sum()),
    )
    if mass is not None:
        ds.attrs["mass"] = float(mass)
    if attrs:
        ds.attrs.update(attrs)
    return ds


def outputs_of(record: xr.Dataset) -> tuple[str, ...]:
    """Measured output channels of a record (what a model is scored on)."""
    return OUTPUTS[record.attrs["kind"]]
