"""The bayes-mr verbs on several records: two files, a manifest, --set, and the one-line refusals."""

import json

import pytest
from golden.cases import _device

from bayes_mr.cli.commands import main
from bayes_mr.data import write_record

MODEL = "dahl+force_offset"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("records")
    write_record(_device(), d / "a.csv")
    write_record(_device(), d / "b.csv")
    write_record(_device().isel(time=slice(None, None, 2)), d / "h.csv")  # another sampling interval
    (d / "m.csv").write_text("file,current [A],role\na.csv,0.5,train\nb.csv,1.0,train\na.csv,0.75,test\n")
    return d


def test_fit_two_files_writes_the_joint_json(files, tmp_path):
    one, two = tmp_path / "one.json", tmp_path / "two.json"
    assert main(["fit", str(files / "a.csv"), "--model", MODEL, "--json", str(one), "--quiet"]) == 0
    assert main(["fit", str(files / "a.csv"), str(files / "b.csv"), "--model", MODEL, "--json", str(two),
                 "--quiet", "--set", "current=0.5", "-o", str(tmp_path / "two.nc")]) == 0
    a, b = json.loads(one.read_text()), json.loads(two.read_text())
    assert set(a) <= set(b) and b["n_records"] == 2 and "records" not in a
    assert [r["conditions"] for r in b["records"]] == [{"current": 0.5}, {"current": 0.5}]
    assert set(b["sigma"]) == {"force[0]", "force[1]"} and set(b["params"]) == set(a["params"])
    # two copies of one record: the pooled scores are each copy's
    assert b["mse"] == pytest.approx(b["records"][0]["mse"], rel=1e-12)
    val = tmp_path / "val.json"
    assert main(["validate", str(tmp_path / "two.nc"), str(files / "a.csv"), str(files / "b.csv"),
                 "--json", str(val)]) == 0
    v = json.loads(val.read_text())
    assert v["n_records"] == 2 and v["mse"] == pytest.approx(b["mse"], rel=1e-9)


def test_manifest_fits_train_rows_and_predicts_test_rows(files, tmp_path):
    out = tmp_path / "m.json"
    assert main(["fit", str(files / "m.csv"), "--model", MODEL, "--json", str(out), "--quiet"]) == 0
    s = json.loads(out.read_text())
    assert s["n_records"] == 2 and [r["conditions"]["current"] for r in s["records"]] == [0.5, 1.0]
    assert s["test"]["validated_on"].endswith("a.csv") and s["test"]["mse"] > 0
    assert s["test"]["records"][0]["conditions"] == {"current": 0.75} and s["test"]["records"][0]["role"] == "test"


@pytest.mark.parametrize("argv, says", [
    (["fit", "{a}", "{h}", "--model", "dahl", "--engine", "ukf"], "h.csv: sampled every 0.004 s, the first record"),
    (["diagnose", "{a}", "{a}", "--model", "dahl", "--validate", "{a}"], "validates on each held-out condition"),
    (["fit", "{a}", "--model", "dahl", "--set", "current=high"], "--set current=high: not a number"),
    (["fit", "{a}", "{a}", "--model", "dahl", "--engine", "ukf", "--record-offsets"],
     "the UKF does not estimate per-record force offsets"),
    (["fit", "{a}", "{a}", "--model", "dahl+force_offset", "--record-offsets"], "drop +force_offset"),
    (["diagnose", "{a}", "--model", "dahl", "--record-offsets"], "on one record the offset is the model's"),
])
def test_refusals_are_one_line(files, tmp_path, capsys, argv, says):
    out = tmp_path / "out.json"
    argv = [a.format(a=files / "a.csv", h=files / "h.csv") for a in argv] + ["--quiet", "--json", str(out)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert says in err and "\n" not in err and not out.exists()


def test_bad_manifest_names_file_line_and_column(files, tmp_path, capsys):
    bad = files / "bad.csv"
    bad.write_text("file,current\na.csv,0.5\nmissing.csv,1\n")
    out = tmp_path / "out.json"
    assert main(["fit", str(bad), "--model", "dahl", "--json", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert f"{bad}, column 'file', line 3: no such file 'missing.csv'" in err and not out.exists()


def test_compare_a_manifest_predicts_its_test_rows(files, tmp_path):
    out = tmp_path / "cmp.json"
    assert main(["compare", str(files / "m.csv"), "--models", f"dahl,{MODEL}", "--engines", "lsq", "--json",
                 str(out), "--quiet"]) == 0
    c = json.loads(out.read_text())
    assert c["selected"] == MODEL and [r["conditions"]["current"] for r in c["records"]] == [0.5, 1.0]
    row = next(r for r in c["rows"] if r["model"] == MODEL)
    assert row["n_records"] == 2 and row["validation"]["mse"] == pytest.approx(row["mse"], rel=1e-9)


def test_record_offsets_on_fit_compare_and_loco(files, tmp_path):
    # the golden device test carries a force offset; with --record-offsets each copy gets its own f0[r]
    fit, cmp, loco = tmp_path / "fit.json", tmp_path / "cmp.json", tmp_path / "loco.json"
    assert main(["fit", str(files / "a.csv"), str(files / "b.csv"), "--model", "dahl", "--record-offsets",
                 "--json", str(fit), "--quiet", "-o", str(tmp_path / "fit.nc")]) == 0
    f = json.loads(fit.read_text())
    assert f["record_offsets"] and f["point"]["f0[0]"] == pytest.approx(f["point"]["f0[1]"], rel=1e-4)
    # two copies of one record: each offset is that record's force_offset fit's f0
    one = tmp_path / "one.json"
    assert main(["fit", str(files / "a.csv"), "--model", MODEL, "--json", str(one), "--quiet"]) == 0
    assert f["point"]["f0[0]"] == pytest.approx(json.loads(one.read_text())["point"]["f0"], rel=1e-4)
    val = tmp_path / "val.json"
    assert main(["validate", str(tmp_path / "fit.nc"), str(files / "a.csv"), str(files / "b.csv"),
                 "--json", str(val)]) == 0
    v = json.loads(val.read_text())
    assert v["records"][0]["mse"] == pytest.approx(f["records"][0]["mse"], rel=1e-3)
    assert main(["compare", str(files / "a.csv"), str(files / "b.csv"), "--models", "dahl", "--engines", "lsq",
                 "--record-offsets", "--json", str(cmp), "--quiet"]) == 0
    row = json.loads(cmp.read_text())["rows"][0]
    assert row["point"]["f0[1]"] == pytest.approx(f["point"]["f0[1]"], rel=1e-9)
    assert main(["validate", "--loco", str(files / "m.csv"), "--model", "dahl", "--record-offsets",
                 "--json", str(loco), "--quiet"]) == 0
    table = json.loads(loco.read_text())["table"]
    assert len(table) == 3 and all(r["force_nrmse"] < 0.05 for r in table)
