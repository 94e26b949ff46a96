"""Fault injection (and clean synthetic records) for tests and for calibrating quality control.

Each ``inject_*`` function returns a *new* record and the sorted indices of
the samples it corrupted (the ground truth a detector must mask). The faults
imitate what lab records carry: a channel clipped at a rail value,
isolated spikes, a dropout / flat-line, and the end-of-test jump-and-ring
seen in the second measured record of the NEES MR damper (displacement
jumps, velocity about three times anything before, force steps of about two
force ranges between samples over the last ~2 % of the record).

:func:`clean_record` makes fault-free simulated records of several signal
families — the families the quality thresholds are calibrated on.
"""

from __future__ import annotations

import numpy as np
import xarray as xr
from scipy import signal as sps

from bayes_mr.data.derive import smooth_velocity
from bayes_mr.data.schema import DEVICE, STRUCTURE, make_record


def _copy_with(ds: xr.Dataset, name: str, values: np.ndarray) -> xr.Dataset:
    out = ds.copy(deep=True)
    out[name] = ("time", np.asarray(values, float), dict(ds[name].attrs))
    return out


def _rederive_velocity(ds: xr.Dataset) -> xr.Dataset:
    """Keep a Savitzky–Golay velocity consistent with a corrupted displacement."""
    v = ds.get("velocity")
    if v is None or v.attrs.get("derived") != "savgol":
        return ds
    window = int(v.attrs.get("savgol_window", 0)) or None
    vel = smooth_velocity(ds["displacement"].values, float(ds.attrs["dt"]), window=window)
    return _copy_with(ds, "velocity", vel)


def inject_clipping(
    ds: xr.Dataset,
    channel: str,
    fraction_of_peak: float | None = None,
    n: int | None = None,
) -> tuple[xr.Dataset, np.ndarray]:
    """Clip a channel at a constant rail value on the side of its largest excursion.

    Give exactly one of ``fraction_of_peak`` (rail = that fraction of the
    signed peak value) or ``n`` (rail chosen so that the ``n`` most extreme
    samples are clipped — "about two hundred force samples clipped" is
    ``n=200``).

    Returns
    -------
    record : xarray.Dataset
    index : ndarray of int
        Samples whose value was replaced by the rail.
    """
    if (fraction_of_peak is None) == (n is None):
        raise ValueError("inject_clipping: give exactly one of fraction_of_peak or n")
    x = ds[channel].values.astype(float)
    centre = np.median(x)
    top = np.max(x) - centre >= centre - np.min(x)
    sign = 1.0 if top else -1.0
    if n is not None:
        if not 0 < n < x.size:
            raise ValueError(f"inject_clipping: n must be in 1..{x.size - 1}")
        rail = np.sort(sign * x)[::-1][n] * sign
    else:
        peak = np.max(x) if top else np.min(x)
        rail = fraction_of_peak * peak
    hit = sign * x > sign * rail
    y = np.where(hit, rail, x)
    out = _copy_with(ds, channel, y)
    if channel == "displacement":
        out = _rederive_velocity(out)
    return out, np.flatnonzero(hit)


def inject_spikes(
    ds: xr.Dataset,
    channel: str,
    n: int,
    size: float,
    rng: np.random.Generator | int | None = None,
    width: int = 1,
) -> tuple[xr.Dataset, np.ndarray]:
    """Add ``n`` isolated spikes of ``size`` × the channel's standard deviation.

    Spikes have a random sign, are ``width`` samples wide, lie away from the
    first and last 2 % of the record and at least 50 samples apart.

    Returns
    -------
    record : xarray.Dataset
    index : ndarray of int
        Samples carrying a spike.
    """
    rng = np.random.default_rng(rng)
    x = ds[channel].values.astype(float)
    nt = x.size
    lo, hi = int(0.02 * nt), int(0.98 * nt) - width
    if n * 50 > hi - lo:
        raise ValueError("inject_spikes: too many spikes for the record length")
    # draw on a coarse grid so spikes keep ≥ 50 samples apart
    slots = rng.choice((hi - lo) // 50, size=n, replace=False)
    starts = lo + 50 * np.sort(slots) + rng.integers(0, 50 - width, size=n)
    amp = size * np.std(x) * rng.choice([-1.0, 1.0], size=n)
    y = x.copy()
    idx = []
    for s, a in zip(starts, amp):
        y[s : s + width] += a
        idx.extend(range(s, s + width))
    out = _copy_with(ds, channel, y)
    if channel == "displacement":
        out = _rederive_velocity(out)
    return out, np.asarray(idx, int)


def inject_jump_and_ring(
    ds: xr.Dataset,
    start_fraction: float = 0.98,
    *,
    jump: float = 0.3,
    velocity_factor: float = 3.0,
    force_factor: float = 2.0,
    ring_hz: float | None = None,
) -> tuple[xr.Dataset, np.ndarray]:
    """End-of-test disturbance from ``start_fraction`` of the record to its end.

    From sample ``i0 = round(start_fraction * n)``:

    * displacement jumps by ``jump`` × its range and rings about the new level
      (half the jump, at ``ring_hz``, decaying over the disturbance);
    * a measured velocity rings with a peak of ``velocity_factor`` × the largest
      |velocity| before ``i0`` (a derived velocity is re-derived);
    * force alternates sample to sample by ``force_factor`` × its range before
      ``i0`` (decaying), i.e. steps of about two force ranges between samples;
    * accelerations ring with ``velocity_factor`` × their peak before ``i0``.

    Voltage (a command) is left alone.

    Parameters
    ----------
    ring_hz : float, optional
        Ringing frequency [Hz]; default ``fs / 10``.

    Returns
    -------
    record : xarray.Dataset
    index : ndarray of int
        ``i0 .. n-1``.
    """
    n = ds.sizes["time"]
    i0 = int(round(start_fraction * n))
    if not 0 < i0 < n:
        raise ValueError("inject_jump_and_ring: start_fraction must leave samples before and after")
    fs = float(ds.attrs["fs"])
    ring_hz = fs / 10 if ring_hz is None else ring_hz
    tau = np.arange(n - i0) / fs
    env = np.exp(-tau / max(tau[-1], 1.0 / fs))
    ring = np.sin(2 * np.pi * ring_hz * tau + np.pi / 2) * env
    out = ds.copy(deep=True)
    for name in out.data_vars:
        if name in ("valid", "voltage"):
            continue
        x = out[name].values.astype(float)
        before = x[:i0]
        if name == "displacement":
            j = jump * np.ptp(before)
            x[i0:] += j * (1.0 + 0.5 * ring)
        elif name == "velocity":
            if out[name].attrs.get("derived") == "savgol":
                continue
            x[i0:] += velocity_factor * np.max(np.abs(before)) * ring
        elif name == "force":
            alt = np.where(np.arange(n - i0) % 2 == 0, 0.5, -0.5)
            x[i0:] += force_factor * np.ptp(before) * alt * env
        else:
            x[i0:] += velocity_factor * np.max(np.abs(before)) * ring
        out[name] = ("time", x, dict(ds[name].attrs))
    out = _rederive_velocity(out)
    return out, np.arange(i0, n)


def inject_dropout(
    ds: xr.Dataset,
    channel: str,
    start: int | float,
    n: int,
    value: float | None = None,
) -> tuple[xr.Dataset, np.ndarray]:
    """Flat-line ``n`` samples of a channel from ``start`` on.

    Parameters
    ----------
    start : int or float
        First sample (int) or fraction of the record (float in (0, 1)).
    value : float, optional
        Value held during the dropout; default the last good value (a
        "repeated last value" dropout); ``0.0`` gives an exact-zero dropout.

    Returns
    -------
    record : xarray.Dataset
    index : ndarray of int
        The flat-lined samples (a held last value starts one sample later,
        since the sample at ``start - 1`` keeps its true value).
    """
    x = ds[channel].values.astype(float)
    s = int(round(start * x.size)) if isinstance(start, float) else int(start)
    if not 0 < s < x.size - n:
        raise ValueError("inject_dropout: the dropout must lie inside the record")
    y = x.copy()
    y[s : s + n] = x[s - 1] if value is None else value
    out = _copy_with(ds, channel, y)
    if channel == "displacement":
        out = _rederive_velocity(out)
    return out, np.arange(s, s + n)


# ---------------------------------------------------------------- clean records


def _excitation(kind: str, t: np.ndarray, rng: np.random.Generator, f_max: float) -> np.ndarray:
    """Unit-RMS excitation of a family, tapered to zero over 0.2 s at both ends."""
    fs = 1.0 / (t[1] - t[0])
    n = t.size
    if kind == "random":
        sos = sps.butter(4, [0.2, f_max], btype="bandpass", fs=fs, output="sos")
        y = sps.sosfiltfilt(sos, rng.standard_normal(n + 2000))[1000:-1000]
    elif kind == "sweep":  # frequency sweep up then down (thesis 3-71 shape)
        half = t[-1] / 2
        f = np.where(t < half, 0.2 + (f_max - 0.2) * t / half, f_max - (f_max - 0.2) * (t - half) / half)
        phase = 2 * np.pi * np.cumsum(f) / fs + rng.uniform(0, 2 * np.pi)
        y = np.sin(phase)
    elif kind == "amplitude-sweep":  # amplitude up then down at a fixed frequency
        f0 = rng.uniform(0.15, 0.3) * f_max
        # a smooth envelope: an actuator cannot follow a kink in the amplitude
        y = np.sin(np.pi * t / t[-1]) * np.sin(2 * np.pi * f0 * t + rng.uniform(0, 2 * np.pi))
    elif kind == "resampled":  # an earthquake-like record at 50 Hz, linearly interpolated (thesis)
        t50 = np.arange(0.0, t[-1] + 0.04, 0.02)
        sos = sps.butter(4, min(15.0, 0.8 * 25.0), fs=50.0, output="sos")
        g = sps.sosfiltfilt(sos, rng.standard_normal(t50.size))
        u = t50 / t50[-1]
        g *= np.minimum(u / 0.1, 1.0) * np.exp(-np.maximum(u - 0.4, 0.0) / 0.2)
        y = np.interp(t, t50, g)
    else:
        raise ValueError(f"unknown signal family {kind!r}: use random, sweep, amplitude-sweep or resampled")
    ramp = np.clip(np.minimum(t - t[0], t[-1] - t) / 0.2, 0, 1)
    y = y * (0.5 - 0.5 * np.cos(np.pi * ramp))
    return y / np.sqrt(np.mean(y**2))


def _dahl(x: np.ndarray, sigma: float) -> np.ndarray:
    """Dahl state z for a displacement history: dz/dt = σ ẋ (1 − z sgn ẋ).

    Exact per step for piecewise-linear x: with s = sgn Δx,
    z ← s − (s − z) exp(−σ |Δx|).
    """
    dx = np.diff(x)
    decay = np.exp(-sigma * np.abs(dx)).tolist()
    s = np.sign(dx).tolist()
    z = [0.0]
    zi = 0.0
    for si, di in zip(s, decay):
        zi = si - (si - zi) * di
        z.append(zi)
    return np.asarray(z)


def clean_record(
    signal: str = "random",
    kind: str = DEVICE,
    *,
    seed: int = 0,
    duration: float = 10.0,
    fs: float = 2048.0,
    amplitude: float = 5e-3,
    f_max: float = 20.0,
    force_scale: float = 100.0,
    noise: float = 0.01,
    velocity: bool = True,
    mass: float = 50.0,
) -> xr.Dataset:
    """A fault-free simulated record with ``noise`` × RMS Gaussian noise on every channel.

    Device test: the displacement follows the family (RMS ``amplitude`` [m]);
    force = ``force_scale`` · (tanh(ẋ / 0.005 m/s) + 0.2 z), z a Dahl state
    with σ = 3 / amplitude — sharp corners at every velocity reversal.
    Structure test: the ground acceleration follows the family (RMS
    ``amplitude`` [m/s²]) and drives m = ``mass`` kg, k = 20 kN/m, c = 100 N·s/m
    with a Dahl damper F_d = ``force_scale`` · 0.25 N, σ = 2500 (the thesis's
    numerical-study frame), integrated by symplectic Euler with 8 sub-steps.

    Parameters
    ----------
    signal : {"random", "sweep", "amplitude-sweep", "resampled"}
        Band-limited random (0.2–``f_max`` Hz), frequency sweep up–down
        (0.2–``f_max`` Hz), amplitude sweep up–down, or an earthquake-like
        enveloped random record sampled at 50 Hz and linearly interpolated to
        ``fs`` (as the thesis resampled El Centro; ``f_max`` is not used).
    kind : {"device", "structure"}
    seed : int
        Seeds the excitation and the noise.
    velocity : bool
        Device tests: include a measured (noisy) velocity channel.

    Returns
    -------
    xarray.Dataset
        Record in the package schema; ``source`` names the family and seed.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(int(round(duration * fs))) / fs
    e = _excitation(signal, t, rng, f_max)
    if kind == DEVICE:
        channels = _device_channels(amplitude * e, fs, amplitude, force_scale, velocity)
    elif kind == STRUCTURE:
        channels = _frame_channels(amplitude * e, fs, force_scale, mass)
    else:
        raise ValueError(f"kind must be 'device' or 'structure', got {kind!r}")
    noisy = {
        name: y + noise * np.sqrt(np.mean(y**2)) * rng.standard_normal(y.size)
        for name, y in channels.items()
    }
    return make_record(
        t,
        noisy,
        kind=kind,
        mass=mass if kind == STRUCTURE else None,
        source=f"clean_record({signal!r}, {kind!r}, seed={seed})",
    )


def _device_channels(
    x: np.ndarray, fs: float, amplitude: float, force_scale: float, velocity: bool
) -> dict[str, np.ndarray]:
    """Displacement x [m], tanh-plus-Dahl force [N] and (if ``velocity``) velocity [m/s] of a device test."""
    v = np.gradient(x, 1 / fs)
    z = _dahl(x, 3.0 / amplitude)
    f = force_scale * (np.tanh(v / 0.005) + 0.2 * z)
    channels = {"displacement": x, "force": f}
    if velocity:
        channels["velocity"] = v
    return channels


def _frame_channels(ag: np.ndarray, fs: float, force_scale: float, mass: float) -> dict[str, np.ndarray]:
    """Channels of the thesis's Dahl frame driven by ground acceleration ``ag`` [m/s²] (symplectic Euler, 8 sub-steps)."""
    k, c, F_d, sig = 2e4, 100.0, 0.25 * force_scale, 2500.0
    sub = 8
    h = 1.0 / (fs * sub)
    n = ag.size
    xs, vs, zs = np.zeros(n), np.zeros(n), np.zeros(n)
    xi = vi = zi = 0.0
    agl = ag.tolist()
    for i in range(1, n):
        a0, a1 = agl[i - 1], agl[i]
        for j in range(sub):
            a = a0 + (a1 - a0) * (j + 0.5) / sub
            acc = -(c * vi + k * xi + F_d * zi) / mass - a
            vi += h * acc
            dx = h * vi
            s = 1.0 if dx > 0 else -1.0
            zi = s - (s - zi) * np.exp(-sig * abs(dx))
            xi += dx
        xs[i], vs[i], zs[i] = xi, vi, zi
    f = F_d * zs
    acc_abs = -(c * vs + k * xs + f) / mass
    return {"ground_acceleration": ag, "displacement": xs, "acceleration": acc_abs, "force": f}
