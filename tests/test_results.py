"""results: the one InferenceData schema every estimator writes, its netCDF round trip and the JSON.

Built here from made-up draws on a small record, so the schema is checked apart from any estimator.
"""

import json
import math

import numpy as np
import pytest
import xarray as xr
from records import offset_device_record

from bayes_mr.inference import results
from bayes_mr.inference.base import Posterior

NAMES = ("c", "k", "F_d", "sigma", "f0")
UNITS = ("N·s/m", "N/m", "N", "1/m", "N")


@pytest.fixture(scope="module")
def record():
    return offset_device_record(1.0)


@pytest.fixture(scope="module")
def idata(record):
    rng = np.random.default_rng(0)
    point = np.array([800.0, 300.0, 200.0, 3000.0, -60.0])
    draws = point * (1 + 0.01 * rng.standard_normal((2, 50, 5)))
    summary = results.FitSummary(
        model="dahl+force_offset", engine="lsq", kind="device",
        params=dict(zip(NAMES, draws.reshape(-1, 5).mean(axis=0))),
        params_sd=dict(zip(NAMES, draws.reshape(-1, 5).std(axis=0))),
        log_evidence=-12.5, force_nrmse=0.01, masked=0, wall_s=1.5, extra={"evidence_route": "laplace"},
    )
    n = record.sizes["time"]
    idx = np.arange(0, n, 10)
    post = Posterior(engine="lsq", draws=draws, point=point, x_draws=np.zeros((0, 5)),
                     lp=rng.standard_normal((2, 50)))
    return results.make_inference_data(
        summary, post, NAMES, UNITS, record, log_likelihood={"force": rng.standard_normal((2, 5, idx.size))},
        ll_index=idx, predictive={"force": np.tile(record["force"].values, (2, 3, 1))},
    )


def test_every_group_of_the_schema(idata, record):
    assert {"posterior", "sample_stats", "log_likelihood", "observed_data", "posterior_predictive",
            "constant_data", "point_estimate"} <= set(idata.groups())
    assert list(idata.posterior.data_vars) == list(NAMES)
    assert idata.posterior["k"].attrs["units"] == "N/m"
    assert idata.posterior.sizes == {"chain": 2, "draw": 50}
    np.testing.assert_array_equal(idata.observed_data["force"].values, record["force"].values)
    assert set(idata.constant_data.data_vars) == {"displacement", "velocity", "valid"}
    assert idata.posterior.attrs["model"] == "dahl+force_offset" and idata.posterior.attrs["engine"] == "lsq"


def test_netcdf_round_trip_keeps_summary_and_point(idata, tmp_path):
    path = results.save(idata, tmp_path / "fit.nc")
    assert not list(tmp_path.glob("*.tmp"))
    back = results.load_result(path)
    assert results.summary_of(back).to_dict() == results.summary_of(idata).to_dict()
    assert results.point_of(back) == {"c": 800.0, "k": 300.0, "F_d": 200.0, "sigma": 3000.0, "f0": -60.0}
    np.testing.assert_array_equal(back.posterior["c"].values, idata.posterior["c"].values)


def test_summary_carries_the_contract_fit_keys(idata):
    d = results.summary_of(idata).to_dict()
    assert {"model", "engine", "params", "params_sd", "log_evidence", "mse", "force_errors", "force_nrmse",
            "masked", "trained", "diverged", "wall_s", "point", "rmse", "noise_model"} <= set(d)
    assert d["evidence_route"] == "laplace"  # extras travel beside the fixed keys
    assert results.FitSummary.from_dict(d).to_dict() == d


def test_json_has_no_nan_and_is_written_whole(tmp_path):
    path = results.write_json({"a": math.nan, "b": np.float64(2.0), "c": [np.int64(3), np.inf]}, tmp_path / "o.json")
    assert json.loads(path.read_text()) == {"a": None, "b": 2.0, "c": [3, None]}
    assert not list(tmp_path.glob("*.tmp"))


def test_load_refuses_what_is_not_a_result(tmp_path):
    with pytest.raises(FileNotFoundError, match="bayes-mr fit"):
        results.load_result(tmp_path / "missing.nc")
    other = tmp_path / "other.nc"
    xr.Dataset({"x": ("t", np.arange(3.0))}).to_netcdf(other)
    with pytest.raises(ValueError, match="not a bayes_mr result"):
        results.load_result(other)
