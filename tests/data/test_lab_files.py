"""The files labs have: MATLAB (v5, v7.3) and HDF5 records with a column mapping; corrupted records.

The property-based tests corrupt small slices of the packaged NEES record at
random and require either a one-line :class:`RecordError` or a record (with
its quality report), never another exception, and never an output file from
a read that failed.
"""

from __future__ import annotations

import gzip
import io
import warnings
from pathlib import Path

import h5py
import numpy as np
import pandas as pd
import pytest
import scipy.io
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bayes_mr.cli.commands import main
from bayes_mr.data import RecordError, load
from bayes_mr.data.quality import report_of
from bayes_mr.data.read_arrays import parse_columns

PACKAGED = Path(__file__).resolve().parents[2] / "bayes_mr" / "data" / "resources" / "nees_ranran_50.csv.gz"


def nees_frame() -> pd.DataFrame:
    with gzip.open(PACKAGED, "rt") as f:
        return pd.read_csv(f, nrows=4000)


NEES = nees_frame()
LAB = {"time": "t", "displacement": "D", "velocity": "V", "voltage": "U", "force": "F"}
MAPPING = ",".join(f"{k}={v}" for k, v in LAB.items())


def lab_arrays(n: int = 1200) -> dict[str, np.ndarray]:
    """The first ``n`` NEES samples under lab names, displacement in mm."""
    cols = {var: NEES[name].to_numpy()[:n].copy() for name, var in LAB.items()}
    cols["D"] *= 1e3
    return cols


def check_record(ds, n: int) -> None:
    ref = NEES.iloc[:n]
    np.testing.assert_allclose(ds["displacement"].values, ref["displacement"].to_numpy(), rtol=1e-12)
    np.testing.assert_allclose(ds["force"].values, ref["force"].to_numpy(), rtol=1e-12)
    assert ds.attrs["kind"] == "device" and ds.sizes["time"] == n


def test_mat_v5_with_column_mapping(tmp_path):
    p = tmp_path / "run.mat"
    scipy.io.savemat(p, {**{k: v[:, None] for k, v in lab_arrays().items()}, "note": "rig 2"})
    ds = load(p, columns=MAPPING, units=["displacement=mm"], quality=False)
    check_record(ds, 1200)
    # the same as a mapping, and a struct's fields by their path
    q = tmp_path / "struct.mat"
    scipy.io.savemat(q, {"data": lab_arrays()})
    ds = load(q, columns={k: f"data.{v}" for k, v in LAB.items()}, units={"displacement": "mm"}, quality=False)
    check_record(ds, 1200)


def write_v73(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """A MATLAB v7.3-style file: HDF5 with 1×n datasets (MATLAB stores column vectors transposed)."""
    with h5py.File(path, "w", userblock_size=512) as f:
        for k, v in arrays.items():
            d = f.create_dataset(k, data=v[None, :])
            d.attrs["MATLAB_class"] = np.bytes_("double")
        f.create_dataset("label", data=np.frombuffer(b"rig", np.uint8)[None, :]).attrs["MATLAB_class"] = np.bytes_("char")


def test_mat_v73_and_hdf5(tmp_path):
    p = tmp_path / "run73.mat"
    write_v73(p, lab_arrays())
    check_record(load(p, columns=MAPPING, units=["displacement=mm"], quality=False), 1200)
    h = tmp_path / "run.h5"
    with h5py.File(h, "w") as f:
        g = f.create_group("run1")
        for k, v in lab_arrays().items():
            g.create_dataset(k, data=v)
        g["D"].attrs["units"] = "mm"
    check_record(load(h, columns={k: f"run1/{v}" for k, v in LAB.items()}, quality=False), 1200)


def test_hdf5_with_schema_names_needs_no_mapping(tmp_path):
    h = tmp_path / "plain.hdf5"
    with h5py.File(h, "w") as f:
        for name in LAB:
            f.create_dataset(name, data=NEES[name].to_numpy()[:900])
        f.create_dataset("comment_matrix", data=np.zeros((3, 3)))
    check_record(load(h, quality=False), 900)


def one_line(excinfo) -> str:
    msg = str(excinfo.value)
    assert "\n" not in msg
    return msg


def test_array_file_errors_name_file_column_and_sample(tmp_path):
    arrays = lab_arrays()
    arrays["F"][417] = np.nan
    p = tmp_path / "nan.mat"
    scipy.io.savemat(p, arrays)
    with pytest.raises(RecordError) as e:
        load(p, columns=MAPPING)
    msg = one_line(e)
    assert "nan.mat" in msg and "force=F" in msg and "sample 417" in msg
    with pytest.raises(RecordError) as e:
        load(p, columns="time=t,displacement=X,force=F")
    assert "no variable 'X'" in one_line(e) and "D" in str(e.value)
    with pytest.raises(RecordError) as e:
        load(p)  # no mapping, no schema names
    assert "--columns" in one_line(e)
    short = lab_arrays()
    short["F"] = short["F"][:-5]
    q = tmp_path / "short.mat"
    scipy.io.savemat(q, short)
    with pytest.raises(RecordError) as e:
        load(q, columns=MAPPING)
    assert "force=F" in one_line(e) and "same length" in str(e.value)
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"not an hdf5 file at all")
    with pytest.raises(RecordError) as e:
        load(bad)
    assert "bad.h5" in one_line(e)


def test_csv_with_column_mapping_and_parse_errors(tmp_path):
    p = tmp_path / "lab.csv"
    df = pd.DataFrame(lab_arrays(600)).rename(columns={"D": "D [mm]"})
    df.to_csv(p, index=False)
    check_record(load(p, columns=MAPPING, quality=False), 600)
    with pytest.raises(RecordError) as e:
        load(p, columns="time=t,displacement=Q,force=F")
    assert "no column 'Q'" in one_line(e)
    for bad in ("time", "time=t,bogus=D", "time=t,time=D", "time=t,force=t"):
        with pytest.raises(ValueError):
            parse_columns(bad)


def test_cli_columns_option(tmp_path, capsys):
    p = tmp_path / "lab.mat"
    scipy.io.savemat(p, lab_arrays())
    out = tmp_path / "fit.json"
    # a mapping that misses a variable fails at the read: one line, status 2, nothing written
    assert main(["fit", str(p), "--model", "dahl", "--columns", "time=t,displacement=Z,force=F",
                 "--json", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "no variable 'Z'" in err and not out.exists()
    from bayes_mr.cli.commands import _read, build_parser

    args = build_parser().parse_args(["fit", str(p), "--model", "dahl", "--columns", "time=t,displacement=D",
                                      "--columns", "velocity=V,voltage=U,force=F", "--units", "displacement=mm"])
    check_record(_read(str(p), args), 1200)


# --- property-based corruption of the packaged record -----------------------------------------

N_ROWS = 600
CORRUPTIONS = ("nan", "truncate", "swap", "duplicate_time", "reverse_time", "units", "text", "blank")


def corrupt(lines: list[str], kind: str, row: int, col: int, col2: int, factor: float) -> list[str]:
    """``lines`` (header first) with one corruption at data row ``row`` / columns ``col``, ``col2``."""
    out = list(lines)
    r = 1 + row
    cells = out[r].split(",")
    if kind == "nan":
        cells[col] = "nan"
    elif kind == "truncate":
        out[r] = ",".join(cells[: max(1, col)])[: max(1, len(out[r]) // 2)]
        return out
    elif kind == "swap":  # two columns' headers exchanged (values under the wrong names)
        head = out[0].split(",")
        head[col], head[col2] = head[col2], head[col]
        out[0] = ",".join(head)
        return out
    elif kind == "duplicate_time":
        cells[0] = out[r - 1].split(",")[0]
    elif kind == "reverse_time":
        out[r], out[r + 1] = out[r + 1], out[r]
        return out
    elif kind == "units":  # one column in other units, the header unchanged
        for i in range(1, len(out)):
            c = out[i].split(",")
            c[col] = repr(float(c[col]) * factor)
            out[i] = ",".join(c)
        return out
    elif kind == "text":
        cells[col] = "1.2.3"
    elif kind == "blank":
        cells[col] = ""
    out[r] = ",".join(cells)
    return out


def base_lines(start: int) -> list[str]:
    buf = io.StringIO()
    NEES.iloc[start:start + N_ROWS].to_csv(buf, index=False, float_format="%.10g")
    return buf.getvalue().strip().splitlines()


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    kind=st.sampled_from(CORRUPTIONS),
    start=st.integers(0, len(NEES) - N_ROWS - 1),
    row=st.integers(1, N_ROWS - 2),
    col=st.integers(0, 4),
    col2=st.integers(0, 4),
    factor=st.sampled_from([1e-3, 1e3, 9.80665, 0.0254]),
)
def test_corrupted_records_fail_in_one_line_or_load(tmp_path, kind, start, row, col, col2, factor):
    lines = corrupt(base_lines(start), kind, row, col, col2, factor)
    p = tmp_path / f"corrupt_{kind}.csv"
    p.write_text("\n".join(lines) + "\n")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a UnitWarning is an allowed outcome
            ds = load(p)
    except RecordError as exc:
        msg = str(exc)
        assert "\n" not in msg and p.name in msg
        return
    # read: a valid record whose quality control reported what it masked
    assert ds.sizes["time"] == N_ROWS and ds.attrs["masked"] == int((~ds["valid"].values).sum())
    rep = report_of(ds)
    assert rep is not None and rep["masked"] <= ds.attrs["masked"]
    for name in ("displacement", "force"):
        assert np.isfinite(ds[name].values).all()


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(kind=st.sampled_from(("nan", "truncate", "duplicate_time", "reverse_time", "text", "blank")),
       row=st.integers(1, N_ROWS - 2), col=st.integers(0, 4))
def test_failed_read_writes_nothing(tmp_path_factory, kind, row, col):
    d = tmp_path_factory.mktemp("cli")
    p = d / "bad.csv"
    p.write_text("\n".join(corrupt(base_lines(0), kind, row, col, col, 1.0)) + "\n")
    out, res = d / "fit.json", d / "fit.nc"
    code = main(["fit", str(p), "--model", "dahl", "--json", str(out), "-o", str(res), "--quiet"])
    assert code == 2
    assert sorted(x.name for x in d.iterdir()) == ["bad.csv"]
