"""A notebook's view: fit, compare and diagnose a record using only ``import bayes_mr as bm``."""

import subprocess
import sys

import numpy as np
import pytest

import bayes_mr as bm


@pytest.fixture(scope="module")
def device_csv(tmp_path_factory):
    """A Dahl device test with a -60 N force offset hidden in it, 2 s at 500 Hz, 1 % noise, as CSV."""
    model = bm.get_model("dahl+force_offset")
    sig = bm.make_signal("blwn", duration=2.0, fs=500.0, amplitude=0.01, fmax=5.0, seed=3)
    theta = model.theta("device", {"c": 800.0, "k": 300.0, "F_d": 200.0, "sigma": 3000.0, "f0": -60.0})
    rec = bm.synthesize(model, theta, sig.time, sig.as_input("device"), noise=0.01, seed=4, source="notebook")
    return bm.write_record(rec, tmp_path_factory.mktemp("nb") / "device.csv")


def test_fit_compare_and_diagnose_through_the_public_face(device_csv, tmp_path):
    record = bm.load(device_csv)
    assert record.attrs["kind"] == "device"

    idata = bm.Identify("dahl+force_offset", bm.LeastSquares()).fit(record, progress=False)
    summary = bm.summary_of(idata)
    assert summary.engine == "lsq" and summary.noise_model == "iid"
    assert abs(summary.params["f0"] + 60.0) < 3 * summary.params_sd["f0"] + 0.5
    assert set(summary.point) == set(summary.params) and summary.rmse["force"] > 0
    back = bm.load_result(bm.save(idata, tmp_path / "fit.nc"))
    assert bm.point_of(back) == pytest.approx(summary.point)
    assert bm.validate(back, record)["mse"] == pytest.approx(summary.mse, rel=1e-9)

    out = bm.compare(record, ["dahl", "dahl+force_offset"], engines=("lsq",), progress=False)
    assert out["selected"] == "dahl+force_offset" and out["bayes_factors"]["dahl"] > 3

    report = bm.diagnose(record, "dahl", progress=False)
    assert report["cause"] == "force_offset" and report["gain"]["mse_ratio"] < 0.5


def test_every_public_name_resolves_and_unknown_names_fail():
    for name in bm.__all__:
        assert getattr(bm, name) is not None
    with pytest.raises(AttributeError, match="no attribute 'fit_everything'"):
        bm.fit_everything  # noqa: B018


def test_estimators_share_one_protocol():
    from bayes_mr.inference.base import Estimator

    for est in (bm.LeastSquares(), bm.Emcee(evidence="laplace"), bm.UKF(n_lhs=1, taus=(0.1,))):
        assert isinstance(est, Estimator) and est.name in ("lsq", "mcmc", "ukf")
    assert isinstance(bm.engine("ukf", n_lhs=2), bm.UKF)


def test_import_is_cheap_and_has_no_side_effects():
    """``import bayes_mr`` loads none of the heavy layers and leaves matplotlib alone."""
    code = ("import sys, bayes_mr; "
            "heavy = [m for m in ('numba', 'matplotlib', 'arviz', 'bayes_mr.inference') if m in sys.modules]; "
            "print(','.join(heavy))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == ""
    np.testing.assert_equal(sorted(bm.__all__), bm.__all__)
