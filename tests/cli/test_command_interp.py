"""``--command-interp``: the command between samples on the command line, in the records it writes and in its JSON.

``simulate`` writes how it read the command as the record's ``command_interp`` attribute (kept by netCDF, lost by
CSV, as ``input_interp`` is); the verbs that read a record take the attribute, or the flag over it, and say in
their JSON which reading they used. A bad value stops with one line naming the file and the attribute.
"""

import json

import numpy as np
import pytest
from records import device_inputs

from bayes_mr.cli.commands import main
from bayes_mr.data import load, write_record

FS = 500.0


@pytest.fixture(scope="module")
def records(tmp_path_factory):
    """A spencer device test under a switching command, simulated with the command held and with it linear."""
    directory = tmp_path_factory.mktemp("command_interp")
    inp = device_inputs(0.01, n=1000, fs=FS)
    t = np.arange(inp.n) / FS
    source = directory / "in.csv"
    np.savetxt(source, np.column_stack([t, inp.rows]), delimiter=",", comments="",
               header="time [s],displacement [m],velocity [m/s],voltage [V]")
    out = {}
    for reading in ("hold", "linear"):
        out[reading] = directory / f"{reading}.nc"
        assert main(["simulate", "--model", "spencer", "--input", str(source), "--noise", "0.005", "--seed", "1",
                     "--command-interp", reading, "-o", str(out[reading])]) == 0
    return out


def _fit(tmp_path, data, *flags) -> dict:
    js = tmp_path / "fit.json"
    assert main(["fit", str(data), "--model", "dahl", "--engine", "lsq", "--quiet", "--json", str(js), *flags]) == 0
    return json.loads(js.read_text())


def test_simulate_writes_the_reading_it_used(records):
    held, linear = load(records["hold"]), load(records["linear"])
    assert held.attrs["command_interp"] == "hold" and linear.attrs["command_interp"] == "linear"
    gap = np.sqrt(np.mean((held["force"].values - linear["force"].values) ** 2)) / np.std(linear["force"].values)
    assert gap > 5e-3, gap  # the two readings simulate different forces


def test_fit_and_validate_say_the_reading(tmp_path, records):
    assert _fit(tmp_path, records["hold"])["command_interp"] == "hold"  # the netCDF's attribute
    csv = write_record(load(records["hold"]), tmp_path / "held.csv")  # a CSV carries no attribute
    assert _fit(tmp_path, csv)["command_interp"] == "linear"
    assert _fit(tmp_path, records["hold"], "--command-interp", "linear")["command_interp"] == "linear"
    res = tmp_path / "fit.nc"
    assert _fit(tmp_path, csv, "--command-interp", "hold", "-o", str(res))["command_interp"] == "hold"
    val = tmp_path / "val.json"
    assert main(["validate", str(res), str(csv), "--command-interp", "hold", "--json", str(val)]) == 0
    assert json.loads(val.read_text())["command_interp"] == "hold"


def test_a_bad_reading_is_one_line_naming_the_attribute(tmp_path, records, capsys):
    rec = load(records["hold"])
    rec.attrs["command_interp"] = "zoh"
    bad = write_record(rec, tmp_path / "bad.nc")
    assert main(["fit", str(bad), "--model", "dahl", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "bad.nc" in err and "command_interp='zoh'" in err and "hold" in err and "\n" not in err
    with pytest.raises(SystemExit) as stop:
        main(["fit", str(records["hold"]), "--model", "dahl", "--command-interp", "zoh"])
    assert stop.value.code == 2
