"""Exact sensitivities (bayes_mr.models.sensitivity) against central differences on the same schedule.

Every covered case (each form in a device test, alone and with each covered effect and several together; the
command linear and held, and the drive band-limited) must give the simulator's own force bit for bit and each
column of ∂f/∂θ within 1e-6 (relative, column norm) of central differences of the simulator on the replayed
schedule; and least squares' Jacobian in φ built from them must agree with its finite-difference one likewise.
The thesis forms' parameters are stiff enough that RK4 needs sub-steps, simulated without ROS2 (whose steps
have no sensitivities: least squares takes finite differences there, tested below).
"""

from __future__ import annotations

import numpy as np
import pytest
from records import _excitation, _voltage, device_inputs, structure_inputs, structure_record

from bayes_mr.inference.lsq.refine import Residuals
from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.models import get_model
from bayes_mr.models.integrate import BRANCH_CODE, steps
from bayes_mr.simulation.inputs import Inputs
from bayes_mr.simulation.sensitivity import covered, force_sensitivities, output_sensitivities, replayable
from bayes_mr.simulation.simulate import simulate, synthesize

#: Relative agreement of a sensitivity column with central differences (the issue's criterion).
RTOL = 1e-6

CASES = [
    ("spencer", {}, "linear", "linear"),
    ("spencer", {}, "hold", "linear"),
    ("spencer+force_offset", {"f0": -40.0}, "linear", "linear"),
    ("spencer+force_offset", {"f0": 25.0}, "hold", "bandlimited"),
    ("spencer+stiffness_drift", {"drift": 0.2}, "linear", "linear"),
    ("spencer+asymmetry", {"asym": 0.25}, "linear", "linear"),
    ("spencer+command_saturation", {"u_s": 1.5}, "linear", "linear"),
    ("spencer+field_decay", {"r_d": 0.4}, "hold", "linear"),
    ("spencer+cubic_stiffness", {"k3": 1e8}, "linear", "linear"),
    ("spencer+shear_thinning", {}, "linear", "linear"),
    ("spencer+stribeck_friction", {}, "linear", "linear"),
    ("spencer+inertia", {"m_e": 2.0}, "linear", "linear"),
    ("spencer+sensor_delay", {"delay": 0.0023}, "linear", "linear"),
    ("spencer+command_polynomial", {"b2": 0.4, "b3": -0.08}, "hold", "linear"),
    ("spencer+exponential_saturation", {"u_e": 0.8}, "linear", "linear"),
    ("spencer+command_polynomial+command_saturation+exponential_saturation",
     {"b2": 0.3, "b3": 0.05, "u_s": 1.5, "u_e": 1.2}, "hold", "linear"),
    ("spencer+stiffness_drift+asymmetry+command_saturation+force_offset", {"drift": -0.1, "asym": 0.1, "u_s": 1.2,
                                                                           "f0": 10.0}, "hold", "linear"),
]

# the thesis forms at 8 mm with rates that need 2-18 RK4 sub-steps per 1-ms interval; bouc-wen at a device's
# force scale (its defaults are Table 3.2's 0.2-kg oscillator), hardening (γ < 0) and softening
DAHL = {"sigma": 2e4}
LUGRE = {"alpha": 2e4}
NBW = {"rho": 2e4, "n": 1.5}
BW = {"c": 200.0, "k": 2e4, "beta1": 2e4, "gamma": 1e4, "n": 1.0}
BW_HARD = {"c": 200.0, "k": 2e4, "beta1": 2e5, "gamma": -1e5, "n": 1.3}
THESIS_CASES = [
    ("dahl", DAHL, "linear", "linear"),
    ("dahl", DAHL, "hold", "bandlimited"),
    ("lugre", LUGRE, "linear", "linear"),
    ("bouc-wen", BW, "linear", "linear"),
    ("bouc-wen", BW_HARD, "linear", "linear"),
    ("normalized-bouc-wen", NBW, "linear", "linear"),
    ("dahl+low_velocity_rolloff", {**DAHL, "c_s": 500.0}, "linear", "linear"),
    ("lugre+low_velocity_rolloff", {**LUGRE, "c_s": 800.0}, "linear", "linear"),
    ("dahl+voltage_dependence+command_saturation+field_decay", {**DAHL, "u_s": 1.5, "r_d": 0.4}, "hold", "linear"),
    ("dahl+voltage_dependence+command_polynomial", {**DAHL, "b2": 0.4, "b3": -0.08}, "linear", "linear"),
    ("lugre+voltage_dependence+exponential_saturation+command_saturation", {**LUGRE, "u_e": 0.8, "u_s": 1.5},
     "hold", "linear"),
    ("lugre+stiffness_drift+asymmetry+force_offset", {**LUGRE, "drift": 0.2, "asym": 0.25, "f0": 10.0}, "linear",
     "linear"),
    ("lugre+voltage_dependence+low_velocity_rolloff+asymmetry", {**LUGRE, "c_s": 800.0, "asym": 0.2}, "linear",
     "linear"),
    ("normalized-bouc-wen+voltage_dependence+low_velocity_rolloff+stiffness_drift",
     {**NBW, "c_s": 300.0, "drift": -0.1}, "linear", "linear"),
    ("normalized-bouc-wen+asymmetry+force_offset+cubic_stiffness", {**NBW, "asym": 0.2, "f0": -20.0, "k3": 1e8},
     "linear", "linear"),
    ("bouc-wen+cubic_stiffness+shear_thinning+stribeck_friction", {**BW, "k3": 1e8}, "linear", "linear"),
    ("dahl+inertia+sensor_delay", {**DAHL, "m_e": 2.0, "delay": 0.0023}, "linear", "linear"),
]


def _perturbed_theta(model, values, seed=0):
    """The published parameters (and ``values``) moved a few per cent, so no term sits at a special value."""
    theta = model.theta("device", values)
    rng = np.random.default_rng(seed)
    return theta * np.exp(0.05 * rng.standard_normal(theta.size))


def _inputs(command_interp, interp, n=1200):
    inp = device_inputs(0.008, n=n, fs=1000.0, seed=2)
    return inp.with_command_interp(command_interp).with_interp(interp)


@pytest.mark.parametrize("name, values, command_interp, interp", CASES + THESIS_CASES)
def test_sensitivities_match_central_differences(name, values, command_interp, interp):
    model = get_model(name)
    inputs = _inputs(command_interp, interp)
    theta = _perturbed_theta(model, values)
    sim = simulate(model, inputs, theta, ros2=False)  # RK4 throughout (spencer's schedule is the same either way)
    sched = sim.schedule[0]
    # the stiff law needs sub-steps here or holds its state on a loading branch (not with low_velocity_rolloff):
    # the schedule's replay is tested too
    held = sched >= BRANCH_CODE
    assert steps(sched[~held]).max() > 1 or held.any()
    if "low_velocity_rolloff" not in name:
        assert held.any()
    force, dforce, failed = force_sensitivities(model, inputs, theta, sched)
    assert failed == -1
    np.testing.assert_array_equal(force, sim["force"])  # the same operations as the simulator
    names = model.param_names("device")
    for j, pname in enumerate(names):
        # a step of 1e-7: at 1e-6 the perturbed runs of n straddle a kink of the law (|ẋ − ẏ|, sgn z) at a few
        # samples, where the difference quotient is off by 2e-5 and the sensitivity (agreeing to 4e-10 at
        # 1e-7 and 1e-8) is not
        h = 1e-7 * abs(theta[j])
        up, down = theta.copy(), theta.copy()
        up[j] += h
        down[j] -= h
        pair = simulate(model, inputs, np.vstack([up, down]), schedule=sched)["force"]
        fd = (pair[0] - pair[1]) / (2 * h)
        rel = np.linalg.norm(dforce[:, j] - fd) / np.linalg.norm(fd)
        assert rel < RTOL, f"{name}: ∂f/∂{pname} differs from central differences by {rel:.2e} (relative)"


#: Structure and forced tests: every form, and effects on the command path, the law and the force. The forced
#: test's mass m is a parameter, so its column (through ẍ = (p − f_r)/m) is tested too.
FRAME_CASES = [
    ("structure", "dahl", DAHL),
    ("structure", "lugre", {}),
    ("structure", "bouc-wen", {"c": 100.0, "k": 2e4, "beta1": 2e4, "gamma": 1e4, "n": 1.0}),
    ("structure", "normalized-bouc-wen", {}),
    ("structure", "spencer", {}),
    ("structure", "spencer+force_offset+stiffness_drift", {"f0": -20.0, "drift": 0.1}),
    ("structure", "dahl+low_velocity_rolloff", {"c_s": 500.0}),
    ("structure", "lugre+voltage_dependence+command_saturation+field_decay", {"u_s": 1.5, "r_d": 0.4}),
    ("structure", "normalized-bouc-wen+stiffness_drift+asymmetry+force_offset+cubic_stiffness",
     {"drift": 0.2, "asym": 0.2, "f0": 5.0, "k3": 1e8}),
    ("structure", "dahl+shear_thinning+stribeck_friction+sensor_delay", {"delay": 0.0023}),
    ("forced", "dahl", DAHL),
    ("forced", "bouc-wen", {"c": 100.0, "k": 2e4, "beta1": 2e4, "gamma": 1e4, "n": 1.0}),
    ("forced", "normalized-bouc-wen", {}),
    ("forced", "spencer", {}),
    ("forced", "dahl+low_velocity_rolloff+voltage_dependence", {"c_s": 500.0}),
]
FRAME_CHANNELS = ("displacement", "velocity", "acceleration")


def _frame_inputs(kind, n=1200):
    """A 50-kg storey under 3 m/s² of ground acceleration, or a mass driven by up to 200 N (five sines each)."""
    if kind == "structure":
        return structure_inputs(3.0, 50.0, n=n, seed=1)
    t, _, _, xdd = _excitation(n, 1e-3, 1)
    return Inputs.forced(200.0 * xdd / np.abs(xdd).max(), 1e-3, _voltage(t))


@pytest.mark.parametrize("kind, name, values", FRAME_CASES)
def test_frame_sensitivities_match_central_differences(kind, name, values):
    """x, ẋ and the absolute acceleration of a structure or forced test, and their derivatives.

    A column is the derivative of the three channels together, each over its RMS (as a fit weighs channels:
    a parameter's column in one channel can be negligible against the channel, spencer's c0b on the
    displacement is 1e-10 m per N·s/m, and no difference resolves that part to 1e-6). The reference is the best
    of central differences at steps 1e-7, 1e-5 and 1e-4 (relative): these outputs pass through the frame's
    integration, where a small step's difference is rounding (its error grows as 1/step: spencer 7e-5 at 1e-7,
    6e-7 at 1e-5), and at a larger step the perturbed runs straddle a kink (sgn z) of the law at some sample
    (spencer's n: 2e-3 at 1e-5, 6e-7 at 1e-7). Each error has its step; the sensitivity agrees with the
    difference that is free of it.
    """
    model = get_model(name)
    inputs = _frame_inputs(kind)
    theta = model.theta(kind, values)
    theta = theta * np.exp(0.05 * np.random.default_rng(0).standard_normal(theta.size))
    sim = simulate(model, inputs, theta)
    sched = sim.schedule[0]
    y, dy, failed = output_sensitivities(model, inputs, theta, sched)
    assert failed == -1
    for m, c in enumerate(FRAME_CHANNELS):
        np.testing.assert_array_equal(y[:, m], sim[c])  # the same operations as the simulator
    rms = np.sqrt(np.mean(y**2, axis=0))
    for j, pname in enumerate(model.param_names(kind)):
        col = dy[:, :, j] / rms
        rel = np.inf
        for step in (1e-7, 1e-5, 1e-4):
            h = step * abs(theta[j])
            up, down = theta.copy(), theta.copy()
            up[j] += h
            down[j] -= h
            pair = simulate(model, inputs, np.vstack([up, down]), schedule=sched)
            fd = np.stack([(pair[c][0] - pair[c][1]) / (2 * h) for c in FRAME_CHANNELS], axis=1) / rms
            rel = min(rel, np.linalg.norm(col - fd) / np.linalg.norm(col))
        assert rel < RTOL, f"{kind} {name}: ∂y/∂{pname} differs from central differences by {rel:.2e}"


def _record(name, values, seed=5):
    model = get_model(name)
    inputs = _inputs("linear", "linear", n=900)
    x, xd, v = inputs.rows.T
    t = np.arange(inputs.n) * inputs.dt
    return synthesize(model, _perturbed_theta(model, values, seed), t,
                      {"displacement": x, "velocity": xd, "voltage": v}, noise=0.01, seed=seed)


@pytest.mark.parametrize("name, values", [
    ("spencer", {}), ("spencer+force_offset", {"f0": -40.0}),
    # hardening (γ < 0, on the sign-free asinh coordinate) and not stiff, so the default simulation takes RK4
    ("bouc-wen", {"c": 200.0, "k": 2e4, "beta1": 2e3, "gamma": -1e3, "n": 1.0}),
    ("lugre+low_velocity_rolloff", {"c_s": 800.0}),
])
def test_least_squares_jacobian_is_exact(name, values):
    """Residuals' Jacobian in φ from the sensitivities agrees with its central differences, and is used."""
    lik = OutputError(name, _record(name, values))
    coords = lik.par.coords
    phi = coords.to_phi(np.clip(_perturbed_theta(lik.model, values, 9)[lik.par.free_idx], coords.lower, coords.upper))
    sd = lik.noise_sd
    exact = Residuals(lik, sd)
    assert exact.exact
    exact(phi)
    assert replayable(exact.schedule)  # RK4 throughout: the sensitivities, not the fallback
    J = exact.jacobian(phi)
    fd = Residuals(lik, sd, exact=False)
    fd(phi)
    J_fd = fd.jacobian(phi, central=True)
    rel = np.linalg.norm(J - J_fd, axis=0) / np.linalg.norm(J_fd, axis=0)
    assert np.all(rel < RTOL), dict(zip(lik.par.names, rel))


def _forced_record(name, values, seed=5, n=900):
    """A forced test of ``name`` with its mass m a parameter (no ``mass`` given), 1 % noise."""
    model = get_model(name)
    inputs = _frame_inputs("forced", n)
    t = np.arange(inputs.n) * inputs.dt
    theta = model.theta("forced", values)
    return synthesize(model, theta * np.exp(0.05 * np.random.default_rng(seed).standard_normal(theta.size)), t,
                      {"applied_force": inputs.rows[:, 0], "voltage": inputs.rows[:, 2]}, noise=0.01, seed=seed)


@pytest.mark.parametrize("kind, name", [("structure", "dahl"), ("structure", "spencer+force_offset"),
                                        ("forced", "bouc-wen")])
def test_least_squares_jacobian_is_exact_on_several_channels(kind, name):
    """A structure test (displacement, acceleration) and a forced one (three channels, m estimated): the
    sensitivities' Jacobian in φ, each channel over its own σ, agrees with central differences, and least
    squares uses it."""
    record = (structure_record(name, {"f0": 5.0} if "force_offset" in name else {}, n=900)[0] if kind == "structure"
              else _forced_record(name, {"c": 100.0, "k": 2e4, "beta1": 2e4, "gamma": -5e3, "n": 1.0}))
    lik = OutputError(name, record)
    assert lik.kind == kind and len(lik.channels) >= 2
    assert kind != "forced" or "m" in lik.par.names  # the mass estimated: its column through ẍ = (p − f_r)/m
    coords = lik.par.coords
    phi = coords.to_phi(np.clip(_theta_near(lik, kind, record), coords.lower, coords.upper))
    sd = lik.noise_sd
    exact = Residuals(lik, sd)
    assert exact.exact
    exact(phi)
    assert replayable(exact.schedule)
    J = exact.jacobian(phi)
    fd = Residuals(lik, sd, exact=False)
    fd(phi)
    J_fd = fd.jacobian(phi, central=True)
    # the command's coefficients of a record without a command have zero columns, exactly, in both
    err, size = np.linalg.norm(J - J_fd, axis=0), np.linalg.norm(J_fd, axis=0)
    assert np.all(err <= RTOL * size), dict(zip(lik.par.names, err / size))


def _theta_near(lik, kind, record):
    """The record's true free parameters (its ``theta`` attribute) moved a few per cent."""
    truth = dict(kv.split("=") for kv in record.attrs["theta"].split(", ")) if "theta" in record.attrs else None
    names = lik.model.param_names(kind)
    full = (np.array([float(truth[n]) for n in names]) if truth is not None else lik.model.theta(kind, {}))
    return full[lik.par.free_idx] * np.exp(0.03 * np.random.default_rng(3).standard_normal(lik.par.free_idx.size))


def test_models_without_sensitivities_keep_finite_differences():
    """A form or effect the kernel has no partials of is not covered: its Jacobian stays finite differences; a
    covered one takes the sensitivities in a structure test as in a device test."""
    for name in ("spencer", "spencer+force_offset", "dahl", "lugre+voltage_dependence+field_decay",
                 "lugre+voltage_dependence+command_polynomial", "spencer+exponential_saturation",
                 "bouc-wen+low_velocity_rolloff", "normalized-bouc-wen+sensor_delay"):
        assert covered(name, "device"), name
    for kind in ("structure", "forced"):
        assert covered("dahl", kind) and covered("spencer+force_offset", kind)
    for name, kind in (("spencer+field_dynamics", "device"), ("dahl+small_amplitude_regime", "structure"),
                       ("spencer+small_amplitude_regime", "device"), ("spencer+term(xdot*abs(x))", "device"),
                       ("dahl+small_amplitude_regime", "device"), ("lugre+term(x*x*x)", "forced"),
                       ("lugre+voltage_dependence+field_dynamics", "device")):
        assert not covered(name, kind), name
    lik = OutputError("dahl+small_amplitude_regime", _record("dahl+small_amplitude_regime", {}))
    assert not Residuals(lik, lik.noise_sd).exact
    lik = OutputError("dahl", structure_record("dahl", {}, n=600)[0])
    assert Residuals(lik, lik.noise_sd).exact  # covered: least squares takes the sensitivities in any kind
    with pytest.raises(ValueError, match="no exact sensitivities"):
        force_sensitivities("dahl+small_amplitude_regime", device_inputs(0.008),
                            get_model("dahl+small_amplitude_regime").theta("device", {}), np.ones(1499, int))


def test_ros2_intervals_fall_back_to_finite_differences():
    """A covered model whose evaluation took a stiff interval by ROS2 has no sensitivities there: the exact
    Residuals' Jacobian at that point is the finite-difference one, number for number, and no sensitivity run
    is made; the sensitivity kernel refuses such a schedule."""
    from bayes_mr.simulation.simulate import tally

    # low_velocity_rolloff: the state is not held on its branches (branch.on_branch), where ROS2 takes them
    name, values = "dahl+low_velocity_rolloff", {**DAHL, "c_s": 5e4}
    lik = OutputError(name, _record(name, values))
    coords = lik.par.coords
    phi = coords.to_phi(np.clip(_perturbed_theta(lik.model, values, 9)[lik.par.free_idx], coords.lower, coords.upper))
    sd = lik.noise_sd
    exact = Residuals(lik, sd)
    assert exact.exact  # dahl is covered ...
    with tally() as calls:
        exact(phi)
        J = exact.jacobian(phi)
    assert not replayable(exact.schedule)  # ... but this evaluation took ROS2 intervals
    assert not any(c["sensitivities"] for c in calls)
    fd = Residuals(lik, sd, exact=False)
    fd(phi)
    np.testing.assert_array_equal(J, fd.jacobian(phi))
    with pytest.raises(ValueError, match="all RK4"):
        force_sensitivities(lik.model, lik.inputs, lik.par.full(phi), exact.schedule)


def test_exact_and_finite_difference_least_squares_reach_the_same_optimum():
    """Least squares on a dahl device test (RK4 throughout, so every Jacobian is exact) ends where the finite-
    difference refinement does: the same −ln L to 8 digits, from the same start."""
    from bayes_mr.inference.lsq.refine import refine
    from bayes_mr.simulation.simulate import tally

    lik = OutputError("dahl", _record("dahl", {}))
    coords = lik.par.coords
    phi0 = coords.to_phi(np.clip(_perturbed_theta(lik.model, {}, 11)[lik.par.free_idx] * 1.3, coords.lower,
                                 coords.upper))
    sd = lik.noise_sd
    with tally() as calls:
        a = refine(lik, phi0, sd, max_nfev=60, exact=True)
    assert sum(c["sensitivities"] for c in calls) >= 3  # the exact path was taken at every step
    b = refine(lik, phi0, sd, max_nfev=60, exact=False)
    assert a.status > 0 and b.status > 0
    assert abs(a.cost - b.cost) <= 1e-8 * b.cost, (a.cost, b.cost)
    np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-4)


def test_tally_counts_runs_and_their_sub_steps():
    """simulate.tally notes each call: members, replays, sensitivity runs, sub-steps and the cap's share."""
    from bayes_mr.simulation.simulate import tally

    model = get_model("spencer")
    inputs = _inputs("linear", "linear", n=400)
    theta = model.theta("device", {})
    with tally() as calls:
        sim = simulate(model, inputs, np.vstack([theta, theta]), n_max=3)
        simulate(model, inputs, theta, schedule=sim.schedule[0])
        force_sensitivities(model, inputs, theta, sim.schedule[0])
    simulate(model, inputs, theta)  # outside the block: not noted
    assert [(c["members"], c["replayed"], c["sensitivities"]) for c in calls] == [
        (2, False, False), (1, True, False), (1, True, True)]
    n_steps = steps(sim.schedule)  # a held branch interval's entry carries BRANCH_CODE: its count is the rest
    assert calls[0]["at_cap"] == np.count_nonzero(n_steps >= 3) > 0
    assert calls[0]["substeps"] == n_steps.sum() and calls[1]["substeps"] == calls[1]["at_cap"] == 0
