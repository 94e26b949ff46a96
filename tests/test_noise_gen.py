"""Band-limited white noise (bayes_mr.numerics.synthetic_noise)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal as sps

from bayes_mr.numerics.synthetic_noise import add_noise, band_limited_noise, zero_phase_lowpass_gain


@pytest.mark.parametrize("band", [None, 25.0])
def test_rms_is_exact_and_mean_zero(band):
    e = band_limited_noise(5000, 500.0, 0.37, 1, band=band)
    assert e.shape == (5000,)
    assert np.sqrt(np.mean(e**2)) == pytest.approx(0.37, rel=1e-12)
    assert abs(e.mean()) < 1e-14


def test_seeded():
    a = band_limited_noise(1000, 100.0, 1.0, 7, band=10.0)
    b = band_limited_noise(1000, 100.0, 1.0, np.random.default_rng(7), band=10.0)
    c = band_limited_noise(1000, 100.0, 1.0, 8, band=10.0)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)
    gen = np.random.default_rng(0)
    first, second = band_limited_noise(100, 1.0, 1.0, gen), band_limited_noise(100, 1.0, 1.0, gen)
    assert not np.allclose(first, second)  # a Generator advances between calls


def test_band_limit_in_spectrum():
    fs, band = 1000.0, 50.0
    e = band_limited_noise(2**17, fs, 1.0, 2, band=band)
    f, p = sps.welch(e, fs=fs, nperseg=4096)
    total = p.sum()
    assert p[f > 2 * band].sum() < 1e-4 * total
    # shape of the passband and the corner: PSD ∝ |H(f)|⁴ with |H|² = 1/(1 + (f/fc)^8)
    passband = p[(f > 2) & (f < 0.5 * band)].mean()
    gain4 = zero_phase_lowpass_gain(f, band) ** 2
    near = (f > 0.9 * band) & (f < 1.1 * band)
    assert p[near].mean() / passband == pytest.approx(gain4[near].mean(), rel=0.15)
    assert gain4[np.argmin(np.abs(f - band))] == pytest.approx(0.25, rel=0.05)


def test_white_without_band():
    e = band_limited_noise(2**16, 1000.0, 1.0, 3)
    f, p = sps.welch(e, fs=1000.0, nperseg=1024)
    low, high = p[(f > 10) & (f < 250)].mean(), p[(f > 250) & (f < 490)].mean()
    assert low / high == pytest.approx(1.0, rel=0.05)


def test_add_noise_level_is_fraction_of_rms():
    t = np.arange(4000) / 1000.0
    x = 2.0 + np.sin(2 * np.pi * 3 * t)  # RMS = sqrt(4 + 1/2) = 2.1213…
    noisy, sd = add_noise(x, 0.01, 5, fs=1000.0, band=100.0)
    assert sd == pytest.approx(0.01 * np.sqrt(4.5), rel=1e-3)
    assert sd == pytest.approx(0.01 * np.sqrt(np.mean(x**2)), rel=1e-12)
    assert np.sqrt(np.mean((noisy - x) ** 2)) == pytest.approx(sd, rel=1e-12)
    again, _ = add_noise(x, 0.01, 5, fs=1000.0, band=100.0)
    np.testing.assert_array_equal(noisy, again)
    same, zero = add_noise(x, 0.0, 5, fs=1000.0)
    assert zero == 0.0 and np.array_equal(same, x)


def test_errors():
    x = np.ones(100)
    with pytest.raises(ValueError, match="fraction"):
        add_noise(x, 1.0, 1, fs=100.0)  # "1 %" passed as a percentage
    with pytest.raises(ValueError, match="fraction"):
        add_noise(x, -0.01, 1, fs=100.0)
    with pytest.raises(ValueError, match="non-finite"):
        add_noise(np.array([1.0, np.nan, 2.0]), 0.01, 1, fs=100.0)
    with pytest.raises(ValueError, match="1-D"):
        add_noise(np.ones((3, 3)), 0.01, 1, fs=100.0)
    with pytest.raises(ValueError, match="band"):
        band_limited_noise(100, 100.0, 1.0, 1, band=50.0)
    with pytest.raises(ValueError, match="rms"):
        band_limited_noise(100, 100.0, -1.0, 1)
    with pytest.raises(TypeError, match="Generator"):
        band_limited_noise(100, 100.0, 1.0, None)
    with pytest.raises(ValueError, match="at least 2"):
        band_limited_noise(1, 100.0, 1.0, 1)
