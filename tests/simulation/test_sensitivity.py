"""Exact sensitivities (bayes_mr.models.sensitivity) against central differences on the same schedule.

Every covered case (spencer in a device test, alone and with each covered effect and several together; the
command linear and held, and the drive band-limited) must give the simulator's own force bit for bit and each
column of ∂f/∂θ within 1e-6 (relative, column norm) of central differences of the simulator on the replayed
schedule; and least squares' Jacobian in φ built from them must agree with its finite-difference one likewise.
"""

from __future__ import annotations

import numpy as np
import pytest
from records import device_inputs

from bayes_mr.inference.lsq.refine import Residuals
from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.models import get_model
from bayes_mr.models.integrate import BRANCH_CODE, steps
from bayes_mr.simulation.sensitivity import covered, force_sensitivities
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
    ("spencer+stiffness_drift+asymmetry+command_saturation+force_offset", {"drift": -0.1, "asym": 0.1, "u_s": 1.2,
                                                                           "f0": 10.0}, "hold", "linear"),
]


def _perturbed_theta(model, values, seed=0):
    """The published parameters (and ``values``) moved a few per cent, so no term sits at a special value."""
    theta = model.theta("device", values)
    rng = np.random.default_rng(seed)
    return theta * np.exp(0.05 * rng.standard_normal(theta.size))


def _inputs(command_interp, interp, n=1200):
    inp = device_inputs(0.008, n=n, fs=1000.0, seed=2)
    return inp.with_command_interp(command_interp).with_interp(interp)


@pytest.mark.parametrize("name, values, command_interp, interp", CASES)
def test_sensitivities_match_central_differences(name, values, command_interp, interp):
    model = get_model(name)
    inputs = _inputs(command_interp, interp)
    theta = _perturbed_theta(model, values)
    sim = simulate(model, inputs, theta)
    sched = sim.schedule[0]
    # the stiff law needs sub-steps here, and z is held on its loading branches in part of the intervals: the
    # replay of both is tested too
    held = sched >= BRANCH_CODE
    assert 0.1 < held.mean() < 0.9 and steps(sched[~held]).max() > 1
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


def _record(name, values, seed=5):
    model = get_model(name)
    inputs = _inputs("linear", "linear", n=900)
    x, xd, v = inputs.rows.T
    t = np.arange(inputs.n) * inputs.dt
    return synthesize(model, _perturbed_theta(model, values, seed), t,
                      {"displacement": x, "velocity": xd, "voltage": v}, noise=0.01, seed=seed)


@pytest.mark.parametrize("name, values", [("spencer", {}), ("spencer+force_offset", {"f0": -40.0})])
def test_least_squares_jacobian_is_exact(name, values):
    """Residuals' Jacobian in φ from the sensitivities agrees with its central differences, and is used."""
    lik = OutputError(name, _record(name, values))
    coords = lik.par.coords
    phi = coords.to_phi(np.clip(_perturbed_theta(lik.model, values, 9)[lik.par.free_idx], coords.lower, coords.upper))
    sd = lik.noise_sd
    exact = Residuals(lik, sd)
    assert exact.exact
    exact(phi)
    J = exact.jacobian(phi)
    fd = Residuals(lik, sd, exact=False)
    fd(phi)
    J_fd = fd.jacobian(phi, central=True)
    rel = np.linalg.norm(J - J_fd, axis=0) / np.linalg.norm(J_fd, axis=0)
    assert np.all(rel < RTOL), dict(zip(lik.par.names, rel))


def test_models_without_sensitivities_keep_finite_differences():
    """A form or effect the kernel has no partials of is not covered: its Jacobian stays finite differences."""
    assert covered("spencer", "device") and covered("spencer+force_offset", "device")
    for name, kind in (("dahl", "device"), ("spencer+field_dynamics", "device"), ("spencer", "structure"),
                       ("spencer+small_amplitude_regime", "device"), ("spencer+term(xdot*abs(x))", "device")):
        assert not covered(name, kind)
    lik = OutputError("dahl+force_offset", _record("dahl+force_offset", {"f0": 5.0}))
    assert not Residuals(lik, lik.noise_sd).exact
    with pytest.raises(ValueError, match="no exact sensitivities"):
        force_sensitivities("dahl", device_inputs(0.008), get_model("dahl").theta("device", {}), np.ones(1499, int))


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
