"""A test matrix from a manifest CSV: per-file conditions, a constant command, one-line errors."""

import numpy as np
import pytest
from golden.cases import _device

from bayes_mr.data import write_record
from bayes_mr.data.records import RecordSet, is_manifest, load_records, read_manifest, with_constant_command
from bayes_mr.data.schema import RecordError


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    d = tmp_path_factory.mktemp("matrix")
    rec = _device()
    write_record(rec, d / "a.csv")
    commanded = rec.assign(voltage=("time", np.full(rec.sizes["time"], 2.0), {"units": "V"}))
    write_record(commanded, d / "v.csv")
    return d


def _manifest(folder, text: str, name: str = "m.csv"):
    path = folder / name
    path.write_text(text)
    return path


def test_constant_current_per_file(folder):
    path = _manifest(folder, "file,current [mA],temperature [C],role\na.csv,500,25,train\na.csv,,40,test\n"
                             "v.csv,250,25,train\n")
    assert is_manifest(path) and not is_manifest(folder / "a.csv")
    rs = load_records(path, constants={"current": 0.1})
    assert len(rs) == 3 and rs.roles == ("train", "test", "train")
    assert rs.conditions[0] == {"current": 0.5, "temperature": 25.0}  # mA → A
    assert rs.conditions[1] == {"current": 0.1, "temperature": 40.0}  # --set where the manifest has none
    np.testing.assert_array_equal(rs[0]["current"].values, 0.5)
    assert rs[0].attrs["command_from"] == "condition"
    assert "current" not in rs[2] and "voltage" in rs[2]  # the file's own command wins
    assert rs.describe()[0]["units"] == {"temperature": "C"}
    train, test = rs.split()
    assert len(train) == 2 and len(test) == 1 and test.conditions[0]["temperature"] == 40.0


def test_a_list_of_files_and_an_attribute(folder):
    rs = load_records([folder / "a.csv", folder / "a.csv"])
    assert isinstance(rs, RecordSet) and len(rs) == 2 and rs.roles == ("train", "train")
    rec = rs[0].assign_attrs(voltage=1.5)
    assert float(with_constant_command(rec, {})["voltage"][0]) == 1.5


@pytest.mark.parametrize("text, where", [
    ("name,current\na.csv,1\n", "m.csv, column 'file': a manifest needs a 'file' column"),
    ("file,current\nb.csv,1\n", "m.csv, column 'file', line 2: no such file 'b.csv'"),
    ("file,current\na.csv,0.5\na.csv,high\n", "m.csv, column 'current', line 3: 'high' is not a number"),
    ("file,role\na.csv,validation\n", "m.csv, column 'role', line 2: unknown role 'validation'"),
    ("file,current,voltage\na.csv,1,2\n", "m.csv, column 'current', line 2: a test ran at a constant current or"),
    ("file,current [kA]\na.csv,1\n", "m.csv, column 'current', line 2: unknown unit 'kA'"),
    ("file,current\na.csv,1,2\n", "m.csv, line 2: 3 cells for 2 columns"),
])
def test_bad_manifest_is_one_line(folder, text, where):
    with pytest.raises(RecordError) as err:
        read_manifest(_manifest(folder, text))
    msg = str(err.value)
    assert "\n" not in msg and " — " in msg  # one line: what is wrong — what to do
    assert msg.startswith(str(folder / "m.csv")) and where.split(", ", 1)[1] in msg


def test_bm_load_reads_a_manifest_or_a_list(folder):
    import bayes_mr as bm

    path = _manifest(folder, "file,current\na.csv,0.5\na.csv,1\n", "pair.csv")
    for rs in (bm.load(path), bm.load([folder / "a.csv", folder / "a.csv"], constants={"current": 0.5})):
        assert isinstance(rs, bm.RecordSet) and len(rs) == 2 and float(rs[0]["current"][0]) == 0.5
    assert not isinstance(bm.load(folder / "a.csv"), bm.RecordSet)


def test_the_packaged_matrix_loads_with_its_conditions():
    # the simulated constant-current matrix ships as gzipped CSVs and a manifest: 3 amplitudes × 3 frequencies
    # × 3 currents, each test's current a command channel, its amplitude and frequency conditions in mm and Hz
    from itertools import product

    from bayes_mr.data import load_packaged
    from bayes_mr.data.nees import packaged_manifest

    path = packaged_manifest("damper-matrix-sim")
    assert is_manifest(path) and path.name == "manifest.csv"
    matrix = load_packaged("damper-matrix-sim")
    assert isinstance(matrix, RecordSet) and len(matrix) == 27 and matrix.kind == "device"
    assert matrix.units == {"current": "A", "amplitude": "mm", "frequency": "Hz"}
    grid = {(c["amplitude"], c["frequency"], c["current"]) for c in matrix.conditions}
    assert grid == set(product((2.0, 6.0, 20.0), (0.5, 1.5, 4.0), (0.0, 0.5, 1.0)))
    for rec, cond in zip(matrix, matrix.conditions):
        assert np.all(rec["current"].values == cond["current"]) and rec.attrs["command_from"] == "condition"
        x = rec["displacement"].values
        assert 0.5 * (x.max() - x.min()) == pytest.approx(1e-3 * cond["amplitude"], rel=1e-3)
        assert rec["valid"].values.all()  # simulated: nothing for quality control to mask
    assert [r.sizes["time"] for r in matrix][:3] == [1600, 1600, 1600]
    with pytest.raises(KeyError, match="damper-matrix-sim"):
        packaged_manifest("no-such-matrix")
