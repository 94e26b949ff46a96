"""Input signals (thesis Table 5.1, §3.8.1) and the packaged ground motions."""

from __future__ import annotations

import gzip
import hashlib
from importlib import resources

import numpy as np
import pytest

from bayes_mr.data.ground_motions import (
    STANDARD_GRAVITY, GroundMotionFormatError, load_ground_motion, read_peer_at2, read_two_column,
)
from bayes_mr.signals import Signal, integrate_acceleration, make_signal, signal_names, thesis_signal

G = STANDARD_GRAVITY
ALL = list(signal_names())
ANALYTIC = ["blwn", "amp-sweep-up-down", "amp-sweep-up", "freq-sweep-up", "freq-sweep-up-down"]


def d1(f, h):
    """Five-point first derivative at samples 2 … n−3 (error O(h⁴))."""
    return (-f[4:] + 8 * f[3:-1] - 8 * f[1:-3] + f[:-4]) / (12 * h)


def d2(f, h):
    """Five-point second derivative at samples 2 … n−3 (error O(h⁴))."""
    return (-f[4:] + 16 * f[3:-1] - 30 * f[2:-2] + 16 * f[1:-3] - f[:-4]) / (12 * h * h)


def upward_crossing_frequency(t, x):
    """Local frequency from successive upward zero crossings: (mid-times, 1/period)."""
    k = np.flatnonzero((x[:-1] < 0) & (x[1:] >= 0))
    tc = t[k] - x[k] * (t[k + 1] - t[k]) / (x[k + 1] - x[k])
    return 0.5 * (tc[1:] + tc[:-1]), 1.0 / np.diff(tc)


# --------------------------------------------------------------------------- #
# kinematic consistency
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("name", ANALYTIC)
def test_analytic_derivatives_match_finite_differences(name):
    s = make_signal(name, seed=11)
    x, v, a, h = s.displacement, s.velocity, s.acceleration, s.dt
    keep = np.ones(len(s) - 4, bool)
    if name.endswith("up-down"):
        # amplitude or frequency turns at duration/2: acceleration jumps there
        turn = round(len(s) / 2) - 2
        keep[turn - 3 : turn + 4] = False
    # Five-point differences are accurate to ~1e-7 of the peak for these
    # oversampled signals; 1e-6 still catches small terms such as A·φ''·cos φ
    # of a chirp (~2e-4 of the peak acceleration).
    assert np.max(np.abs(d1(x, h) - v[2:-2])[keep]) < 1e-6 * np.abs(v).max()
    assert np.max(np.abs(d2(x, h) - a[2:-2])[keep]) < 1e-6 * np.abs(a).max()
    assert np.max(np.abs(d1(v, h) - a[2:-2])[keep]) < 1e-6 * np.abs(a).max()


@pytest.mark.parametrize("name", ["step", "elcentro", "loma-prieta"])
def test_sampled_kinematics_are_exact_integrals(name):
    # Acceleration linear between samples ⇒ these recurrences hold exactly.
    s = make_signal(name, duration=6.0)
    x, v, a, h = s.displacement, s.velocity, s.acceleration, s.dt
    assert x[0] == 0.0 and v[0] == 0.0
    np.testing.assert_allclose(np.diff(v), h * (a[:-1] + a[1:]) / 2, rtol=0, atol=1e-12 * np.abs(v).max())
    np.testing.assert_allclose(
        np.diff(x), h * v[:-1] + h * h * (2 * a[:-1] + a[1:]) / 6, rtol=0, atol=1e-12 * np.abs(x).max()
    )


def test_integrate_acceleration_is_exact_for_linear_acceleration():
    dt = 0.01
    t = np.arange(101) * dt
    v, x = integrate_acceleration(2.0 + 3.0 * t, dt)
    np.testing.assert_allclose(v, 2 * t + 1.5 * t**2, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(x, t**2 + 0.5 * t**3, rtol=1e-12, atol=1e-15)


# --------------------------------------------------------------------------- #
# amplitudes, frequencies, durations
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize(
    "name, amp, fmax, dur",
    [
        ("blwn", 3e-3, 20.0, 40.0),
        ("amp-sweep-up-down", 2e-3, 4.0, 40.0),
        ("amp-sweep-up", 2e-3, 4.0, 40.0),
        ("freq-sweep-up", 0.75e-3, 20.0, 40.0),
        ("freq-sweep-up-down", 0.5e-3, 20.0, 40.0),
    ],
)
def test_thesis_defaults(name, amp, fmax, dur):
    s = make_signal(name, seed=0)
    assert len(s) == round(dur * 4096) and s.fs == pytest.approx(4096.0)
    assert s.time[-1] == pytest.approx(dur - 1 / 4096)
    assert s.params["amplitude"] == amp and s.params["fmax"] == fmax and s.params["duration"] == dur
    if name == "blwn":
        # Table 5.1: r ~ N(0, A²) low-passed at F keeps a fraction ≈ sqrt(1.8 F/fs) of A
        rms = np.sqrt(np.mean(s.displacement**2))
        assert rms == pytest.approx(s.params["rms"], rel=1e-12)
        assert rms == pytest.approx(amp * np.sqrt(1.8 * fmax / 4096), rel=0.15)
    elif name.startswith("amp"):
        # highest sine peak, t = (k + 1/4)/f, sits a quarter period from the envelope's top
        ramp = dur if name == "amp-sweep-up" else dur / 2
        top = amp * (1 - 1 / (4 * fmax * ramp))
        assert np.abs(s.displacement).max() == pytest.approx(top, rel=1e-6)
    else:
        assert np.abs(s.displacement).max() == pytest.approx(amp, rel=1e-3)
        assert np.abs(s.displacement).max() <= amp * (1 + 1e-12)


def test_freq_sweep_up_reaches_fmax_linearly():
    s = make_signal("freq-sweep-up", amplitude=1e-3, fmax=20.0, duration=10.0, fs=2048)
    tm, f = upward_crossing_frequency(s.time, s.displacement)
    np.testing.assert_allclose(f, 20.0 * tm / 10.0, rtol=0, atol=2e-3 * 20.0)
    assert f[-1] > 0.99 * 20.0


def test_freq_sweep_up_down_turns_at_half_duration():
    # Eq. 3-71 as printed would restart at 0 Hz after T and end at fmax;
    # the implemented sweep falls back from fmax to 0.
    s = thesis_signal("I")
    T = 20.0
    tm, f = upward_crossing_frequency(s.time, s.displacement)
    expected = np.where(tm < T, 10.0 * tm / T, 10.0 * (2 * T - tm) / T)
    far = np.abs(tm - T) > 0.2
    np.testing.assert_allclose(f[far], expected[far], rtol=0, atol=2e-3 * 10.0)
    assert f.max() == pytest.approx(10.0, rel=5e-3)
    assert np.all(f[tm > 39.0] < 0.5)
    assert np.abs(s.displacement).max() == pytest.approx(0.8e-3, rel=1e-3)
    assert len(s) == 40 * 4096 and s.params["preset"] == "thesis signal I"


@pytest.mark.parametrize("name", ["amp-sweep-up", "amp-sweep-up-down"])
def test_amplitude_sweeps_have_fixed_frequency_and_ramped_envelope(name):
    s = make_signal(name, amplitude=2e-3, fmax=4.0, duration=20.0, fs=1024)
    tm, f = upward_crossing_frequency(s.time, s.displacement)
    np.testing.assert_allclose(f[tm > 1.0], 4.0, rtol=1e-3)
    x, t = np.abs(s.displacement), s.time
    envelope = t / 20.0 if name == "amp-sweep-up" else 1 - np.abs(t - 10.0) / 10.0
    assert np.all(x <= 2e-3 * envelope + 1e-15)
    # at 1024 Hz every sine peak, t = (2k + 1)/16 s, is a sample: there |x| = A·envelope
    peaks = 64 * (2 * np.arange(160) + 1)
    np.testing.assert_allclose(x[peaks], 2e-3 * envelope[peaks], rtol=1e-12)


def test_amp_sweep_up_down_needs_whole_cycles():
    with pytest.raises(ValueError, match="must be an integer"):
        make_signal("amp-sweep-up-down", fmax=4.0, duration=10.1)


def test_step_ramp_and_hold():
    s = make_signal("step")
    fs, A = 4096.0, 10e-3
    n_ramp = round(0.1 * fs)
    assert s.params["ramp_time"] == pytest.approx(n_ramp / fs)
    assert len(s) == 5 * 4096
    ideal = A * np.clip((s.time - 1 / fs) * fs / n_ramp, 0.0, 1.0)
    corners = np.zeros(len(s), bool)
    corners[[1, 1 + n_ramp]] = True
    np.testing.assert_allclose(s.displacement[~corners], ideal[~corners], rtol=0, atol=1e-15)
    # rounding of each corner over ±1 sample: at most A·dt/(6 T_r)
    assert np.abs(s.displacement - ideal)[corners].max() == pytest.approx(A / n_ramp / 6, rel=1e-9)
    assert s.velocity[5:n_ramp].min() == pytest.approx(A / (n_ramp / fs), rel=1e-12)
    assert np.all(s.velocity[n_ramp + 3 :] == pytest.approx(0.0, abs=1e-15))
    assert s.displacement[-1] == pytest.approx(A, rel=1e-12)


def test_blwn_band_limited():
    s = make_signal("blwn", duration=20.0, fs=1024, amplitude=1e-3, fmax=20.0, seed=5)
    power = np.abs(np.fft.rfft(s.displacement)) ** 2
    freqs = np.fft.rfftfreq(len(s), s.dt)
    assert power[freqs > 40.0].sum() < 1e-4 * power.sum()
    assert power[(freqs > 5) & (freqs < 15)].sum() > 0.3 * power.sum()
    # starts and ends at rest
    for arr in (s.displacement, s.velocity, s.acceleration):
        assert abs(arr[0]) < 1e-12 * np.abs(arr).max() and abs(arr[-1]) < 1e-12 * np.abs(arr).max()


# --------------------------------------------------------------------------- #
# earthquakes
# --------------------------------------------------------------------------- #
def test_elcentro_record():
    t, ag = load_ground_motion("elcentro")
    assert t.size == 2688 and t[1] == pytest.approx(0.02) and t[-1] == pytest.approx(53.74)
    assert np.abs(ag).max() / G == pytest.approx(0.349, abs=5e-4)
    assert ag[0] == pytest.approx(-1.4275799e-3 * G, rel=1e-12)


def test_loma_prieta_record():
    t, ag = load_ground_motion("loma-prieta")
    assert t.size == 7995
    assert np.allclose(np.diff(t), 0.005)
    assert ag[0] == pytest.approx(0.1394908e-2 * G, rel=1e-12)
    assert ag[-1] == pytest.approx(0.1801168e-4 * G, rel=1e-12)


@pytest.mark.parametrize("scale", [0.4, 0.5])
def test_earthquake_pga_is_scale_times_record(scale):
    raw = np.abs(load_ground_motion("elcentro")[1]).max()
    # 4000 Hz: every record sample (0.02 s) is on the grid, so linear
    # interpolation keeps the peak exactly
    s = make_signal("elcentro", scale=scale, fs=4000, duration=53.76, baseline="none")
    assert np.abs(s.acceleration).max() == pytest.approx(scale * raw, rel=1e-12)
    assert np.abs(s.acceleration).max() / G == pytest.approx(0.349 * scale, rel=2e-3)
    corrected = make_signal("elcentro", scale=scale, fs=4000, duration=53.76)
    assert np.abs(corrected.acceleration).max() == pytest.approx(scale * raw, rel=5e-3)
    assert corrected.params["baseline_max_correction"] < 5e-3 * scale * raw


def test_baseline_correction_removes_drift():
    raw = make_signal("elcentro", scale=1.0, fs=200, duration=53.76, baseline="none")
    fixed = make_signal("elcentro", scale=1.0, fs=200, duration=53.76)
    assert np.abs(raw.displacement).max() > 1.0  # metres of drift
    assert 0.1 < np.abs(fixed.displacement).max() < 0.25
    assert abs(fixed.velocity[-1]) < 1e-12 and abs(fixed.displacement[-1]) < 1e-12
    # an already processed record is left essentially untouched
    lp = make_signal("loma-prieta", scale=1.0, fs=200)
    assert lp.params["baseline_max_correction"] < 1e-5


def test_earthquake_defaults_and_presets():
    s = make_signal("elcentro")
    assert s.params["scale"] == 0.4 and s.fs == pytest.approx(4096.0)
    assert len(s) == 42 * 4096
    lp = make_signal("loma-prieta")
    assert lp.time[-1] <= 39.97 and lp.time[-1] > 39.97 - 1 / 4096
    two = thesis_signal("ii")
    assert two.fs == pytest.approx(4000.0) and two.params["scale"] == 0.5
    assert len(two) == 214961  # 0 … 53.74 s at 4000 Hz
    assert np.abs(two.acceleration).max() / G == pytest.approx(0.5 * 0.3487, rel=5e-3)


def test_earthquake_limits():
    with pytest.raises(ValueError, match="exceeds the record"):
        make_signal("loma-prieta", duration=45.0)
    with pytest.raises(ValueError, match="only upsamples"):
        make_signal("loma-prieta", fs=100.0)


def test_packaged_files_are_the_originals():
    expected = {
        "elcentro_1940_ns.dat.gz": "fd6e0ec6ec0d8eb8ff01152ce86b8f2a815f18fd95bdc32fc7a655cd70dd45b0",
        "RSN753_LOMAP_CLS000.AT2.gz": "1865b6d3762424b9b9869a6ea9282f1104d77afd7b0cc5f0e78ea6e3914493d7",
    }
    folder = resources.files("bayes_mr.data").joinpath("resources")
    notes = folder.joinpath("GROUND_MOTIONS.md").read_text()
    for name, digest in expected.items():
        data = gzip.decompress(folder.joinpath(name).read_bytes())
        assert hashlib.sha256(data).hexdigest() == digest
        assert digest in notes


# --------------------------------------------------------------------------- #
# file formats
# --------------------------------------------------------------------------- #
AT2_HEAD = "PEER NGA STRONG MOTION DATABASE RECORD\nTest\nACCELERATION TIME SERIES IN UNITS OF G\n"


def test_at2_reader_parses_and_checks(tmp_path):
    good = tmp_path / "ok.AT2.gz"
    with gzip.open(good, "wt") as fh:
        fh.write(AT2_HEAD + "NPTS=    7, DT=   .0100 SEC,\n")
        fh.write("   .1E-01  -.2E-01-.3E-01   .4E-01   .5E-01\n   .6E-01   .7E-01\n")
    t, a = read_peer_at2(good)
    np.testing.assert_allclose(t, 0.01 * np.arange(7))
    np.testing.assert_allclose(a / G, [0.01, -0.02, -0.03, 0.04, 0.05, 0.06, 0.07])

    cases = {
        "NPTS=8 but": "NPTS=    8, DT=   .0100 SEC,\n" + "  .1  .2  .3  .4  .5\n  .6  .7\n",
        "line 4": "NPTS 7 DT .01\n" + "  .1  .2  .3  .4  .5\n  .6  .7\n",
        "5 values": "NPTS=    7, DT=   .0100 SEC,\n" + "  .1  .2  .3  .4  .5  .6\n  .7\n",
        "unexpected text": "NPTS=    7, DT=   .0100 SEC,\n" + "  .1  .2  x3  .4  .5\n  .6  .7\n",
    }
    for i, (message, body) in enumerate(cases.items()):
        bad = tmp_path / f"bad{i}.AT2"
        bad.write_text(AT2_HEAD + body)
        with pytest.raises(GroundMotionFormatError, match=message):
            read_peer_at2(bad)
    cm = tmp_path / "cm.AT2"
    cm.write_text(AT2_HEAD.replace("UNITS OF G", "UNITS OF CM/S/S") + "NPTS= 2, DT= .01 SEC\n .1 .2\n")
    with pytest.raises(GroundMotionFormatError, match="line 3"):
        read_peer_at2(cm)


def test_two_column_reader_checks(tmp_path):
    ok = tmp_path / "ok.dat"
    ok.write_text("0.00 0.1\r\n0.02 -0.2\r\n\r\n0.04 0.3\r\n")
    t, a = read_two_column(ok)
    np.testing.assert_allclose(t, [0, 0.02, 0.04])
    np.testing.assert_allclose(a, [0.1 * G, -0.2 * G, 0.3 * G])
    for body, message in [
        ("0.00 0.1\n0.02 0.2 9\n", "expected 2 columns"),
        ("0.00 0.1\n0.02 0.2\n0.05 0.3\n", "not uniformly"),
        ("0.00 0.1\n0.02 abc\n", "not a number"),
        ("0.00 0.1\n0.02 nan\n", "non-finite"),
    ]:
        bad = tmp_path / "bad.dat"
        bad.write_text(body)
        with pytest.raises(GroundMotionFormatError, match=message):
            read_two_column(bad)


# --------------------------------------------------------------------------- #
# API contract
# --------------------------------------------------------------------------- #
def test_blwn_seeded_reproducibility():
    a = make_signal("blwn", duration=2.0, seed=3)
    b = make_signal("blwn", duration=2.0, seed=3)
    c = make_signal("blwn", duration=2.0, rng=np.random.default_rng(3))
    d = make_signal("blwn", duration=2.0, seed=4)
    np.testing.assert_array_equal(a.displacement, b.displacement)
    np.testing.assert_array_equal(a.acceleration, c.acceleration)
    assert not np.allclose(a.displacement, d.displacement)
    fresh = make_signal("blwn", duration=2.0)
    again = make_signal("blwn", duration=2.0, seed=fresh.params["seed"])
    np.testing.assert_array_equal(fresh.velocity, again.velocity)


def test_errors():
    with pytest.raises(ValueError, match="valid names: blwn, .*loma-prieta"):
        make_signal("kobe")
    with pytest.raises(ValueError, match="does not take 'fmax'"):
        make_signal("elcentro", fmax=10.0)
    with pytest.raises(ValueError, match="does not take 'scale'"):
        make_signal("freq-sweep-up", scale=0.5)
    with pytest.raises(ValueError, match="below fs/2"):
        make_signal("freq-sweep-up", fmax=600.0, fs=1000.0)
    with pytest.raises(ValueError, match="not both"):
        make_signal("blwn", seed=1, rng=np.random.default_rng(1))
    with pytest.raises(ValueError, match="amplitude must be a positive"):
        make_signal("step", amplitude=-1e-3)
    with pytest.raises(ValueError, match="baseline"):
        make_signal("elcentro", baseline="quadratic")
    with pytest.raises(ValueError, match="valid: I, II"):
        thesis_signal("III")


def test_signal_object():
    s = make_signal("freq-sweep-up", duration=1.0, fs=512)
    with pytest.raises(ValueError):
        s.displacement[0] = 1.0  # read-only
    assert set(s.as_input("structure")) == {"ground_acceleration"}
    assert s.as_input("device")["velocity"] is s.velocity
    with pytest.raises(ValueError, match="kind"):
        s.as_input("frame")
    with pytest.raises(ValueError, match="samples"):
        Signal(np.arange(3.0), np.zeros(3), np.zeros(2), np.zeros(3), "x")
    assert all(isinstance(v, str) and v for v in signal_names().values())
    assert len(signal_names()) == 8
