"""The reference simulator (scipy, from the contract's equations) and ``bm.simulate`` agree on clean inputs.

Tolerances. ``tests/reference_sim.py`` integrates with LSODA at 1e-8 relative tolerance; the package's RK4
is run here with a tight sub-step bound (``c_acc=0.05``, RK4 everywhere) so that what is compared is the
equations, not two step controls: measured force/displacement/acceleration NRMSE 2e-6–2e-5 on every case,
checked at 1e-3 (the brief's bound). With the package's default step control (``c_acc=1``, ROS2 where it
passes its 1e-3 error test) the error is that step control's own — the contract quotes 1e-3 to 3e-3 of the SD
for RK4 at c_acc = 1 on the measured damper — and is checked at 5e-3. Both simulators read the device
velocity as the given samples, linear between them (the package's reading of a record), and the command
linear between samples (the package's default reading of it) — or, in the last tests, held (``zoh``, the
package's ``command_interp="hold"``).
"""

import numpy as np
import pytest
from scipy.signal import butter, sosfiltfilt

import bayes_mr as bm
from reference_sim import EFFECTS, FORMS, simulate_reference

FS, N, MASS = 1000.0, 2000, 50.0
EQUATIONS_TOL = 1e-3
DEFAULT_STEP_TOL = 5e-3

#: Effect values in a dahl structure test (response ≈ 0.6 mm) and a dahl device test (x ≈ 5 mm RMS).
STRUCTURE = {"force_offset": {"f0": 2.0}, "stiffness_drift": {"drift": 0.02}, "asymmetry": {"asym": 0.3},
             "small_amplitude_regime": {"r_s": 0.5, "x_s": 4e-4}, "low_velocity_rolloff": {"c_s": 1.5e4},
             "sensor_delay": {"delay": 0.004}, "cubic_stiffness": {"k3": 8e9},
             "voltage_dependence": {"a_v": 1.0, "c_v": 50.0, "eta": 50.0}}
DEVICE = {**STRUCTURE, "small_amplitude_regime": {"r_s": 0.5, "x_s": 4e-3}, "low_velocity_rolloff": {"c_s": 5e3},
          "cubic_stiffness": {"k3": 8e7}}


def _inputs():
    rng = np.random.default_rng(11)
    t = np.arange(N) / FS
    x = sosfiltfilt(butter(4, 5.0, fs=FS, output="sos"), rng.standard_normal(N))
    x *= 5e-3 / x.std() * np.clip(t / 0.2, 0, 1) ** 2
    ag = sosfiltfilt(butter(4, 8.0, fs=FS, output="sos"), rng.standard_normal(N))
    ag *= 3.0 / ag.std() * np.clip(t / 0.2, 0, 1)
    volt = np.where(np.sin(2 * np.pi * 0.7 * t) > 0, 2.0, 0.0)
    return t, x, np.gradient(x, 1 / FS), ag, volt


def _errors(form, kind, effects: dict, command: bool):
    t, x, xd, ag, volt = _inputs()
    v = volt if command else None
    model = bm.get_model(form + "".join("+" + e for e in effects))
    theta = model.theta(kind, {k: val for d in effects.values() for k, val in d.items()})
    params = dict(zip(model.param_names(kind), theta))
    inputs = bm.Inputs.device(x, xd, 1 / FS, v) if kind == "device" else bm.Inputs.structure(ag, 1 / FS, MASS, v)
    ref = simulate_reference(form, params, t, kind=kind, effects=list(effects), displacement=x, velocity=xd,
                             ground_acceleration=ag, voltage=v, mass=MASS)
    channels = ["force"] if kind == "device" else ["displacement", "acceleration"]
    out = {}
    for label, options in (("equations", {"c_acc": 0.05, "ros2": False}), ("default", {})):
        sim = bm.simulate(model, inputs, theta, **options)
        out[label] = {c: float(np.sqrt(np.mean((sim[c] - ref[c]) ** 2)) / np.std(ref[c])) for c in channels}
    return out


CASES = ([(f, k, None) for f in FORMS for k in ("device", "structure")]
         + [("dahl", k, e) for e in EFFECTS for k in ("device", "structure")])


@pytest.mark.parametrize("case", CASES, ids=lambda c: f"{c[0]}-{c[1]}-{c[2] or 'clean'}")
def test_reference_simulator_agrees_with_simulate(case):
    form, kind, effect = case
    effects = {} if effect is None else {effect: (DEVICE if kind == "device" else STRUCTURE)[effect]}
    errors = _errors(form, kind, effects, command=form == "spencer" or effect == "voltage_dependence")
    assert max(errors["equations"].values()) <= EQUATIONS_TOL, errors
    assert max(errors["default"].values()) <= DEFAULT_STEP_TOL, errors


def test_a_held_command_is_not_a_linear_one():
    """The command's reading between samples is an option, and it matters: a held command lags the linear one by
    half a sample on average, and on spencer's 0/2 V square wave at 1 kHz that moves the force by 5.9e-3 of
    its SD, several times the agreement tolerance."""
    t, x, xd, _, volt = _inputs()
    params = dict(zip(bm.get_model("spencer").param_names("device"), bm.get_model("spencer").theta("device", {})))
    run = {c: simulate_reference("spencer", params, t, kind="device", displacement=x, voltage=volt, command=c)["force"]
           for c in ("linear", "zoh")}
    assert np.sqrt(np.mean((run["linear"] - run["zoh"]) ** 2)) / np.std(run["linear"]) > 4 * EQUATIONS_TOL


def test_the_package_reads_a_held_command_as_the_reference_writes_it():
    """spencer under the 0/2 V square wave held between samples: read with ``command_interp="hold"`` the package
    gives the reference's force to the agreement tolerances (measured 2.7e-8 with the tight step, 6.3e-6 with the
    default one); read linear it misses it by the half-sample lead of its command (5.9e-3 of the SD)."""
    t, x, xd, _, volt = _inputs()
    model = bm.get_model("spencer")
    theta = model.theta("device", {})
    ref = simulate_reference("spencer", dict(zip(model.param_names("device"), theta)), t, kind="device",
                             displacement=x, velocity=xd, voltage=volt, command="zoh")["force"]
    inputs = bm.Inputs.device(x, xd, 1 / FS, volt)

    def error(reading, **options):
        force = bm.simulate(model, inputs.with_command_interp(reading), theta, **options)["force"]
        return float(np.sqrt(np.mean((force - ref) ** 2)) / np.std(ref))

    assert error("hold", c_acc=0.05, ros2=False) <= EQUATIONS_TOL
    assert error("hold") <= DEFAULT_STEP_TOL
    assert error("linear", c_acc=0.05, ros2=False) > 4 * EQUATIONS_TOL


def test_reference_simulator_is_independent_of_the_package():
    import ast

    import reference_sim

    tree = ast.parse(open(reference_sim.__file__).read())
    imported = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    imported |= {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    assert not any(name.startswith("bayes_mr") for name in imported), imported
