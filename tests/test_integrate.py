"""The adaptive integrator (bayes_mr.models.integrate): ROS2 where a device test is stiff, RK4 elsewhere."""

import numpy as np
import pytest

from bayes_mr.models import get_model, integrate, kernel
from bayes_mr.models.drivers import run_batch
from bayes_mr.simulation.simulate import simulate
from records import device_inputs, structure_inputs
from test_simulate import THESIS_FRAME, reference_simulation

#: Device tests whose hysteretic state is stiff at 1 kHz (tens of RK4 sub-steps per sample at high velocity):
#: every form that may use ROS2, alone and under effects with states and switches of their own.
STIFF_DEVICE = [
    ("dahl", {"sigma": 2e5, "F_d": 300.0, "c": 2000.0, "k": 500.0}),
    ("normalized-bouc-wen", {"k_z": 300.0, "rho": 1e5, "n": 2.0, "sigma": 0.7, "c": 2000.0}),
    ("lugre", {"beta": 3e7, "alpha": 1e5, "epsilon": 500.0, "c": 2000.0, "k": 500.0}),
    ("bouc-wen", {"c": 2000.0, "k": 3e4, "beta1": 1e5, "gamma": -0.9e5, "n": 1.0}),
    ("lugre+force_offset+voltage_dependence+asymmetry+small_amplitude_regime+low_velocity_rolloff",
     {"beta": 3e7, "alpha": 1e5, "epsilon": 500.0, "c": 2000.0, "k": 500.0, "f0": -120.0, "a_v": 1.5,
      "c_v": 400.0, "eta": 100.0, "asym": -0.2, "r_s": 0.4, "x_s": 0.004, "c_s": 2e4}),
    ("normalized-bouc-wen+stiffness_drift+small_amplitude_regime+cubic_stiffness",
     {"k_z": 300.0, "rho": 1e5, "c": 2000.0, "drift": 0.1, "r_s": 2.0, "x_s": 0.003, "k3": 1e7}),
]


def _nrmse(y, r):
    return float(np.sqrt(np.mean((y - r) ** 2)) / np.std(r))


def _run(model, inputs, theta, rtol=None):
    """One simulation through the driver, with the error test's tolerance set (None: the default)."""
    lay, cst = model.layout(inputs.kind), model.constants(inputs.mass)
    if rtol is not None:
        cst[kernel.K_RTOL] = rtol
    n = inputs.grid_rows.shape[0]
    out, schedule, failed = np.empty((1, n, 2)), np.zeros((1, n - 1), np.int64), np.empty(1, np.int64)
    run_batch(lay, cst, theta[None], inputs.dt, inputs.grid_rows, out, schedule, False, failed, 1)
    return out[0, :, 0], schedule[0]


@pytest.mark.parametrize("name,values", STIFF_DEVICE, ids=[c[0][:40] for c in STIFF_DEVICE])
def test_stiff_device_tests_keep_the_accuracy_of_rk4(name, values):
    """Against solve_ivp, the adaptive step is within the simulator's bound (1e-3 of the SD, as
    ``test_matches_solve_ivp``) or within 1.5× RK4's own error where that is larger, and ROS2 takes most of
    the stiff intervals (else this tests nothing)."""
    model = get_model(name)
    inputs = device_inputs(0.006, fs=1000.0)
    theta = model.theta("device", values)
    ref = reference_simulation(model, "device", theta, inputs)
    # the states integrated on their loading branches too, where the default holds them (branch.on_branch)
    adaptive = simulate(model, inputs, theta, hold_branch=False)
    rk4 = simulate(model, inputs, theta, ros2=False, hold_branch=False)
    stiff = np.abs(rk4.schedule) > 2
    assert stiff.mean() > 0.3
    assert np.mean(adaptive.schedule[stiff] < 0) > 0.6
    assert np.all(rk4.schedule >= 0)
    for j, channel in enumerate(adaptive.outputs):
        err, err_rk4 = _nrmse(adaptive[channel], ref[:, j]), _nrmse(rk4[channel], ref[:, j])
        assert err <= max(1e-3, 1.5 * err_rk4), (channel, err, err_rk4)


def test_the_error_test_is_what_keeps_the_accuracy():
    """With every ROS2 step accepted (no error test), the stiff lugre device test with effects misses the
    bound by an order of magnitude (measured 2.0e-2 of the SD; 2.2e-4 with the test): steps across a velocity
    reversal must go back to RK4."""
    name, values = STIFF_DEVICE[4]
    model = get_model(name)
    inputs = device_inputs(0.006, fs=1000.0)
    theta = model.theta("device", values)
    ref = reference_simulation(model, "device", theta, inputs)[:, 0]
    tested, kept = _run(model, inputs, theta)
    untested, taken = _run(model, inputs, theta, rtol=np.inf)
    assert _nrmse(tested, ref) < 1e-3 < _nrmse(untested, ref)
    assert 0 < np.mean(kept < 0) < np.mean(taken < 0)


@pytest.mark.parametrize("case", [0, 3], ids=["dahl", "bouc-wen"])
def test_a_replayed_schedule_replays_the_method(case):
    """Finite differences replay the schedule: the same parameters give the same outputs bit for bit, ROS2
    intervals included (bouc-wen: some in several steps), and a perturbed set, integrated by the same methods
    and step counts, stays within the simulator's bound of its own free simulation."""
    name, values = STIFF_DEVICE[case]
    model = get_model(name)
    inputs = device_inputs(0.006, fs=1000.0)
    theta = model.theta("device", values)
    first = simulate(model, inputs, theta)
    assert np.any(first.schedule < 0) and np.any(first.schedule > 2)
    assert np.any(first.schedule < -1) == (name == "bouc-wen")
    again = simulate(model, inputs, np.stack([theta, theta * 1.001]), schedule=first.schedule)
    np.testing.assert_array_equal(again["force"][0], first["force"])
    free = simulate(model, inputs, theta * 1.001)["force"]
    assert _nrmse(again["force"][1], free) < 1e-3


@pytest.mark.parametrize("case", [0, 3], ids=["dahl", "bouc-wen"])
def test_ros2_in_m_steps_converges_at_second_order(case):
    """Every interval replayed as m ROS2 steps (a schedule of −m, transitions included): against solve_ivp the
    error falls with m, towards fourfold per doubling (second order; measured 1.9, 2.5, 3.0, 3.4 for dahl from
    m = 1 to 16, the stiff branch's pre-asymptotic range first), so the inputs are interpolated at each step's
    ends (held at the interval's, the error would stall at first order)."""
    name, values = STIFF_DEVICE[case]
    model = get_model(name)
    inputs = device_inputs(0.006, fs=1000.0)
    theta = model.theta("device", values)
    ref = reference_simulation(model, "device", theta, inputs)[:, 0]
    n = inputs.grid_rows.shape[0]
    errs = np.array([_nrmse(simulate(model, inputs, theta, schedule=np.full(n - 1, -m))["force"], ref)
                     for m in (1, 2, 4, 8, 16)])
    ratios = errs[:-1] / errs[1:]
    assert np.all(ratios > 1.8) and ratios[-1] > 3.0, ratios


def test_structure_tests_and_spencer_stay_on_rk4():
    """ROS2 is for device tests (module docstring) and not for spencer (``Form.ros2``): their stiff intervals
    are RK4's, and ``ros2=False`` changes nothing there."""
    inputs = structure_inputs(THESIS_FRAME["accel"], THESIS_FRAME["mass"], fs=1000.0)
    model = get_model("dahl")
    theta = model.theta("structure", {"sigma": 2e5})
    sim = simulate(model, inputs, theta)
    assert np.any(sim.schedule > 2) and np.all(sim.schedule > 0)
    np.testing.assert_array_equal(sim["acceleration"], simulate(model, inputs, theta, ros2=False)["acceleration"])
    spencer = get_model("spencer")
    dev = device_inputs(0.006, fs=1000.0)
    sim = simulate(spencer, dev, spencer.theta("device", {}))
    assert np.any(sim.schedule > 2) and np.all(sim.schedule > 0)


def test_a_non_stiff_record_is_integrated_as_before():
    """Where no interval needs more than ROS2_ABOVE sub-steps, the adaptive simulator is RK4 bit for bit."""
    model = get_model("dahl")
    inputs = device_inputs(0.006, fs=1000.0)
    theta = model.theta("device", {"sigma": 1e3, "F_d": 300.0, "c": 2000.0, "k": 500.0})
    sim = simulate(model, inputs, theta)
    assert np.all(np.abs(sim.schedule) <= 2)
    np.testing.assert_array_equal(sim["force"], simulate(model, inputs, theta, ros2=False)["force"])


#: A stiff case of every form for the branch test: the published spencer, and the thesis forms of STIFF_DEVICE.
HELD = [("spencer", {})] + STIFF_DEVICE[:4]


@pytest.mark.parametrize("kind", ["device", "structure"])
@pytest.mark.parametrize("name,values", HELD, ids=[c[0] for c in HELD])
def test_a_saturated_loading_branch_is_held_at_the_same_accuracy(name, values, kind):
    """A hysteretic state at its saturation on a loading branch stays there however fast the piston moves
    (branch.on_branch), so an interval there holds it and integrates the other states at their own pace. Against
    a fine reference the error is that of integrating the state everywhere (measured: equal to three digits),
    in far fewer sub-steps where RK4 took those intervals (structure tests: 0.06× for spencer, 0.12–0.2× for
    the thesis forms; spencer's device test 0.23×); where ROS2 took them (the thesis forms' device tests) in
    about as many steps, each an RK4 sub-step instead of a Rosenbrock step."""
    inputs = (device_inputs(0.006, n=2000, fs=1000.0) if kind == "device"
              else structure_inputs(THESIS_FRAME["accel"] * 5, THESIS_FRAME["mass"], n=2000, fs=1000.0))
    channel = "force" if kind == "device" else "acceleration"
    model = get_model(name)
    theta = model.theta(kind, values)
    held = simulate(model, inputs, theta)
    integrated = simulate(model, inputs, theta, hold_branch=False)
    ref = simulate(model, inputs, theta, c_acc=0.02, n_max=4000, ros2=False, hold_branch=False)[channel]
    err, err_int = _nrmse(held[channel], ref), _nrmse(integrated[channel], ref)
    on = held.schedule[0] >= integrate.BRANCH_CODE
    assert on.mean() > 0.3 and np.all(integrated.schedule < integrate.BRANCH_CODE)
    assert err <= 1.2 * err_int + 1e-7, (err, err_int)
    n_held, n_int = integrate.steps(held.schedule).sum(), integrate.steps(integrated.schedule).sum()
    if np.all(integrated.schedule > 0):  # RK4 took every interval: the held ones need far fewer sub-steps
        assert n_held < 0.5 * n_int, (n_held, n_int)
    else:  # ROS2 took the stiff ones: one RK4 sub-step stands for one Rosenbrock step
        assert n_held <= 1.05 * n_int, (n_held, n_int)
    # the schedule it wrote replays its numbers
    np.testing.assert_array_equal(simulate(model, inputs, theta, schedule=held.schedule[0])[channel], held[channel])


def test_the_stiffest_prior_draws_cost_no_more_at_a_higher_cap():
    """The bench's stiff corners (:func:`bayes_mr.bench.kernels.stiff_corners`), on a short record: with the branch
    held no interval reaches the cap and the sub-steps are those of the lower cap, and the held run takes no more
    sub-steps than the plain RK4 one (the bench's timings themselves are not asserted: a machine's speed is not a
    test)."""
    from bayes_mr.bench.kernels import stiff_corners

    out = stiff_corners(forms=("bouc-wen",), duration=1.0, draws=20, repeats=1)["bouc-wen"]
    assert out["timed"] == 2
    low, high = out["held_400"], out["held_1600"]
    assert low["share_at_cap"] == high["share_at_cap"] == 0.0
    assert low["substeps_per_interval"] == high["substeps_per_interval"]
    assert low["completed"] == 2
    assert low["substeps_per_interval"] <= out["rk4_400"]["substeps_per_interval"]
