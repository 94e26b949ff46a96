"""Reading, writing, units, derived channels and the packaged NEES record (bayes_mr.data)."""

from __future__ import annotations

import gzip
import json
import warnings
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from bayes_mr.data import load, write_record
from bayes_mr.data.derive import bandwidth, decimate_record, resample, smooth_velocity
from faults import clean_record, inject_spikes
from bayes_mr.data.nees import convert_nees, load_packaged
from bayes_mr.data.nees import main as nees_main
from bayes_mr.data.quality import apply_quality
from bayes_mr.data.schema import MIN_SAMPLES, RecordError, make_record
from bayes_mr.data.units import UnitWarning, parse_unit_options

RAW_NEES = Path(__file__).resolve().parents[3] / "shared" / "data" / "nees-mr-damper" / "ranran_50.csv.gz"
FS = 1000.0
N = 600


# ------------------------------------------------------------------ helpers


def device_rows(n=N, fs=FS, seed=0):
    """A plausible device test in SI: 5 mm, 3 Hz displacement, ~100 N force, with noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fs
    x = 5e-3 * np.sin(2 * np.pi * 3 * t) + 1e-5 * rng.standard_normal(n)
    f = 100 * np.tanh(2 * np.pi * 3 * 5e-3 * np.cos(2 * np.pi * 3 * t) / 0.01) + rng.standard_normal(n)
    return t, x, f


def write_csv(path: Path, header: list[str], columns: list, *, trailing_comma=False, fmt=repr) -> Path:
    """Write a CSV by hand (so tests control every byte); columns are arrays or lists of strings."""
    end = ",\n" if trailing_comma else "\n"
    lines = [",".join(header) + end]
    for row in zip(*columns):
        lines.append(",".join(c if isinstance(c, str) else fmt(float(c)) for c in row) + end)
    text = "".join(lines)
    if path.name.endswith(".gz"):
        with gzip.open(path, "wt") as fh:
            fh.write(text)
    else:
        path.write_text(text)
    return path


def device_csv(tmp_path, name="rec.csv", **kw):
    t, x, f = device_rows()
    return write_csv(tmp_path / name, ["time", "displacement", "force"], [t, x, f], **kw)


def one_line_error(excinfo) -> str:
    msg = str(excinfo.value)
    assert "\n" not in msg
    return msg


def strcols(*cols):
    return [[repr(float(v)) for v in c] for c in cols]


# ------------------------------------------------------------------ reading: bad input


def test_missing_file(tmp_path):
    with pytest.raises(RecordError) as e:
        load(tmp_path / "nope.csv")
    msg = one_line_error(e)
    assert "nope.csv" in msg and "not found" in msg


def test_unreadable_gzip(tmp_path):
    p = tmp_path / "broken.csv.gz"
    p.write_bytes(b"\x1f\x8b\x08\x00garbage that is not deflate data")
    with pytest.raises(RecordError) as e:
        load(p)
    msg = one_line_error(e)
    assert "broken.csv.gz" in msg and "cannot read" in msg


def test_unknown_file_type(tmp_path):
    p = tmp_path / "rec.txt"
    p.write_text("time,displacement,force\n")
    with pytest.raises(RecordError, match="unknown file type"):
        load(p)


def test_missing_required_column(tmp_path):
    t, x, _ = device_rows()
    p = write_csv(tmp_path / "nof.csv", ["time", "displacement"], [t, x])
    with pytest.raises(RecordError) as e:
        load(p)
    msg = one_line_error(e)
    assert "nof.csv" in msg and "column 'force'" in msg and "missing" in msg


def test_unknown_column_lists_valid_ones(tmp_path):
    t, x, f = device_rows()
    p = write_csv(tmp_path / "extra.csv", ["time", "displacement", "force", "temperature"], [t, x, f, f])
    with pytest.raises(RecordError) as e:
        load(p)
    msg = one_line_error(e)
    assert "column 'temperature'" in msg and "line 1" in msg
    for valid in ("time", "displacement", "force", "velocity", "voltage"):
        assert valid in msg


def test_non_numeric_cell_names_line(tmp_path):
    t, x, f = device_rows()
    cols = strcols(t, x, f)
    cols[2][7] = "12,5".replace(",", ";")  # a decimal comma gone wrong
    p = write_csv(tmp_path / "text.csv", ["time", "displacement", "force"], cols)
    with pytest.raises(RecordError) as e:
        load(p)
    msg = one_line_error(e)
    # data row 7 (0-based) is file line 9: header is line 1
    assert "text.csv" in msg and "column 'force'" in msg and "line 9" in msg and "non-numeric" in msg


def test_empty_cell(tmp_path):
    t, x, f = device_rows()
    cols = strcols(t, x, f)
    cols[1][20] = ""
    p = write_csv(tmp_path / "hole.csv", ["time", "displacement", "force"], cols)
    with pytest.raises(RecordError) as e:
        load(p)
    msg = one_line_error(e)
    assert "column 'displacement'" in msg and "line 22" in msg and "empty cell" in msg


@pytest.mark.parametrize("bad, word", [("nan", "NaN"), ("inf", "infinite"), ("-inf", "infinite")])
def test_nan_inf_first_offending_line(tmp_path, bad, word):
    t, x, f = device_rows()
    cols = strcols(t, x, f)
    cols[2][50] = bad       # later in the file …
    cols[1][30] = bad       # … this one comes first
    p = write_csv(tmp_path / "nan.csv", ["time", "displacement", "force"], cols)
    with pytest.raises(RecordError) as e:
        load(p)
    msg = one_line_error(e)
    assert "column 'displacement'" in msg and "line 32" in msg and word in msg


def test_too_many_fields(tmp_path):
    t, x, f = device_rows()
    cols = strcols(t, x, f)
    cols[2][10] = cols[2][10] + ",3.0"
    p = write_csv(tmp_path / "wide.csv", ["time", "displacement", "force"], cols)
    with pytest.raises(RecordError) as e:
        load(p)
    assert "line 12" in one_line_error(e)


def test_non_increasing_time(tmp_path):
    t, x, f = device_rows()
    t = t.copy()
    t[100] = t[99]
    p = write_csv(tmp_path / "rep.csv", ["time", "displacement", "force"], [t, x, f])
    with pytest.raises(RecordError) as e:
        load(p)
    msg = one_line_error(e)
    assert "column 'time'" in msg and "line 102" in msg and "does not increase" in msg


def test_non_uniform_time(tmp_path):
    t, x, f = device_rows()
    t = t.copy()
    t[200:] += 0.5 / FS  # a half-sample gap: a lost sample or a clock slip
    p = write_csv(tmp_path / "gap.csv", ["time", "displacement", "force"], [t, x, f])
    with pytest.raises(RecordError) as e:
        load(p)
    msg = one_line_error(e)
    assert "column 'time'" in msg and "line 202" in msg and "non-uniform" in msg


def test_rounded_time_is_rebuilt(tmp_path):
    t, x, f = device_rows(fs=4096.0)
    p = write_csv(
        tmp_path / "rounded.csv", ["time", "displacement", "force"],
        [[f"{v:.6f}" for v in t], strcols(x)[0], strcols(f)[0]],
    )
    ds = load(p)
    assert "time_rebuilt" in ds.attrs
    # rounding to 1 µs leaves the step known to about 1e-6 of itself
    np.testing.assert_allclose(np.diff(ds["time"].values), 1 / 4096.0, rtol=1e-6)
    assert np.ptp(np.diff(ds["time"].values)) < 1e-15
    # jitter within 1e-6 of a step is float round-off: kept as written
    assert "time_rebuilt" not in load(device_csv(tmp_path)).attrs


def test_too_few_samples(tmp_path):
    t, x, f = device_rows(n=MIN_SAMPLES - 1)
    p = write_csv(tmp_path / "short.csv", ["time", "displacement", "force"], [t, x, f])
    with pytest.raises(RecordError) as e:
        load(p)
    msg = one_line_error(e)
    assert "short.csv" in msg and f"only {MIN_SAMPLES - 1} samples" in msg


def test_structure_needs_mass(tmp_path):
    ds = clean_record("sweep", "structure", seed=1, duration=1.0, fs=1024.0, amplitude=1.0)
    p = write_record(ds, tmp_path / "frame.csv")
    with pytest.raises(RecordError) as e:
        load(p)
    msg = one_line_error(e)
    assert "frame.csv" in msg and "--mass" in msg
    assert load(p, mass=42.0).attrs["mass"] == 42.0
    nc = write_record(ds, tmp_path / "frame.nc")
    assert load(nc).attrs["mass"] == ds.attrs["mass"]
    assert load(nc, mass=7.0).attrs["mass"] == 7.0  # the argument overrides the file


def test_duplicate_column(tmp_path):
    t, x, f = device_rows()
    p = write_csv(tmp_path / "dup.csv", ["time", "displacement", "force", "force [kN]"], [t, x, f, f])
    with pytest.raises(RecordError, match="duplicate"):
        load(p)


def test_trailing_comma_and_blank_line_tolerated(tmp_path):
    p = device_csv(tmp_path, trailing_comma=True)
    p.write_text(p.read_text() + "\n\n")
    ds = load(p, velocity=None)
    _, _, f = device_rows()
    np.testing.assert_array_equal(ds["force"].values, f)
    assert set(ds.data_vars) == {"displacement", "force", "valid"}


# ------------------------------------------------------------------ units


@pytest.mark.parametrize(
    "header, unit, factor",
    [
        ("displacement", "mm", 1e-3), ("displacement", "cm", 1e-2), ("displacement", "in", 0.0254),
        ("force", "kN", 1e3), ("force", "lbf", 4.4482216152605), ("force", "kip", 4448.2216152605),
        ("voltage", "mV", 1e-3), ("velocity", "in/s", 0.0254), ("velocity", "cm/s", 1e-2),
    ],
)
def test_header_units_convert_to_si(tmp_path, header, unit, factor):
    t, x, f = device_rows()
    si = {"displacement": x, "force": f, "voltage": 2.0 + 0 * t, "velocity": np.gradient(x, t)}
    cols = {"displacement": x, "force": f}
    if header in ("voltage", "velocity"):
        cols[header] = si[header]
    raw = {k: (v / factor if k == header else v) for k, v in cols.items()}
    names = [f"{k} [{unit}]" if k == header else k for k in raw]
    p = write_csv(tmp_path / "u.csv", ["time"] + names, [t] + list(raw.values()))
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnitWarning)
        ds = load(p, velocity=None)
    np.testing.assert_allclose(ds[header].values, si[header], rtol=1e-12, atol=1e-15)
    assert ds[header].attrs["units"] in ("m", "N", "V", "m/s")


def test_structure_units_g_and_ms(tmp_path):
    ds = clean_record("random", "structure", seed=2, duration=1.0, fs=1024.0, amplitude=2.0)
    t = ds["time"].values
    cols = [t * 1e3, ds["ground_acceleration"].values / 9.80665, ds["displacement"].values * 1e3,
            ds["acceleration"].values * 100]
    p = write_csv(tmp_path / "s.csv", ["time [ms]", "ground_acceleration [g]", "displacement [mm]",
                                       "acceleration [cm/s^2]"], cols)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnitWarning)
        back = load(p, mass=50.0)
    for name in ("ground_acceleration", "displacement", "acceleration"):
        np.testing.assert_allclose(back[name].values, ds[name].values, rtol=1e-12)
    np.testing.assert_allclose(back.attrs["fs"], 1024.0, rtol=1e-9)


def test_units_argument_and_cli_form(tmp_path):
    t, x, f = device_rows()
    p = write_csv(tmp_path / "cm.csv", ["time", "displacement", "force"], [t, x * 100, f])
    a = load(p, units={"displacement": "cm"})
    b = load(p, units=["displacement=cm"])
    np.testing.assert_allclose(a["displacement"].values, x, rtol=1e-12)
    np.testing.assert_array_equal(a["displacement"].values, b["displacement"].values)
    assert parse_unit_options(["displacement=cm", "force = kN"]) == {"displacement": "cm", "force": "kN"}
    with pytest.raises(ValueError, match="COLUMN=UNIT"):
        parse_unit_options(["displacement"])


def test_unknown_unit_lists_accepted(tmp_path):
    t, x, f = device_rows()
    p = write_csv(tmp_path / "furl.csv", ["time", "displacement [furlong]", "force"], [t, x, f])
    with pytest.raises(RecordError) as e:
        load(p)
    msg = one_line_error(e)
    assert "furl.csv" in msg and "column 'displacement'" in msg and "furlong" in msg
    assert all(u in msg for u in ("m", "cm", "mm", "in"))
    with pytest.raises(RecordError, match=r"column 'force'.*unknown unit 'N·m'"):
        load(device_csv(tmp_path), units={"force": "N·m"})


def test_unit_conflicts_and_unknown_targets(tmp_path):
    t, x, f = device_rows()
    p = write_csv(tmp_path / "mm.csv", ["time", "displacement [mm]", "force"], [t, x * 1e3, f])
    with pytest.raises(RecordError, match="header says"):
        load(p, units={"displacement": "cm"})
    load(p, units={"displacement": "MM"})  # the same unit, spelt differently: fine
    with pytest.raises(RecordError, match="column 'velocity'.*does not have"):
        load(p, units={"velocity": "cm/s"})
    with pytest.raises(RecordError, match="column 'temp'.*unknown column"):
        load(p, units={"temp": "K"})


@pytest.mark.parametrize(
    "column, scale, hint",
    [
        ("displacement", 1e3, "--units displacement=mm"),   # mm read as m
        ("force", 1e-3, "--units force=kN"),                # kN read as N
        ("time", 1e3, "--units time=ms"),                   # ms read as s
    ],
)
def test_implausible_magnitude_warns(tmp_path, column, scale, hint):
    t, x, f = device_rows(n=400)
    if column == "force":
        f = f * 1e-4  # a tiny damper force in kN: 0.01 kN read as 0.01 N
    cols = {"time": t, "displacement": x, "force": f}
    cols[column] = cols[column] * scale
    p = write_csv(tmp_path / "w.csv", list(cols), list(cols.values()))
    with pytest.warns(UnitWarning, match=hint) as rec:
        load(p, velocity=None)
    assert any("w.csv" in str(w.message) and f"column '{column}'" in str(w.message) for w in rec)


def test_ground_acceleration_in_g_warns(tmp_path):
    ds = clean_record("sweep", "structure", seed=3, duration=1.0, fs=1024.0, amplitude=0.1)
    ag_in_g = ds["ground_acceleration"].values / 9.80665 / 5
    cols = [ds["time"].values, ag_in_g, ds["displacement"].values, ds["acceleration"].values]
    p = write_csv(tmp_path / "g.csv", ["time", "ground_acceleration", "displacement", "acceleration"], cols)
    with pytest.warns(UnitWarning, match="ground_acceleration=g") as rec:
        out = load(p, mass=50.0)
    assert any("g.csv" in str(w.message) for w in rec if issubclass(w.category, UnitWarning))
    # a warning, not a conversion: the data are read as written
    np.testing.assert_allclose(out["ground_acceleration"].values, ag_in_g)


def test_si_record_does_not_warn(tmp_path):
    t, x, f = device_rows()
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        out = load(device_csv(tmp_path))
    assert [str(w.message) for w in rec if issubclass(w.category, UnitWarning)] == []
    np.testing.assert_allclose(out["force"].values, f)


# ------------------------------------------------------------------ velocity, resampling, decimation


def test_derived_velocity_is_smooth_and_accurate(tmp_path):
    fs = 2048.0
    t = np.arange(4096) / fs
    rng = np.random.default_rng(4)
    x_true = 4e-3 * np.sin(2 * np.pi * 2 * t) + 1e-3 * np.sin(2 * np.pi * 7 * t)
    v_true = 4e-3 * 2 * np.pi * 2 * np.cos(2 * np.pi * 2 * t) + 1e-3 * 2 * np.pi * 7 * np.cos(2 * np.pi * 7 * t)
    x = x_true + 2e-6 * rng.standard_normal(t.size)
    f = 50 * np.tanh(v_true / 0.01) + 0.5 * rng.standard_normal(t.size)
    p = write_csv(tmp_path / "nov.csv", ["time", "displacement", "force"], [t, x, f])
    ds = load(p)
    v = ds["velocity"]
    assert v.attrs["derived"] == "savgol" and v.attrs["savgol_window"] > 5
    assert 7 <= v.attrs["bandwidth_hz"] < 30
    err = np.abs(v.values - v_true)[50:-50].max() / np.abs(v_true).max()
    raw = np.abs(np.diff(x) * fs - v_true[:-1])[50:-50].max() / np.abs(v_true).max()
    assert err < 0.01 < raw  # a forward difference is an order of magnitude worse
    assert "velocity" not in load(p, velocity=None)
    direct = smooth_velocity(x, 1 / fs, window=v.attrs["savgol_window"])
    np.testing.assert_allclose(direct, v.values)


def test_bandwidth_of_a_tone():
    t = np.arange(8192) / 1024.0
    assert abs(bandwidth(np.sin(2 * np.pi * 12 * t), 1 / 1024.0) - 12) <= 1.0


def test_resample_linear_default_and_bandlimited():
    t50 = np.arange(0, 4, 0.02)
    y50 = np.sin(2 * np.pi * 1.3 * t50) + 0.5 * np.sin(2 * np.pi * 4.1 * t50)
    t_new, y_lin = resample(t50, y50, 4000.0)
    assert t_new[1] - t_new[0] == pytest.approx(1 / 4000) and t_new[-1] == pytest.approx(t50[-1])
    np.testing.assert_allclose(y_lin[::80], y50, atol=1e-12)  # linear keeps every original sample
    _, y_bl = resample(t50, y50, 4000.0, method="bandlimited")
    truth = np.sin(2 * np.pi * 1.3 * t_new) + 0.5 * np.sin(2 * np.pi * 4.1 * t_new)
    inner = slice(400, -400)
    assert np.abs(y_bl - truth)[inner].max() < 0.5 * np.abs(y_lin - truth)[inner].max()
    _, y_fft = resample(t50, y50, 3333.3, method="bandlimited")  # not a small rational ratio
    assert y_fft.size == int(np.floor(t50[-1] * 3333.3)) + 1
    with pytest.raises(ValueError):
        resample(t50, y50, 100.0, method="cubic")


def test_decimate_record_antialiases_and_keeps_mask():
    fs = 2048.0
    t = np.arange(8192) / fs
    slow = 0.01 * np.sin(2 * np.pi * 3 * t)
    fast = 0.002 * np.sin(2 * np.pi * 300 * t)  # above the new Nyquist (128 Hz)
    valid = np.ones(t.size, bool)
    valid[1000:1003] = False
    ds = make_record(t, {"displacement": slow + fast, "force": 10 * slow}, valid=valid,
                     attrs={"noise_sd_force": 0.4})
    out = decimate_record(ds, 8)
    assert out.attrs["fs"] == pytest.approx(256.0) and out.sizes["time"] == 1024
    resid = out["displacement"].values - slow[::8]
    keep = out["valid"].values.copy()
    keep[:50] = keep[-50:] = False  # filter start-up at the ends
    tk = out["time"].values[keep]
    # plain x[::8] would alias the 300 Hz tone to 44 Hz with amplitude 0.002
    basis = np.column_stack([np.sin(2 * np.pi * 44 * tk), np.cos(2 * np.pi * 44 * tk)])
    alias = np.hypot(*np.linalg.lstsq(basis, resid[keep], rcond=None)[0])
    assert alias < 1e-3 * 0.002
    assert np.abs(resid[keep]).max() < 0.02 * 0.01  # the 3 Hz tone passes (Chebyshev ripple)
    bad = np.flatnonzero(~out["valid"].values)
    # kept sample k is invalid iff its span (k-1)*8+1 .. (k+1)*8-1 touches 1000..1002
    expect = [k for k in range(1024) if (k - 1) * 8 + 1 <= 1002 and (k + 1) * 8 - 1 >= 1000]
    assert bad.tolist() == expect == [125, 126]
    assert out.attrs["masked"] == 2 and out.attrs["decimated"] == 8
    assert out.attrs["noise_sd_force"] == pytest.approx(0.4 / np.sqrt(8))
    assert np.isfinite(out["displacement"].values).all()
    out2 = decimate_record(ds, 16)  # two stages
    assert out2.sizes["time"] == 512


# ------------------------------------------------------------------ writing


@pytest.mark.parametrize("suffix", ["csv", "csv.gz", "nc"])
@pytest.mark.parametrize("kind", ["device", "structure"])
def test_round_trip(tmp_path, suffix, kind):
    ds = clean_record("random", kind, seed=5, duration=1.0, fs=1024.0,
                      amplitude=3e-3 if kind == "device" else 1.0)
    p = write_record(ds, tmp_path / f"rt.{suffix}")
    back = load(p, mass=ds.attrs.get("mass") if suffix != "nc" else None)
    assert back.attrs["kind"] == kind
    np.testing.assert_array_equal(back["time"].values, ds["time"].values)
    for name in ds.data_vars:
        np.testing.assert_array_equal(back[name].values, ds[name].values)
    if suffix == "nc" and kind == "structure":
        assert back.attrs["mass"] == ds.attrs["mass"]


def test_round_trip_netcdf_keeps_mask_report_and_attrs(tmp_path):
    clean = clean_record("sweep", "device", seed=6, duration=2.0, fs=1024.0, amplitude=3e-3)
    faulty, _ = inject_spikes(clean, "force", 3, 5.0, 0)
    ds = apply_quality(faulty)
    assert ds.attrs["masked"] > 0
    back = load(write_record(ds, tmp_path / "q.nc"))
    for name in ds.data_vars:
        np.testing.assert_array_equal(back[name].values, ds[name].values)
    assert back.attrs["quality"] == ds.attrs["quality"]
    assert back.attrs["masked"] == ds.attrs["masked"]
    assert back["velocity"].attrs == ds["velocity"].attrs


def test_netcdf_keeps_how_its_command_reads_and_refuses_an_unknown_reading(tmp_path):
    """``command_interp`` (the command held between samples, or linear) travels in netCDF; another value stops the
    load with one line naming the file and the attribute."""
    ds = clean_record("random", "device", seed=8, duration=1.0, fs=1024.0)
    assert load(write_record(ds.assign_attrs(command_interp="hold"), tmp_path / "h.nc")).attrs["command_interp"] == "hold"
    write_record(ds.assign_attrs(command_interp="zoh"), tmp_path / "z.nc")
    with pytest.raises(RecordError, match=r"z\.nc: attribute command_interp='zoh' .* hold .* linear"):
        load(tmp_path / "z.nc")


def test_round_trip_derived_velocity(tmp_path):
    ds = load(device_csv(tmp_path))
    back = load(write_record(ds, tmp_path / "d.nc"))
    assert back["velocity"].attrs["derived"] == "savgol"
    xr.testing.assert_equal(back, ds)


def _dir_listing(d: Path):
    return sorted(p.name for p in d.iterdir())


def test_write_errors_leave_nothing(tmp_path):
    ds = clean_record("random", "device", seed=7, duration=1.0, fs=1024.0)
    before = _dir_listing(tmp_path)
    with pytest.raises(RecordError, match="unknown file type"):
        write_record(ds, tmp_path / "out.xlsx")
    with pytest.raises(RecordError, match="directory does not exist"):
        write_record(ds, tmp_path / "missing" / "out.csv")
    broken = ds.copy(deep=True)
    broken["force"].values[17] = np.nan
    for suffix in ("csv", "csv.gz", "nc"):
        with pytest.raises(RecordError) as e:
            write_record(broken, tmp_path / f"out.{suffix}")
        msg = one_line_error(e)
        assert "column 'force'" in msg and "sample 17" in msg
    frame = clean_record("random", "structure", seed=7, duration=1.0, fs=1024.0, amplitude=1.0)
    del frame.attrs["mass"]
    with pytest.raises(RecordError, match="mass"):
        write_record(frame, tmp_path / "frame.nc")
    assert _dir_listing(tmp_path) == before  # no output and no temporary file


def test_failed_write_keeps_old_file(tmp_path):
    ds = clean_record("random", "device", seed=8, duration=1.0, fs=1024.0)
    p = write_record(ds, tmp_path / "keep.csv")
    old = p.read_bytes()
    broken = ds.copy(deep=True)
    broken["displacement"].values[3] = np.inf
    with pytest.raises(RecordError):
        write_record(broken, p)
    assert p.read_bytes() == old
    assert _dir_listing(tmp_path) == ["keep.csv"]


def test_csv_columns_are_schema_names_time_first(tmp_path):
    ds = clean_record("random", "device", seed=9, duration=1.0, fs=1024.0)
    p = write_record(ds, tmp_path / "cols.csv.gz")
    with gzip.open(p, "rt") as fh:
        header = fh.readline().strip().split(",")
    assert header == ["time", "displacement", "force", "velocity"]


# ------------------------------------------------------------------ the packaged NEES record


@pytest.fixture(scope="module")
def nees():
    return load_packaged("nees-ranran-50")


def test_nees_packaged_si(nees):
    ds = nees
    assert ds.sizes["time"] == 74_068
    assert ds.attrs["kind"] == "device" and ds.attrs["source"] == "nees-ranran-50"
    assert ds.attrs["fs"] == pytest.approx(3004.8, rel=1e-7)
    assert ds["time"].values[-1] == pytest.approx(74_067 / 3004.8, rel=1e-9)
    # SI magnitudes: the raw file had cm and cm/s
    assert np.abs(ds["displacement"]).max() == pytest.approx(0.00667, rel=1e-3)
    assert np.abs(ds["velocity"]).max() == pytest.approx(0.592166, rel=1e-4)
    assert np.abs(ds["force"]).max() == pytest.approx(1909.9439, rel=1e-6)
    assert float(ds["force"].mean()) == pytest.approx(-123.78, abs=0.05)
    assert 2.2 < float(ds["voltage"].max()) < 2.7
    assert ds.attrs["doi"] == "10.4231/D3V11VM6X"
    assert "cm -> m" in ds.attrs["conversion"]
    assert set(ds.data_vars) == {"displacement", "velocity", "voltage", "force", "valid"}


def test_nees_quality_masks_nothing(nees):
    # looked at by eye: no rails, spikes or end disturbance; the -124 N mean is a preload
    report = json.loads(nees.attrs["quality"])
    assert report["masked"] == 0 and nees.attrs["masked"] == 0 and nees["valid"].values.all()
    assert report["channels"] == ["displacement", "velocity", "force"]


def test_provenance_file_ships():
    from importlib import resources

    text = resources.files("bayes_mr.data").joinpath("resources", "PROVENANCE.md").read_text()
    assert "10.4231/D3V11VM6X" in text and "i / 3004.8" in text


def _raw_nees(path: Path, n=400, bad=None, drop=None):
    fs = 3004.8
    rng = np.random.default_rng(10)
    cols = {"t": np.round(np.arange(n) / fs, 4), "A": rng.standard_normal(n),
            "D": 0.3 * np.sin(np.arange(n) / 30), "Y": np.where(np.arange(n) % 80 < 40, 2.25, 0.0),
            "fs": None, "V": 3.0 * np.cos(np.arange(n) / 30), "F": 500 * np.tanh(np.cos(np.arange(n) / 30))}
    header = [c for c in cols if c != drop]
    lines = [",".join(f'"{c}"' for c in header) + ",\n"]
    for i in range(n):
        row = []
        for c in header:
            if c == "fs":
                row.append(repr(fs) if i == 0 else "")
            else:
                row.append(repr(float(cols[c][i])))
        if bad and i == bad[1]:
            row[header.index(bad[0])] = "x"
        lines.append(",".join(row) + ",\n")
    with gzip.open(path, "wt") as fh:
        fh.write("".join(lines))
    return path, cols


def test_convert_nees_small_raw(tmp_path):
    raw, cols = _raw_nees(tmp_path / "raw.csv.gz")
    out = convert_nees(raw, tmp_path / "out.csv.gz")
    ds = load(out, quality=False)
    assert ds.attrs["fs"] == pytest.approx(3004.8, rel=1e-9)  # rebuilt from fs, not the rounded t
    np.testing.assert_allclose(ds["displacement"].values, cols["D"] * 0.01, rtol=1e-7)
    np.testing.assert_allclose(ds["velocity"].values, cols["V"] * 0.01, rtol=1e-7)
    np.testing.assert_allclose(ds["force"].values, cols["F"], rtol=1e-7)
    np.testing.assert_array_equal(ds["voltage"].values, cols["Y"])
    assert nees_main([str(raw), str(tmp_path / "cli.csv")]) == 0
    assert nees_main([]) == 2


def test_convert_nees_errors_write_nothing(tmp_path):
    raw, _ = _raw_nees(tmp_path / "raw.csv.gz", drop="F")
    with pytest.raises(RecordError, match="column 'F'.*missing"):
        convert_nees(raw, tmp_path / "out.csv.gz")
    raw2, _ = _raw_nees(tmp_path / "raw2.csv.gz", bad=("D", 37))
    with pytest.raises(RecordError) as e:
        convert_nees(raw2, tmp_path / "out.csv.gz")
    assert "column 'D'" in one_line_error(e) and "line 39" in str(e.value)
    with pytest.raises(RecordError, match="not found"):
        convert_nees(tmp_path / "none.csv.gz", tmp_path / "out.csv.gz")
    assert nees_main([str(raw), str(tmp_path / "cli.csv")]) == 1
    assert _dir_listing(tmp_path) == ["raw.csv.gz", "raw2.csv.gz"]


@pytest.mark.skipif(not RAW_NEES.exists(), reason="shared raw NEES file not present")
def test_packaged_file_is_the_converted_raw_file(tmp_path, nees):
    out = convert_nees(RAW_NEES, tmp_path / "nees.csv.gz")
    fresh = load(out, quality=False, velocity=None)
    for name in ("displacement", "velocity", "voltage", "force"):
        np.testing.assert_array_equal(fresh[name].values, nees[name].values)


def test_load_composes_the_steps(tmp_path):
    """load() is read_file → with_velocity → apply_quality → trim_excited, nothing more."""
    from bayes_mr.data.derive import with_velocity
    from bayes_mr.data.read import read_file
    from bayes_mr.data.trim import trim_excited

    p = device_csv(tmp_path)
    by_hand = apply_quality(with_velocity(read_file(p)))
    xr.testing.assert_identical(load(p), by_hand)
    assert list(load(p).data_vars) == ["displacement", "force", "velocity", "valid"]
    trimmed, report = trim_excited(by_hand)
    ds = load(p, trim=True)
    assert json.loads(ds.attrs.pop("trim")) == json.loads(json.dumps(report))
    xr.testing.assert_identical(ds, trimmed)
