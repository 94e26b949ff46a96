"""A simulation with the exact derivatives of its outputs: one augmented run instead of p + 1.

:func:`output_sensitivities` runs :func:`bayes_mr.models.sensitivity.run_sensitivities` (RK4 with the forward
sensitivity equations, differentiated step by step) on a replayed sub-step schedule, so its derivatives are
those of the simulation a finite difference on that schedule would difference, without its truncation and
rounding error: a device test's force, a structure or forced test's displacement, velocity and absolute
acceleration (:data:`CHANNELS`); :func:`force_sensitivities` is the device test's one channel. :func:`covered`
says which models have them, :func:`replayable` which schedules (RK4 throughout: a ROS2 interval's step is not
differentiated, :mod:`bayes_mr.models.sensitivity`); least squares falls back to finite differences for the
others (:class:`bayes_mr.inference.lsq.refine.Residuals`).
"""

from __future__ import annotations

from time import perf_counter

import numpy as np

from bayes_mr._compile.specialise import kernel
from bayes_mr.models import Model, get_model
from bayes_mr.models.sensitivity import run_sensitivities
from bayes_mr.simulation.inputs import Inputs
from bayes_mr.simulation.simulate import OUTPUT_NAMES, delay, note

#: Effects whose partial derivatives the sensitivity kernel has (besides the form's own), and the two applied
#: to the kernel's force here, as :func:`~bayes_mr.simulation.simulate.simulate` applies them (``inertia``,
#: ``sensor_delay``).
COVERED_EFFECTS = frozenset({"force_offset", "stiffness_drift", "asymmetry", "voltage_dependence",
                             "command_saturation", "command_polynomial", "exponential_saturation", "field_decay",
                             "low_velocity_rolloff", "cubic_stiffness", "shear_thinning", "stribeck_friction",
                             "inertia", "sensor_delay"})
#: Forms, by kind of test, whose partial derivatives it has.
COVERED_FORMS = {kind: frozenset({"spencer", "normalized-bouc-wen", "dahl", "lugre", "bouc-wen"})
                 for kind in ("device", "structure", "forced")}
#: The outputs, by kind of test, whose derivatives a run gives (a structure or forced test's damper force has
#: none: it is not an output least squares fits there unless measured, and then finite differences serve).
CHANNELS = {"device": ("force",), "structure": ("displacement", "velocity", "acceleration"),
            "forced": ("displacement", "velocity", "acceleration")}


def covered(model: Model | str, kind: str) -> bool:
    """Whether ``model`` in a ``kind`` test has exact sensitivities (:data:`COVERED_FORMS`, :data:`COVERED_EFFECTS`).

    A covered model's sensitivities differentiate RK4 steps only: whether one evaluation can have them depends
    also on its schedule (:func:`replayable`).
    """
    model = get_model(model)
    return (model.form.name in COVERED_FORMS.get(kind, ())
            and all(e.name in COVERED_EFFECTS for e in model.effects))


def replayable(schedule: np.ndarray) -> bool:
    """Whether a simulation's sub-step ``schedule`` took every interval by RK4 (all counts positive), so that
    :func:`force_sensitivities` can differentiate it.

    An interval taken by ROS2 (a negative count: a stiff interval of a thesis form in a device test,
    :mod:`bayes_mr.models.integrate`) is not differentiated: its step depends on θ and s also through the
    forward-difference Jacobian in its W, whose exact derivative the kernel does not have. A caller falls back
    to finite differences for that evaluation (:class:`bayes_mr.inference.lsq.refine.Residuals`).
    """
    sched = np.asarray(schedule)
    return sched.size > 0 and bool(np.all(sched >= 1))


def output_sensitivities(model: Model | str, inputs: Inputs, theta: np.ndarray, schedule: np.ndarray,
                         channels: tuple[str, ...] | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """Measured channels and their derivatives with respect to every parameter, in one run.

    Parameters
    ----------
    model : Model or str
        A model :func:`covered` for ``inputs.kind``.
    inputs : Inputs
    theta : ndarray, shape (P,)
        Full parameter vector [SI] (``model.param_names(kind)`` order).
    schedule : ndarray of int, shape (S·(N-1),)
        The RK4 sub-steps of a simulation of the same inputs (:attr:`~bayes_mr.simulation.simulate.Simulation.schedule`
        row, :func:`replayable`); the derivatives are those of a simulation on it.
    channels : tuple of str, optional
        Outputs of :data:`CHANNELS` for the kind (default: all of them): a device test's ``force`` [N]; a
        structure or forced test's ``displacement`` [m], ``velocity`` [m/s], ``acceleration`` [m/s²].

    Returns
    -------
    y : ndarray, shape (N, C)
        The channels, the same numbers as :func:`~bayes_mr.simulation.simulate.simulate` on that schedule.
    dy : ndarray, shape (N, C, P)
        ∂y_c/∂θ_j [channel unit per unit of θ_j].
    failed : int
        Sample where the state became non-finite, or -1.
    """
    model = get_model(model)
    kind = inputs.kind
    if not covered(model, kind):
        raise ValueError(f"{model.name} in a {kind} test has no exact sensitivities (covered: "
                         f"{COVERED_FORMS}, effects {sorted(COVERED_EFFECTS)})")
    channels = CHANNELS[kind] if channels is None else tuple(channels)
    unknown = [c for c in channels if c not in CHANNELS[kind]]
    if unknown:
        raise ValueError(f"no sensitivities of {unknown} in a {kind} test (of {', '.join(CHANNELS[kind])})")
    theta = np.ascontiguousarray(theta, float)
    S, rows = inputs.upsample, inputs.grid_rows
    sched = np.ascontiguousarray(np.asarray(schedule, np.int64).ravel())
    if sched.size != max(rows.shape[0] - 1, 1) or not replayable(sched):
        raise ValueError(f"schedule of {sched.size} counts: this input's grid needs {rows.shape[0] - 1}, "
                         "all RK4 (positive)")
    N = inputs.n
    out = np.empty((N, len(OUTPUT_NAMES[kind])))
    dout = np.empty((N, len(CHANNELS[kind]), theta.size))
    lay = model.layout(kind)
    # no work counted: under auto a specialised kernel runs where one is on disk, but none is compiled in the
    # background (its quick compile would take minutes, not seconds: bayes_mr.models.sensitivity, "Kernels")
    run = kernel(run_sensitivities, lay)
    t0 = perf_counter()
    failed = run(lay, model.constants(inputs.mass), theta, inputs.dt / S, rows, out, dout, sched, S, inputs.hold)
    note(1, True, sched[None, :], 0, perf_counter() - t0, sensitivities=True)
    failed = int((failed + S - 1) // S) if failed >= 0 else -1
    names = model.param_names(kind)
    y = {c: out[:, OUTPUT_NAMES[kind].index(c)] for c in CHANNELS[kind]}
    dy = {c: dout[:, m] for m, c in enumerate(CHANNELS[kind])}
    if model.effect("inertia"):  # f += m_e ẍ (simulate), before the delay as there
        j = names.index("m_e")
        y["force"] = y["force"] + theta[j] * inputs.acceleration
        dy["force"][:, j] = inputs.acceleration
    lagged = model.delay_channel(kind)
    if lagged in channels:
        y[lagged], dy[lagged] = _delayed(y[lagged], dy[lagged], theta[names.index("delay")], inputs.dt,
                                         names.index("delay"))
    return (np.stack([y[c] for c in channels], axis=1), np.stack([dy[c] for c in channels], axis=1), failed)


def force_sensitivities(model: Model | str, inputs: Inputs, theta: np.ndarray,
                        schedule: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """A device test's force f_r [N] (N,) and ∂f_r/∂θ_j (N, P) in one run, and the failed sample or -1
    (:func:`output_sensitivities` of its one channel)."""
    if inputs.kind != "device":
        raise ValueError(f"force_sensitivities is a device test's; a {inputs.kind} test: output_sensitivities")
    y, dy, failed = output_sensitivities(model, inputs, theta, schedule)
    return y[:, 0], dy[:, 0], failed


def _delayed(force: np.ndarray, dforce: np.ndarray, tau: float, dt: float, j: int) -> tuple[np.ndarray, np.ndarray]:
    """The force lagged by τ [s] as :func:`~bayes_mr.simulation.simulate.delay` lags it (linear interpolation,
    held at the first sample before it), its sensitivities lagged likewise, and ∂/∂τ: minus the slope of the
    interpolant at t − τ (0 where the first sample is held; a sample's own time takes the slope after it)."""
    n = force.size
    lagged = delay(np.vstack([force, dforce.T]), np.full(dforce.shape[1] + 1, tau), dt)
    q = (np.arange(n) * dt - tau) / dt
    k = np.clip(np.floor(q).astype(int), 0, n - 2)
    slope = np.where(q >= 0.0, (force[k + 1] - force[k]) / dt, 0.0)
    dforce = lagged[1:].T.copy()
    dforce[:, j] = -slope
    return lagged[0], dforce
