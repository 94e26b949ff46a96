"""What drives a simulation: a test's input rows on a uniform grid (:class:`Inputs`).

Structure tests are driven by the ground acceleration, forced tests by the
applied force, device tests by the imposed displacement and velocity; every
kind may carry a damper command. :func:`bayes_mr.simulation.simulate.simulate` runs a
model on them.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np
import xarray as xr

from bayes_mr.simulation import input_grid

#: Input channel that drives each kind of test (a device test is also driven by its velocity).
DRIVE = {"structure": "ground_acceleration", "device": "displacement", "forced": "applied_force"}
#: Damper command channels (whichever a record has drives spencer and voltage_dependence).
COMMANDS = ("voltage", "current")


@dataclass(frozen=True)
class Inputs:
    """What drives a model: the kernel's input rows on a uniform grid.

    Attributes
    ----------
    kind : {"structure", "device", "forced"}
    dt : float
        Sample interval [s].
    rows : ndarray, shape (N, 3)
        Structure: ground acceleration [m/s²], 0, command;
        forced: applied force [N], 0, command;
        device: displacement [m], velocity [m/s], command. The command is the
        damper's voltage [V] or current [A], whichever the record has.
    mass : float or None
        Storey mass [kg] (structure tests); a forced test's mass is its
        parameter ``m`` (this field only records a known one).
    interp : {"linear", "bandlimited"}
        The drive between samples (:mod:`bayes_mr.simulation.input_grid`): linear, or
        reconstructed band-limited on a grid :attr:`upsample` times finer
        (the command column is never reconstructed band-limited).
    grid : int or None
        Band-limited only: simulation steps per sample interval, fixed (see
        :meth:`with_rows`); None chooses them from the drive's bandwidth.
    command_interp : {"linear", "hold"}
        The command between samples: linear, or held from each sample to the
        next (a DAC's zero-order hold). A property of the record, not of the
        model: the same model simulates either.
    """

    kind: str
    dt: float
    rows: np.ndarray
    mass: float | None = None
    interp: str = "linear"
    grid: int | None = None
    command_interp: str = "linear"

    def __post_init__(self):
        if self.interp not in input_grid.INTERPS:
            raise ValueError(f"Inputs.interp must be one of {', '.join(input_grid.INTERPS)}, got {self.interp!r}")
        if self.command_interp not in input_grid.COMMAND_INTERPS:
            raise ValueError(f"Inputs.command_interp must be one of {', '.join(input_grid.COMMAND_INTERPS)}, "
                             f"got {self.command_interp!r}")

    @property
    def hold(self) -> bool:
        """True when the command is held between samples (the simulator's and the UKF's ``hold`` flag)."""
        return self.command_interp == "hold"

    @cached_property
    def upsample(self) -> int:
        """Simulation steps per sample interval: 1 (linear), else chosen from the drive's bandwidth."""
        if self.interp == "linear":
            return 1
        if self.grid is not None:
            return int(self.grid)
        return input_grid.factor(self.rows, self.kind, self.dt)

    def with_rows(self, rows: np.ndarray) -> "Inputs":
        """The same inputs with other ``rows`` (e.g. perturbed by noise) on the same simulation grid.

        The grid factor of band-limited inputs follows the drive's bandwidth,
        which noise widens; a perturbed input must keep this one's grid so a
        :attr:`Simulation.schedule` of this input can be replayed on it.
        """
        if np.shape(rows) != self.rows.shape:
            raise ValueError(f"rows of shape {np.shape(rows)} cannot replace rows of shape {self.rows.shape}")
        return replace(self, rows=np.asarray(rows, float), grid=self.upsample if self.interp != "linear" else None)

    @cached_property
    def grid_rows(self) -> np.ndarray:
        """Kernel input rows on the simulation grid ``dt / upsample``, (upsample·(N−1)+1, 3)."""
        if self.upsample == 1:
            return self.rows  # a held command is held by the simulator between these rows
        return input_grid.upsample(self.rows, self.kind, self.upsample, self.command_interp)

    @property
    def n(self) -> int:
        return self.rows.shape[0]

    @property
    def time(self) -> np.ndarray:
        return np.arange(self.n) * self.dt

    @cached_property
    def acceleration(self) -> np.ndarray:
        """Imposed acceleration ẍ [m/s²] of a device test (what ``inertia`` multiplies).

        The Savitzky–Golay smoothing differentiator of the imposed velocity
        (:func:`bayes_mr.data.derive.smooth_velocity`, window for the record's
        bandwidth) — the velocity being itself the same derivative of the
        imposed displacement when the record had none — so noise on the
        measured motion is not amplified by a raw second difference.
        Computed once per input.
        """
        from bayes_mr.data.derive import smooth_velocity

        if self.kind != "device":
            raise ValueError(f"the imposed acceleration is a device-test input, not a {self.kind} test's")
        return smooth_velocity(self.rows[:, 1], self.dt)

    @classmethod
    def from_record(cls, record: xr.Dataset, interp: str | None = None,
                    command_interp: str | None = None) -> "Inputs":
        """Inputs of a record in the package schema.

        ``interp`` ("linear", "bandlimited"; None or "auto": the record's
        ``input_interp`` attribute when it has one, else chosen from the
        drive's bandwidth, :func:`bayes_mr.simulation.input_grid.choose`).
        ``command_interp`` ("linear", "hold"; None or "auto": the record's
        ``command_interp`` attribute when it has one, else linear).
        """
        kind = record.attrs["kind"]
        n = record.sizes["time"]
        rows = np.zeros((n, 3))
        for name in COMMANDS:
            if name in record:
                rows[:, 2] = record[name].values
                break
        if kind != "device":
            rows[:, 0] = record[DRIVE[kind]].values
            mass = float(record.attrs["mass"]) if "mass" in record.attrs else None
        else:
            rows[:, 0] = record["displacement"].values
            if "velocity" not in record:
                raise ValueError(
                    f"{record.attrs.get('source', 'record')}: device test without a velocity channel — "
                    "read it with bayes_mr.data.load, which derives one"
                )
            rows[:, 1] = record["velocity"].values
            mass = None
        dt = float(record.attrs["dt"])
        declared = interp if interp not in (None, "auto") else record.attrs.get("input_interp")
        held = input_grid.command(command_interp, record.attrs.get("command_interp"),
                                  str(record.attrs.get("source", "record")))
        return cls(kind, dt, rows, mass, input_grid.choose(rows, kind, dt, declared), command_interp=held)

    @classmethod
    def structure(cls, ground_acceleration, dt: float, mass: float, voltage=None, *,
                  command_interp: str = "linear") -> "Inputs":
        """Structure-test inputs from a ground acceleration [m/s²] sampled every dt [s] (command [V or A])."""
        ag = np.asarray(ground_acceleration, float)
        rows = np.zeros((ag.size, 3))
        rows[:, 0] = ag
        if voltage is not None:
            rows[:, 2] = voltage
        return cls("structure", float(dt), rows, float(mass), command_interp=command_interp)

    @classmethod
    def forced(cls, applied_force, dt: float, command=None, mass: float | None = None, *,
               command_interp: str = "linear") -> "Inputs":
        """Forced-test inputs from an applied force [N] sampled every dt [s] (``mass`` [kg] if known)."""
        p = np.asarray(applied_force, float)
        rows = np.zeros((p.size, 3))
        rows[:, 0] = p
        if command is not None:
            rows[:, 2] = command
        return cls("forced", float(dt), rows, None if mass is None else float(mass), command_interp=command_interp)

    @classmethod
    def device(cls, displacement, velocity, dt: float, voltage=None, *, command_interp: str = "linear") -> "Inputs":
        """Device-test inputs from an imposed displacement [m] and velocity [m/s] (command [V or A])."""
        x = np.asarray(displacement, float)
        rows = np.zeros((x.size, 3))
        rows[:, 0] = x
        rows[:, 1] = velocity
        if voltage is not None:
            rows[:, 2] = voltage
        return cls("device", float(dt), rows, None, command_interp=command_interp)

    def slice(self, start: int, stop: int) -> "Inputs":
        return Inputs(self.kind, self.dt, self.rows[start:stop].copy(), self.mass, self.interp, self.grid,
                      self.command_interp)

    def with_interp(self, interp: str | None) -> "Inputs":
        """These inputs read another way ("linear", "bandlimited"; None or "auto": chosen by bandwidth)."""
        if interp in (None, "auto"):
            interp = input_grid.choose(self.rows, self.kind, self.dt)
        return self if interp == self.interp else replace(self, interp=interp)

    def with_command_interp(self, command_interp: str) -> "Inputs":
        """These inputs with the command read another way between samples ("linear", "hold")."""
        held = input_grid.command(command_interp)
        return self if held == self.command_interp else replace(self, command_interp=held)
