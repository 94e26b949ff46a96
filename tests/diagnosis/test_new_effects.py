"""The command-path, fluid, friction and inertia effects: their physics, their composition, and diagnose naming them when hidden.

Hidden-effect records are simulated like those of ``test_diagnose.py`` (1 % RMS noise on the
input and on every output, a dahl storey of 50 kg or a dahl damper on a device test); the effects
on the command path hide in a ``dahl+voltage_dependence`` record driven by a command that steps
between several levels (two levels alone cannot tell a saturating gain from a smaller linear one).
The default run holds each effect once; the two-magnitude, two-seed matrix is ``slow``.
"""

import numpy as np
import pytest

from bayes_mr.diagnosis.diagnose import THRESHOLD, diagnose
from bayes_mr.diagnosis.screen import COMPARED_LAWS, applicable
from bayes_mr.models import NONE, get_model
from bayes_mr.models.effects import ON_COMMAND
from bayes_mr.signals import make_signal
from bayes_mr.simulation.simulate import Inputs, simulate, synthesize
from records import case_id, device_inputs, effect_cases, naming_failures, structure_inputs

MASS = 50.0  # kg, the thesis's numerical frame (§3.8)
NEW = ("command_saturation", "field_dynamics", "shear_thinning", "stribeck_friction", "inertia", "field_decay",
       "command_polynomial", "exponential_saturation")
#: The voltage-dependent base of the command-path effects (a_v [1/V], c_v [N·s/(m·V)], eta [1/s]).
VD = {"a_v": 1.0, "c_v": 50.0, "eta": 50.0}

#: Two magnitudes of each effect: dahl storey (F_d = 25 N, c = 100 N·s/m, ~0.08 m/s peak velocity).
STRUCTURE_MAGNITUDES = {
    "shear_thinning": [{"c_p": 150.0, "m_hb": 0.5, "v_p": 0.01}, {"c_p": 400.0, "m_hb": 0.5, "v_p": 0.01}],
    "stribeck_friction": [{"F_st": 2.0, "v_s": 0.008}, {"F_st": 5.0, "v_s": 0.008}],
    "command_saturation": [1.5, 0.7],  # V, against commands up to 2.5 V
    "field_dynamics": [0.01, 0.03],  # s, before the 20 ms field lag
    "field_decay": [0.3, 4.0],  # decay rate / rise rate of the 20 ms field lag
}
#: ... and a dahl damper on a device test (~0.15 m/s peak velocity, ~110 N peak force).
DEVICE_MAGNITUDES = {
    "shear_thinning": [{"c_p": 150.0, "m_hb": 0.5, "v_p": 0.01}, {"c_p": 400.0, "m_hb": 0.5, "v_p": 0.01}],
    "stribeck_friction": [{"F_st": 5.0, "v_s": 0.015}, {"F_st": 12.0, "v_s": 0.015}],
    "command_saturation": [1.5, 0.7],
    "field_dynamics": [0.01, 0.03],
    "inertia": [1.0, 3.0],  # kg
    "field_decay": [0.3, 4.0],
}


def stepped_command(n: int, fs: float, seed: int, top: float = 2.5, mean_hold: float = 0.4) -> np.ndarray:
    """Command [V] holding random levels in [0, top] for exponentially distributed times [s]."""
    rng = np.random.default_rng(seed + 900)
    v = np.zeros(n)
    i = 0
    while i < n:
        hold = max(1, int(rng.exponential(mean_hold) * fs))
        v[i:i + hold] = rng.uniform(0.0, top)
        i += hold
    return v


def hidden_record(kind: str, effect: str | None, value=None, *, seed: int = 0, duration: float = 6.0,
                  fs: float = 500.0, noise: float = 0.01, commanded: bool | None = None):
    """A dahl test (``+voltage_dependence`` for the command-path effects) with ``effect`` hidden at ``value``.

    ``commanded`` (default: for the command-path effects) makes the base ``dahl+voltage_dependence``
    under a stepped command. Returns the record and the base model diagnose starts from.
    """
    if commanded is None:
        commanded = effect in ON_COMMAND
    base = "dahl+voltage_dependence" if commanded else "dahl"
    model = get_model(base + (f"+{effect}" if effect else ""))
    values = dict(VD) if commanded else {}
    if effect:
        values.update(value if isinstance(value, dict) else {model.effect(effect).primary: value})
    amplitude = 3e-3 if kind == "structure" else 10e-3
    sig = make_signal("blwn", duration=duration, fs=fs, amplitude=amplitude, fmax=10.0, seed=seed)
    inputs = sig.as_input(kind)
    if commanded:
        inputs["voltage"] = stepped_command(len(sig), fs, seed)
    rec = synthesize(model, model.theta(kind, values), sig.time, inputs, mass=MASS if kind == "structure" else None,
                     noise=noise, seed=seed + 77, source=f"{model.name}-{seed}")
    return rec, base


# --- physics and composition ------------------------------------------------------------------


def _with(base: str, effect: str, kind: str, values: dict, inputs: Inputs):
    m0, m1 = get_model(base), get_model(f"{base}+{effect}")
    key = "force" if kind == "device" else "acceleration"
    return simulate(m0, inputs, m0.theta(kind))[key], simulate(m1, inputs, m1.theta(kind, values))[key]


@pytest.mark.parametrize("kind", ["device", "structure"])
@pytest.mark.parametrize("effect,off", [
    ("command_saturation", {"u_s": 1e6}), ("field_dynamics", {"tau_c": 1e-9}),
    ("shear_thinning", {"c_p": 1e-9}), ("stribeck_friction", {"F_st": 1e-9}), ("field_decay", {"r_d": 1.0}),
])
def test_an_effect_switched_off_gives_the_base_model_back(kind, effect, off):
    """Every new effect nests its base: at its off value the response is the base model's."""
    base = "dahl+voltage_dependence" if effect in ON_COMMAND else "dahl"
    inputs = device_inputs(0.01) if kind == "device" else structure_inputs(3.0, MASS)
    y0, y1 = _with(base, effect, kind, off, inputs)
    assert np.max(np.abs(y1 - y0)) < 1e-6 * np.max(np.abs(y0))


def test_inertia_switched_off_and_on_is_m_e_times_the_imposed_acceleration():
    inputs = device_inputs(0.01, seed=2)
    y0, y_off = _with("dahl", "inertia", "device", {"m_e": 1e-12}, inputs)
    _, y_on = _with("dahl", "inertia", "device", {"m_e": 2.0}, inputs)
    np.testing.assert_allclose(y_off, y0, atol=1e-9)
    # the five-sine motion's exact acceleration, away from the ramp and the Savitzky–Golay edges
    from records import _excitation

    _, x, _, xdd = _excitation(inputs.n, inputs.dt, 2)
    xdd = xdd * 0.01 / np.abs(x).max()
    inner = slice(300, -50)
    err = (y_on - y0)[inner] - 2.0 * xdd[inner]
    assert np.sqrt(np.mean(err**2)) < 0.01 * np.sqrt(np.mean((2.0 * xdd[inner]) ** 2))


def test_field_dynamics_is_a_second_lag_of_the_step_response():
    """A command step through two lags: the force rises later, and the coil update is exact for any τ_c.

    At constant velocity dahl's z is saturated, so the force is linear in the filtered command u:
    the command's share (with minus without the step) is u's step response.
    """
    n, fs = 600, 1000.0
    volt = np.where(np.arange(n) >= 100, 2.0, 0.0)
    x = 0.05 * np.arange(n) / fs
    moving = lambda v: Inputs.device(x, np.full(n, 0.05), 1 / fs, v)  # noqa: E731

    def share(effect_values, tau=None):
        base = "dahl+voltage_dependence" + ("+field_dynamics" if tau else "")
        m = get_model(base)
        th = m.theta("device", {**effect_values, **({"tau_c": tau} if tau else {})})
        return simulate(m, moving(volt), th)["force"] - simulate(m, moving(np.zeros(n)), th)["force"]

    half = lambda y: int(np.argmax(y > 0.5 * y[-1])) - 100  # noqa: E731
    one, two = share(VD), share(VD, 0.02)
    assert half(one) == pytest.approx(1e3 * np.log(2) / 50.0, abs=1.5)  # 13.9 ms for η = 50 /s
    # two lags, 20 ms each: u(t) = 1 − (1 + t/τ)e^{−t/τ} reaches ½ at 1.678 τ = 33.6 ms
    assert half(two) == pytest.approx(33.6, abs=1.5)
    assert two[-1] == pytest.approx(one[-1], rel=1e-3)
    # a τ_c far below the sample interval (exact exponential, no RK4 stiffness) is the one-lag model
    np.testing.assert_allclose(share(VD, 1e-7), one, atol=1e-4 * one[-1])


def _command_share(model: str, values: dict, volt: np.ndarray, fs: float = 1000.0, speed: float = 0.05):
    """Force of ``model`` at constant velocity under ``volt`` less the same without command [N]: with dahl's
    z saturated the force is linear in the field-dependent coefficients, so this is the command's share."""
    n = len(volt)
    x = speed * np.arange(n) / fs
    m = get_model(model)
    th = m.theta("device", values)
    run = lambda v: simulate(m, Inputs.device(x, np.full(n, speed), 1 / fs, v), th)["force"]  # noqa: E731
    return run(volt) - run(np.zeros(n))


def test_field_decay_rises_at_eta_and_falls_at_r_d_eta():
    """A command pulse: the field lag's half-rise time is ln 2/η, its half-decay time ln 2/(r_d·η)."""
    n = 1200
    volt = np.where((np.arange(n) >= 100) & (np.arange(n) < 600), 2.0, 0.0)
    share = _command_share("dahl+voltage_dependence+field_decay", {**VD, "r_d": 0.25}, volt)
    rise = int(np.argmax(share > 0.5 * share[599])) - 100
    fall = int(np.argmax(share[600:] < 0.5 * share[599]))
    assert rise == pytest.approx(1e3 * np.log(2) / 50.0, abs=1.5)  # 13.9 ms for η = 50 /s
    assert fall == pytest.approx(1e3 * np.log(2) / (0.25 * 50.0), abs=1.5)  # 55.5 ms at r_d = 0.25
    sym = _command_share("dahl+voltage_dependence", VD, volt)
    np.testing.assert_allclose(share[:600], sym[:600], atol=1e-9 * share[599])  # the rise is untouched


def test_command_saturation_saturates_every_field_dependent_coefficient():
    """At a held command the command's share is (a_v·F_d + c_v·ẋ)·u_s·tanh(v/u_s): strength and viscous term."""
    volt = np.full(800, 2.0)
    vals = {**VD, "u_s": 0.8}
    share = _command_share("dahl+voltage_dependence+command_saturation", vals, volt)
    f_d = get_model("dahl").theta("device", {})[get_model("dahl").param_names("device").index("F_d")]
    expect = (VD["a_v"] * f_d + VD["c_v"] * 0.05) * 0.8 * np.tanh(2.0 / 0.8)
    assert share[-1] == pytest.approx(expect, rel=1e-6)


def test_shear_thinning_and_stribeck_follow_their_equations():
    """A device test at constant velocities: the added force is the equation's, in both directions."""
    fs = 1000.0
    for v in (-0.3, -0.004, 0.001, 0.02, 0.3):
        x = v * np.arange(400) / fs
        inputs = Inputs.device(x, np.full(400, v), 1 / fs)
        p = {"c_p": 300.0, "m_hb": 0.4, "v_p": 0.01}
        y0, y1 = _with("dahl", "shear_thinning", "device", p, inputs)
        hb = p["c_p"] * p["v_p"] * np.sign(v) * ((1 + abs(v) / p["v_p"]) ** p["m_hb"] - 1) / p["m_hb"]
        assert y1[-1] - y0[-1] == pytest.approx(hb, rel=1e-9)
        p = {"F_st": 8.0, "v_s": 0.005}
        y0, y1 = _with("dahl", "stribeck_friction", "device", p, inputs)
        sf = p["F_st"] * np.exp(-(v / p["v_s"]) ** 2) * np.tanh(v / (0.1 * p["v_s"]))
        assert y1[-1] - y0[-1] == pytest.approx(sf, rel=1e-9)


@pytest.mark.parametrize("form", ["normalized-bouc-wen", "dahl", "lugre", "bouc-wen", "spencer"])
def test_every_new_effect_composes_with_every_form(form):
    """FORM+EFFECT simulates in device and structure tests; where it cannot apply, a clear error."""
    dev, st = device_inputs(0.01, n=400), structure_inputs(3.0, MASS, n=400)
    for effect in NEW:
        for kind, inputs in (("device", dev), ("structure", st)):
            name = f"{form}+{effect}"
            if effect in ON_COMMAND and form != "spencer":
                with pytest.raises(ValueError, match="command path"):
                    get_model(name).param_names(kind)
                name = f"{form}+voltage_dependence+{effect}"
            if effect == "inertia" and kind != "device":
                with pytest.raises(ValueError, match="device tests only"):
                    get_model(name).layout(kind)
                continue
            m = get_model(name)
            sim = simulate(m, inputs, m.theta(kind))
            assert sim.ok.all(), name
            assert len(m.state_names(kind)) == m.layout(kind)[5], name  # L_NS


def test_diagnose_offers_the_new_effects_only_where_they_apply():
    rec, _ = hidden_record("structure", "field_dynamics", 0.01, duration=1.0)
    plain = {e.name for e in applicable(get_model("dahl"), rec)}
    commanded = {e.name for e in applicable(get_model("dahl+voltage_dependence"), rec)}
    assert {"shear_thinning", "stribeck_friction"} <= plain
    assert not plain & {*ON_COMMAND, "inertia"}
    assert set(ON_COMMAND) - set(COMPARED_LAWS) <= commanded and "inertia" not in commanded
    assert not commanded & set(COMPARED_LAWS)  # current laws are compared across a matrix, not screened
    dev, _ = hidden_record("device", None, duration=1.0)
    assert "inertia" in {e.name for e in applicable(get_model("dahl"), dev)}


def test_the_ukf_engine_refuses_inertia_clearly():
    from bayes_mr.inference.ukf.filter import make_problem
    from bayes_mr.likelihood.output_error import OutputError

    rec, _ = hidden_record("device", "inertia", 1.0, duration=1.0)
    with pytest.raises(ValueError, match="inertia"):
        make_problem(OutputError(get_model("dahl+inertia"), rec))


# --- diagnose: hidden effects named, clean records none ---------------------------------------

#: One device case per effect by default (a device diagnose is ~4× cheaper than a structure one);
#: the structure cases, the other magnitude and seed are in the slow matrix.
DEFAULT = [
    ("device", "shear_thinning", 1, 0),
    ("device", "stribeck_friction", 1, 0),
    ("device", "inertia", 0, 1),
    ("device", "command_saturation", 1, 0),
    ("device", "field_dynamics", 1, 1),
    ("device", "field_decay", 1, 0),
]
FULL = effect_cases(STRUCTURE_MAGNITUDES, DEVICE_MAGNITUDES, DEFAULT)


def _diagnose_case(case) -> tuple[dict, str]:
    kind, effect, magnitude, seed = case
    table = STRUCTURE_MAGNITUDES if kind == "structure" else DEVICE_MAGNITUDES
    rec, base = hidden_record(kind, effect, table[effect][magnitude], seed=seed)
    return diagnose(rec, base, progress=False).to_dict(), effect


@pytest.mark.parametrize("case", DEFAULT, ids=case_id)
def test_new_hidden_effect_is_named_and_gains(case):
    out, effect = _diagnose_case(case)
    assert not naming_failures(out, effect, THRESHOLD, top_first=False)


@pytest.mark.slow
@pytest.mark.parametrize("case", FULL, ids=case_id)
def test_new_hidden_effect_is_named_and_gains_full_matrix(case):
    out, effect = _diagnose_case(case)
    assert not naming_failures(out, effect, THRESHOLD, top_first=False)


def test_clean_commanded_record_gives_none():
    """A clean dahl+voltage_dependence record under a stepped command: the command-path effects stay quiet."""
    rec, base = hidden_record("device", None, seed=11, commanded=True)
    out = diagnose(rec, base, progress=False).to_dict()
    assert out["cause"] == NONE, out["causes"][:2]


CLEAN_SLOW = [(k, c, s) for k in ("structure", "device") for c in (False, True) for s in (12, 13)]


@pytest.mark.slow
@pytest.mark.parametrize("case", CLEAN_SLOW, ids=lambda c: f"{c[0]}-{'vd' if c[1] else 'dahl'}-s{c[2]}")
def test_clean_record_gives_none_with_the_new_vocabulary(case):
    """Clean dahl (and dahl+voltage_dependence) records of several seeds: none of the larger vocabulary passes."""
    kind, commanded, seed = case
    rec, base = hidden_record(kind, None, seed=seed, commanded=commanded)
    out = diagnose(rec, base, progress=False).to_dict()
    assert out["cause"] == NONE, out["causes"][:2]
    assert all(c["score"] is None or c["score"] <= THRESHOLD for c in out["causes"])
