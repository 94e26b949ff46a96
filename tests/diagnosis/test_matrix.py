"""Diagnose over a test matrix: the baseline fitted by one likelihood, the residual by condition, and an effect kept
only when it predicts the conditions it was not fitted on (leave-one-condition-out held-out gain)."""

import json
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from bayes_mr.cli.commands import main
from bayes_mr.data import write_record
from bayes_mr.data.records import RecordSet
from bayes_mr.diagnosis.diagnose import diagnose
from bayes_mr.diagnosis.inflation import design_effect
from bayes_mr.diagnosis.matrix import NOT_TRANSFERRED, ambiguity, compare_joint, fit_baseline
from bayes_mr.diagnosis.ranking import compare_fits
from bayes_mr.inference.lsq.least_squares import LSQSettings
from bayes_mr.diagnosis.search import Search
from bayes_mr.likelihood.joint import JointLikelihood
from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.models import get_model
from bayes_mr.simulation.simulate import synthesize

TRUTH = {"c": 800.0, "k": 300.0, "F_d": 200.0, "sigma": 3000.0}
#: (amplitude [m], frequency [Hz]) of each sine test: 2 amplitudes × 2 frequencies, 1.5 s at 500 Hz, 1 % noise
MATRIX = ((0.005, 2.0), (0.005, 4.0), (0.01, 1.0), (0.01, 2.0))


def _test(i: int, amp: float, freq: float, f0: float = 0.0, periods: int = 1):
    """Sine test ``i`` of the damper (dahl), with a force offset ``f0`` [N]; ``periods`` × 1.5 s long."""
    model = get_model("dahl+force_offset" if f0 else "dahl")
    t = np.arange(750 * periods) / 500.0
    w = 2 * np.pi * freq
    inputs = {"displacement": amp * np.sin(w * t), "velocity": amp * w * np.cos(w * t)}
    theta = model.theta("device", dict(TRUTH, **({"f0": f0} if f0 else {})))
    return synthesize(model, theta, t, inputs, noise=0.01, seed=30 + i, source=f"s{i}")


def _set(records) -> RecordSet:
    return RecordSet(tuple(records), ({},) * len(records), ("train",) * len(records), "matrix", {})


def _diagnose(records, candidates=None):
    return diagnose(_set(records), "dahl", search=Search(candidates=candidates), progress=False).to_dict()


def test_an_offset_of_the_device_is_named_kept_and_transfers():
    d = _diagnose([_test(i, a, f, f0=20.0) for i, (a, f) in enumerate(MATRIX)],
                  ("force_offset", "asymmetry", "cubic_stiffness"))
    assert d["n_records"] == 4 and d["n_folds"] == 4 and d["cause"] == "force_offset" and d["transfers"]
    assert d["effects"] == ["force_offset"] and d["selection"][0]["name"] == "force_offset"
    assert d["extended"]["params"]["f0"] == pytest.approx(20.0, rel=0.05)
    assert d["held_out_gain"] > 0.9 and d["gain"]["training_gain"] > 0.9
    kept = next(c for c in d["causes"] if c["name"] == "force_offset")
    assert kept["selected"] and kept["transfers"] and kept["held_out_gain"] == d["held_out_gain"]
    # the residual by condition: every test at the baseline's error, every one brought to the noise by the extension
    assert [r["amplitude"] for r in d["by_condition"]] == pytest.approx([a for a, _ in MATRIX], rel=0.03)
    assert all(r["extended"]["force_nrmse"] < 0.5 * r["baseline"]["force_nrmse"] for r in d["by_condition"])
    # a constant force is the larger a share of the force the smaller the test: the small, slow test is missed most
    worst = max(d["by_condition"], key=lambda r: r["baseline"]["force_nrmse"])
    assert d["worst_condition"]["file"] == worst["file"] and d["worst_condition"]["amplitude"] < 0.0075


def test_the_design_effect_of_a_set_sums_its_records():
    # two copies of one record: the iid and HAC covariances both double, and their ratio, κ, is the record's
    rec = _test(0, 0.005, 2.0, f0=20.0)
    model = get_model("dahl+force_offset")
    one, two = OutputError(model, rec), JointLikelihood(model, [rec, rec])
    phi = one.par.coords.to_phi(np.array([dict(TRUTH, f0=20.0)[n] for n in one.par.names]))
    idx = [one.par.names.index("f0")]
    sigma = np.asarray(one.noise_sd, float)
    k1, _ = design_effect(one, phi, sigma, idx)
    k2, _ = design_effect(two, phi, np.concatenate([sigma, sigma]), idx)
    assert k2 == pytest.approx(k1, rel=1e-9) and k1 > 0


def test_an_offset_of_one_test_fits_only_its_training_conditions():
    # a load-cell bias in one long test: on the joint likelihood it passes, but fitted without that test the offset
    # is gone, and fitted with it the others are predicted worse
    records = [_test(i, a, f, f0=6.0 if i == 2 else 0.0, periods=8 if i == 2 else 1)
               for i, (a, f) in enumerate(MATRIX)]
    d = _diagnose(records, ("force_offset",))
    row = d["causes"][0]
    assert row["name"] == "force_offset" and row["score"] > d["threshold"] and row["training_gain"] > 0.1
    assert row["held_out_gain"] < 0 and not row["transfers"] and row["note"] == NOT_TRANSFERRED
    assert d["cause"] == "none" and not d["transfers"] and NOT_TRANSFERRED in d["verdict"]
    assert d["extended"]["model"] == "dahl" and d["held_out_gain"] is None


def test_a_clean_matrix_gives_none(tmp_path):
    d0 = tmp_path / "m"
    d0.mkdir()
    files = []
    for i, (a, f) in enumerate(MATRIX):
        write_record(_test(i, a, f), d0 / f"s{i}.csv")
        files.append(str(d0 / f"s{i}.csv"))
    out = tmp_path / "d.json"
    assert main(["diagnose", *files, "--model", "dahl", "--json", str(out), "--quiet"]) == 0
    d = json.loads(out.read_text())
    assert d["n_records"] == 4 and d["cause"] == "none" and d["effects"] == [] and not d["transfers"]
    assert all(c["score"] is None or c["score"] < d["threshold"] for c in d["causes"])
    assert len(d["by_condition"]) == 4 and all(r["baseline"]["force_nrmse"] < 0.05 for r in d["by_condition"])


def _untimed(d):
    """``d`` without its wall times (the only numbers two identical runs may differ in)."""
    if isinstance(d, dict):
        return {k: _untimed(v) for k, v in d.items() if k != "wall_s"}
    if isinstance(d, list):
        return [_untimed(v) for v in d]
    return d


def test_one_record_through_the_set_path_is_todays_diagnosis():
    rec = _test(0, 0.005, 2.0, f0=20.0)
    kw = dict(search=Search(candidates=("force_offset",)), terms=False, progress=False)
    alone = diagnose(rec, "dahl", **kw).to_dict()
    assert _untimed(diagnose(_set([rec]), "dahl", **kw).to_dict()) == _untimed(alone)
    assert alone["cause"] == "force_offset" and "n_records" not in alone


def test_a_current_law_is_named_on_a_constant_current_matrix():
    # each test at one constant current: no single record varies its command, the matrix does (0 and 1 A)
    model = get_model("dahl+voltage_dependence")
    truth = dict(TRUTH, a_v=2.0, c_v=400.0, eta=50.0)
    records, conditions = [], []
    for i, (amp, freq, current) in enumerate(((0.005, 2.0, 0.0), (0.005, 2.0, 1.0), (0.01, 1.0, 0.0),
                                              (0.01, 1.0, 1.0))):
        t = np.arange(750) / 500.0
        w = 2 * np.pi * freq
        inputs = {"displacement": amp * np.sin(w * t), "velocity": amp * w * np.cos(w * t),
                  "current": np.full(t.size, current)}
        records.append(synthesize(model, model.theta("device", truth), t, inputs, noise=0.01, seed=40 + i,
                                  source=f"c{i}"))
        conditions.append({"current": current})
    matrix = RecordSet(tuple(records), tuple(conditions), ("train",) * 4, "matrix", {"current": "A"})
    d = diagnose(matrix, "dahl", search=Search(candidates=("voltage_dependence", "force_offset")),
                 progress=False).to_dict()
    assert d["n_folds"] == 4 and d["effects"] == ["voltage_dependence"] and d["held_out_gain"] > 0.9
    assert d["extended"]["params"]["a_v"] == pytest.approx(2.0, rel=0.1)
    assert d["extended"]["params"]["c_v"] == pytest.approx(400.0, rel=0.1)
    assert [r["command_value"] for r in d["by_condition"]] == [0.0, 1.0, 0.0, 1.0]


def test_an_offset_of_one_test_is_absorbed_by_its_nuisance():
    # the load-cell bias of the test above, with a force offset per record: the baseline holds it in that test's
    # f0[2], and no effect is named for it (force_offset, which the offsets nest, is not screened)
    records = [_test(i, a, f, f0=6.0 if i == 2 else 0.0, periods=8 if i == 2 else 1)
               for i, (a, f) in enumerate(MATRIX)]
    d = diagnose(replace(_set(records), record_offsets=True), "dahl",
                 search=Search(candidates=("force_offset", "asymmetry", "cubic_stiffness")), progress=False).to_dict()
    assert d["record_offsets"] and d["cause"] == "none" and d["effects"] == [] and d["ambiguous"] == []
    assert "force_offset" not in {c["name"] for c in d["causes"]}
    p, sd = d["baseline"]["params"], d["baseline"]["params_sd"]
    for r in range(4):
        truth = 6.0 if r == 2 else 0.0
        assert abs(p[f"f0[{r}]"] - truth) < 3 * sd[f"f0[{r}]"], (r, p[f"f0[{r}]"], sd[f"f0[{r}]"])
    assert all(row["baseline"]["force_nrmse"] < 0.02 for row in d["by_condition"])  # every test at the noise


def test_a_matrix_diagnosis_has_one_records_keys():
    rec = _test(0, 0.005, 2.0, f0=20.0)
    kw = dict(search=Search(candidates=("force_offset", "asymmetry")), terms=False, progress=False)
    alone = diagnose(rec, "dahl", **kw).to_dict()
    d = diagnose(_set([_test(i, a, f, f0=20.0) for i, (a, f) in enumerate(MATRIX)]), "dahl", **kw).to_dict()
    assert set(alone) <= set(d) and set(alone["gain"]) <= set(d["gain"])
    assert d["cause"] == "force_offset" and d["ambiguous"] == [] and d["alternatives"] == []
    assert d["at_noise_floor"] and d["unexplained_ratio"] < d["floor_ratio_threshold"]
    assert len(d["residuals"]["before"]) == 4 and d["gain"]["delta_score"] > d["threshold"]


def _stub(lik, predicted):
    """What the Vuong test reads of a joint fit: its likelihood, one prediction per record, each record's σ."""
    sigma = np.concatenate([np.sqrt(np.mean((p.y[:, 0] - f["force"]) ** 2, keepdims=True))
                            for p, f in zip(lik.parts, predicted)])
    return SimpleNamespace(lik=lik, predicted=predicted, result=SimpleNamespace(sigma=sigma))


def test_the_matrix_ambiguity_test_sums_each_records_vuong_test():
    rec = _test(0, 0.005, 2.0)
    rng = np.random.default_rng(3)
    truth = {"force": rec["force"].values - 2.0 * rng.standard_normal(rec.sizes["time"])}  # 1 % noise off
    poor = {"force": truth["force"] + 3.0 * np.sin(np.arange(rec.sizes["time"]) / 7.0)}
    one, two = OutputError("dahl", rec), JointLikelihood("dahl", [rec, rec])
    single = compare_fits(*(SimpleNamespace(lik=one, predicted=p, result=SimpleNamespace(
        sigma=_stub(two, [p] * 2).result.sigma[:1])) for p in (truth, poor)))
    joint = compare_joint(_stub(two, [truth] * 2), _stub(two, [poor] * 2))
    # two independent copies of a record: D doubles, and so does its long-run variance (independent blocks)
    assert joint["difference"] == pytest.approx(2 * single["difference"], rel=1e-12)
    assert joint["sd"] == pytest.approx(np.sqrt(2) * single["sd"], rel=1e-12)
    assert joint["z"] > 10


def test_ambiguous_effects_on_a_matrix_are_those_that_transfer_and_tie():
    records = _set([_test(i, a, f) for i, (a, f) in enumerate(MATRIX[:2])])
    base = fit_baseline(records, "dahl", LSQSettings())
    rng = np.random.default_rng(4)

    def moved(scale, smooth=False):
        n = records[0].sizes["time"]
        wiggle = (lambda: np.sin(np.arange(n) / 7.0)) if smooth else (lambda: rng.standard_normal(n))
        return replace(base, predicted=[{**p, "force": p["force"] + scale * wiggle()} for p in base.predicted])

    cand = lambda name, fit: SimpleNamespace(name=name, fit=fit, mse_ratio=0.5, delta_loglik=100.0)
    cause = cand("cause", base)
    screened = [(cause, {"transfers": True}), (cand("twin", moved(0.02)), {"transfers": True}),
                (cand("local", moved(0.02)), {"transfers": False}),  # told apart by the held-out conditions
                (cand("poor", moved(3.0, smooth=True)), {"transfers": True})]
    out = ambiguity([(cause, {})], screened)
    assert out["ambiguous"] == ["cause", "twin"]
    (alt,) = out["alternatives"]
    assert alt["name"] == "twin" and abs(alt["z"]) < 1.96 and alt["extended"]["model"] == "dahl"
    assert ambiguity([], screened) == {"ambiguous": [], "alternatives": []}


def test_diagnose_out_writes_the_matrix_report(tmp_path):
    d0 = tmp_path / "m"
    d0.mkdir()
    files = []
    for i, (a, f) in enumerate(MATRIX):
        write_record(_test(i, a, f, f0=6.0 if i == 2 else 0.0), d0 / f"s{i}.csv")
        files.append(str(d0 / f"s{i}.csv"))
    out, rep = tmp_path / "d.json", tmp_path / "rep"
    assert main(["diagnose", *files, "--model", "dahl", "--record-offsets", "--json", str(out), "--out", str(rep),
                 "--quiet"]) == 0
    d = json.loads(out.read_text())
    assert d["record_offsets"] and d["cause"] == "none" and d["baseline"]["params"]["f0[2]"] == pytest.approx(6, abs=1)
    assert json.loads((rep / "diagnose.json").read_text())["cause"] == "none"
    assert set(d["figures"]) == {"condition_map", "window_worst"}
    for path in list(d["figures"].values()) + [d["report"]]:
        assert Path(path).is_file() and Path(path).stat().st_size > 1000
    text = (rep / "diagnose.md").read_text()
    assert "f0[r]" in text and "## By condition" in text and "![condition_map](condition_map.png)" in text
    assert f"record {d['worst_condition']['record']}" in text
    # the fits as results validate reads: the baseline predicts a test with its own offset profiled
    assert set(d["results"]) == {"baseline", "extended"}
    val = tmp_path / "v.json"
    assert main(["validate", d["results"]["baseline"], files[2], "--json", str(val)]) == 0
    v = json.loads(val.read_text())
    assert v["record_offset"] == pytest.approx(6, abs=1) and v["force_nrmse"] < 0.02


def _at_currents(currents) -> RecordSet:
    """Tests of the packaged matrix (6 mm, 1.5 Hz), one per current [A], the current channel set to it."""
    from bayes_mr.data import load_packaged

    matrix = load_packaged("damper-matrix-sim")
    base = next(r for r, c in zip(matrix, matrix.conditions) if c["amplitude"] == 6.0 and c["frequency"] == 1.5)
    recs = [base.assign(current=("time", np.full(base.sizes["time"], float(u)), base["current"].attrs))
            for u in currents]
    return RecordSet(tuple(recs), tuple({"current": float(u)} for u in currents), ("train",) * len(recs), "m",
                     {"current": "A"})


def test_a_constant_current_matrix_offers_the_current_laws_it_can_tell_apart():
    from bayes_mr.diagnosis.matrix import candidates

    def offered(model, currents):
        return {e.name for e in candidates(get_model(model), _at_currents(currents))}

    # two non-zero currents tell a one-parameter saturation from the linear law, not a cubic's two coefficients
    three = offered("spencer", (0.0, 0.5, 1.0))
    assert {"exponential_saturation", "command_saturation"} <= three and "command_polynomial" not in three
    assert "command_polynomial" in offered("spencer", (0.0, 0.5, 1.0, 1.5))
    # one current: no current law at all; a model with its law already: no second one
    assert not {"exponential_saturation", "command_saturation", "command_polynomial"} & offered("spencer", (0.5, 0.5))
    laws = offered("spencer+exponential_saturation", (0.0, 0.5, 1.0, 1.5))
    assert not {"exponential_saturation", "command_saturation", "command_polynomial"} & laws
    # a model without a command path is offered none (dahl: voltage_dependence first)
    assert not {"exponential_saturation", "command_polynomial"} & offered("dahl", (0.0, 0.5, 1.0, 1.5))
