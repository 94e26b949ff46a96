"""Several records, one likelihood: the sum over records, and a set of one record is that record to the bit."""

import json

import numpy as np
import pytest
from golden.cases import _device, estimator

from bayes_mr.data.records import RecordSet
from bayes_mr.inference.identify import Identify, LeastSquares, validate, validate_records
from bayes_mr.inference.lsq.joint import fit_joint
from bayes_mr.inference.results import summary_of
from bayes_mr.likelihood.joint import JointLikelihood
from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.models import get_model
from bayes_mr.signals import make_signal
from bayes_mr.simulation.simulate import synthesize

MODEL = "dahl+force_offset"


@pytest.fixture(scope="module")
def rec():
    return _device()


@pytest.fixture(scope="module")
def noisier():
    """The golden device test's truth under another motion, with 3 % noise (another noise floor)."""
    model = get_model(MODEL)
    sig = make_signal("blwn", duration=2.0, fs=500.0, amplitude=0.008, fmax=5.0, seed=5)
    theta = model.theta("device", {"c": 800.0, "k": 300.0, "F_d": 200.0, "sigma": 3000.0, "f0": -60.0})
    return synthesize(model, theta, sig.time, sig.as_input("device"), noise=0.03, seed=6, source="noisier")


def _points(lik):
    lo, hi = lik.lower, lik.upper
    return np.vstack([0.5 * (lo + hi), 0.3 * lo + 0.7 * hi, 0.8 * lo + 0.2 * hi])


def test_one_record_is_that_record(rec):
    one, joint = OutputError(MODEL, rec), JointLikelihood(MODEL, [rec])
    x = _points(one)
    assert joint.names == one.names and joint.ndim == one.ndim
    np.testing.assert_array_equal(joint.lower, one.lower)
    np.testing.assert_array_equal(joint.upper, one.upper)
    np.testing.assert_array_equal(joint(x), one(x))
    np.testing.assert_array_equal(joint.log_likelihood(x), one.log_likelihood(x))


def test_two_copies_double_the_log_likelihood(rec):
    one, two = OutputError(MODEL, rec), JointLikelihood(MODEL, [rec, rec])
    x = _points(one)
    x2 = np.hstack([x, x[:, one.n_params:]])  # the same σ for both copies
    assert two.ndim == one.ndim + 1 and two.names[-2:] == ("sigma_force[0]", "sigma_force[1]")
    np.testing.assert_array_equal(two.log_likelihood(x2), 2 * one.log_likelihood(x))
    np.testing.assert_array_equal(two.per_record(x2), np.column_stack([one.log_likelihood(x)] * 2))
    np.testing.assert_allclose(two.log_prior(x2) - one.log_prior(x), -float(np.sum(one.log_sigma_hi - one.log_sigma_lo)))


def test_one_record_fit_gives_todays_numbers(rec):
    plain = summary_of(Identify(MODEL, LeastSquares()).fit(rec, progress=False)).to_dict()
    for data in ([rec], RecordSet((rec,))):
        joint = summary_of(Identify(MODEL, LeastSquares()).fit(data, progress=False)).to_dict()
        plain.pop("wall_s", None), joint.pop("wall_s")
        assert joint == plain


def test_one_record_chain_gives_todays_numbers(rec):
    plain = summary_of(Identify(MODEL, estimator("mcmc")).fit(rec, progress=False)).to_dict()
    joint = summary_of(Identify(MODEL, estimator("mcmc")).fit([rec], progress=False)).to_dict()
    for s in (plain, joint):
        s.pop("wall_s")
        s.pop("evidence_routes")  # each route's own wall time
    assert joint == plain


def test_two_records_share_parameters_and_keep_their_noise(rec, noisier):
    lik = JointLikelihood(MODEL, [rec, noisier])
    res = fit_joint(lik)
    truth = {"c": 800.0, "F_d": 200.0, "sigma": 3000.0, "f0": -60.0}
    for name, value in truth.items():
        assert abs(res.theta[name] - value) < 4 * res.sd_theta[name] + 0.01 * abs(value), name
    sd0, sd1 = res.sigma  # each record's ML noise SD [N]: the 3 % record's is the larger
    assert sd1 > 1.5 * sd0
    assert res.log_likelihood == pytest.approx(float(lik.log_likelihood(lik.joint_x(res.phi, res.sigma))[0]),
                                               rel=1e-9)


def test_two_record_result_has_the_record_dimension(rec, noisier):
    idata = Identify(MODEL, LeastSquares(n_draws=200)).fit(RecordSet((rec, noisier), ({"current": 0.5}, {})),
                                                           progress=False)
    s = summary_of(idata).to_dict()
    assert s["n_records"] == 2 and [r["file"] for r in s["records"]] == ["golden-device", "noisier"]
    assert s["records"][0]["conditions"] == {"current": 0.5}
    assert set(s["sigma"]) == {"force[0]", "force[1]"}
    n = [r["n_valid"] for r in s["records"]]
    assert s["mse"] == pytest.approx((n[0] * s["records"][0]["mse"] + n[1] * s["records"][1]["mse"]) / sum(n))
    ll = idata.log_likelihood
    assert ll["per_record"].dims == ("chain", "draw", "record") and ll.sizes["record"] == 2
    assert set(np.unique(ll["obs_record"].values)) == {0, 1}
    assert idata.posterior_predictive.sizes["time"] == rec.sizes["time"] + noisier.sizes["time"]
    assert list(np.unique(idata.observed_data["record"].values)) == [0, 1]


def test_validate_pools_the_records(rec):
    idata = Identify(MODEL, LeastSquares(n_draws=50)).fit(rec, progress=False)
    one = validate(idata, rec)
    both = validate_records(idata, [rec, rec])
    assert both["n_records"] == 2 and len(both["records"]) == 2
    for key in ("mse", "force_nrmse"):
        assert both[key] == pytest.approx(one[key], rel=1e-12)
    assert both["rmse"]["force"] == pytest.approx(one["rmse"]["force"], rel=1e-12)


def test_emcee_on_two_records(rec):
    idata = Identify(MODEL, estimator("mcmc")).fit([rec, rec], progress=False)
    s = summary_of(idata).to_dict()
    assert s["engine"] == "mcmc" and s["n_records"] == 2 and set(s["sigma"]) == {"force[0]", "force[1]"}
    assert idata.log_likelihood["per_record"].sizes["record"] == 2


def test_ukf_filters_the_records_in_turn(rec, noisier):
    """One filter run over both records: the states restart at the second's first sample, the parameters carry."""
    idata = Identify(MODEL, estimator("ukf")).fit([rec, noisier], progress=False)
    s = summary_of(idata).to_dict()
    training = idata["ukf_training"]
    assert s["engine"] == "ukf" and s["n_records"] == 2 and s["trained"] > 0
    assert json.loads(training.attrs["record_starts"]) == [0, rec.sizes["time"]]
    assert " + " in s["validated_on"]  # runs chosen by their MSE pooled over both records
    truth = {"c": 800.0, "F_d": 200.0, "f0": -60.0}
    for name, value in truth.items():
        assert abs(s["point"][name] - value) < 0.05 * abs(value), name
    assert idata.log_likelihood["per_record"].sizes["record"] == 2


def test_ar_orders_are_chosen_per_record(rec, noisier):
    lik = JointLikelihood(MODEL, [rec, noisier], residual="ar")
    res = fit_joint(lik)
    assert all(p.residual.resolved for p in lik.parts)
    assert res.evidence_terms.sigma_counts.size == 2  # one ln σ integral per record and channel
    assert np.isfinite(res.log_evidence)
    s = summary_of(Identify(MODEL, LeastSquares(n_draws=50), noise="ar").fit([rec, noisier], progress=False)).to_dict()
    assert set(s["ar_coef"]) == {"force[0]", "force[1]"} and all(r["noise_model"].startswith("ar(") for r in s["records"])


def test_a_constant_current_matrix_identifies_the_current_law():
    """Tests at 0 A and 1 A (the current given as a condition) separate F_d from its current factor 1 + a_v·u,
    which one constant-current record confounds (it sees only F_d·(1 + a_v·I))."""
    from bayes_mr.data.records import with_constant_command

    model = get_model("dahl+voltage_dependence")
    truth = {"c": 800.0, "k": 300.0, "F_d": 200.0, "sigma": 3000.0, "a_v": 2.0, "c_v": 400.0, "eta": 50.0}
    recs = []
    for i, current in enumerate((0.0, 1.0)):
        sig = make_signal("blwn", duration=2.0, fs=500.0, amplitude=0.01, fmax=5.0, seed=3 + i)
        inputs = {**sig.as_input("device"), "current": np.full(sig.time.size, current)}
        rec = synthesize(model, model.theta("device", truth), sig.time, inputs, noise=0.01, seed=4 + i,
                         source=f"{current} A")
        recs.append(with_constant_command(rec.drop_vars("current"), {"current": current}))
    alone = fit_joint(JointLikelihood(model, recs[1:], fixed={"eta": 50.0}))
    both = fit_joint(JointLikelihood(model, recs, fixed={"eta": 50.0}))
    assert alone.theta["F_d"] * (1 + alone.theta["a_v"]) == pytest.approx(600.0, rel=0.02)
    assert abs(alone.theta["F_d"] - 200.0) > 100.0  # one current: the split is the prior's, not the data's
    for name in ("F_d", "a_v", "c_v", "c"):
        assert abs(both.theta[name] - truth[name]) < 3 * both.sd_theta[name] + 0.005 * truth[name], name
