"""Prediction of untested conditions: the table by condition of `validate` over a matrix, leave-one-condition-out
as one command, and its heat map."""

import json

import numpy as np
import pytest

from bayes_mr.cli.commands import main
from bayes_mr.data import write_record
from bayes_mr.data.records import load_records
from bayes_mr.models import get_model
from bayes_mr.selection.loco import condition_folds, leave_one_out
from bayes_mr.simulation.simulate import synthesize

MODEL = "dahl+voltage_dependence"
TRUTH = {"c": 800.0, "k": 300.0, "F_d": 200.0, "sigma": 3000.0, "a_v": 2.0, "c_v": 400.0, "eta": 50.0}
#: (amplitude [m], frequency [Hz], current [A]) of each sine test, 1 % noise, 1.5 s at 500 Hz
MATRIX = ((0.005, 2.0, 0.0), (0.005, 2.0, 1.0), (0.01, 1.0, 0.5))


@pytest.fixture(scope="module")
def matrix(tmp_path_factory):
    """Three sine tests of one damper; the current is the manifest's (the files have no command column), the
    amplitude is given for the first test only (in mm), the others' estimated from their records."""
    d = tmp_path_factory.mktemp("matrix")
    model = get_model(MODEL)
    rows = ["file,current [A],amplitude [mm]"]
    for i, (amp, freq, current) in enumerate(MATRIX):
        t = np.arange(750) / 500.0
        w = 2 * np.pi * freq
        inputs = {"displacement": amp * np.sin(w * t), "velocity": amp * w * np.cos(w * t),
                  "current": np.full(t.size, current)}
        rec = synthesize(model, model.theta("device", TRUTH), t, inputs, noise=0.01, seed=20 + i, source=f"s{i}")
        write_record(rec.drop_vars("current"), d / f"s{i}.csv")
        rows.append(f"s{i}.csv,{current},{amp * 1e3 if i == 0 else ''}")
    (d / "m.csv").write_text("\n".join(rows) + "\n")
    return d


def test_loco_is_one_command_with_its_table_and_heat_map(matrix, tmp_path):
    out, figure = tmp_path / "loco.json", tmp_path / "loco.png"
    assert main(["validate", "--loco", str(matrix / "m.csv"), "--model", MODEL, "--fix", "eta=50", "--json", str(out),
                 "--figure", str(figure), "--quiet"]) == 0
    d = json.loads(out.read_text())
    assert all(r["params"].get("eta", 50.0) == 50.0 for r in d["table"])  # every fold's fit holds it fixed
    assert d["model"] == MODEL and d["engine"] == "lsq" and d["n_folds"] == 3 and figure.stat().st_size > 0
    for row, (amp, freq, current) in zip(d["table"], MATRIX):
        assert row["file"] not in row["trained_on"] and len(row["trained_on"]) == 2
        assert (row["command"], row["command_value"]) == ("current", current)
        assert row["amplitude"] == pytest.approx(amp, rel=0.03) and row["frequency"] == pytest.approx(freq, rel=0.01)
        # the damper's law is in the model: each held-out test is predicted to the noise (1 % of the force's RMS)
        assert row["force_nrmse"] < 0.02 and abs(row["energy_error"]) < 0.02 and abs(row["peak_force_error"]) < 0.05
    assert [r["amplitude_from"] for r in d["table"]] == ["manifest", "record", "record"]
    assert d["worst"]["force_nrmse"] == max(r["force_nrmse"] for r in d["table"])
    assert min(r["force_nrmse"] for r in d["table"]) <= d["pooled"]["force_nrmse"] <= d["worst"]["force_nrmse"] * 1.2


def test_validate_of_several_records_tables_them_by_condition(matrix, tmp_path):
    fit, out, figure = tmp_path / "fit.nc", tmp_path / "val.json", tmp_path / "val.png"
    assert main(["fit", str(matrix / "s0.csv"), "--model", MODEL, "--set", "current=0", "-o", str(fit),
                 "--json", str(tmp_path / "fit.json"), "--quiet"]) == 0
    assert main(["validate", str(fit), str(matrix / "m.csv"), "--json", str(out), "--figure", str(figure)]) == 0
    v = json.loads(out.read_text())
    rows = v["by_condition"]
    assert [r["record"] for r in rows] == [0, 1, 2] and figure.is_file()
    assert [r["force_nrmse"] for r in rows] == pytest.approx([r["force_nrmse"] for r in v["records"]], rel=1e-12)
    # fitted at 0 A alone, the current law is the prior's: the tests at 0.5 A and 1 A are missed
    assert rows[0]["force_nrmse"] < 0.02 and min(rows[1]["force_nrmse"], rows[2]["force_nrmse"]) > 0.05


def test_loco_refusals_are_one_line(matrix, tmp_path, capsys):
    out = tmp_path / "out.json"
    cases = [(["validate", "--loco", str(matrix / "m.csv")], "--loco fits a model in each fold"),
             (["validate", str(matrix / "r.nc"), str(matrix / "s0.csv"), "--fix", "eta=50"], "without --loco"),
             (["validate", "--loco", str(matrix / "s0.csv"), "--model", MODEL, "--set", "current=0"],
              "needs at least two records, got 1")]
    for argv, says in cases:
        assert main(argv + ["--json", str(out), "--quiet"]) == 2
        err = capsys.readouterr().err.strip()
        assert says in err and "\n" not in err and not out.exists()
    with pytest.raises(ValueError, match="at least two records"):
        leave_one_out(load_records([matrix / "s0.csv"]), MODEL)


def test_repeats_of_a_test_are_one_condition_held_out_together(matrix):
    """A repeat of the held-out test in the training set would let the fit see the condition it predicts."""
    (matrix / "repeats.csv").write_text("file,current [A]\ns0.csv,0\ns0.csv,0\ns2.csv,0.5\n")
    records = load_records(matrix / "repeats.csv")
    assert condition_folds(records) == [0, 0, 1]
    assert condition_folds(load_records(matrix / "m.csv")) == [0, 1, 2]  # same motion, another current
    d = leave_one_out(records, MODEL)
    assert d["n_folds"] == 2 and [r["fold"] for r in d["table"]] == [0, 0, 1]
    assert d["table"][0]["trained_on"] == d["table"][1]["trained_on"] == [str((matrix / "s2.csv").resolve())]
    assert len(d["table"][2]["trained_on"]) == 2
    with pytest.raises(ValueError, match="every record is at one condition"):
        leave_one_out(load_records([matrix / "s0.csv", matrix / "s0.csv"], constants={"current": 0.0}), MODEL)
