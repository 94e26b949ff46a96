"""Fixed-step simulation of any model under any input, compiled and batched.

RK4 as in the thesis (3-9), on the record's own sample grid, with the input
linear between samples — or, for an input with content near the Nyquist rate,
on a grid S times finer with the drive reconstructed band-limited
(:mod:`bayes_mr.simulation.input_grid`; ``Inputs.interp``); the command linear or
held between samples (``Inputs.command_interp``). Each sample interval is split into as many RK4
sub-steps as a local stability/accuracy bound asks for (h·λ ≤ c_acc, λ the
fastest local rate of the model, see :func:`bayes_mr.models.kernel.rate`),
so a stiff Dahl or Spencer law stays stable at a coarse sampling rate without
paying for sub-steps where the motion is slow; where that bound asks for
several, an L-stable Rosenbrock step is tried first and kept where its error
test passes (:mod:`bayes_mr.models.integrate`): on a hysteretic branch the
stiff state sits at its attractor and one step follows it. Every simulation
starts from rest at the first sample.

Batches of parameter sets (UKF sigma points, MCMC walkers, Jacobian columns)
run in parallel; a *schedule* (sub-steps per interval) can be replayed so
that perturbed parameter sets integrate on exactly the same grid — finite
differences then see the model, not the step control.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass
from time import perf_counter

import numpy as np
import xarray as xr

from bayes_mr.simulation import input_grid
from bayes_mr._compile.specialise import kernel
from bayes_mr.simulation.inputs import COMMANDS, DRIVE, Inputs
from bayes_mr.models import Model, get_model
from bayes_mr.models.drivers import run_batch
from bayes_mr.models.integrate import steps
from bayes_mr.numerics.synthetic_noise import as_seed_sequence

#: Output channels of a simulation, by kind of test.
OUTPUT_NAMES = {
    "structure": ("displacement", "velocity", "acceleration", "force"),
    "device": ("force", "damper_force"),
    "forced": ("displacement", "velocity", "acceleration", "force"),
}
#: Where :func:`simulate` notes each call while :func:`tally` is open (None: nowhere, the usual case).
_TALLY: list | None = None


@contextmanager
def tally():
    """Note every :func:`simulate` call made inside the block: how many, and how stiff.

    Yields a list that receives one dict per call: ``members`` (parameter sets simulated), ``replayed``
    (a schedule was replayed: a finite-difference Jacobian's perturbed sets), ``sensitivities`` (a run with
    the forward sensitivities, :mod:`bayes_mr.simulation.sensitivity`, on a replayed schedule), ``intervals`` (sample
    intervals per member), ``at_cap`` (intervals, over the members that chose their own sub-steps, that
    hit ``n_max``), ``substeps`` (RK4 sub-steps plus ROS2 steps, over those members), ``cap`` and
    ``wall_s``. The benchmark reads it to say where a fit's time goes (:mod:`bayes_mr.bench.spencer`).
    Not thread-local: calls of every thread are noted.
    """
    global _TALLY
    before, _TALLY = _TALLY, []
    try:
        yield _TALLY
    finally:
        _TALLY = before


def note(members: int, replayed: bool, schedules: np.ndarray, n_max: int, wall_s: float,
         sensitivities: bool = False) -> None:
    """One simulation call into the open :func:`tally` (nothing when none is open); ``sensitivities``: a run
    with the forward sensitivities (:mod:`bayes_mr.simulation.sensitivity`)."""
    if _TALLY is None:
        return
    own = steps(schedules[:0] if replayed else schedules)
    _TALLY.append({"members": int(members), "replayed": bool(replayed), "sensitivities": bool(sensitivities),
                   "intervals": int(schedules.shape[1]),
                   "at_cap": int(np.count_nonzero(own >= n_max)), "substeps": int(own.sum()),
                   "cap": int(n_max), "wall_s": float(wall_s)})


@dataclass(frozen=True)
class Simulation:
    """Result of :func:`simulate`.

    Attributes
    ----------
    outputs : dict of str → ndarray
        Channel → array of shape (B, N) (or (N,) for a single parameter set).
    failed : ndarray of int, shape (B,)
        Sample where the state became non-finite, or -1.
    schedule : ndarray of int, shape (B, S·(N-1))
        RK4 sub-steps each interval of the simulation grid took (S =
        ``Inputs.upsample``: 1 unless the input is reconstructed band-limited),
        or minus the number of ROS2 steps where ROS2 took it instead, or
        :data:`~bayes_mr.models.integrate.BRANCH_CODE` plus the sub-steps where the
        hysteretic state was held on its loading branch (:mod:`bayes_mr.models.integrate`;
        :func:`~bayes_mr.models.integrate.steps` gives every interval's count);
        replaying it replays each method.
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
    ros2: bool = True,
    hold_branch: bool = True,
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
    ros2 : bool
        Try the L-stable Rosenbrock step on intervals where RK4 would need
        more than :data:`~bayes_mr.models.integrate.ROS2_ABOVE` sub-steps,
        kept where its error test passes (:mod:`bayes_mr.models.integrate`);
        False integrates every interval with RK4, the thesis's integrator.
    hold_branch : bool
        Hold ``spencer``'s z at its saturation through an interval on a loading
        branch, where that is the law's own solution
        (:func:`~bayes_mr.models.branch.on_branch`); False integrates it there
        too, as the UKF's sigma points are.
    schedule : ndarray of int, shape (S·(N-1),), optional
        Replay these sub-steps for every member instead of choosing them (a
        previous :attr:`Simulation.schedule` row of the same inputs).

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
    cst = model.constants(inputs.mass, c_acc=c_acc, n_max=n_max, ros2=ros2, hold_branch=hold_branch)
    names = OUTPUT_NAMES[kind]
    out = np.empty((B, N, len(names)))
    failed = np.empty(B, dtype=np.int64)
    S, rows = inputs.upsample, inputs.grid_rows
    replay = schedule is not None
    if replay:
        schedules = np.ascontiguousarray(np.asarray(schedule, np.int64).reshape(1, -1))
        if schedules.shape[1] != max(rows.shape[0] - 1, 1):
            # the kernel reads it unchecked: a schedule of another grid would be read past its end
            raise ValueError(f"schedule has {schedules.shape[1]} sub-step counts, this input's grid needs "
                             f"{rows.shape[0] - 1} (replay a schedule on the inputs it came from, or on "
                             "Inputs.with_rows of them)")
    else:
        schedules = np.zeros((B, max(rows.shape[0] - 1, 1)), dtype=np.int64)
    run_batch_ = kernel(run_batch, lay, work=B * rows.shape[0])  # specialised when it pays (bayes_mr._compile.specialise)
    t0 = perf_counter()
    run_batch_(lay, cst, np.ascontiguousarray(P), inputs.dt / S, rows, out, schedules, replay, failed, S,
               inputs.hold)
    note(B, replay, schedules, n_max, perf_counter() - t0)
    # the first sample whose output is NaN (a fine-grid row between samples fails the next sample)
    failed = np.where(failed >= 0, (failed + S - 1) // S, -1)
    outputs = {name: out[:, :, j] for j, name in enumerate(names)}
    if model.effect("inertia"):
        # the load cell also feels the moving mass m_e·ẍ; a sensor delay (below) lags it with the rest
        j_mass = model.param_names(kind).index("m_e")
        outputs["force"] = outputs["force"] + P[:, j_mass, None] * inputs.acceleration[None, :]
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
    input_interp: str = "linear",
    command_interp: str = "linear",
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
    input_interp : {"linear", "bandlimited", "auto"}
        The input between samples (:mod:`bayes_mr.simulation.input_grid`), kept in the
        record's attributes so a fit reads the input as it was simulated.
    command_interp : {"linear", "hold", "auto"}
        The command between samples ("auto": linear), kept in the record's
        ``command_interp`` attribute likewise.

    Returns
    -------
    xarray.Dataset
        Record with ``noise_sd_<channel>`` attributes and the true ``force`` (damper force) channel.
    """
    from bayes_mr.data.schema import OUTPUTS, kind_of, make_record

    model = get_model(model)
    kind = kind_of([k for k, v in inputs.items() if v is not None], source)
    if kind == "forced" and mass is not None:
        m = float(np.asarray(theta, float)[model.param_names(kind).index("m")])
        if not np.isclose(m, mass, rtol=1e-12):
            raise ValueError(f"mass {mass} kg differs from the parameter m = {m} kg")
    seq = as_seed_sequence(seed)
    time = np.asarray(time, float)
    dt = float(time[1] - time[0])
    noisy = _noise_adder(noise, 1.0 / dt, np.random.default_rng(seq), band)
    attrs = {"noise_fraction": float(noise), "seed_entropy": str(seq.entropy), "model": model.name,
             "theta": ", ".join(f"{n}={v:.6g}" for n, v in zip(model.param_names(kind), theta))}
    held = input_grid.command(command_interp)
    channels, sds, sim, interp = _measure(model, theta, kind, inputs, dt, mass, noisy, input_grid.check(input_interp),
                                          held)
    attrs.update(input_interp=interp, command_interp=held)
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
    from bayes_mr.numerics.synthetic_noise import band_limited_noise

    def noisy(x):
        if noise <= 0:
            return np.asarray(x, float), 0.0
        sd = noise * float(np.sqrt(np.mean(np.square(x))))
        return x + band_limited_noise(x.size, fs, sd, rng, band), sd

    return noisy


def _measure(model: Model, theta, kind: str, inputs: dict, dt: float, mass: float | None, noisy, interp: str,
             held: str):
    """Simulate and 'measure' a test: the recorded channels, their noise SDs, the simulation and its input_interp.

    ``interp`` ("auto" resolved from the clean input's bandwidth) reads the
    input between samples (:class:`Inputs`), ``held`` the command.

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
        rows = (Inputs.structure(felt, dt, mass, volt, command_interp=held) if kind == "structure"
                else Inputs.forced(felt, dt, volt, mass, command_interp=held))
        if interp == "auto":  # as a fit of the record will read it: from the recorded (clean) input
            interp = input_grid.choose(Inputs.forced(u, dt).rows, kind, dt)
        rows = rows.with_interp(interp)
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
        rows = Inputs.device(x, v, dt, volt, command_interp=held).with_interp(interp)
        interp = rows.interp
        sim = simulate(model, rows, theta)
        channels = {}
        for name, value in (("displacement", x), ("velocity", v), ("force", sim["force"])):
            channels[name], sds[name] = noisy(value)
    return channels, sds, sim, interp
