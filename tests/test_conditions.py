"""Scores by test condition: a sine test's amplitude and frequency read from its record, and the energy
dissipated per cycle of laws whose loop area is known in closed form."""

import numpy as np
import pytest
import xarray as xr

from bayes_mr.scores.conditions import condition_row, dominant_frequency, energy_per_cycle, motion_of

FS = 500.0


def _sine(amplitude, frequency, duration=2.0):
    t = np.arange(int(duration * FS)) / FS
    w = 2 * np.pi * frequency
    return t, amplitude * np.sin(w * t), amplitude * w * np.cos(w * t)


@pytest.mark.parametrize("amplitude, frequency", [(0.002, 5.0), (0.01, 1.0), (0.025, 0.75)])
def test_amplitude_and_frequency_of_a_sine_test(amplitude, frequency):
    _, x, _ = _sine(amplitude, frequency)
    noisy = x + np.random.default_rng(0).normal(0.0, 0.002 * amplitude, x.size)
    a, f, start = motion_of(noisy, FS)
    assert a == pytest.approx(amplitude, rel=0.01) and f == pytest.approx(frequency, rel=0.01)
    period = round(FS / frequency)  # the steady part starts one period in, on a record of two periods or more
    assert start == (period if 2 * period <= x.size else 0)
    assert np.isnan(dominant_frequency(np.ones(600), FS))


def test_energy_per_cycle_of_a_dashpot_and_of_coulomb_friction():
    """∮ F dx: π c ω A² for a dashpot F = c ẋ, 4 F_d A for friction F = F_d sgn(ẋ) (the loop's area)."""
    amplitude, frequency, c, f_d = 0.01, 2.0, 800.0, 200.0
    _, x, v = _sine(amplitude, frequency)
    e, cycles = energy_per_cycle(c * v, x, FS, frequency, start=250)
    assert cycles == 3 and e == pytest.approx(np.pi * c * 2 * np.pi * frequency * amplitude**2, rel=1e-3)
    e, _ = energy_per_cycle(f_d * np.sign(v), x, FS, frequency, start=250)
    assert e == pytest.approx(4 * f_d * amplitude, rel=1e-3)
    assert energy_per_cycle(c * v, x, FS, frequency, start=x.size - 10) == (None, 0)


def test_a_condition_row_takes_the_manifest_first_and_scores_the_prediction():
    t, x, v = _sine(0.005, 2.0)
    force = 800.0 * v + 200.0 * np.tanh(v / 0.01)
    rec = xr.Dataset({"displacement": ("time", x), "force": ("time", force)}, coords={"time": t})
    same = condition_row(rec, force, conditions={"current": 0.5, "amplitude": 5.0}, units={"amplitude": "mm"})
    assert same["amplitude"] == pytest.approx(0.005) and same["amplitude_from"] == "manifest"
    assert same["frequency"] == pytest.approx(2.0, rel=0.01) and same["frequency_from"] == "record"
    assert (same["command"], same["command_value"]) == ("current", 0.5)
    assert same["force_nrmse"] == 0 and same["peak_force_error"] == 0 and same["energy_error"] == 0
    low = condition_row(rec, 0.9 * force)  # 10 % low everywhere: every relative error is -10 %
    assert low["amplitude_from"] == "record" and low["command"] is None
    assert low["peak_force_error"] == pytest.approx(-0.1) and low["energy_error"] == pytest.approx(-0.1)
    assert low["force_nrmse"] == pytest.approx(0.1, rel=0.02)
