"""Fixed-step simulation of any model under any input, compiled and batched.

RK4 as in the thesis (3-9), on the record's own sample grid, with the input
linear between samples. Each sample interval is split into as many RK4
sub-steps as a local stability/accuracy bound asks for (h·λ ≤ c_acc, λ the
fastest local rate of the model, see :func:`bayes_mr.models.kernel.rate`),
so a stiff Dahl or Spencer law stays stable at a coarse sampling rate without
paying for sub-steps where the motion is slow. Every simulation starts from
rest at the first sample.

Batches of parameter sets (UKF sigma points, MCMC walkers, Jacobian columns)
run in parallel; a *schedule* (sub-steps per interval) can be replayed so
that perturbed parameter sets integrate on exactly the same grid — finite
differences then see the model, not the step control.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr

from .models import Model, get_model
from .models import kernel

#: Output channels of a simulation, by kind of test.
OUTPUT_NAMES = {
    "structure": ("displacement", "velocity", "acceleration", "force"),
    "device": ("force", "damper_force"),
}


@dataclass(frozen=True)
class Inputs:
    """What drives a model: the kernel's input rows on a uniform grid.

    Attributes
    ----------
    kind : {"structure", "device"}
    dt : float
        Sample interval [s].
    rows : ndarray, shape (N, 3)
        Structure: ground acceleration [m/s²], 0, voltage [V];
        device: displacement [m], velocity [m/s], voltage [V].
    mass : float or None
        Storey mass [kg] (structure tests).
    """

    kind: str
    dt: float
    rows: np.ndarray
    mass: float | None = None

    @property
    def n(self) -> int:
        return self.rows.shape[0]

    @property
    def time(self) -> np.ndarray:
        return np.arange(self.n) * self.dt

    @classmethod
    def from_record(cls, record: xr.Dataset) -> "Inputs":
        """Inputs of a record in the package schema."""
        kind = record.attrs["kind"]
        n = record.sizes["time"]
        rows = np.zeros((n, 3))
        if "voltage" in record:
            rows[:, 2] = record["voltage"].values
        if kind == "structure":
            rows[:, 0] = record["ground_acceleration"].values
            mass = float(record.attrs["mass"])
        else:
            rows[:, 0] = record["displacement"].values
            if "velocity" not in record:
                raise ValueError(
                    f"{record.attrs.get('source', 'record')}: device test without a velocity channel — "
                    "read it with bayes_mr.data.read_record, which derives one"
                )
            rows[:, 1] = record["velocity"].values
            mass = None
        return cls(kind, float(record.attrs["dt"]), rows, mass)

    @classmethod
    def structure(cls, ground_acceleration, dt: float, mass: float, voltage=None) -> "Inputs":
        """Structure-test inputs from a ground acceleration [m/s²] sampled every dt [s]."""
        ag = np.asarray(ground_acceleration, float)
        rows = np.zeros((ag.size, 3))
        rows[:, 0] = ag
        if voltage is not None:
            rows[:, 2] = voltage
        return cls("structure", float(dt), rows, float(mass))

    @classmethod
    def device(cls, displacement, velocity, dt: float, voltage=None) -> "Inputs":
        """Device-test inputs from an imposed displacement [m] and velocity [m/s]."""
        x = np.asarray(displacement, float)
        rows = np.zeros((x.size, 3))
        rows[:, 0] = x
        rows[:, 1] = velocity
        if voltage is not None:
            rows[:, 2] = voltage
        return cls("device", float(dt), rows, None)

    def slice(self, start: int, stop: int) -> "Inputs":
        return Inputs(self.kind, self.dt, self.rows[start:stop].copy(), self.mass)


@dataclass(frozen=True)
class Simulation:
    """Result of :func:`simulate`.

    Attributes
    ----------
    outputs : dict of str → ndarray
        Channel → array of shape (B, N) (or (N,) for a single parameter set).
    failed : ndarray of int, shape (B,)
        Sample where the state became non-finite, or -1.
    schedule : ndarray of int, shape (B, N-1)
        RK4 sub-steps used in each sample interval.
    """

    outputs: dict[str, np.ndarray]
    failed: np.ndarray
    schedule: np.ndarray

    def __getitem__(self, name: str) -> np.ndarray:
        return self.outputs[name]

    @property
    def ok(self) -> np.ndarray:
        return self.failed < 0


def simulate(
    model: Model | str,
    inputs: Inputs,
    theta: np.ndarray,
    *,
    c_acc: float = 1.0,
    n_max: int = 400,
    schedule: np.ndarray | None = None,
) -> Simulation:
    """Simulate ``model`` driven by ``inputs`` for one or many parameter sets.

    Parameters
    ----------
    model : Model or str
        E.g. ``"dahl"`` or ``get_model("lugre+force_offset")``.
    inputs : Inputs
        Input rows and sample interval (see :class:`Inputs`).
    theta : ndarray, shape (P,) or (B, P)
        Full parameter vectors in SI, in ``model.param_names(kind)`` order.
    c_acc : float
        Sub-step bound: RK4 sub-steps per sample are ceil(h·λ / c_acc).
    n_max : int
        Most sub-steps per sample.
    schedule : ndarray of int, shape (N-1,), optional
        Replay these sub-steps for every member instead of choosing them.

    Returns
    -------
    Simulation
    """
    model = get_model(model)
    kind = inputs.kind
    theta = np.asarray(theta, float)
    single = theta.ndim == 1
    P = np.atleast_2d(theta)
    n_par = len(model.param_names(kind))
    if P.shape[1] != n_par:
        raise ValueError(f"{model.name} ({kind} test) has {n_par} parameters, got {P.shape[1]}")
    B, N = P.shape[0], inputs.n
    lay = model.layout(kind)
    cst = model.constants(inputs.mass, c_acc=c_acc, n_max=n_max)
    names = OUTPUT_NAMES[kind]
    out = np.empty((B, N, len(names)))
    failed = np.empty(B, dtype=np.int64)
    if schedule is None:
        schedules = np.zeros((B, max(N - 1, 1)), dtype=np.int64)
        kernel.run_batch(lay, cst, np.ascontiguousarray(P), inputs.dt, inputs.rows, out, schedules, False, failed)
    else:
        schedules = np.ascontiguousarray(np.asarray(schedule, np.int64).reshape(1, -1))
        kernel.run_batch(lay, cst, np.ascontiguousarray(P), inputs.dt, inputs.rows, out, schedules, True, failed)
    outputs = {name: out[:, :, j] for j, name in enumerate(names)}
    channel = model.delay_channel(kind)
    if channel is not None:
        j_delay = model.param_names(kind).index("delay")
        outputs[channel] = delay(outputs[channel], P[:, j_delay], inputs.dt)
    if single:
        outputs = {k: v[0] for k, v in outputs.items()}
    return Simulation(outputs, failed, schedules)


def delay(y: np.ndarray, tau: np.ndarray, dt: float) -> np.ndarray:
    """Delay each row of ``y`` (B, N) by ``tau[b]`` seconds (linear interpolation).

    Before the first sample the signal is held at its first value.
    """
    y = np.asarray(y, float)
    B, N = y.shape
    t = np.arange(N) * dt
    out = np.empty_like(y)
    for b in range(B):
        out[b] = np.interp(t - tau[b], t, y[b], left=y[b, 0])
    return out
