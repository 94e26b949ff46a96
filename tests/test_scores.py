"""scores: the thesis's criteria of a prediction (3-44..3-49), their normalisation and the mask.

Predictions here are the record itself shifted by a known error, so every score has an
exact value to compare with: one noise SD of error on every channel is MSE 100 per channel.
"""

import numpy as np
import pytest
from records import offset_device_record, structure_record

from bayes_mr.scores import Scorer, score


@pytest.fixture(scope="module")
def structure():
    rec, _ = structure_record("dahl", {}, n=1500, seed=3, rms=0.6, process=False)
    return rec


@pytest.fixture(scope="module")
def device():
    return offset_device_record(2.0)


def _shifted(rec, channels, k=1.0):
    """Each channel of ``rec`` plus k of its noise SDs."""
    return {c: rec[c].values + k * rec.attrs[f"noise_sd_{c}"] for c in channels}


def test_one_noise_sd_of_error_is_100_per_channel(structure, device):
    pred = _shifted(structure, ("displacement", "acceleration")) | {"force": structure["force"].values}
    assert score(structure, pred)["mse"] == pytest.approx(200.0, rel=1e-12)
    assert score(device, _shifted(device, ("force",), k=2.0))["mse"] == pytest.approx(400.0, rel=1e-12)


def test_force_scores_where_the_force_is_measured(structure, device):
    f = device["force"].values
    out = score(device, {"force": f + 3.0})
    assert out["force_nrmse"] == pytest.approx(3.0 / f.std(), rel=1e-12)
    assert out["force_errors"]["E_t"] == pytest.approx(out["force_nrmse"], rel=1e-12)
    exact = score(structure, {"displacement": structure["displacement"].values,
                              "acceleration": structure["acceleration"].values, "force": structure["force"].values})
    assert exact["mse"] == 0.0 and exact["force_nrmse"] == 0.0
    assert exact["force_errors"] == {"E_t": 0.0, "E_x": 0.0, "E_xdot": 0.0}


def test_masked_samples_are_left_out(device):
    rec = device.copy(deep=True)
    valid = np.ones(rec.sizes["time"], bool)
    valid[100:300] = False
    rec["valid"] = ("time", valid)
    pred = _shifted(rec, ("force",))
    pred["force"][100:300] = np.nan  # anything may sit in a masked sample
    out = score(rec, pred)
    assert out["n"] == valid.sum()
    assert out["mse"] == pytest.approx(100.0, rel=1e-12)


def test_scorer_prepares_once_and_scores_like_score(structure):
    scorer = Scorer(structure)
    pred = _shifted(structure, ("displacement", "acceleration"), k=0.5) | {"force": structure["force"].values}
    assert scorer(pred) == score(structure, pred)
    assert scorer.channels == ("displacement", "acceleration") and scorer.has_force


def test_noise_override_and_bad_predictions(structure, device):
    pred = _shifted(device, ("force",))
    sd = device.attrs["noise_sd_force"]
    assert score(device, pred, noise_sd={"force": 2 * sd})["mse"] == pytest.approx(25.0, rel=1e-12)
    with pytest.raises(ValueError, match="does not use"):
        Scorer(device, noise_sd={"displacement": 1.0})
    with pytest.raises(ValueError, match="lacks"):
        score(structure, {"displacement": structure["displacement"].values})


def test_pooled_scores_are_the_scores_over_every_sample():
    """The pooled force NRMSE, RMSE and MSE of two records equal the scores over their samples together."""
    import xarray as xr

    from bayes_mr.scores.metrics import force_nrmse
    from bayes_mr.scores.pooled import pooled

    rng = np.random.default_rng(3)
    recs, scores, f_all, fh_all = [], [], [], []
    for n, scale in ((400, 1.0), (700, 3.0)):
        f = scale * rng.standard_normal(n) + scale
        fh = f + 0.1 * rng.standard_normal(n)
        valid = np.ones(n, bool)
        valid[::50] = False
        recs.append(xr.Dataset({"force": ("time", f), "valid": ("time", valid)}))
        rmse = float(np.sqrt(np.mean((f - fh)[valid] ** 2)))
        scores.append({"n": int(valid.sum()), "mse": 100 * rmse**2 / 0.01, "rmse": {"force": rmse},
                       "force_nrmse": force_nrmse(f, fh, valid), "force_errors": None})
        f_all.append(f[valid])
        fh_all.append(fh[valid])
    out = pooled(recs, scores)
    f, fh = np.concatenate(f_all), np.concatenate(fh_all)
    assert out["force_nrmse"] == pytest.approx(force_nrmse(f, fh), rel=1e-12)
    assert out["rmse"]["force"] == pytest.approx(float(np.sqrt(np.mean((f - fh) ** 2))), rel=1e-12)
    assert out["mse"] == pytest.approx(100 * float(np.mean((f - fh) ** 2)) / 0.01, rel=1e-12)
    assert out["force_errors"] is None and out["n"] == f.size
