"""Derived channels: smoothed velocity, resampled ground motions, decimated records.

* :func:`smooth_velocity` — velocity from displacement by a Savitzky–Golay
  derivative, as the thesis differentiated displacement to get velocity, but
  smoothing: a raw forward difference multiplies the displacement noise by
  ``√2/dt``; :func:`with_velocity` adds it to a device record that has none
  (the "derive" step of :func:`bayes_mr.data.load`).
* :func:`resample` — a ground motion onto a new sampling rate; **linear
  interpolation is the default**, as in the thesis (El Centro at 50 Hz → 4000 Hz),
  a band-limited (polyphase / FFT) alternative on request.
* :func:`decimate_record` — anti-aliased, zero-phase decimation of a whole
  record, keeping the quality mask conservative; used to make likelihoods cheaper.
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import xarray as xr
from scipy import signal

from bayes_mr.data.schema import UNITS

#: Fraction of the (detrended) signal power below the record's bandwidth.
BANDWIDTH_POWER = 0.99
#: Largest Savitzky–Golay window [s]: longer windows only add edge effects.
MAX_WINDOW_S = 0.05


def bandwidth(x: np.ndarray, dt: float, power: float = BANDWIDTH_POWER) -> float:
    """Frequency below which ``power`` of the signal's variance lies [Hz].

    Welch periodogram (Hann windows of ~1 s or n/8 samples) of the linearly
    detrended signal; the cumulative power is read at ``power``.

    Parameters
    ----------
    x : array, shape (n,)
        Signal (any unit).
    dt : float
        Sample interval [s].
    power : float
        Fraction of the variance, 0 < power < 1.

    Returns
    -------
    float
        Bandwidth [Hz]; the Nyquist frequency for a constant signal.
    """
    x = signal.detrend(np.asarray(x, float))
    fs = 1.0 / dt
    nper = int(min(x.size, max(256, min(round(fs), x.size // 8))))
    f, p = signal.welch(x, fs=fs, nperseg=nper)
    c = np.cumsum(p)
    if c[-1] <= 0:
        return fs / 2
    return float(f[np.searchsorted(c, power * c[-1])])


def savgol_window(dt: float, f_band: float, polyorder: int = 3, tol: float = 0.01) -> int:
    """Longest Savitzky–Golay derivative window that is accurate to ``tol`` up to ``f_band``.

    The window is chosen from the sampling rate and the record's bandwidth:
    the largest odd length L (≥ polyorder + 2, ≤ :data:`MAX_WINDOW_S` · fs)
    whose derivative filter's gain stays within ``tol`` (relative) of the ideal
    differentiator ``iω`` for every frequency up to ``f_band``. A longer
    window averages more noise away, so the longest admissible one is taken.

    Parameters
    ----------
    dt : float
        Sample interval [s].
    f_band : float
        Highest frequency that must pass undistorted [Hz].
    polyorder : int
        Polynomial order of the local fit (3: exact for cubic motion).
    tol : float
        Largest relative error of the derivative's gain in the band.

    Returns
    -------
    int
        Window length in samples (odd).
    """
    fs = 1.0 / dt
    lo = polyorder + 2 + (polyorder + 2 + 1) % 2
    hi = max(lo, int(MAX_WINDOW_S * fs) | 1)
    w_band = 2 * np.pi * min(f_band, 0.45 * fs) * dt
    omega = np.linspace(w_band / 64, w_band, 64)
    best = lo
    for length in range(lo, hi + 1, 2):
        h = signal.savgol_coeffs(length, polyorder, deriv=1, delta=1.0, use="conv")
        _, resp = signal.freqz(h, worN=omega)
        half = length // 2  # freqz of a centred FIR: undo the half-window delay
        gain = np.abs(resp * np.exp(1j * omega * half))
        if np.max(np.abs(gain / omega - 1.0)) > tol:
            break
        best = length
    return best


def smooth_velocity(
    x: np.ndarray,
    dt: float,
    *,
    window: int | None = None,
    polyorder: int = 3,
    f_band: float | None = None,
    tol: float = 0.01,
    return_info: bool = False,
):
    """Velocity from displacement by a Savitzky–Golay smoothing differentiator.

    Parameters
    ----------
    x : array, shape (n,)
        Displacement [m] (any unit: velocity comes out in that unit per s).
    dt : float
        Sample interval [s].
    window : int, optional
        Window length in samples (odd). Default: :func:`savgol_window` for the
        record's bandwidth (:func:`bandwidth`, 99 % of the variance) — the
        longest window whose derivative is within ``tol`` of exact up to that
        frequency.
    polyorder : int
        Order of the local polynomial.
    f_band : float, optional
        Bandwidth to preserve [Hz]; default estimated from ``x``.
    tol : float
        Relative gain error allowed inside the band.
    return_info : bool
        Also return ``{"window", "polyorder", "bandwidth_hz"}``.

    Returns
    -------
    v : ndarray, shape (n,)
        Velocity [m/s]. Edges use a polynomial fit to the first/last window
        (``mode="interp"``), not padding.
    info : dict
        Only if ``return_info``.
    """
    x = np.asarray(x, float)
    if f_band is None:
        f_band = bandwidth(x, dt)
    if window is None:
        window = savgol_window(dt, f_band, polyorder, tol)
    window = min(window, x.size - (1 - x.size % 2))  # odd and not longer than the record
    v = signal.savgol_filter(x, window, polyorder, deriv=1, delta=dt, mode="interp")
    if return_info:
        return v, {"window": int(window), "polyorder": int(polyorder), "bandwidth_hz": float(f_band)}
    return v


def savgol_attrs(info: dict) -> dict:
    """Attributes of a velocity derived by :func:`smooth_velocity` (its ``info``)."""
    return {
        "savgol_window": info["window"],
        "savgol_polyorder": info["polyorder"],
        "bandwidth_hz": info["bandwidth_hz"],
    }


def with_velocity(ds: xr.Dataset) -> xr.Dataset:
    """A device record with a ``velocity`` derived from displacement (the record itself if it has one).

    The derivative is :func:`smooth_velocity`'s Savitzky–Golay differentiator
    with the window chosen for the record's bandwidth; the new variable is
    marked ``derived="savgol"`` with ``savgol_window``, ``savgol_polyorder``
    and ``bandwidth_hz`` [Hz] (quality control re-derives it from a repaired
    displacement and does not assess it itself).

    Parameters
    ----------
    ds : xarray.Dataset
        Device-test record in the package schema.

    Returns
    -------
    xarray.Dataset
        A new record with ``velocity`` [m/s] placed after the file's channels.
    """
    if "velocity" in ds:
        return ds
    t = ds["time"].values
    # the step over the whole span, as the reader checked the grid (the
    # ``dt`` attribute is the median step, which differs in the last bits)
    dt = (t[-1] - t[0]) / (t.size - 1)
    v, info = smooth_velocity(ds["displacement"].values, dt, return_info=True)
    attrs = {
        "units": UNITS["velocity"],
        "derived": "savgol",
        **savgol_attrs(info),
        "description": "Savitzky-Golay derivative of displacement (bayes_mr.data.derive.smooth_velocity)",
    }
    out = ds.assign(velocity=("time", v, attrs))
    # velocity among the channels, before the mask (the order CSVs are written in)
    names = [str(n) for n in ds.data_vars if n != "valid"] + ["velocity"]
    return out[names + (["valid"] if "valid" in ds else [])]


def resample(
    t: np.ndarray,
    y: np.ndarray,
    fs_new: float,
    method: str = "linear",
) -> tuple[np.ndarray, np.ndarray]:
    """Resample a uniformly sampled signal (e.g. a ground motion) to ``fs_new``.

    Parameters
    ----------
    t : array, shape (n,)
        Uniform sample times [s].
    y : array, shape (n,)
        Values (any unit).
    fs_new : float
        New sampling rate [Hz].
    method : {"linear", "bandlimited"}
        ``"linear"`` (default, as in the thesis: El Centro at 50 Hz linearly
        interpolated to 4000 Hz) keeps every original sample and adds corners
        at them, i.e. content above the old Nyquist frequency.
        ``"bandlimited"`` interpolates with no content above the old Nyquist
        frequency: polyphase filtering (:func:`scipy.signal.resample_poly`)
        when ``fs_new / fs`` is a ratio of integers up to 1000, otherwise FFT
        resampling (:func:`scipy.signal.resample`) of the linearly detrended
        signal. It rings (Gibbs) near sharp features and at the ends.

    Returns
    -------
    t_new : ndarray, shape (m,)
        ``t[0] + k / fs_new`` up to ``t[-1]``.
    y_new : ndarray, shape (m,)
    """
    t = np.asarray(t, float)
    y = np.asarray(y, float)
    if t.shape != y.shape or t.ndim != 1 or t.size < 2:
        raise ValueError("resample: t and y must be 1-D arrays of the same length ≥ 2")
    if not fs_new > 0:
        raise ValueError(f"resample: fs_new must be positive, got {fs_new}")
    dt = (t[-1] - t[0]) / (t.size - 1)
    m = int(np.floor((t[-1] - t[0]) * fs_new * (1 + 1e-12))) + 1
    t_new = t[0] + np.arange(m) / fs_new
    if method == "linear":
        return t_new, np.interp(t_new, t, y)
    if method != "bandlimited":
        raise ValueError(f"resample: method must be 'linear' or 'bandlimited', got {method!r}")
    ratio = fs_new * dt
    frac = Fraction(ratio).limit_denominator(1000)
    if abs(float(frac) - ratio) <= 1e-9 * ratio:
        up, down = frac.numerator, frac.denominator
        # padtype="line": extrapolate the end trend instead of zero-padding,
        # so the filter does not pull the ends towards zero
        out = signal.resample_poly(y, up, down, padtype="line")
    else:
        trend = np.polyval(np.polyfit(t - t[0], y, 1), t_new - t[0])
        base = signal.detrend(y)
        n_fft = int(round(y.size * ratio))
        out = signal.resample(base, n_fft)
        out = out[: m] + trend[: min(m, n_fft)]
    if out.size < m:  # the last new sample can lie one step past what the filter returns
        out = np.concatenate([out, np.full(m - out.size, y[-1])])
    return t_new, out[:m]


def _stages(factor: int) -> list[int]:
    """Split a decimation factor into stages ≤ 10 (scipy advises ≤ 13 per IIR stage)."""
    stages, rest = [], factor
    for p in range(10, 1, -1):
        while rest % p == 0 and rest > 1:
            stages.append(p)
            rest //= p
    if rest > 1:
        stages.append(rest)  # a large prime: one FIR stage (see decimate_record)
    return stages or [1]


def decimate_record(ds: xr.Dataset, factor: int) -> xr.Dataset:
    """Anti-aliased, zero-phase decimation of a whole record by an integer factor.

    Every channel is low-pass filtered (:func:`scipy.signal.decimate`,
    Chebyshev I order 8 applied forwards and backwards, in stages of ≤ 10; a
    prime factor > 13 uses a zero-phase FIR) and every ``factor``-th sample is
    kept (``time[::factor]``). Masked samples are first bridged by linear
    interpolation so a fault does not ring through the filter; a decimated
    sample is valid only if every source sample from the previous kept
    sample to the next one (exclusive) was valid.

    Noise attributes ``noise_sd_<channel>`` are divided by ``sqrt(factor)``
    (white noise loses that share of its variance in the anti-alias filter);
    the attribute ``decimated`` records the factor applied so far.

    Parameters
    ----------
    ds : xarray.Dataset
        Record in the package schema.
    factor : int
        Decimation factor ≥ 1.

    Returns
    -------
    xarray.Dataset
        New record with ``fs / factor``.
    """
    factor = int(factor)
    if factor < 1:
        raise ValueError(f"decimate_record: factor must be ≥ 1, got {factor}")
    if factor == 1:
        return ds.copy(deep=True)
    n = ds.sizes["time"]
    if n // factor < 2:
        raise ValueError(f"decimate_record: {n} samples cannot be decimated by {factor}")
    valid = ds["valid"].values.astype(bool) if "valid" in ds else np.ones(n, bool)
    idx = np.arange(n)
    keep = idx[::factor]
    out = ds.isel(time=keep).copy(deep=True)
    for name, da in ds.data_vars.items():
        if name == "valid" or da.dims != ("time",):
            continue
        y = da.values.astype(float)
        if not valid.all() and valid.any():
            y = np.interp(idx, idx[valid], y[valid])
        for q in _stages(factor):
            ftype = "iir" if q <= 13 else "fir"
            y = signal.decimate(y, q, ftype=ftype, zero_phase=True)
        out[name] = ("time", y[: keep.size], dict(da.attrs))
    # a kept sample k*factor summarises source samples (k-1)*factor+1 .. (k+1)*factor-1
    bad = (~valid).astype(float)
    window = np.ones(2 * factor - 1)
    touched = np.convolve(bad, window, mode="same") > 0
    new_valid = ~touched[keep]
    out["valid"] = ("time", new_valid, dict(ds["valid"].attrs) if "valid" in ds else {})
    dt = float(ds.attrs.get("dt", np.median(np.diff(ds["time"].values)))) * factor
    out.attrs.update(fs=1.0 / dt, dt=dt, masked=int((~new_valid).sum()))
    out.attrs["decimated"] = int(ds.attrs.get("decimated", 1)) * factor
    for key in list(out.attrs):
        if key.startswith("noise_sd_"):
            out.attrs[key] = float(out.attrs[key]) / np.sqrt(factor)
    return out
