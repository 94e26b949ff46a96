"""The current laws beside the linear one: a constant-current matrix identifies them, one current cannot.

At one constant current I a record sees the field-dependent force only through F_d·(1 + a_v·g(I)) and
c + c_v·g(I): the law g's shape and the gains are one product. Tests at several currents separate them; a
fit of one reports the law's parameters at about their prior's width (the direction the record does not
move), not a false precision.
"""

import numpy as np
import pytest

from bayes_mr.data.records import with_constant_command
from bayes_mr.inference.lsq.joint import fit_joint
from bayes_mr.likelihood.joint import JointLikelihood
from bayes_mr.models import get_model
from bayes_mr.signals import make_signal
from bayes_mr.simulation.simulate import synthesize

BASE = {"c": 800.0, "k": 300.0, "F_d": 200.0, "sigma": 3000.0, "a_v": 2.0, "c_v": 400.0, "eta": 50.0}
#: law → (its parameters' truth, g(u) at those, the constant currents [A] of the matrix). A cubic's two
#: coefficients beside the linear gain need three non-zero currents; a one-parameter saturation, two.
LAWS = {
    "exponential_saturation": ({"u_e": 0.5}, lambda u, p: np.sign(u) * p["u_e"] * (1 - np.exp(-abs(u) / p["u_e"])),
                               (0.0, 0.5, 1.0)),
    "command_polynomial": ({"b2": -0.6, "b3": 0.2}, lambda u, p: u * (1 + p["b2"] * u + p["b3"] * u * u),
                           (0.0, 0.4, 0.7, 1.0)),
}


def _matrix(law):
    """Band-limited white-noise tests of one damper, 2 s at 500 Hz each, 1 % noise, the current a condition."""
    model = get_model(f"dahl+voltage_dependence+{law}")
    own, _, currents = LAWS[law]
    truth = {**BASE, **own}
    recs = []
    for i, current in enumerate(currents):
        sig = make_signal("blwn", duration=2.0, fs=500.0, amplitude=0.01, fmax=5.0, seed=3 + i)
        inputs = {**sig.as_input("device"), "current": np.full(sig.time.size, current)}
        rec = synthesize(model, model.theta("device", truth), sig.time, inputs, noise=0.01, seed=4 + i,
                         source=f"{current} A")
        recs.append(with_constant_command(rec.drop_vars("current"), {"current": current}))
    return model, truth, recs


@pytest.fixture(scope="module", params=list(LAWS))
def matrix(request):
    return (request.param, *_matrix(request.param))


def test_a_constant_current_matrix_recovers_the_law(matrix):
    law, model, truth, recs = matrix
    fit = fit_joint(JointLikelihood(model, recs, fixed={"eta": 50.0}))  # constant currents: the lag is a start-up
    for name in ("F_d", "a_v", "c_v", "c", *LAWS[law][0]):
        assert abs(fit.theta[name] - truth[name]) < 3 * fit.sd_theta[name], name
    for name in LAWS[law][0]:
        assert fit.sd_theta[name] < 0.1 * abs(truth[name]), name


def test_one_current_reports_the_law_unidentified(matrix):
    law, model, truth, recs = matrix
    own, g, currents = LAWS[law]
    fit = fit_joint(JointLikelihood(model, recs[-1:], fixed={"eta": 50.0}))

    def seen(p):  # what the one current fixes: the yield force there
        return p["F_d"] * (1 + p["a_v"] * g(currents[-1], p))

    assert seen(fit.theta) == pytest.approx(seen(truth), rel=0.02)
    for name in own:  # the split of that product is not the record's: its SD says so
        assert fit.sd_theta[name] > 0.5 * abs(truth[name]), name


def test_each_law_at_its_off_value_is_the_linear_law():
    """b2 = b3 = 0, and u_e far above the command: the model of the linear law, under a varying command."""
    from bayes_mr.inference.identify import predict

    base = get_model("dahl+voltage_dependence")
    sig = make_signal("blwn", duration=1.0, fs=500.0, amplitude=0.01, fmax=5.0, seed=3)
    current = 0.5 + 0.5 * np.sin(2 * np.pi * 1.5 * sig.time)
    rec = synthesize(base, base.theta("device", BASE), sig.time, {**sig.as_input("device"), "current": current},
                     noise=0.01, seed=4)
    linear = predict(base, rec, BASE)["force"]
    poly = predict("dahl+voltage_dependence+command_polynomial", rec, {**BASE, "b2": 0.0, "b3": 0.0})["force"]
    assert np.array_equal(poly, linear)
    far = predict("dahl+voltage_dependence+exponential_saturation", rec, {**BASE, "u_e": 1e6})["force"]
    assert np.allclose(far, linear, rtol=1e-5, atol=1e-6 * np.abs(linear).max())
