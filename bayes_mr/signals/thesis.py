"""The analytic thesis signals: frequency and amplitude sweeps, the step, BLWN.

Velocity and acceleration are the exact derivatives of the displacement:
closed-form for sweeps, exact integrals of a sampled acceleration for the
step, spectral derivatives times a smooth taper for BLWN.

Reading of Table 5.1 (where it is ambiguous or inconsistent)
-----------------------------------------------------------
* Frequency sweeps use eq. 3-71. For up–down the sweep turns at
  ``T = duration / 2`` (the thesis calls T "the length of the signal" for
  signal I, 40 s, while eq. 3-71 runs to 2T; we keep the stated length, so
  signal I is 40 s long and peaks at 10 Hz at 20 s — pass ``duration=80`` for
  the other reading). The second branch of eq. 3-71 as printed,
  ``sin(π t f (2T − t)/T)``, has instantaneous frequency ``f (t − T)/T``: it
  jumps from f to 0 at T and climbs back to f — an up–up sweep, not up–down.
  We use the frequency-continuous mirror of the up sweep,
  ``φ(t) = 2φ(T) − φ(2T − t) = 2π f T − π f (2T − t)²/T``, whose frequency
  falls linearly from f at T to 0 at 2T (phase and velocity continuous at T).
* Table 5.1 prints the *amplitude* sweeps (II, VI) with the same chirp
  formula as the frequency sweeps. A chirp of constant amplitude is not an
  amplitude sweep, and the table's f = 4 Hz fits a fixed test frequency, so
  we implement amplitude sweeps as a sine at ``fmax`` whose amplitude ramps
  linearly 0 → A (up), or 0 → A → 0 with the turn at ``duration / 2``
  (up–down). For up–down, ``fmax · duration`` must be an integer so the turn
  falls on a zero of the sine (else the velocity would jump there).
* Step: the table's T (0.1 s) is the ramp time (``ramp_time``), rounded to a
  whole number of samples; the record then holds A until ``duration``
  (default 5 s, our choice: the thesis does not give the record length). The ramp starts
  one sample after t = 0 and its two corners are rounded over ±1 sample: the
  acceleration is then a one-sample triangular pulse of area ±A/T_r at each
  corner, which the sampled acceleration represents exactly (a sharp corner
  would need a Dirac pulse that no sample can hold, and a structure driven by
  a sampled zero acceleration would not move). Between the corners the
  displacement is the exact ramp / plateau.
* BLWN: as Table 5.1 writes it — draw ``r ~ N(0, A²)`` per sample, low-pass
  it at F with the zero-phase Butterworth of :mod:`bayes_mr.numerics.synthetic_noise` (gain 1
  in the pass band), and taper the first and last second (quintic, so x, v, a
  start and end at 0). The motion's RMS is then about ``A · sqrt(1.8 F/fs)``
  (0.29 mm for A = 3 mm, F = 20 Hz, 4096 Hz; the actual value is in
  ``params["rms"]``). Rescaling to RMS = A instead would ask a small shake
  table for 7.5 g peaks, which the thesis's table cannot have delivered.
"""

from __future__ import annotations

import numpy as np

from bayes_mr.numerics.synthetic_noise import zero_phase_lowpass_gain
from bayes_mr.signals.signal import integrate_acceleration

# Taper of the BLWN ends [s] (capped at a quarter of the record): the table
# must start and end at rest; 1 s leaves 95 % of a 40 s record untouched.
_BLWN_TAPER_S = 1.0


def _from_phase(amp: float, phi, dphi, ddphi):
    """x = A sin φ(t) and its exact derivatives."""
    s, c = np.sin(phi), np.cos(phi)
    return amp * s, amp * dphi * c, amp * (ddphi * c - dphi * dphi * s)


def _smootherstep(s: np.ndarray, length: float):
    """Quintic ramp 0 → 1 on s ∈ [0, 1] (zero 1st and 2nd derivative at both ends) and d/dt, d²/dt²."""
    s = np.clip(s, 0.0, 1.0)
    h = s**3 * (10.0 - 15.0 * s + 6.0 * s * s)
    dh = 30.0 * s * s * (1.0 - s) ** 2 / length
    ddh = 60.0 * s * (1.0 - s) * (1.0 - 2.0 * s) / length**2
    return h, dh, ddh


def freq_sweep_up(t: np.ndarray, amplitude: float, fmax: float, duration: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Chirp A sin(π f t²/T) (eq. 3-71), frequency 0 → ``fmax`` [Hz] over ``duration`` [s].

    Returns displacement [m], velocity [m/s] and acceleration [m/s²] at times ``t`` [s].
    """
    T = duration
    phi = np.pi * fmax * t * t / T  # eq. 3-71, first branch: f(t) = fmax t / T
    return _from_phase(amplitude, phi, 2 * np.pi * fmax * t / T, np.full_like(t, 2 * np.pi * fmax / T))


def freq_sweep_up_down(t: np.ndarray, amplitude: float, fmax: float, duration: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Chirp 0 → ``fmax`` → 0 Hz turning at ``duration`` / 2 (eq. 3-71, frequency-continuous).

    Returns displacement [m], velocity [m/s] and acceleration [m/s²] at times ``t`` [s].
    """
    T = duration / 2.0
    up = t < T
    down_t = 2 * T - t
    # Down branch: mirror of the up phase about t = T (see module docstring).
    phi = np.where(up, np.pi * fmax * t * t / T, 2 * np.pi * fmax * T - np.pi * fmax * down_t**2 / T)
    dphi = 2 * np.pi * fmax * np.where(up, t, down_t) / T
    ddphi = np.where(up, 1.0, -1.0) * 2 * np.pi * fmax / T
    return _from_phase(amplitude, phi, dphi, ddphi)


def amp_sweep(t: np.ndarray, amplitude: float, fmax: float, duration: float, *, down: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sine at ``fmax`` [Hz] whose amplitude ramps 0 → A [m] (or 0 → A → 0 when ``down``).

    Returns displacement [m], velocity [m/s] and acceleration [m/s²] at times ``t`` [s].
    """
    w = 2 * np.pi * fmax
    if down:
        Th = duration / 2.0
        env = 1.0 - np.abs(t - Th) / Th
        denv = np.where(t < Th, 1.0, -1.0) / Th
    else:
        env = t / duration
        denv = np.full_like(t, 1.0 / duration)
    s, c = np.sin(w * t), np.cos(w * t)
    x = amplitude * env * s
    v = amplitude * (denv * s + env * w * c)
    a = amplitude * (2 * denv * w * c - env * w * w * s)  # env'' = 0 between corners
    return x, v, a


def step(n: int, fs: float, amplitude: float, ramp_time: float) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], float]:
    """Ramp to ``amplitude`` [m] over ``ramp_time`` [s], then hold, in ``n`` samples at ``fs`` [Hz].

    Returns (displacement, velocity, acceleration) and the ramp time actually
    used [s] (a whole number of samples).
    """
    dt = 1.0 / fs
    n_ramp = max(1, round(ramp_time * fs))
    if n < n_ramp + 3:
        raise ValueError(
            f"step: duration must exceed the ramp by 2 samples ({(n_ramp + 3) / fs:g} s at fs={fs:g} Hz)"
        )
    peak = amplitude / (n_ramp * dt) / dt  # triangle of half-width dt and area A / T_r
    a = np.zeros(n)
    a[1] = peak
    a[1 + n_ramp] = -peak
    v, x = integrate_acceleration(a, dt)
    return (x, v, a), n_ramp / fs


def blwn(n: int, fs: float, amplitude: float, fmax: float, gen: np.random.Generator) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], float]:
    """Band-limited white noise: N(0, ``amplitude``²) [m] low-passed at ``fmax`` [Hz], tapered at both ends.

    Returns (displacement, velocity, acceleration) of ``n`` samples at ``fs``
    [Hz] and the taper length [s].
    """
    t = np.arange(n) / fs
    # Thesis: r ~ N(0, A²), x = lowPassFilter(r, F); filtered in the frequency
    # domain so x is a trigonometric polynomial with exact derivatives.
    r = gen.normal(0.0, amplitude, n)
    freqs = np.fft.rfftfreq(n, 1.0 / fs)
    spec = np.fft.rfft(r) * zero_phase_lowpass_gain(freqs, fmax)
    iw = 2j * np.pi * freqs
    if n % 2 == 0:
        iw[-1] = 0.0  # the Nyquist term has no odd derivative on the grid
    xf = np.fft.irfft(spec, n)
    vf = np.fft.irfft(iw * spec, n)
    af = np.fft.irfft(iw * iw * spec, n)
    # Smooth taper so the motion starts and ends at rest (x, v, a → 0).
    length = min(_BLWN_TAPER_S, t[-1] / 4.0)
    h1, dh1, ddh1 = _smootherstep(t / length, length)
    h2, dh2, ddh2 = _smootherstep((t[-1] - t) / length, length)
    dh2 = -dh2  # d/dt of h((t_end − t)/L); the second derivative keeps its sign
    w, dw, ddw = h1 * h2, dh1 * h2 + h1 * dh2, ddh1 * h2 + 2 * dh1 * dh2 + h1 * ddh2
    x = xf * w
    v = vf * w + xf * dw
    a = af * w + 2 * vf * dw + xf * ddw
    return (x, v, a), length

