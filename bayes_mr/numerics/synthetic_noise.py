"""Band-limited white noise, as the thesis adds it to inputs and measurements.

The thesis makes its simulated data "real" with "1 % RMS random, band-limited
white noise" on the input and on every measured output (§3.4, §3.8.1).
:func:`add_noise` does exactly that; :func:`band_limited_noise` draws the noise.

Filter convention (shared with the BLWN signal of :mod:`bayes_mr.signals`): a
zero-phase Butterworth low-pass of order :data:`BUTTER_ORDER` applied forward
and backward, i.e. the real gain ``|H(f)|² = 1 / (1 + (f/f_c)^(2·order))`` on
every Fourier coefficient. It is applied in the frequency domain (circularly),
so the noise is stationary from the first sample to the last, with no
start-up transient such as ``filtfilt``'s padding leaves. At ``f_c`` the
amplitude gain is 1/2 (−6 dB); at ``2 f_c`` it is 1/257.
"""

from __future__ import annotations

import numpy as np

#: Order of the Butterworth prototype (applied twice: zero phase, 8th-order roll-off).
BUTTER_ORDER = 4

RngLike = np.random.Generator | np.random.SeedSequence | int


def as_seed_sequence(seed: np.random.SeedSequence | int | None) -> np.random.SeedSequence:
    """``seed`` as a :class:`numpy.random.SeedSequence` (itself if it is one).

    ``None`` draws fresh entropy from the operating system: the callers that
    allow it record ``.entropy`` with their result, so the draw can be repeated.
    """
    return seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)


def as_generator(rng: RngLike) -> np.random.Generator:
    """A :class:`numpy.random.Generator` from a Generator, a SeedSequence or an int seed.

    ``None`` is refused: every random draw in the package is reproducible
    from an explicit seed (no global or hidden RNG).
    """
    if rng is None:
        raise TypeError("pass a numpy.random.Generator or an integer seed (None is not reproducible)")
    if isinstance(rng, (bool, float)):
        raise TypeError(f"rng must be a numpy Generator, SeedSequence or int, got {rng!r}")
    return np.random.default_rng(rng)


def zero_phase_lowpass_gain(freqs: np.ndarray, band: float, order: int = BUTTER_ORDER) -> np.ndarray:
    """Gain of a forward–backward (zero-phase) Butterworth low-pass.

    Parameters
    ----------
    freqs : array
        Frequencies [Hz] (non-negative).
    band : float
        Corner frequency f_c [Hz] of the Butterworth prototype.
    order : int
        Prototype order; the forward–backward gain falls as ``f^(−2·order)``.

    Returns
    -------
    ndarray
        ``1 / (1 + (f/f_c)^(2·order))``, same shape as ``freqs`` (real, so no phase shift).
    """
    return 1.0 / (1.0 + (np.asarray(freqs, float) / band) ** (2 * order))


def _check_band(band: float | None, fs: float) -> None:
    if band is None:
        return
    if not np.isfinite(band) or not 0 < band < fs / 2:
        raise ValueError(f"band must be in (0, fs/2) = (0, {fs / 2:g}) Hz, got {band!r}")


def band_limited_noise(
    n: int, fs: float, rms: float, rng: RngLike, band: float | None = None
) -> np.ndarray:
    """Zero-mean Gaussian noise with an exact RMS, optionally low-passed.

    Parameters
    ----------
    n : int
        Number of samples (≥ 2).
    fs : float
        Sampling rate [Hz].
    rms : float
        Requested root mean square (units of the channel). The sample mean is
        removed before rescaling, so the returned noise has RMS = SD (ddof 0)
        = ``rms`` to rounding.
    rng : numpy.random.Generator or int or SeedSequence
        Source of randomness (an int is a seed).
    band : float, optional
        Low-pass corner [Hz], ``0 < band < fs/2``: zero-phase Butterworth (see
        the module docstring). ``None`` keeps the noise white up to fs/2.

    Returns
    -------
    ndarray, shape (n,)
    """
    n = int(n)
    if n < 2:
        raise ValueError(f"need at least 2 samples, got n={n}")
    if not np.isfinite(fs) or fs <= 0:
        raise ValueError(f"fs must be a positive sampling rate [Hz], got {fs!r}")
    if not np.isfinite(rms) or rms < 0:
        raise ValueError(f"rms must be finite and ≥ 0, got {rms!r}")
    _check_band(band, fs)
    gen = as_generator(rng)
    w = gen.standard_normal(n)
    if band is not None:
        spec = np.fft.rfft(w)
        spec *= zero_phase_lowpass_gain(np.fft.rfftfreq(n, 1.0 / fs), band)
        w = np.fft.irfft(spec, n)
    w -= w.mean()
    norm = np.sqrt(np.mean(w * w))
    if rms == 0.0:
        return np.zeros(n)
    return w * (rms / norm)


def add_noise(
    x: np.ndarray,
    percent_rms: float,
    rng: RngLike,
    fs: float,
    band: float | None = None,
) -> tuple[np.ndarray, float]:
    """Add Gaussian noise whose RMS is a given fraction of the signal's RMS.

    Parameters
    ----------
    x : array, shape (n,)
        Clean signal (finite).
    percent_rms : float
        Noise level as a FRACTION of RMS(x): 0.01 is the thesis's "1 % RMS"
        (same convention as ``--noise 0.01`` on the command line). Values ≥ 1
        are refused, because they almost always mean a percentage was passed.
    rng : numpy.random.Generator or int or SeedSequence
        Source of randomness (an int is a seed).
    fs : float
        Sampling rate of ``x`` [Hz].
    band : float, optional
        Low-pass corner of the noise [Hz]; ``None`` = white up to fs/2.

    Returns
    -------
    noisy : ndarray, shape (n,)
        ``x + noise``.
    sd : float
        Standard deviation (= RMS) of the noise actually added, in the units of
        ``x``: ``percent_rms · sqrt(mean(x²))``. Use it as σ in the likelihood
        and in the MSE.
    """
    x = np.asarray(x, dtype=float)
    if x.ndim != 1:
        raise ValueError(f"x must be 1-D, got shape {x.shape}")
    if not np.isfinite(x).all():
        raise ValueError(f"x has {int((~np.isfinite(x)).sum())} non-finite values")
    if not np.isfinite(percent_rms) or not 0 <= percent_rms < 1:
        raise ValueError(
            f"percent_rms is a fraction in [0, 1) (0.01 = 1 % RMS), got {percent_rms!r}"
        )
    sd = float(percent_rms * np.sqrt(np.mean(x * x)))
    return x + band_limited_noise(x.size, fs, sd, rng, band), sd
