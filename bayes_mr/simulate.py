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

from ._specialise import kernel
from .models import Model, get_model
from .models.drivers import run_batch

#: Output channels of a simulation, by kind of test.
OUTPUT_NAMES = {
    "structure": ("displacement", "velocity", "acceleration", "force"),
    "device": ("force", "damper_force"),
    "forced": ("displacement", "velocity", "acceleration", "force"),
}
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
    def forced(cls, applied_force, dt: float, command=None, mass: float | None = None) -> "Inputs":
        """Forced-test inputs from an applied force [N] sampled every dt [s] (``mass`` [kg] if known)."""
        p = np.asarray(applied_force, float)
        rows = np.zeros((p.size, 3))
        rows[:, 0] = p
        if command is not None:
            rows[:, 2] = command
        return cls("forced", float(dt), rows, None if mass is None else float(mass))

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
    run_batch_ = kernel(run_batch, lay)  # specialised to this model (see bayes_mr._specialise)
    if schedule is None:
        schedules = np.zeros((B, max(N - 1, 1)), dtype=np.int64)
        run_batch_(lay, cst, np.ascontiguousarray(P), inputs.dt, inputs.rows, out, schedules, False, failed)
    else:
        schedules = np.ascontiguousarray(np.asarray(schedule, np.int64).reshape(1, -1))
        run_batch_(lay, cst, np.ascontiguousarray(P), inputs.dt, inputs.rows, out, schedules, True, failed)
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


def synthesize(
    model: Model | str,
    theta: np.ndarray,
    time: np.ndarray,
    inputs: dict[str, np.ndarray],
    *,
    mass: float | None = None,
    noise: float = 0.0,
    seed: int | np.random.SeedSequence | None = None,
    band: float | None = None,
    source: str = "simulate",
    outputs: tuple[str, ...] | None = None,
) -> xr.Dataset:
    """A simulated test record in the package schema, with noise.

    Parameters
    ----------
    model : Model or str
    theta : ndarray, shape (P,)
        Full parameter vector [SI].
    time : ndarray, shape (N,)
        Uniform sample times [s].
    inputs : dict
        Structure test: ``ground_acceleration`` [m/s²]; forced test:
        ``applied_force`` [N]; device test: ``displacement`` [m] and
        ``velocity`` [m/s]; optionally the damper command ``voltage`` [V] or
        ``current`` [A].
    mass : float, optional
        Storey mass [kg] (structure tests). Forced tests: the known mass,
        written to the record (it must equal θ's ``m``); None leaves the mass
        a parameter to identify.
    noise : float
        Noise as a fraction of each channel's RMS (0.01 = 1 %), thesis §3.8:
        on the input as process noise (structure and forced: the frame feels
        ẍ_g + w, the mass p + w, while the record keeps the clean input;
        device: the recorded motion carries the noise) and on every measured
        output.
    outputs : tuple of str, optional
        The measured outputs to keep (structure and forced tests; any
        non-empty subset of the kind's outputs). Default: all.
    seed : int or SeedSequence, optional
        Seed of the noise (its entropy is stored in the record's attributes).
    band : float, optional
        Low-pass corner of the noise [Hz] (default: white up to Nyquist).

    Returns
    -------
    xarray.Dataset
        Record with ``noise_sd_<channel>`` attributes and the true
        ``force`` (damper force) channel.
    """
    from .data.schema import OUTPUTS, kind_of, make_record

    model = get_model(model)
    kind = kind_of([k for k, v in inputs.items() if v is not None], source)
    if kind == "forced" and mass is not None:
        m = float(np.asarray(theta, float)[model.param_names(kind).index("m")])
        if not np.isclose(m, mass, rtol=1e-12):
            raise ValueError(f"mass {mass} kg differs from the parameter m = {m} kg")
    seq = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    time = np.asarray(time, float)
    dt = float(time[1] - time[0])
    noisy = _noise_adder(noise, 1.0 / dt, np.random.default_rng(seq), band)
    attrs = {"noise_fraction": float(noise), "seed_entropy": str(seq.entropy), "model": model.name,
             "theta": ", ".join(f"{n}={v:.6g}" for n, v in zip(model.param_names(kind), theta))}
    channels, sds, sim = _measure(model, theta, kind, inputs, dt, mass, noisy)
    if outputs is not None:
        channels, sds = _keep_outputs(kind, outputs, channels, sds, OUTPUTS[kind])
    attrs.update({f"noise_sd_{name}": sd for name, sd in sds.items()})
    for name in COMMANDS:
        if inputs.get(name) is not None:
            channels[name] = np.asarray(inputs[name], float)
    if not sim.ok.all():
        raise ValueError(f"the simulation of {model.name} diverged at sample {int(sim.failed[0])}: "
                         "check the parameters (a stiffer law may need a higher sampling rate)")
    return make_record(time, channels, kind=kind, mass=mass, source=source, attrs=attrs)


def _keep_outputs(kind: str, outputs, channels: dict, sds: dict, possible: tuple[str, ...]):
    """The channels and noise SDs without the outputs a partial record does not measure."""
    drop = [c for c in possible if c not in outputs]
    unknown = [c for c in outputs if c not in possible]
    if unknown or kind == "device":
        raise ValueError(f"outputs {unknown or outputs}: a {kind} test measures {', '.join(possible)}")
    return ({c: v for c, v in channels.items() if c not in drop}, {c: v for c, v in sds.items() if c not in drop})


def _noise_adder(noise: float, fs: float, rng: np.random.Generator, band: float | None):
    """``x ↦ (x + noise, its SD)``: band-limited noise of SD ``noise`` × RMS(x); none when ``noise`` ≤ 0."""
    from .synthetic_noise import band_limited_noise

    def noisy(x):
        if noise <= 0:
            return np.asarray(x, float), 0.0
        sd = noise * float(np.sqrt(np.mean(np.square(x))))
        return x + band_limited_noise(x.size, fs, sd, rng, band), sd

    return noisy


def _measure(model: Model, theta, kind: str, inputs: dict, dt: float, mass: float | None, noisy):
    """Simulate and 'measure' a test: the recorded channels, their noise SDs and the simulation.

    The noise is drawn in a fixed order (structure: input, displacement,
    acceleration; forced: input, displacement, velocity, acceleration;
    device: displacement, velocity, force) so a seed gives the same record.
    """
    volt = next((inputs[c] for c in COMMANDS if inputs.get(c) is not None), None)
    sds = {}
    if kind != "device":
        drive = DRIVE[kind]
        u = np.asarray(inputs[drive], float)
        felt, sd_u = noisy(u)  # the frame (mass) feels the input + w; the record keeps the input
        rows = Inputs.structure(felt, dt, mass, volt) if kind == "structure" else Inputs.forced(felt, dt, volt, mass)
        sim = simulate(model, rows, theta)
        channels = {drive: u}
        names = ("displacement", "acceleration") if kind == "structure" else ("displacement", "velocity", "acceleration")
        for name in names:
            channels[name], sds[name] = noisy(sim[name])
        channels["force"] = sim["force"]
        sds[drive] = sd_u
    else:
        x = np.asarray(inputs["displacement"], float)
        v = np.asarray(inputs["velocity"], float)
        sim = simulate(model, Inputs.device(x, v, dt, volt), theta)
        channels = {}
        for name, value in (("displacement", x), ("velocity", v), ("force", sim["force"])):
            channels[name], sds[name] = noisy(value)
    return channels, sds, sim
