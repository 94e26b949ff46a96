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
  - forced test (a mass driven by a measured force): ``applied_force``
    (input), any non-empty subset of ``displacement``, ``velocity``,
    ``acceleration`` (absolute ``ẍ``);
  - structure and forced tests measure any non-empty subset of their outputs
    (:data:`OUTPUTS`); every test may carry a damper command, ``voltage`` [V]
    or ``current`` [A] (:data:`COMMANDS`);

* ``valid`` (bool on ``time``): False for samples that quality control masked;
  every likelihood, filter update and metric uses only valid samples;
* attributes: ``kind`` (``"structure"``, ``"device"`` or ``"forced"``),
  ``fs`` [Hz], ``dt`` [s], ``source`` (file or generator), ``mass`` [kg]
  (structure tests; forced tests when known), ``masked`` (number of invalid samples), and optional noise
  standard deviations ``noise_sd_<channel>`` in the channel's units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr

STRUCTURE = "structure"
DEVICE = "device"
FORCED = "forced"
KINDS = (STRUCTURE, DEVICE, FORCED)

#: SI unit of every channel the package knows.
UNITS: dict[str, str] = {
    "time": "s",
    "ground_acceleration": "m/s^2",
    "displacement": "m",
    "acceleration": "m/s^2",
    "velocity": "m/s",
    "force": "N",
    "voltage": "V",
    "current": "A",
    "applied_force": "N",
}

#: Damper command channels: whichever a record has drives ``spencer`` and ``voltage_dependence``.
COMMANDS = ("voltage", "current")
#: Values of a record's ``command_interp`` attribute: the command linear between samples (the default), or held
#: from each sample to the next, as a DAC holds it (:mod:`bayes_mr.simulation.input_grid`).
COMMAND_INTERPS = ("linear", "hold")

#: Columns a test of each kind must have (its input; a device test also its force).
REQUIRED: dict[str, tuple[str, ...]] = {
    STRUCTURE: ("ground_acceleration",),
    DEVICE: ("displacement", "force"),
    FORCED: ("applied_force",),
}
#: Channels a model may be scored on, by kind; a record measures a non-empty subset (:func:`outputs_of`).
OUTPUTS: dict[str, tuple[str, ...]] = {
    STRUCTURE: ("displacement", "acceleration"),
    DEVICE: ("force",),
    FORCED: ("displacement", "velocity", "acceleration"),
}
OPTIONAL: dict[str, tuple[str, ...]] = {
    STRUCTURE: OUTPUTS[STRUCTURE] + ("force",) + COMMANDS,
    DEVICE: ("velocity",) + COMMANDS,
    FORCED: OUTPUTS[FORCED] + ("force",) + COMMANDS,
}

#: Fewest samples a record may have (the filters and metrics need a few hundred).
MIN_SAMPLES = 300


class RecordError(ValueError):
    """Bad input: the message is one line naming file, column, row and the remedy."""


def kind_of(columns, source: str = "record") -> str:
    """Kind of test from its column names (``ground_acceleration`` → structure, ``applied_force`` → forced).

    Raises
    ------
    RecordError
        Both inputs are present (``source`` names the file in the message).
    """
    columns = list(columns)
    if "applied_force" in columns and "ground_acceleration" in columns:
        raise Where(source, "applied_force").error(
            "a record has either ground_acceleration (structure test) or applied_force (forced test), not both",
            "drop one of the two columns",
        )
    if "ground_acceleration" in columns:
        return STRUCTURE
    return FORCED if "applied_force" in columns else DEVICE


def check_mass(kind: str, mass: float | None, source: str) -> None:
    """A structure test needs a positive mass; a forced test's mass, when given, must be positive.

    Raises
    ------
    RecordError
        One line naming ``source`` and the remedy.
    """
    if mass is None and kind != STRUCTURE:
        return
    if mass is None or not np.isfinite(mass) or mass <= 0:
        if kind == STRUCTURE and mass is None:
            raise Where(source).error("a structure test needs the storey mass",
                                      "pass --mass KG (or a netCDF 'mass' attribute)")
        raise Where(source).error(f"mass {mass} kg is not a positive number",
                                  "pass --mass KG with KG > 0 (or a positive netCDF 'mass' attribute)")


def command_of(record) -> str | None:
    """The damper command channel a record has (``voltage`` or ``current``), or None."""
    for name in COMMANDS:
        if name in record:
            return name
    return None


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


def _check_channels(kind: str, channels, source: str) -> None:
    """Required columns present, no unknown one, at least one output, one command at most."""
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
    measured = [c for c in OUTPUTS[kind] if c in channels]
    if not measured:
        raise Where(source, OUTPUTS[kind][0]).error(
            f"no output column for a {kind} test",
            f"a {kind} test measures at least one of {', '.join(OUTPUTS[kind])}",
        )
    if sum(c in channels for c in COMMANDS) > 1:
        raise Where(source, "current").error("a record has voltage or current as the damper command, not both",
                                             "drop one of the two columns")


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
    kind : {"structure", "device", "forced"}, optional
        Defaults to the kind read from the channel names.
    mass : float, optional
        Storey mass [kg]; required for a structure test; the driven mass of a
        forced test when known (else it is a parameter ``m``).
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
    kind = kind or kind_of(channels, source)
    where = Where(source)
    if kind not in KINDS:
        raise ValueError(f"unknown kind of test '{kind}'; valid: {', '.join(KINDS)}")
    _check_channels(kind, channels, source)
    check_mass(kind, mass, source)
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
    """Measured output channels of a record (what a model is scored on): those of its kind it has.

    Raises
    ------
    RecordError
        The record has none of them.
    """
    kind = record.attrs["kind"]
    present = tuple(c for c in OUTPUTS[kind] if c in record)
    if not present:
        raise Where(str(record.attrs.get("source", "record")), OUTPUTS[kind][0]).error(
            f"no output column for a {kind} test", f"a {kind} test measures at least one of {', '.join(OUTPUTS[kind])}")
    return present
