"""What diagnose leaves unexplained: the residual against the noise floor, the verdict, the fits it writes.

``unexplained`` is about 1 on clean simulated records (1 % noise on input and
outputs) and far above 1 when the model misses a term; a term outside the
vocabulary (quadratic damping c2·ẋ|ẋ|, which no effect of the SPEC is) gives
"unexplained by the vocabulary", not "none — the model is right".
"""

import json

import numpy as np
import pytest

from bayes_mr.cli.commands import main
from bayes_mr.data import load
from bayes_mr.diagnosis.diagnose import diagnose
from bayes_mr.diagnosis.fits import fit_model
from bayes_mr.diagnosis.residuals import residual_views
from bayes_mr.diagnosis.unexplained import AT_FLOOR, BEYOND, FLOOR_RATIO, unexplained, verdict, worst_ratio
from bayes_mr.models import NONE
from records import simulated_record


def _fitted_ratios(unexp):
    return {c: u["ratio"] for c, u in unexp.items() if u["in_likelihood"]}


@pytest.mark.parametrize("case", [("structure", "dahl", "blwn", 3), ("device", "lugre", "chirp", 0)],
                         ids=lambda c: "-".join(map(str, c)))
def test_unexplained_is_about_one_on_clean_records(case):
    kind, form, signal, seed = case
    rec = simulated_record(kind, form, signal=signal, seed=seed)
    fit = fit_model(rec, form)
    unexp = unexplained(rec, residual_views(rec, fit.predicted))
    ratios = _fitted_ratios(unexp)
    assert ratios and all(0.8 < r < 1.3 for r in ratios.values()), ratios
    assert verdict([], unexp) == AT_FLOOR
    u = next(iter(unexp.values()))
    assert 0 < u["variance_share"] < 0.05
    # white noise at the floor: about 1 in every band above the excitation (up to its 10 Hz a structure's
    # response to the 1 % process noise, which an output-error model does not follow, adds to it)
    bands = [b["ratio"] for b in u["where"]["frequency"] if b["lo_hz"] >= 20.0]
    assert bands and all(0.7 < r < 1.5 for r in bands), u["where"]["frequency"]


def test_unexplained_is_far_above_one_where_a_term_is_missing():
    rec = simulated_record("device", "dahl", {"force_offset": 20.0}, duration=3.0, seed=1)
    fit = fit_model(rec, "dahl")
    unexp = unexplained(rec, residual_views(rec, fit.predicted))
    assert worst_ratio(unexp) > 10 * FLOOR_RATIO
    assert verdict([], unexp) == BEYOND
    # an effect named while the model stays far above its floor explains only part of the residual
    assert verdict(["force_offset"], unexp) == f"partly explained by force_offset; the rest {BEYOND}"


def stroke_damping_record(seed: int, share: float = 0.3):
    """A dahl device test with a hidden c_x·|x|·ẋ (damping growing with the stroke; c_x sized to ``share`` of the
    force RMS), outside the vocabulary. (A quadratic c2·ẋ|ẋ| was this test's term until ``shear_thinning``
    joined the vocabulary: a Herschel–Bulkley exponent near 2 holds it.)"""
    rec = simulated_record("device", "dahl", duration=4.0, seed=seed)
    clean = simulated_record("device", "dahl", duration=4.0, seed=seed, noise=0.0)
    term = np.abs(clean["displacement"].values) * clean["velocity"].values
    c_x = share * float(np.std(clean["force"].values)) / float(np.std(term))  # N·s/m²
    rec["force"] = rec["force"] + c_x * term
    return rec


def test_a_term_outside_the_vocabulary_is_reported_as_such():
    out = diagnose(stroke_damping_record(seed=3), "dahl", progress=False, terms=False).to_dict()
    assert out["unexplained_ratio"] > 3 * FLOOR_RATIO
    assert not out["at_noise_floor"]
    if out["cause"] == NONE:
        assert out["verdict"] == BEYOND
    else:  # a vocabulary effect took part of it: the rest must still show
        assert out["verdict"].startswith("partly explained by") and out["verdict"].endswith(BEYOND)
    u = out["unexplained"]["force"]
    # stroke damping lives at high speed: the fastest velocity bins carry the largest residual
    vel = u["where"]["velocity"]
    assert max(vel[0]["ratio"], vel[-1]["ratio"]) > 1.5 * min(r["ratio"] for r in vel)


def test_clean_record_verdict_is_at_the_noise_floor():
    out = diagnose(simulated_record("structure", "dahl", signal="blwn", seed=3), "dahl", progress=False).to_dict()
    assert out["cause"] == NONE and out["verdict"] == AT_FLOOR and out["at_noise_floor"]
    assert all(0.8 < r < 1.3 for r in _fitted_ratios(out["unexplained"]).values())
    json.dumps(out, allow_nan=False)


def test_diagnose_out_writes_fits_that_validate_scores(tmp_path):
    """``--out`` writes baseline.nc and extended.nc; ``validate`` scores them as the JSON's ``validation`` says."""
    train = simulated_record("device", "dahl", {"force_offset": 20.0}, duration=3.0, seed=1, voltage=True)
    test = simulated_record("device", "dahl", {"force_offset": 20.0}, duration=3.0, seed=2, voltage=True)
    paths = {}
    for name, rec in (("train", train), ("test", test)):
        paths[name] = tmp_path / f"{name}.csv"
        rec[["displacement", "velocity", "voltage", "force"]].to_dataframe().reset_index().to_csv(paths[name],
                                                                                                  index=False)
    out_dir = tmp_path / "d"
    assert main(["diagnose", str(paths["train"]), "--model", "dahl", "--validate", str(paths["test"]),
                 "--out", str(out_dir), "--json", str(tmp_path / "diag.json"), "--quiet"]) == 0
    diag = json.loads((tmp_path / "diag.json").read_text())
    assert diag["cause"] == "force_offset" and diag["verdict"] == "explained by force_offset"
    v = diag["validation"]
    assert v["extended_force_nrmse"] < 0.1 < v["baseline_force_nrmse"]
    for label in ("baseline", "extended"):
        assert (out_dir / f"{label}.nc").exists()
        assert main(["validate", str(out_dir / f"{label}.nc"), str(paths["test"]), "--json",
                     str(tmp_path / f"{label}.json")]) == 0
        scored = json.loads((tmp_path / f"{label}.json").read_text())
        assert scored["model"] == diag[label]["model"]
        assert scored["force_nrmse"] == pytest.approx(v[f"{label}_force_nrmse"], rel=1e-6)
    assert {"window_force", "unexplained"} <= set(diag["figures"])
    assert "What remains unexplained" in (out_dir / "diagnose.md").read_text()
    assert load(paths["test"]).attrs["kind"] == "device"


def test_the_term_search_runs_by_default_where_the_model_stays_above_its_floor():
    """By default the term library is searched where what the model leaves is above the noise floor: with no
    effect named, or after the named ones (the measured damper: ~80× after four effects); never at the floor."""
    from bayes_mr.diagnosis.diagnose import _asked

    above = {"verdict": f"partly explained by inertia; the rest {BEYOND}", "effects": ["inertia"], "at_noise_floor": False,
             "unexplained_ratio": 79.3}
    assert _asked(above) == "the extended model at 79.3 × the noise floor"
    assert _asked({**above, "at_noise_floor": True, "unexplained_ratio": 1.1}) is None
    assert _asked({"verdict": BEYOND, "effects": [], "at_noise_floor": False, "unexplained_ratio": 9.0}) == \
        f"verdict '{BEYOND}'"
    assert _asked({"verdict": AT_FLOOR, "effects": [], "at_noise_floor": True, "unexplained_ratio": 1.0}) is None
