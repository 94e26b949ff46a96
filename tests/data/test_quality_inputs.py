"""Quality control on the inputs of thesis chapter 5.

No false alarm on a family of clean simulated tests — step (Table 5.1: 10 mm
over 0.1 s, then held), pulse, sine dwell, sweeps, earthquakes and band-limited
noise, as structure and device tests, several amplitudes and noise seeds —
and a mask never damages what the model sees: a clean device test that starts
with a fast but consistent transient keeps all its samples and fits as it
does without quality control, while the faults of ``test_quality.py`` are still
found (that file runs unchanged).
"""

from __future__ import annotations

import numpy as np
import pytest

from faults import inject_dropout, inject_spikes
from bayes_mr.data.quality import apply_quality, assess, report_of
from bayes_mr.data.quality.consistency import mismatch
from bayes_mr.inference.lsq.least_squares import LSQSettings, fit_lsq
from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.models import get_model
from bayes_mr.signals import Signal, make_signal
from bayes_mr.simulation.simulate import synthesize

FS = 4096.0  # Table 5.1
MASS = 50.0  # kg, the thesis's numerical frame


def step_signal(amplitude: float, duration: float = 2.0) -> Signal:
    """Table 5.1's step test (ramp 0.1 s, then held), shortened to ``duration``."""
    return make_signal("step", amplitude=amplitude, duration=duration, fs=FS)


def pulse_signal(amplitude: float, hold: float = 0.5, duration: float = 2.0) -> Signal:
    """Up by ``amplitude`` [m] over 0.1 s, held ``hold`` s, back down: a step minus a delayed step."""
    up = step_signal(amplitude, duration)
    k = int(round(hold * FS))
    parts = []
    for y in (up.displacement, up.velocity, up.acceleration):
        parts.append(y - np.concatenate([np.zeros(k), y[:-k]]))
    return Signal(up.time, *parts, name="pulse", params={"amplitude": amplitude, "hold": hold})


def dwell_signal(amplitude: float, f: float = 3.0, duration: float = 2.0) -> Signal:
    """A sine dwell that starts at full speed (no taper): x = A sin 2πft."""
    t = np.arange(int(duration * FS)) / FS
    w = 2 * np.pi * f
    return Signal(t, amplitude * np.sin(w * t), amplitude * w * np.cos(w * t), -amplitude * w * w * np.sin(w * t),
                  name="sine-dwell", params={"amplitude": amplitude, "f": f})


def signal_family(scale: float) -> dict[str, Signal]:
    """Every input family at ``scale`` × its Table 5.1 size (2 s; earthquakes 3 s)."""
    return {
        "step": step_signal(10e-3 * scale),
        "pulse": pulse_signal(10e-3 * scale),
        "sine-dwell": dwell_signal(2e-3 * scale),
        "freq-sweep-up": make_signal("freq-sweep-up", amplitude=0.75e-3 * scale, duration=2.0, fs=FS),
        "amp-sweep-up-down": make_signal("amp-sweep-up-down", amplitude=2e-3 * scale, fmax=4.0, duration=2.0, fs=FS),
        "blwn": make_signal("blwn", amplitude=3e-3 * scale, duration=2.0, fs=FS, seed=5),
        "elcentro": make_signal("elcentro", scale=0.4 * scale, duration=3.0, fs=FS),
        "loma-prieta": make_signal("loma-prieta", scale=0.4 * scale, duration=3.0, fs=FS),
    }


#: (kind, size factor, noise fraction, noise seed): two seeds at full size, a small test, a noise-free one.
CASES = [(kind, scale, noise, seed) for kind in ("device", "structure")
         for scale, noise, seed in ((1.0, 0.01, 1), (1.0, 0.01, 2), (0.2, 0.01, 3), (1.0, 0.0, 0))]


@pytest.mark.parametrize("kind,scale,noise,seed", CASES)
def test_clean_chapter5_inputs_mask_nothing(kind, scale, noise, seed):
    model = get_model("dahl")
    theta = model.theta(kind, {})
    for name, sig in signal_family(scale).items():
        ds = synthesize(model, theta, sig.time, sig.as_input(kind), mass=MASS if kind == "structure" else None,
                        noise=noise, seed=seed, source=f"{name}-{kind}")
        valid, report = assess(ds)
        assert valid.all(), f"{name} {kind} ×{scale} noise {noise} seed {seed}: {report.summary()}"


def test_table_5_1_step_test_keeps_every_sample():
    """The thesis step test (10 mm over 0.1 s, 5 s at 4096 Hz) as a structure test: nothing masked, nothing repaired."""
    sig = make_signal("step")
    model = get_model("dahl")
    ds = synthesize(model, model.theta("structure", {}), sig.time, sig.as_input("structure"), mass=MASS,
                    noise=0.01, seed=3)
    out = apply_quality(ds)
    assert out["valid"].values.all() and report_of(out)["repaired"] == {}
    np.testing.assert_array_equal(out["ground_acceleration"].values, ds["ground_acceleration"].values)


# --- a fast, consistent transient is physics ---------------------------------------------


def transient_record(seed: int, fs: float = 1000.0, duration: float = 4.0, rise: float = 5e-3,
                     t_rise: float = 0.04) -> tuple:
    """Dahl device test whose piston first moves ``rise`` [m] in ``t_rise`` [s] (half-cosine), then
    random motion (2 mm RMS, 5 Hz); displacement and velocity exact derivatives, 1 % noise."""
    sig = make_signal("blwn", duration=duration, fs=fs, amplitude=2e-3, fmax=5.0, seed=seed)
    u = np.clip(sig.time / t_rise, 0, 1)
    inputs = sig.as_input("device")
    inputs["displacement"] = inputs["displacement"] + rise * 0.5 * (1 - np.cos(np.pi * u))
    inputs["velocity"] = inputs["velocity"] + np.where(u < 1, rise * 0.5 * np.pi / t_rise * np.sin(np.pi * u), 0.0)
    model = get_model("dahl")
    theta = model.theta("device", {})
    return synthesize(model, theta, sig.time, inputs, noise=0.01, seed=seed + 100), model, theta


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_consistent_transient_keeps_all_samples(seed):
    ds, _, _ = transient_record(seed)
    out = apply_quality(ds)
    assert out["valid"].values.all(), report_of(out)
    np.testing.assert_array_equal(out["velocity"].values, ds["velocity"].values)


def test_consistent_transient_fits_as_without_quality():
    ds, model, theta = transient_record(0, duration=6.0)
    names = model.param_names("device")
    settings = LSQSettings(n_candidates=24, n_starts=2, seed=0)
    fits = {q: fit_lsq(OutputError(model, apply_quality(ds) if q else ds), settings) for q in (True, False)}
    for name in ("c", "k"):
        truth = theta[names.index(name)]
        on, off = fits[True].theta[name], fits[False].theta[name]
        assert abs(on / truth - 1) < 0.02, (name, on, truth)
        assert on == pytest.approx(off, rel=1e-6)  # the record the fit sees is the same


def test_velocity_that_disagrees_is_still_a_fault():
    """The same transient in the velocity alone (the displacement does not move) is masked."""
    ds, _, _ = transient_record(1)
    fs = float(ds.attrs["fs"])
    x = ds["displacement"].values.copy()
    x[: int(0.2 * fs)] = x[int(0.2 * fs)]  # the piston did not make the rise the velocity reports
    bad = ds.copy(deep=True)
    bad["displacement"] = ("time", x, dict(ds["displacement"].attrs))
    valid, report = assess(bad)
    assert not valid[:20].all(), report.summary()


# --- repairs keep the inputs consistent ----------------------------------------------------


def _agreement(ds, a, b):
    """Largest |change of x − ∫v| over [a, b) [m]."""
    e = mismatch(ds["displacement"].values, ds["velocity"].values, float(ds.attrs["dt"]))[a:b]
    return float(np.ptp(e))


def test_velocity_dropout_is_repaired_from_the_displacement():
    ds, _, _ = transient_record(2)
    faulty, idx = inject_dropout(ds, "velocity", 0.5, 60)
    out = apply_quality(faulty)
    assert not out["valid"].values[idx].any()
    rep = report_of(out)["repaired"]
    assert "velocity" in rep and "displacement" not in rep
    a, b = idx[0] - 20, idx[-1] + 20
    # linear bridging would hold the dropped-out value; the repair follows the displacement
    assert _agreement(out, a, b) < 3 * _agreement(ds, a, b) + 1e-12
    v_true = ds["velocity"].values[idx]
    assert np.sqrt(np.mean((out["velocity"].values[idx] - v_true) ** 2)) < 0.1 * np.abs(v_true).max() + 1e-9


def test_displacement_spikes_are_repaired_from_the_velocity():
    ds, _, _ = transient_record(3)
    faulty, idx = inject_spikes(ds, "displacement", 8, 5.0, np.random.default_rng(4), width=2)
    out = apply_quality(faulty)
    assert not out["valid"].values[idx].any()
    x0 = ds["displacement"].values
    noise = float(ds.attrs["noise_sd_displacement"])
    assert np.abs(out["displacement"].values[idx] - x0[idx]).max() < 6 * noise
