"""A notebook's view: fit, compare and diagnose a record using only ``import bayes_mr as bm``."""

import json
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
    assert out.selected == "dahl+force_offset" and out.bayes_factors["dahl"] > 3

    report = bm.diagnose(record, "dahl", progress=False)
    assert report.cause == "force_offset" and report.gain["mse_ratio"] < 0.5


# --- typed results -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def device_record(device_csv):
    return bm.load(device_csv)


@pytest.fixture(scope="module")
def comparison(device_record):
    return bm.compare(device_record, ["dahl", "dahl+force_offset"], engines=("lsq",), progress=False)


@pytest.fixture(scope="module")
def diagnosis(device_record):
    return bm.diagnose(device_record, "dahl", progress=False, terms=False)


def test_compare_returns_a_comparison_with_its_json_table_figure_and_fits(comparison):
    from matplotlib.figure import Figure

    assert isinstance(comparison, bm.Comparison)
    data = comparison.to_dict()
    assert {"rows", "selected", "bayes_factors", "evidence_route", "evidence_engine", "selected_on",
            "crosscheck"} <= set(data) and "idata" not in data
    assert data is not comparison.to_dict() and data == comparison.to_dict()  # a copy each time
    json.dumps(data)  # JSON as it is
    assert comparison.selected == data["selected"] and comparison.rows == data["rows"]
    assert comparison.models == ["dahl", "dahl+force_offset"] and comparison.engines == ["lsq"]
    assert comparison.evidence_route == "laplace" and comparison.row("dahl", "lsq")["engine"] == "lsq"
    assert set(comparison.idata) == {("dahl", "lsq"), ("dahl+force_offset", "lsq")}
    assert bm.summary_of(comparison.idata["dahl", "lsq"]).model == "dahl"
    table = comparison.table()
    assert list(table["model"]) == ["dahl", "dahl+force_offset"] and "ln BF vs selected" in table
    assert table.loc[table["model"] == "dahl", "ln BF vs selected"].item() == comparison.bayes_factors["dahl"]
    assert isinstance(comparison.plot(), Figure)
    assert "dahl+force_offset" in repr(comparison) and "<table" in comparison._repr_html_()


def test_diagnose_returns_a_diagnosis_with_its_json_table_figure_and_fits(diagnosis):
    from matplotlib.figure import Figure

    assert isinstance(diagnosis, bm.Diagnosis)
    data = diagnosis.to_dict()
    assert {"baseline", "cause", "causes", "selection", "extended", "gain", "unexplained", "verdict"} <= set(data)
    json.dumps(data)
    assert diagnosis.cause == "force_offset" == diagnosis.effects[0]
    assert diagnosis.baseline["model"] == "dahl" and diagnosis.extended["model"] == "dahl+force_offset"
    assert diagnosis.gain == data["gain"] and diagnosis.verdict == data["verdict"] and diagnosis.terms is None
    table = diagnosis.table()
    assert list(table.index) == list(range(1, len(diagnosis.causes) + 1))
    assert list(table["score"]) == [c["score"] for c in diagnosis.causes]
    assert list(table["mse_ratio"]) == [c["mse_ratio"] for c in diagnosis.causes]
    assert table.loc[table["selected"], "effect"].tolist() == ["force_offset"]
    assert isinstance(diagnosis.plot(), Figure)
    assert set(diagnosis.idata) == {"baseline", "extended"}
    assert bm.summary_of(diagnosis.idata["extended"]).model == "dahl+force_offset"
    assert bm.point_of(diagnosis.idata["extended"]) == pytest.approx(diagnosis.extended["params"])


def test_forms_and_effects_are_the_vocabulary_of_model_names():
    assert {"dahl", "lugre", "normalized-bouc-wen", "bouc-wen", "spencer"} <= set(bm.FORMS)
    assert "force_offset" in bm.EFFECTS
    for form in bm.FORMS:
        assert bm.get_model(form).name == form
    assert bm.get_model("dahl+force_offset").effects == (bm.EFFECTS["force_offset"],)


# --- one save/load pair --------------------------------------------------------------------


@pytest.mark.parametrize("suffix", [".csv", ".csv.gz", ".nc"])
def test_save_and_load_a_record_as_write_record_and_the_record_reader_do(device_record, tmp_path, suffix):
    from bayes_mr.data import load as read_record

    path = bm.save(device_record, tmp_path / f"rec{suffix}")
    assert path == bm.write_record(device_record, tmp_path / f"ref{suffix}").with_name(f"rec{suffix}")
    back = bm.load(path)
    assert back.identical(read_record(path))
    np.testing.assert_allclose(back["force"].values, device_record["force"].values, rtol=1e-12, atol=0)
    # the reader's options, as bayes_mr.data.load takes them
    options = bm.load(path, quality=False, trim=True)
    assert options.identical(read_record(path, quality=False, trim=True))
    with pytest.raises(bm.RecordError):
        bm.load(tmp_path / f"missing{suffix}")


def test_save_and_load_an_inference_data(comparison, tmp_path):
    idata = comparison.idata["dahl+force_offset", "lsq"]
    back = bm.load(bm.save(idata, tmp_path / "fit.nc"))
    assert bm.summary_of(back).to_dict() == bm.summary_of(idata).to_dict()
    assert bm.point_of(back) == pytest.approx(bm.point_of(idata))
    with pytest.raises(TypeError, match="options"):
        bm.load(tmp_path / "fit.nc", mass=3.0)


def test_save_and_load_a_comparison_with_its_fits(comparison, tmp_path):
    from bayes_mr.inference.results import _jsonable

    path = bm.save(comparison, tmp_path / "compare.json")
    assert json.loads(path.read_text()) == _jsonable(comparison.to_dict())  # the CLI's JSON
    back = bm.load(path)
    assert isinstance(back, bm.Comparison) and back.to_dict() == json.loads(path.read_text())
    assert back.selected == comparison.selected and back.table().equals(comparison.table())
    assert list(back.idata) == list(comparison.idata)
    for key, idata in comparison.idata.items():
        assert bm.point_of(back.idata[key]) == pytest.approx(bm.point_of(idata))
    bm.save(back, path)  # saving again replaces the fits, leaves no stale file
    assert len(list((tmp_path / "compare.idata").glob("*.nc"))) == 2


def test_save_and_load_a_diagnosis_with_its_fits(diagnosis, tmp_path):
    path = bm.save(diagnosis, tmp_path / "diagnose.json")
    back = bm.load(path)
    assert isinstance(back, bm.Diagnosis) and back.to_dict() == json.loads(path.read_text())
    assert back.cause == diagnosis.cause and back.table().equals(diagnosis.table())
    assert set(back.idata) == {"baseline", "extended"}
    assert bm.point_of(back.idata["extended"]) == pytest.approx(bm.point_of(diagnosis.idata["extended"]))


def test_save_refuses_what_it_does_not_know_and_load_a_json_of_something_else(tmp_path):
    with pytest.raises(TypeError, match="cannot write a dict"):
        bm.save({"a": 1}, tmp_path / "x.json")
    (tmp_path / "other.json").write_text("{}")
    with pytest.raises(ValueError, match="neither a comparison nor a diagnosis"):
        bm.load(tmp_path / "other.json")


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
