"""identify: one entry for the estimators — names, a least-squares fit end to end, prediction and
validation on another record (thesis method 2). The estimators themselves are tested in inference/."""

import numpy as np
import pytest
from records import offset_device_record, structure_record

from bayes_mr.inference import results
from bayes_mr.inference.identify import Emcee, Identify, LeastSquares, engine, predict, validate

TRUTH = {"c": 800.0, "k": 300.0, "F_d": 200.0, "sigma": 3000.0, "f0": -60.0}


@pytest.fixture(scope="module")
def fitted():
    return Identify("dahl+force_offset", LeastSquares()).fit(offset_device_record(2.0), seed=0, progress=False)


def test_engine_names():
    assert isinstance(engine("lsq"), LeastSquares) and isinstance(engine("mcmc"), Emcee)
    assert engine("ukf").name == "ukf"
    with pytest.raises(ValueError, match="valid: lsq, ukf, mcmc"):
        engine("bogus")
    with pytest.raises(ValueError, match="evidence"):
        Emcee(evidence="bogus")


def test_a_fit_is_a_result_with_the_contract_keys(fitted):
    s = results.summary_of(fitted).to_dict()
    assert s["model"] == "dahl+force_offset" and s["engine"] == "lsq" and s["kind"] == "device"
    assert set(s["params"]) == set(TRUTH) and s["log_evidence"] is not None and s["wall_s"] > 0
    assert abs(s["params"]["f0"] - TRUTH["f0"]) < 5 * s["params_sd"]["f0"] + 1.0


def test_predict_reproduces_the_result_under_its_own_record(fitted):
    rec = offset_device_record(2.0)
    pred = predict("dahl+force_offset", rec, results.point_of(fitted))
    assert pred["force"].shape == rec["force"].shape
    nrmse = np.sqrt(np.mean((pred["force"] - rec["force"].values) ** 2)) / rec["force"].values.std()
    assert nrmse == pytest.approx(results.summary_of(fitted).force_nrmse, rel=1e-9)


def test_validate_scores_another_record(fitted):
    other = offset_device_record(2.0, seed=7)
    out = validate(fitted, other)
    assert out["validated_on"] == other.attrs["source"] and out["log_evidence"] is None
    assert out["params"] == results.summary_of(fitted).params
    assert 0 < out["force_nrmse"] < 0.1
    rec, _ = structure_record("dahl", {}, n=500)
    with pytest.raises(ValueError, match="device test, the record a structure test"):
        validate(fitted, rec)


def test_validate_keeps_the_parameters_the_fit_held_fixed():
    """A fit with k fixed far from its default predicts another record with that k, not the default."""
    rec, _ = structure_record("dahl", {}, n=1500, seed=3)
    idata = Identify("dahl", LeastSquares(), fixed={"k": 2.2e4}).fit(rec, progress=False)
    summary = results.summary_of(idata)
    assert summary.extra["fixed"] == {"k": 2.2e4}
    assert validate(idata, rec)["mse"] == pytest.approx(summary.mse, rel=1e-9)
