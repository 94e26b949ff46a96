"""A force offset per record: a nuisance of each test, estimated with the shared parameters by least squares and
emcee, profiled on a record a fit predicts, refused by the UKF; one record's is its MODEL+force_offset fit."""

import numpy as np
import pytest
from golden.cases import _device, estimator

from bayes_mr.data.records import RecordSet
from bayes_mr.inference.identify import Identify, LeastSquares, validate_records
from bayes_mr.inference.lsq.joint import fit_joint
from bayes_mr.inference.results import summary_of
from bayes_mr.likelihood.joint import JointLikelihood
from bayes_mr.likelihood.output_error import OutputError, record_scales
from bayes_mr.models import get_model
from bayes_mr.simulation.simulate import synthesize

TRUTH = {"c": 800.0, "k": 300.0, "F_d": 200.0, "sigma": 3000.0}
#: (amplitude [m], frequency [Hz], force offset [N]) of three sine tests, 3 s at 500 Hz, 1 % noise
TESTS = ((0.005, 2.0, 15.0), (0.005, 4.0, -10.0), (0.01, 1.0, 5.0))


def _test(i: int, amp: float, freq: float, f0: float):
    model = get_model("dahl+force_offset")
    t = np.arange(1500) / 500.0
    w = 2 * np.pi * freq
    inputs = {"displacement": amp * np.sin(w * t), "velocity": amp * w * np.cos(w * t)}
    return synthesize(model, model.theta("device", dict(TRUTH, f0=f0)), t, inputs, noise=0.01, seed=40 + i,
                      source=f"t{i}")


@pytest.fixture(scope="module")
def three_tests():
    return RecordSet(tuple(_test(i, *spec) for i, spec in enumerate(TESTS)), record_offsets=True)


def test_offsets_are_labelled_per_record_with_their_own_prior(three_tests):
    lik = JointLikelihood("dahl", three_tests)
    assert lik.record_offsets and lik.names[:7] == ("c", "k", "F_d", "sigma", "f0[0]", "f0[1]", "f0[2]")
    # each offset's flat prior spans ± its own record's force scale (not the set's largest)
    lo, hi = lik.par.coords.lower[4:], lik.par.coords.upper[4:]
    np.testing.assert_allclose(lo, -hi)
    np.testing.assert_allclose(hi, [record_scales(rec).force for rec in three_tests], rtol=1e-12)
    assert len(set(hi)) == 3
    for r, part in enumerate(lik.parts):
        assert part.model.name == "dahl+force_offset"
        assert part.ranges["f0"] == pytest.approx((lo[r], hi[r]))
    # off by default for a list of records: today's likelihood
    assert not JointLikelihood("dahl", list(three_tests)).record_offsets
    with pytest.raises(ValueError, match="drop \\+force_offset"):
        JointLikelihood("dahl+force_offset", three_tests)


def test_least_squares_recovers_every_offset(three_tests):
    lik = JointLikelihood("dahl", three_tests)
    res = fit_joint(lik)
    for r, (_, _, f0) in enumerate(TESTS):
        name = f"f0[{r}]"
        assert abs(res.theta[name] - f0) < 3 * res.sd_theta[name], (name, res.theta[name], res.sd_theta[name])
    for name in ("c", "F_d", "sigma"):
        assert abs(res.theta[name] - TRUTH[name]) < 3 * res.sd_theta[name] + 0.01 * TRUTH[name], name
    # the Laplace log-likelihood is the joint likelihood's at the optimum (each record read at its own offset)
    assert res.log_likelihood == pytest.approx(float(lik.log_likelihood(lik.joint_x(res.phi, res.sigma))[0]),
                                               rel=1e-9)
    # the result: the shared model, every offset, each record scored at its own
    s = summary_of(Identify("dahl", LeastSquares(n_draws=100)).fit(three_tests, progress=False)).to_dict()
    assert s["model"] == "dahl" and s["record_offsets"] and {"f0[0]", "f0[1]", "f0[2]"} <= set(s["params"])
    assert all(r["force_nrmse"] < 0.02 for r in s["records"])


def test_emcee_recovers_every_offset(three_tests):
    idata = Identify("dahl", estimator("mcmc")).fit(three_tests, progress=False)
    s = summary_of(idata).to_dict()
    for r, (_, _, f0) in enumerate(TESTS):
        name = f"f0[{r}]"
        assert abs(s["params"][name] - f0) < 3 * s["params_sd"][name], (name, s["params"][name], s["params_sd"][name])
    assert idata.log_likelihood["per_record"].sizes["record"] == 3


def test_one_record_with_its_offset_is_its_force_offset_fit():
    rec = _device()
    plain = summary_of(Identify("dahl+force_offset", LeastSquares()).fit(rec, progress=False)).to_dict()
    one = summary_of(Identify("dahl", LeastSquares()).fit(RecordSet((rec,), record_offsets=True),
                                                          progress=False)).to_dict()
    plain.pop("wall_s"), one.pop("wall_s")
    assert one == plain
    # and its likelihood is that record's, to the bit
    x = np.vstack([0.5 * (OutputError("dahl+force_offset", rec).lower + OutputError("dahl+force_offset", rec).upper)])
    lik = JointLikelihood("dahl", RecordSet((rec,), record_offsets=True))
    np.testing.assert_array_equal(lik(x), OutputError("dahl+force_offset", rec)(x))


def test_the_ukf_refuses_record_offsets(three_tests):
    with pytest.raises(ValueError, match="UKF does not estimate per-record force offsets"):
        Identify("dahl", estimator("ukf")).fit(three_tests, progress=False)


def test_a_predicted_test_gets_its_own_offset(three_tests):
    train = RecordSet(three_tests.records[:2], record_offsets=True)
    idata = Identify("dahl", LeastSquares(n_draws=50)).fit(train, progress=False)
    held = [three_tests[2], three_tests[2]]
    profiled = validate_records(idata, held)  # the fit had offsets: each predicted record's is profiled on it
    assert profiled["records"][0]["force_nrmse"] < 0.02 and "record_offset" not in profiled
    assert [r["record_offset"] for r in profiled["records"]] == pytest.approx([5.0, 5.0], abs=0.5)
    assert validate_records(idata, [three_tests[2]])["record_offset"] == pytest.approx(5.0, abs=0.5)
    bare = validate_records(idata, held, record_offsets=False)  # no offset: 5 N missed
    assert bare["force_nrmse"] > 1.2 * profiled["force_nrmse"]
