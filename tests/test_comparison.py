"""compare (models × engines, selection by evidence), the diagnose verb and the main job's quick pass."""

import json
import math

import numpy as np
import pytest

from bayes_mr.cli.commands import main
from bayes_mr.selection.comparison import compare, crosscheck, selection_route
from bayes_mr.inference.identify import UKF, Emcee, Identify
from bayes_mr.inference.mcmc.settings import MCMCSettings
from records import offset_device_record

FIT_KEYS = {"model", "engine", "params", "params_sd", "log_evidence", "mse", "force_errors", "force_nrmse",
            "masked", "trained", "diverged", "wall_s"}
SHORT = MCMCSettings(seed=0, progress=False, min_tau_multiple=20.0, rhat_max=1.05, check_every=100)


@pytest.fixture(scope="module")
def device_csv(tmp_path_factory):
    from bayes_mr.data import write_record

    return write_record(offset_device_record(4.0), tmp_path_factory.mktemp("cmp") / "dev.csv")


def test_selection_route_needs_every_model():
    rows = [{"model": "a", "engine": "mcmc", "log_evidence": -1.0}, {"model": "a", "engine": "lsq", "log_evidence": -2.0},
            {"model": "b", "engine": "lsq", "log_evidence": -3.0}, {"model": "b", "engine": "mcmc", "error": "x"}]
    assert selection_route(rows, ["a", "b"]) == ("lsq", "laplace")
    assert selection_route(rows, ["a"]) == ("mcmc", "ti")
    assert selection_route([{"model": "a", "engine": "ukf", "error": "x"}], ["a"]) == (None, None)


def test_compare_selects_the_true_model_by_ti_with_mcmc_and_lsq():
    """Two models × lsq, mcmc: TI selects the model with the hidden offset; every row has the fit keys."""
    rec = offset_device_record(1.6, fs=250.0)
    out = compare(rec, ["dahl", "dahl+force_offset"], engines=("lsq", "mcmc"), progress=False,
                  estimators={"mcmc": Emcee(settings=SHORT)})
    assert len(out.rows) == 4 and all(FIT_KEYS <= set(r) for r in out.rows)
    assert out.evidence_route == "ti" and out.evidence_engine == "mcmc"
    assert out.selected == "dahl+force_offset"
    assert out.bayes_factors["dahl+force_offset"] == 0.0 and out.bayes_factors["dahl"] > 3.0
    assert set(out.idata) == {(m, e) for m in ("dahl", "dahl+force_offset") for e in ("lsq", "mcmc")}
    for r in out.rows:
        if r["engine"] == "mcmc":
            assert set(r["evidence_routes"]) == {"laplace", "ti", "ss"}
    # TI and stepping-stone on the same ladder agree within their errors. (Laplace is 2–5 nats off here:
    # on 1.5 s the weak stiffness k is far from Gaussian in the estimation coordinates — why TI selects.)
    routes = out.row("dahl+force_offset", "mcmc")
    routes = routes["evidence_routes"]
    assert abs(routes["ti"]["log_z"] - routes["ss"]["log_z"]) < 3 * math.hypot(routes["ti"]["total_error"],
                                                                               routes["ss"]["total_error"])
    assert out.crosscheck == {}


def test_crosscheck_of_ukf_and_mcmc_rows():
    """With both engines the comparison carries per-parameter z-scores of the UKF against the posterior."""
    rec = offset_device_record(2.0)
    mc = Identify("dahl+force_offset", Emcee(settings=SHORT, evidence="laplace")).fit(rec, progress=False)
    uk = Identify("dahl+force_offset", UKF(n_lhs=2, taus=(0.01, 0.1))).fit(rec, progress=False)
    cc = crosscheck(uk, mc)
    assert set(cc) == {"c", "k", "F_d", "sigma", "f0"}
    for v in cc.values():
        assert np.isfinite(v["z"]) and v["mcmc_sd"] > 0
    # the offset is linear in the force and well determined by both
    assert abs(cc["f0"]["ukf"] - (-60.0)) < 3.0 and abs(cc["f0"]["mcmc"] - (-60.0)) < 3.0


def test_compare_cli_json_and_table(tmp_path, device_csv, capsys):
    out = tmp_path / "cmp.json"
    assert main(["compare", str(device_csv), "--models", "dahl,dahl+force_offset", "--engines", "lsq",
                 "--validate", str(device_csv), "--out", str(tmp_path / "fits"), "--json", str(out),
                 "--quiet"]) == 0
    data = json.loads(out.read_text())
    assert {"rows", "selected", "bayes_factors"} <= set(data)
    assert data["selected"] == "dahl+force_offset" and data["evidence_route"] == "laplace"
    # the calibrated evidence beside the raw one: one k for both models, the same choice here
    assert data["selected_on"] == "calibrated" and 0 < data["evidence_scale"] <= 1
    assert data["selected_calibrated"] == "dahl+force_offset" and data["bayes_factors_calibrated"]["dahl"] > 0
    assert all(FIT_KEYS <= set(r) and "validation" in r for r in data["rows"])
    assert "| model | engine |" in capsys.readouterr().err
    assert (tmp_path / "fits" / "compare.csv").exists()
    assert (tmp_path / "fits" / "dahl_force_offset__lsq.nc").exists()


def test_compare_cli_unknown_engine_is_one_line(tmp_path, device_csv, capsys):
    assert main(["compare", str(device_csv), "--models", "dahl", "--engines", "lsq,nuts",
                 "--json", str(tmp_path / "x.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown engine 'nuts'" in err[0]
    assert not (tmp_path / "x.json").exists()


def test_diagnose_cli_names_the_hidden_offset(tmp_path, device_csv):
    out = tmp_path / "diag.json"
    assert main(["diagnose", str(device_csv), "--model", "dahl", "--json", str(out), "--out", str(tmp_path / "d"),
                 "--quiet"]) == 0
    data = json.loads(out.read_text())
    assert {"baseline", "cause", "causes", "extended", "gain"} <= set(data)
    assert data["cause"] == "force_offset"
    assert data["gain"]["mse_ratio"] < 0.5 and data["gain"]["validation_mse_ratio"] is None
    assert (tmp_path / "d" / "diagnose.md").exists()


def _later_part_of_the_packaged_record(path, start_s: float = 14.0):
    """The packaged record from ``start_s`` on, as a file: a second test of the same damper for the main job."""
    from bayes_mr.data import load_packaged, write_record

    rec = load_packaged()
    later = rec.isel(time=slice(int(start_s * float(rec.attrs["fs"])), None))
    return write_record(later.assign_coords(time=later["time"].values - float(later["time"].values[0])), path)


def test_run_quick_end_to_end(tmp_path):
    """``bayes-mr run --quick`` on the packaged record writes the report, the tables and the fits; with
    ``--validate`` a second record of the damper is predicted by every fit and by the diagnosis's models."""
    out = tmp_path / "results"
    second = _later_part_of_the_packaged_record(tmp_path / "second.csv")
    assert main(["run", "--quick", "--out", str(out), "--no-readme", "--quiet", "--json",
                 str(tmp_path / "s.json"), "--validate", str(second)]) == 0
    s = json.loads((tmp_path / "s.json").read_text())
    assert s["selected"] in ("dahl", "lugre")
    nrmse = [r["validation"]["force_nrmse"] for r in s["rows"] if "validation" in r]
    assert nrmse and all(0 < v < 1 for v in nrmse)
    assert 0 < s["spencer_1997"]["part_b"]["force_nrmse"] < 1
    assert s["shake_table"]["model"] in ("dahl", "lugre")
    vst = s["shake_table"]["lsq"]
    # the implied damper force (restoring force less the known frame) is the one to compare: the
    # hysteretic part alone misses the damper's own viscous force
    assert vst["force_nrmse_b"] < min(1.0, vst["hysteretic_nrmse_b"])
    text = (out / "report.md").read_text()
    assert "Spencer et al. (1997)" in text and "Virtual shake table" in text
    for name in ("compare.csv", "spencer_parameters.csv", "summary.json", "force_part_b.png"):
        assert (out / name).exists(), name
    assert list((out / "fits").glob("*.nc"))
    # the model choice under both residual models, the comparison's own first
    assert s["noise"] == "iid" and set(s["noise_sensitivity"]) == {"iid", "ar"}
    for noise, d in s["noise_sensitivity"].items():
        assert d["selected"] in ("dahl", "lugre") and d["bayes_factors"][d["selected"]] == 0.0
    # the same choice as the iid refit's, on the evidence the job selected on (calibrated by default)
    key = "selected_calibrated" if s["selected_on"] == "calibrated" else "selected"
    assert s["noise_sensitivity"]["iid"][key] == s["selected"]
    assert "AR residual model" in text
    # the selected model diagnosed on the whole of part A at >= 1 kHz, its extension predicting B
    d = s["diagnose"][s["selected"]]
    assert d["record"]["fs"] >= 1000 and d["record"]["duration_s"] == pytest.approx(s["record"]["part_a_s"], abs=0.01)
    assert d["baseline"]["model"] == s["selected"] and d["extended"]["model"].startswith(s["selected"])
    v = d["validation"]
    assert 0 < v["extended_force_nrmse"] < 1 and 0 < v["baseline_force_nrmse"] < 1
    if d["effects"]:  # an extension is kept only if it lowers the error on A; B is where it is checked
        assert d["gain"]["mse_ratio"] < 1
    assert d["unexplained_ratio"] > 0 and f"Diagnosis of {s['selected']}" in text
    assert (out / f"diagnose_{s['selected']}" / "extended.nc").exists()
    # the second record, prepared as part B was and never fitted
    sr = s["second_record"]
    assert sr["record"]["fs"] == pytest.approx(s["record"]["fs"]) and sr["record"]["duration_s"] > 1.0
    fitted = {(r["model"], r["engine"]) for r in s["rows"] if "error" not in r}
    assert {(r["model"], r["engine"]) for r in sr["rows"]} == fitted
    assert all(0 < r["force_nrmse"] < 1 for r in sr["rows"] if "error" not in r)
    sd = sr["diagnosis"]
    assert sd["fs"] == pytest.approx(d["record"]["fs"]) and sd["extended_model"] == d["extended"]["model"]
    assert 0 < sd["baseline_force_nrmse"] < 1 and 0 < sd["extended_force_nrmse"] < 1
    assert "Second record of the same damper" in text and (out / "force_second_record.png").exists()
    # what the extended model still leaves: the term library searched beyond the vocabulary, whatever the verdict
    t = d["terms"]
    assert t is not None and t["asked"] == "explicitly"
    if t["kept"]:  # kept only where the evidence and a held-out end of A both improve; B is where it is checked
        assert 0 < t["validation"]["force_nrmse"] < 1 and 0 < sd["terms_force_nrmse"] < 1
        assert sd["terms_model"] == t["model"] and (out / f"diagnose_{s['selected']}" / "terms.nc").exists()
        assert "beyond the vocabulary kept" in text


def test_run_refuses_a_second_record_of_another_kind_before_fitting(tmp_path, structure_record, capsys):
    """A structure test given as the damper's second record stops the job at once, naming the problem."""
    from bayes_mr.data import write_record

    rec, _ = structure_record("dahl", {}, n=500)
    path = write_record(rec, tmp_path / "structure.csv")
    assert main(["run", "--quick", "--out", str(tmp_path / "r"), "--no-readme", "--quiet",
                 "--validate", str(path)]) == 2
    assert "structure test" in capsys.readouterr().err and not (tmp_path / "r" / "fits").exists()


def test_selection_route_names_the_route_the_evidence_came_by():
    """An mcmc row whose evidence is the Laplace approximation does not pass for thermodynamic integration."""
    def row(model, engine, route, ln_z):
        return {"model": model, "engine": engine, "evidence_route": route, "log_evidence": ln_z}

    laplace_mcmc = [row(m, e, "laplace", z) for m, z in (("dahl", -10.0), ("lugre", -12.0)) for e in ("lsq", "mcmc")]
    assert selection_route(laplace_mcmc, ["dahl", "lugre"]) == ("lsq", "laplace")
    ti = laplace_mcmc + [row("dahl", "mcmc", "ti", -9.0), row("lugre", "mcmc", "ti", -11.0)]
    assert selection_route(ti, ["dahl", "lugre"]) == ("mcmc", "ti")
    # one model without a TI row: the route every model has
    assert selection_route(ti[:-1], ["dahl", "lugre"]) == ("lsq", "laplace")


def test_lsq_and_mcmc_rows_share_one_least_squares_fit():
    """A model's lsq row and its chain's start are one fit (one job), with the numbers of two separate jobs."""
    from bayes_mr.selection.fit_jobs import fit_job, lsq_mcmc_job, shares_lsq, units
    from bayes_mr.inference.estimators import LeastSquares
    from bayes_mr.inference.lsq.least_squares import LSQSettings

    rec = offset_device_record(1.6, fs=250.0)
    lsq, mcmc = LeastSquares(), Emcee(settings=SHORT, evidence="laplace")
    assert shares_lsq(lsq, mcmc, 0) and not shares_lsq(lsq, mcmc, 1)
    assert not shares_lsq(LeastSquares(settings=LSQSettings(n_starts=2)), mcmc, 0)
    grid = units([("dahl", "lsq"), ("dahl", "mcmc"), ("dahl", "ukf")], {"mcmc": mcmc}, 0)
    assert [[e for e, _ in ests] for _, ests in grid] == [["lsq", "mcmc"], ["ukf"]]
    shared = lsq_mcmc_job("dahl", lsq, mcmc, rec, None, 0, False)
    alone = [fit_job("dahl", e, rec, None, 0, False) for e in (lsq, mcmc)]
    for (a, _), (b, _) in zip(shared, alone):
        assert a["engine"] == b["engine"]
        assert a["log_evidence"] == b["log_evidence"] and a["params"] == b["params"]
        assert a["params_sd"] == b["params_sd"] and a["mse"] == b["mse"]


def test_a_grid_searches_least_squares_from_its_own_seed_and_shares_the_fit_with_the_chain():
    """compare(seed=3): the lsq rows' starts come from seed 3, as the chains' least squares do (one fit for both)."""
    from bayes_mr.selection.fit_jobs import units

    for seed in (0, 3):
        [(model, ests)] = units([("dahl", "lsq"), ("dahl", "mcmc")], {}, seed)
        assert [e for e, _ in ests] == ["lsq", "mcmc"] and ests[0][1].settings.seed == seed
