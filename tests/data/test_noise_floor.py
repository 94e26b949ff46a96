"""Noise floor (no-input record, quiet segment, differencing) and trimming to the excited part."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import signal

from bayes_mr.data import load, write_record
from bayes_mr.data.nees import load_packaged
from bayes_mr.data.noise_floor import differencing_sd, find_quiet, noise_floor
from bayes_mr.data.schema import make_record
from bayes_mr.data.trim import trim_excited

FS = 2048.0
SD = {"displacement": 2e-5, "force": 0.5}


def motion(n, rng, f_max=15.0, rms=4e-3):
    sos = signal.butter(4, [0.3, f_max], btype="bandpass", fs=FS, output="sos")
    x = signal.sosfiltfilt(sos, rng.standard_normal(n + 2000))[1000:-1000]
    return rms * x / np.std(x)


def rig_record(seed, quiet_s=(2.0, 2.0), excited_s=6.0, sd=SD, colored=False):
    """A device test: rest, random motion (tapered in and out over 0.2 s), rest; white sensor noise."""
    rng = np.random.default_rng(seed)
    n0, n1, n2 = (int(round(s * FS)) for s in (quiet_s[0], excited_s, quiet_s[1]))
    x_mid = motion(n1, rng)
    ramp = np.clip(np.minimum(np.arange(n1), np.arange(n1)[::-1]) / (0.2 * FS), 0, 1)
    x = np.concatenate([np.zeros(n0), x_mid * (0.5 - 0.5 * np.cos(np.pi * ramp)), np.zeros(n2)])
    v = np.gradient(x, 1 / FS)
    f = 100 * np.tanh(v / 0.01) - 40.0  # a preload: a quiet force is not zero
    noise = {k: s * rng.standard_normal(x.size) for k, s in sd.items()}
    if colored:  # sensor noise low-passed by an anti-alias filter
        sos = signal.butter(4, 0.2 * FS / 2, fs=FS, output="sos")
        for k in noise:
            y = signal.sosfiltfilt(sos, rng.standard_normal(x.size))
            noise[k] = sd[k] * y / np.std(y)
    t = np.arange(x.size) / FS
    return make_record(t, {"displacement": x + noise["displacement"], "force": f + noise["force"]},
                       source=f"rig seed {seed}")


def no_input_record(seed, seconds=30.0, sd=SD):
    rng = np.random.default_rng(seed)
    n = int(seconds * FS)
    chans = {k: s * rng.standard_normal(n) + (0.0 if k == "displacement" else -40.0) for k, s in sd.items()}
    return make_record(np.arange(n) / FS, chans, source="no input")


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_noise_record_recovers_sd(seed):
    ds = rig_record(seed)
    nf = noise_floor(ds, noise_record=no_input_record(100 + seed))
    for k, s in SD.items():
        assert nf[k] == pytest.approx(s, rel=0.1)
        assert nf.methods[k] == "noise_record"


def test_noise_record_from_a_file(tmp_path):
    p = write_record(no_input_record(7), tmp_path / "noinput.csv")
    nf = noise_floor(rig_record(7), noise_record=load(p, quality=False, velocity=None))
    assert nf["force"] == pytest.approx(SD["force"], rel=0.1)
    # load() reads the no-input file itself and stores the floor in the record
    rec = load(write_record(rig_record(7), tmp_path / "rig.csv"), noise_record=p)
    assert rec.attrs["noise_sd_force"] == pytest.approx(nf["force"], rel=1e-12)
    assert json.loads(rec.attrs["noise_floor"])["methods"]["force"] == "noise_record"


def test_load_noise_floor_before_trim(tmp_path):
    p = write_record(rig_record(15), tmp_path / "rig.csv")
    plain = load(p)
    assert not any(k.startswith("noise_sd_") for k in plain.attrs)  # on request only
    ds = load(p, noise_floor=True, trim=True)
    nf = noise_floor(plain)  # estimated on the untrimmed record, whose quiet parts trimming cuts
    for name, sd in nf.items():
        assert ds.attrs[f"noise_sd_{name}"] == sd
    assert json.loads(ds.attrs["trim"])["trimmed"]


@pytest.mark.parametrize("seed", [4, 5, 6])
@pytest.mark.parametrize("where", ["start", "end"])
def test_quiet_segment_recovers_sd(seed, where):
    ds = rig_record(seed, quiet_s=(3.0, 0.5) if where == "start" else (0.5, 3.0))
    seg = find_quiet(ds)
    assert seg is not None
    t = ds["time"].values
    if where == "start":
        assert seg.start == 0 and 2.0 < t[seg.stop - 1] <= 3.0
    else:
        assert seg.stop == t.size and 6.5 <= t[seg.start] < 7.2  # motion ends at 6.5 s
    nf = noise_floor(ds)
    for k, s in SD.items():
        assert nf[k] == pytest.approx(s, rel=0.1)
        assert nf.methods[k] == "quiet_segment"
    assert nf.segment == (pytest.approx(t[seg.start]), pytest.approx(t[seg.stop - 1]))


def test_quiet_segment_given_in_seconds():
    ds = rig_record(8)
    nf = noise_floor(ds, quiet=(8.5, 9.9))
    assert nf["displacement"] == pytest.approx(SD["displacement"], rel=0.1)
    assert nf.segment[0] >= 8.5 and nf.segment[1] <= 9.9


def test_no_quiet_segment_falls_back_to_differencing():
    ds = rig_record(9, quiet_s=(0.0, 0.0), excited_s=8.0)
    assert find_quiet(ds) is None
    nf = noise_floor(ds)
    assert set(nf.methods.values()) == {"differencing"} and nf.segment is None
    # white noise on an oversampled smooth displacement: Δ³ sees the noise only
    assert nf["displacement"] == pytest.approx(SD["displacement"], rel=0.1)
    assert noise_floor(ds, quiet=False).methods == nf.methods


def test_differencing_is_a_lower_bound_for_coloured_noise():
    ds = rig_record(10, quiet_s=(0.0, 0.0), excited_s=8.0, colored=True)
    est = differencing_sd(ds["displacement"].values)
    assert est < 0.5 * SD["displacement"]
    # the quiet-segment estimate of the same coloured noise is right
    quiet = rig_record(10, colored=True)
    assert noise_floor(quiet)["displacement"] == pytest.approx(SD["displacement"], rel=0.15)


def test_masked_samples_are_left_out():
    ds = rig_record(11)
    valid = ds["valid"].values.copy()
    force = ds["force"].values.copy()
    force[300:310] += 500.0  # a fault in the quiet part, already masked
    valid[295:315] = False
    ds = ds.assign(force=("time", force, ds["force"].attrs), valid=("time", valid))
    assert noise_floor(ds)["force"] == pytest.approx(SD["force"], rel=0.1)


@pytest.mark.parametrize("seed", [12, 13])
def test_trim_finds_the_excited_window(seed):
    ds = rig_record(seed, quiet_s=(2.0, 3.0), excited_s=5.0)
    out, rep = trim_excited(ds)
    assert rep["trimmed"]
    t0, t1 = rep["start_index"] / FS, rep["stop_index"] / FS
    # motion from 2.0 s (0.2 s taper) to 7.0 s; the moving window sees it half a
    # window early, and one more 0.25-s window is kept each side
    assert 1.6 <= t0 <= 2.0 and 7.0 <= t1 <= 7.4
    assert rep["cut_start_s"] == pytest.approx(t0) and rep["cut_end_s"] == pytest.approx(10.0 - t1, abs=1e-3)
    assert out.sizes["time"] == rep["stop_index"] - rep["start_index"]
    assert out["time"].values[0] == 0.0 and out.attrs["trim_offset_s"] == pytest.approx(t0)
    np.testing.assert_array_equal(out["force"].values, ds["force"].values[rep["start_index"]:rep["stop_index"]])
    assert out.attrs["fs"] == ds.attrs["fs"]


def test_trim_leaves_an_always_excited_record():
    ds = rig_record(14, quiet_s=(0.0, 0.0), excited_s=6.0)
    out, rep = trim_excited(ds)
    assert not rep["trimmed"] and out is ds and "reason" in rep


def test_load_trim(tmp_path):
    p = write_record(rig_record(15), tmp_path / "rig.csv")
    ds = load(p, trim=True)
    rep = json.loads(ds.attrs["trim"])
    assert rep["trimmed"] and ds.sizes["time"] < 10 * FS
    assert "trim" not in load(p).attrs  # trimming is on request


def test_real_record_noise_and_trim():
    ds = load_packaged("nees-ranran-50", quality=False)
    seg = find_quiet(ds)
    t = ds["time"].values
    assert seg is not None and seg.stop == t.size and 21.2 < t[seg.start] < 22.0  # rests from ~21.3 s
    nf = noise_floor(ds)
    assert nf.methods["force"] == "quiet_segment"
    assert 0.3 < nf["force"] < 3.0            # N: a load cell's noise, not the 750-N signal
    assert 5e-7 < nf["displacement"] < 1e-5   # m
    _, rep = trim_excited(ds)
    assert rep["cut_start_s"] == 0.0 and 2.8 < rep["cut_end_s"] < 3.4
