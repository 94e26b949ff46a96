"""Prescribed base (shake-table) or piston motions: the thesis's input signals.

Every signal of thesis Table 5.1 (the experiment) and signals I and II of the
numerical study (§3.8.1) as a :class:`Signal`: time plus displacement,
velocity and acceleration that are *consistent* — each is the derivative of the
one before, exactly, not by finite differences of noisy data:

* sweeps and the step ramp are analytic: velocity and acceleration are the
  closed-form derivatives of the displacement;
* BLWN is a trigonometric polynomial (filtered in the frequency domain) times
  a smooth taper: derivatives are its exact spectral derivatives by the
  product rule;
* earthquakes are acceleration records: velocity and displacement are their
  exact integrals from rest under the package's sampling convention (input
  linear between samples, SPEC "Data"), after a documented baseline correction.

A structure test is driven by ``acceleration`` (the ground acceleration
ẍ_g), a device test by ``displacement`` (and ``velocity``); see
:meth:`Signal.as_input`.

Reading of Table 5.1 (where it is ambiguous or inconsistent)
-----------------------------------------------------------
``duration`` is always the length of the returned record: it holds
``round(duration · fs)`` samples at ``t_k = k / fs``, spanning [0, duration).

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
  it at F with the zero-phase Butterworth of :mod:`bayes_mr.synthetic_noise` (gain 1
  in the pass band), and taper the first and last second (quintic, so x, v, a
  start and end at 0). The motion's RMS is then about ``A · sqrt(1.8 F/fs)``
  (0.29 mm for A = 3 mm, F = 20 Hz, 4096 Hz; the actual value is in
  ``params["rms"]``). Rescaling to RMS = A instead would ask a small shake
  table for 7.5 g peaks, which the thesis's table cannot have delivered.
* Earthquakes: Table 5.1 writes ``x_g = A · ElCentro(S k Δt)`` with A = 0.1
  and S = 0.4 — S sits inside the argument, which reads like a time scale.
  We follow the SPEC and §3.8.1 ("set at 50 % of the original earthquake
  acceleration"): the ground ACCELERATION is ``scale`` × the record, on the
  record's own time axis, resampled to ``fs`` by linear interpolation
  (MATLAB ``interp1``, as the thesis did). A is not used.
  The table's T (42 s for El Centro) is the default ``duration``; the Kobe
  record (T = 51 s) is not available and Loma Prieta (39.97 s) stands in for
  it, in full by default.

Units: SI throughout (``amplitude`` in metres, frequencies in Hz).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .data.ground_motions import GROUND_MOTIONS, load_ground_motion
from .synthetic_noise import as_generator, zero_phase_lowpass_gain

#: Sampling rate of every Table 5.1 signal [Hz].
THESIS_FS = 4096.0

#: Baseline corrections applied to earthquake records.
BASELINES = ("cubic", "none")

# Taper of the BLWN ends [s] (capped at a quarter of the record): the table
# must start and end at rest; 1 s leaves 95 % of a 40 s record untouched.
_BLWN_TAPER_S = 1.0


# --------------------------------------------------------------------------- #
# The signal object
# --------------------------------------------------------------------------- #
@dataclass(frozen=True, eq=False)
class Signal:
    """A prescribed motion sampled uniformly from t = 0.

    Attributes
    ----------
    time : ndarray, shape (n,)
        Sample times [s], ``k / fs``.
    displacement : ndarray, shape (n,)
        Displacement [m].
    velocity : ndarray, shape (n,)
        Velocity [m/s], the derivative of ``displacement``.
    acceleration : ndarray, shape (n,)
        Acceleration [m/s²], the derivative of ``velocity``.
    name : str
        Generator name (see :func:`signal_names`).
    params : dict
        Every setting that produced the signal (JSON-serialisable), including
        defaults that were filled in and the seed of random signals.

    The arrays are read-only copies.
    """

    time: np.ndarray
    displacement: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    name: str
    params: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = None
        for attr in ("time", "displacement", "velocity", "acceleration"):
            arr = np.array(getattr(self, attr), dtype=float)  # copy: the caller keeps theirs
            if arr.ndim != 1:
                raise ValueError(f"Signal.{attr} must be 1-D, got shape {arr.shape}")
            if n is None:
                n = arr.size
            elif arr.size != n:
                raise ValueError(f"Signal.{attr} has {arr.size} samples, time has {n}")
            if not np.isfinite(arr).all():
                raise ValueError(f"Signal.{attr} has non-finite values")
            arr.flags.writeable = False
            object.__setattr__(self, attr, arr)
        if n < 2:
            raise ValueError("a Signal needs at least 2 samples")
        object.__setattr__(self, "params", dict(self.params))

    def __len__(self) -> int:
        return self.time.size

    @property
    def dt(self) -> float:
        """Sampling interval [s]."""
        return float((self.time[-1] - self.time[0]) / (self.time.size - 1))

    @property
    def fs(self) -> float:
        """Sampling rate [Hz]."""
        return 1.0 / self.dt

    def as_input(self, kind: str) -> dict[str, np.ndarray]:
        """The channels that drive a test of the given kind.

        Parameters
        ----------
        kind : {"structure", "device"}
            Structure test: the signal is the ground motion →
            ``{"ground_acceleration": acceleration}``. Device test: the signal
            is the piston motion → ``{"displacement": ..., "velocity": ...}``.

        Returns
        -------
        dict
            Channel name (package schema) → array, shape (n,).
        """
        if kind == "structure":
            return {"ground_acceleration": self.acceleration}
        if kind == "device":
            return {"displacement": self.displacement, "velocity": self.velocity}
        raise ValueError(f"kind must be 'structure' or 'device', got {kind!r}")


# --------------------------------------------------------------------------- #
# Kinematics helpers
# --------------------------------------------------------------------------- #
def integrate_acceleration(a: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Velocity and displacement from rest of an acceleration linear between samples.

    Exact for a piecewise-linear acceleration (the package's sampling
    convention): ``v_{k+1} = v_k + dt (a_k + a_{k+1})/2`` and
    ``x_{k+1} = x_k + dt v_k + dt² (2 a_k + a_{k+1})/6``.

    Parameters
    ----------
    a : array, shape (n,)
        Acceleration [m/s²].
    dt : float
        Sampling interval [s].

    Returns
    -------
    v : ndarray, shape (n,)
        Velocity [m/s], ``v[0] = 0``.
    x : ndarray, shape (n,)
        Displacement [m], ``x[0] = 0``.
    """
    a = np.asarray(a, dtype=float)
    v = np.concatenate(([0.0], np.cumsum(0.5 * dt * (a[:-1] + a[1:]))))
    dx = dt * v[:-1] + dt * dt * (2.0 * a[:-1] + a[1:]) / 6.0
    return v, np.concatenate(([0.0], np.cumsum(dx)))


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


# --------------------------------------------------------------------------- #
# Generators (SI units; t = k / fs)
# --------------------------------------------------------------------------- #
def _freq_sweep_up(t, amplitude, fmax, duration):
    T = duration
    phi = np.pi * fmax * t * t / T  # eq. 3-71, first branch: f(t) = fmax t / T
    return _from_phase(amplitude, phi, 2 * np.pi * fmax * t / T, np.full_like(t, 2 * np.pi * fmax / T))


def _freq_sweep_up_down(t, amplitude, fmax, duration):
    T = duration / 2.0
    up = t < T
    down_t = 2 * T - t
    # Down branch: mirror of the up phase about t = T (see module docstring).
    phi = np.where(up, np.pi * fmax * t * t / T, 2 * np.pi * fmax * T - np.pi * fmax * down_t**2 / T)
    dphi = 2 * np.pi * fmax * np.where(up, t, down_t) / T
    ddphi = np.where(up, 1.0, -1.0) * 2 * np.pi * fmax / T
    return _from_phase(amplitude, phi, dphi, ddphi)


def _amp_sweep(t, amplitude, fmax, duration, *, down: bool):
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


def _step(n, fs, amplitude, ramp_time):
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


def _blwn(n, fs, amplitude, fmax, gen):
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


def _earthquake(record, fs, scale, duration, baseline):
    t_rec, ag_rec = load_ground_motion(record)
    dt_rec = t_rec[1] - t_rec[0]
    span = t_rec[-1]
    if fs < (1.0 - 1e-9) / dt_rec:
        raise ValueError(
            f"{record}: fs={fs:g} Hz is below the record's {1 / dt_rec:g} Hz; "
            "linear interpolation only upsamples (downsampling would alias)"
        )
    n_full = int(np.floor(span * fs + 1e-9)) + 1  # every t_k = k/fs ≤ end of record
    if duration is None:
        n = n_full
    else:
        if duration > span + dt_rec * (1 + 1e-9):
            raise ValueError(
                f"{record}: duration {duration:g} s exceeds the record ({span + dt_rec:g} s)"
            )
        n = min(round(duration * fs), n_full)
    if n < 3:
        raise ValueError(f"{record}: duration {duration!r} s gives fewer than 3 samples at {fs:g} Hz")
    dt = 1.0 / fs
    t = np.arange(n) * dt
    a = scale * np.interp(t, t_rec, ag_rec)  # MATLAB interp1 (linear), as the thesis
    v, x = integrate_acceleration(a, dt)
    info = {"baseline": baseline, "baseline_coefficients": [], "baseline_max_correction": 0.0}
    if baseline == "cubic":
        a, coef = _cubic_baseline(t, a, v, x, dt)
        v, x = integrate_acceleration(a, dt)
        corr = np.polynomial.polynomial.polyval(t / t[-1], coef)
        info.update(baseline_coefficients=[float(c) for c in coef],
                    baseline_max_correction=float(np.abs(corr).max()))
    return (x, v, a), info


def _cubic_baseline(t, a, v, x, dt):
    """Subtract q(t) = Σ_{j≤3} c_j (t/T)^j from a: least-squares displacement, at rest at the end.

    The c_j minimise Σ x_corrected² subject to corrected velocity and
    displacement both zero at the last sample. Integration is linear, so the
    corrected kinematics are x − Σ c_j X_j with X_j the exact double integral
    of the sampled basis function: the result stays exactly consistent.
    """
    s = t / t[-1]
    basis = [s**j for j in range(4)]
    integ = [integrate_acceleration(b, dt) for b in basis]
    V = np.column_stack([vi for vi, _ in integ])
    X = np.column_stack([xi for _, xi in integ])
    C = np.vstack([V[-1], X[-1]])
    kkt = np.block([[X.T @ X, C.T], [C, np.zeros((2, 2))]])
    rhs = np.concatenate([X.T @ x, [v[-1], x[-1]]])
    coef = np.linalg.solve(kkt, rhs)[:4]
    return a - np.column_stack(basis) @ coef, coef


# --------------------------------------------------------------------------- #
# Registry
# --------------------------------------------------------------------------- #
@dataclass(frozen=True)
class _Spec:
    description: str
    defaults: dict  # every option the signal takes, with its thesis default
    thesis: str


_SPECS: dict[str, _Spec] = {
    "blwn": _Spec(
        "band-limited white-noise displacement, RMS = amplitude, zero-phase low-pass at fmax",
        {"amplitude": 3e-3, "fmax": 20.0, "duration": 40.0, "fs": THESIS_FS},
        "Table 5.1 signal I",
    ),
    "amp-sweep-up-down": _Spec(
        "sine at fmax, amplitude ramps 0 -> amplitude -> 0 (turn at duration/2)",
        {"amplitude": 2e-3, "fmax": 4.0, "duration": 40.0, "fs": THESIS_FS},
        "Table 5.1 signal II",
    ),
    "elcentro": _Spec(
        "El Centro 1940 N-S ground acceleration x scale (linear resampling, baseline corrected)",
        {"scale": 0.4, "duration": 42.0, "fs": THESIS_FS, "baseline": "cubic"},
        "Table 5.1 signal III",
    ),
    "loma-prieta": _Spec(
        "Loma Prieta 1989 Corralitos 000 x scale, stands in for Kobe (whole record by default)",
        {"scale": 0.4, "duration": None, "fs": THESIS_FS, "baseline": "cubic"},
        "Table 5.1 signal IV (Kobe replaced)",
    ),
    "step": _Spec(
        "ramp to amplitude over ramp_time, then hold until duration",
        {"amplitude": 10e-3, "ramp_time": 0.1, "duration": 5.0, "fs": THESIS_FS},
        "Table 5.1 signal V",
    ),
    "amp-sweep-up": _Spec(
        "sine at fmax, amplitude ramps linearly 0 -> amplitude over duration",
        {"amplitude": 2e-3, "fmax": 4.0, "duration": 40.0, "fs": THESIS_FS},
        "Table 5.1 signal VI",
    ),
    "freq-sweep-up": _Spec(
        "chirp A sin(pi fmax t^2/T), frequency 0 -> fmax over duration (eq. 3-71)",
        {"amplitude": 0.75e-3, "fmax": 20.0, "duration": 40.0, "fs": THESIS_FS},
        "Table 5.1 signal VII",
    ),
    "freq-sweep-up-down": _Spec(
        "chirp 0 -> fmax -> 0 Hz, turn at duration/2 (eq. 3-71, frequency-continuous)",
        {"amplitude": 0.5e-3, "fmax": 20.0, "duration": 40.0, "fs": THESIS_FS},
        "Table 5.1 signal VIII",
    ),
}


def _describe_defaults(defaults: dict) -> str:
    units = {"amplitude": (1e3, "mm"), "fmax": (1.0, "Hz"), "duration": (1.0, "s"), "ramp_time": (1.0, "s")}
    parts = []
    for key, value in defaults.items():
        if key in ("fs", "baseline"):
            continue
        if value is None:
            parts.append(f"{key} whole record")
        elif key in units:
            factor, unit = units[key]
            parts.append(f"{key} {value * factor:g} {unit}")
        else:
            parts.append(f"{key} {value:g}")
    return ", ".join(parts)


def signal_names() -> dict[str, str]:
    """Signal name → one-line description with its thesis defaults (for ``--help``)."""
    return {
        name: f"{spec.description} [{spec.thesis}: {_describe_defaults(spec.defaults)}; {THESIS_FS:g} Hz]"
        for name, spec in _SPECS.items()
    }


def _check_positive(name: str, value) -> float:
    value = float(value)
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    return value


def make_signal(
    name: str,
    *,
    duration: float | None = None,
    fs: float | None = None,
    amplitude: float | None = None,
    fmax: float | None = None,
    scale: float | None = None,
    seed: int | np.random.SeedSequence | None = None,
    rng: np.random.Generator | None = None,
    ramp_time: float | None = None,
    baseline: str | None = None,
) -> Signal:
    """Build one of the thesis's input signals.

    Options left at ``None`` take the thesis value (Table 5.1, see
    :func:`signal_names`). An option that does not apply to the signal (e.g.
    ``fmax`` for an earthquake) raises, so a typo cannot pass silently.

    Parameters
    ----------
    name : str
        One of :func:`signal_names` (``blwn``, ``amp-sweep-up-down``,
        ``amp-sweep-up``, ``freq-sweep-up``, ``freq-sweep-up-down``,
        ``step``, ``elcentro``, ``loma-prieta``).
    duration : float, optional
        Record length [s]; the signal has ``round(duration · fs)`` samples.
        Earthquakes: at most the record length (``None`` for
        ``loma-prieta`` = the whole record).
    fs : float, optional
        Sampling rate [Hz] (default 4096). Earthquakes: at least the record's
        own rate.
    amplitude : float, optional
        Sweeps: peak displacement [m]; step: final displacement [m]; BLWN:
        RMS displacement [m]. Not for earthquakes.
    fmax : float, optional
        Sweeps: highest (frequency sweeps) or fixed (amplitude sweeps)
        frequency [Hz]; BLWN: low-pass corner [Hz]. Below fs/2.
    scale : float, optional
        Earthquakes: factor on the recorded acceleration (thesis 0.4; signal
        II 0.5).
    seed : int or SeedSequence, optional
        Seed of the BLWN draw (ignored by deterministic signals, so a command
        line can pass ``--seed`` to every signal). With neither ``seed`` nor
        ``rng``, fresh entropy is drawn and stored in ``params["seed"]``.
    rng : numpy.random.Generator, optional
        Alternative to ``seed``; not both.
    ramp_time : float, optional
        Step only: ramp time T_r [s] (thesis 0.1 s), rounded to whole samples.
    baseline : {"cubic", "none"}, optional
        Earthquakes only. ``"cubic"`` (default): subtract from the resampled
        acceleration the cubic polynomial in time that minimises the mean
        square ground displacement subject to the ground being at rest
        (v = x = 0) at the last sample; velocity and displacement are then the
        exact integrals (from rest) of the corrected acceleration. This removes
        the metres of drift that integrating a raw record gives (El Centro:
        2.5 m → 0.19 m peak at full scale) while changing its acceleration by
        0.4 % of the PGA at most for the whole record or the default 42 s
        (up to ~2 % when a record is cut short mid-shaking; the value is in
        ``params["baseline_max_correction"]`` [m/s²]). The already processed
        Loma Prieta record is left unchanged to 1e-6 m/s². ``"none"``: the
        thesis's raw ``scale × interp1`` acceleration, exactly; displacement
        then drifts.

    Returns
    -------
    Signal

    Raises
    ------
    ValueError
        Unknown name (lists the valid names), an option the signal does not
        take, or an out-of-range value.
    """
    if name not in _SPECS:
        raise ValueError(f"unknown signal {name!r}; valid names: {', '.join(_SPECS)}")
    spec = _SPECS[name]
    given = {"duration": duration, "fs": fs, "amplitude": amplitude, "fmax": fmax,
             "scale": scale, "ramp_time": ramp_time, "baseline": baseline}
    for key, value in given.items():
        if value is not None and key not in spec.defaults:
            raise ValueError(
                f"signal {name!r} does not take {key!r}; it takes {', '.join(spec.defaults)}"
            )
    opts = {k: (given[k] if given[k] is not None else d) for k, d in spec.defaults.items()}
    if seed is not None and rng is not None:
        raise ValueError("pass seed or rng, not both")

    fs_ = _check_positive("fs", opts["fs"])
    params: dict = {"thesis": spec.thesis, **opts}
    if name in GROUND_MOTIONS:
        scale_ = _check_positive("scale", opts["scale"])
        if opts["baseline"] not in BASELINES:
            raise ValueError(f"baseline must be one of {BASELINES}, got {opts['baseline']!r}")
        dur = None if opts["duration"] is None else _check_positive("duration", opts["duration"])
        (x, v, a), info = _earthquake(name, fs_, scale_, dur, opts["baseline"])
        params.update(info, record=name)
    else:
        dur = _check_positive("duration", opts["duration"])
        n = round(dur * fs_)
        if n < 3:
            raise ValueError(f"duration {dur:g} s gives fewer than 3 samples at fs={fs_:g} Hz")
        amp = _check_positive("amplitude", opts["amplitude"])
        t = np.arange(n) / fs_
        if name == "step":
            (x, v, a), params["ramp_time"] = _step(n, fs_, amp, _check_positive("ramp_time", opts["ramp_time"]))
        else:
            f = _check_positive("fmax", opts["fmax"])
            if f >= fs_ / 2:
                raise ValueError(f"fmax={f:g} Hz must be below fs/2 = {fs_ / 2:g} Hz")
            if name == "blwn":
                if rng is None:
                    seq = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
                    gen = as_generator(seq)
                    params["seed"] = seq.entropy  # reproduces the draw: make_signal(..., seed=this)
                    if seq.spawn_key:  # a spawned child needs its key too
                        params["seed_spawn_key"] = list(seq.spawn_key)
                else:
                    gen = as_generator(rng)
                    params["seed"] = "caller's numpy Generator"
                (x, v, a), params["taper_s"] = _blwn(n, fs_, amp, f, gen)
                params["rms"] = float(np.sqrt(np.mean(x * x)))
            elif name == "amp-sweep-up-down":
                cycles = f * n / fs_
                if abs(cycles - round(cycles)) > 1e-6:
                    good = round(cycles) / f
                    raise ValueError(
                        f"amp-sweep-up-down: fmax·duration = {cycles:g} must be an integer so the "
                        f"amplitude turns at a zero of the sine; e.g. duration={good:g} s"
                    )
                x, v, a = _amp_sweep(t, amp, f, n / fs_, down=True)
            elif name == "amp-sweep-up":
                x, v, a = _amp_sweep(t, amp, f, n / fs_, down=False)
            elif name == "freq-sweep-up":
                x, v, a = _freq_sweep_up(t, amp, f, n / fs_)
            else:
                x, v, a = _freq_sweep_up_down(t, amp, f, n / fs_)
    n = len(x)
    params["duration"] = n / fs_
    return Signal(np.arange(n) / fs_, x, v, a, name, params)


#: Numerical-study presets (§3.8.1).
_THESIS_SIGNALS = {
    "I": ("freq-sweep-up-down", {"amplitude": 0.8e-3, "fmax": 10.0, "duration": 40.0, "fs": 4096.0}),
    # 53.76 s = 2688 samples × 0.02 s: the whole record.
    "II": ("elcentro", {"scale": 0.5, "fs": 4000.0, "duration": 53.76}),
}


def thesis_signal(which: str) -> Signal:
    """Signal I or II of the thesis's numerical study (§3.8.1).

    Parameters
    ----------
    which : {"I", "II"}
        ``"I"``: frequency sweep up–down (eq. 3-71), A = 0.8 mm, f_max = 10 Hz,
        40 s, 4096 Hz. ``"II"``: El Centro N–S at 50 %, the whole record,
        resampled to 4000 Hz (cubic baseline correction, see
        :func:`make_signal`; ``make_signal("elcentro", scale=0.5, fs=4000,
        duration=53.76, baseline="none")`` gives the raw thesis acceleration).

    Returns
    -------
    Signal
        With ``params["preset"] = "thesis signal I"`` (or II).
    """
    key = str(which).strip().upper()
    if key not in _THESIS_SIGNALS:
        raise ValueError(f"unknown thesis signal {which!r}; valid: {', '.join(_THESIS_SIGNALS)}")
    name, kwargs = _THESIS_SIGNALS[key]
    sig = make_signal(name, **kwargs)
    sig.params.update(preset=f"thesis signal {key}", thesis=f"§3.8.1 signal {key}")
    return sig
