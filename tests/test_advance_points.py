"""RK4 stage by stage across points (models.integrate.advance_points) gives advance's numbers, point by point:
bit for bit where the form has no power |z|ⁿ, to rounding where the points' powers come from the vectorised
pow (models.power) instead of the C library's."""

import numpy as np
import pytest

from bayes_mr.models import get_model, integrate, kernel, power
from bayes_mr.models.forms import FORMS
from test_kernel_forces import FORCE_EFFECTS

#: Each form alone and under every force-changing effect and the two updates between sub-steps (the coil's lag and
#: the amplitude envelope), less those a form models itself.
EFFECTS = (*FORCE_EFFECTS, "field_dynamics")
WITH_EFFECTS = ["+".join([f, *(e for e in EFFECTS if e not in FORMS[f].built_in)]) for f in FORMS]


def _inputs(t):
    """A 2 Hz, 1 cm stroke at 1 V (device and forced tests) or ground motion (structure test) at time t."""
    w = 2.0 * np.pi * 2.0
    return np.array([0.01 * np.sin(w * t), 0.01 * w * np.cos(w * t), 1.0])


def _points(model, kind, cst, rng, n_pts, t):
    """Parameters near the model's defaults and states near those of a 2 Hz stroke at time t, ``n_pts`` points.

    The states come from integrating the stroke from rest (fine RK4 steps), so a hysteretic state sits on its
    branch where the piston moves: the intervals on which a device test's ROS2 step passes its error test."""
    lay = model.layout(kind)
    theta = model.theta(kind, {})
    ns = int(lay[kernel.L_NS])
    s = np.zeros(ns)
    work = np.zeros(integrate.work_shape(ns))
    h = 1e-3
    for k in range(int(t / h)):
        k1 = np.zeros(ns)
        kernel.deriv(lay, cst, theta, k * h, _inputs(k * h), s, k1)
        integrate.advance(lay, cst, theta, k * h, h, _inputs(k * h), _inputs((k + 1) * h), s, k1, 20,
                          integrate.RK4, work)
    TH = theta * np.exp(0.05 * rng.standard_normal((n_pts, theta.size)))
    X = np.zeros((n_pts, ns + 4))  # wider than the states, as a UKF's augmented sigma points are
    X[:, :ns] = s * (1.0 + 0.01 * rng.standard_normal((n_pts, ns)))
    return lay, ns, TH, X


@pytest.mark.parametrize("kind", ["structure", "device", "forced"])
@pytest.mark.parametrize("name", [*FORMS, *WITH_EFFECTS])
def test_advance_points_equals_advance_of_each_point(name, kind):
    """With ROS2 tried (a device test's stiff intervals: n_sub above K_STIFF) and its error scale carried from
    interval to interval in the shared scratch. Dahl and LuGre bit for bit; the Bouc–Wen family within 1e-12 of
    the states' scale (a 1-ulp power through ≤ 8 RK4 sub-steps; mostly bit for bit still, as h·ż is far smaller
    than z and an ulp of ż rarely reaches the sum). Largest gap seen: 2.1e-13 on an AMD Zen 3 (AVX2) machine, whose
    compiled power rounds otherwise than on the machine where 1e-13 held."""
    model = get_model(name)
    cst = model.constants(50.0)
    rng = np.random.default_rng(11)
    n_pts = 7
    taken_any = []
    has_power = kernel.power_slot(model.layout(kind))[0] >= 0
    work_one = np.zeros(integrate.work_shape(int(model.layout(kind)[kernel.L_NS])))
    work_all = work_one.copy()
    for trial in range(8):
        t = rng.uniform(0.1, 0.5)
        lay, ns, TH, X = _points(model, kind, cst, rng, n_pts, t)
        h = (1e-3, 1e-2)[trial % 2]
        n_sub = (1, 3, 5, 8)[trial % 4]
        a0, a1 = _inputs(t), _inputs(t + h)
        K1 = np.zeros((n_pts, ns))
        for i in range(n_pts):
            kernel.deriv(lay, cst, TH[i], t, a0, X[i, :ns], K1[i])
        want = X.copy()
        want_taken = []
        for i in range(n_pts):
            s = want[i, :ns].copy()
            n_ros2 = integrate.advance(lay, cst, TH[i], t, h, a0, a1, s, K1[i].copy(), n_sub, integrate.DECIDE,
                                       work_one)
            want_taken.append(n_ros2 > 0)  # ROS2's step count (0: RK4)
            want[i, :ns] = s
        taken = np.zeros(n_pts, np.bool_)
        stages = np.zeros((n_pts, 3, ns))
        got = X.copy()
        pw = np.ones((3, 8))
        integrate.advance_points(lay, cst, TH, t, h, a0, a1, got, K1.copy(), n_pts, n_sub, work_all, stages, taken,
                                 pw)
        if has_power:
            fin = np.isfinite(want)  # a stiff interval RK4 cannot take blows up the same way in both
            np.testing.assert_array_equal(np.isfinite(got), fin)
            scale = np.maximum(np.abs(np.where(fin, want, 0.0)).max(axis=0), 1e-300)
            gap = np.where(fin, np.abs(got - want), 0.0) / scale  # per state, in its scale
            assert gap.max() <= 1e-12, f"largest difference {gap.max():.2e} of the state's scale"
        else:
            np.testing.assert_array_equal(got, want)
        assert list(taken) == want_taken
        taken_any += want_taken
    if kind == "device" and model.form.ros2:
        assert any(taken_any) and not all(taken_any)  # both methods met
    else:
        assert not any(taken_any)


@pytest.mark.parametrize("name", ["normalized-bouc-wen", "bouc-wen", "spencer", "dahl"])
def test_point_powers_are_the_stage_states_powers(name):
    """point_powers gives |z|ⁿ of each point's RK4 stage state (z + step·k of the stage before), within 1 ulp of
    math.pow, for points not taken by ROS2; -1 where the form has no power; the padding left at 1."""
    model = get_model(name)
    lay = model.layout("device")
    cst = model.constants(50.0)
    rng = np.random.default_rng(5)
    n_pts = 5
    lay, ns, TH, X = _points(model, "device", cst, rng, n_pts, 0.3)
    K1 = rng.standard_normal((n_pts, ns))
    stages = rng.standard_normal((n_pts, 3, ns))
    taken = np.array([False, True, False, False, False])
    iz, ip = kernel.power_slot(lay)
    for st, step in ((0, 0.0), (1, 1e-3), (2, 1e-3), (3, 2e-3)):
        pw = np.full((3, 8), 7.0)
        power.point_powers(lay, TH, X, K1, stages, st, step, n_pts, taken, pw)
        if iz < 0:
            assert (pw[0, :n_pts] == -1.0).all()
            continue
        k = K1 if st <= 1 else stages[:, st - 2]
        z = X[:, iz] if st == 0 else X[:, iz] + step * k[:, iz]
        want = np.abs(z) ** TH[:, ip]
        free = ~taken
        np.testing.assert_allclose(pw[0, :n_pts][free], want[free], rtol=2.3e-16, atol=0.0)
        assert (pw[:, n_pts:] == 1.0).all() and (pw[:, 1] == 1.0).all()  # padding and the taken point: 1¹
