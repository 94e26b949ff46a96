"""The signals by name: thesis defaults, one small builder each, :func:`make_signal` and the presets.

Each signal is a :class:`_Spec` — its description, its options with their
Table 5.1 defaults, and a builder that validates the options it uses and
calls the generator of :mod:`~bayes_mr.signals.thesis` or
:mod:`~bayes_mr.signals.earthquake`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import numpy as np

from bayes_mr.numerics.synthetic_noise import as_generator, as_seed_sequence
from bayes_mr.signals.earthquake import BASELINES, earthquake
from bayes_mr.signals.signal import Signal
from bayes_mr.signals.thesis import amp_sweep, blwn, freq_sweep_up, freq_sweep_up_down, step

#: Sampling rate of every Table 5.1 signal [Hz].
THESIS_FS = 4096.0

Kinematics = tuple[np.ndarray, np.ndarray, np.ndarray]


@dataclass(frozen=True)
class _Request:
    """What :func:`make_signal` was asked for, with the thesis defaults filled in."""

    name: str
    opts: dict
    fs: float  # validated sampling rate [Hz]
    seed: int | np.random.SeedSequence | None
    rng: np.random.Generator | None

    def positive(self, key: str) -> float:
        return _check_positive(key, self.opts[key])


def _grid(req: _Request) -> tuple[int, np.ndarray, float]:
    """Samples, sample times [s] and amplitude [m] of an analytic signal."""
    dur = req.positive("duration")
    n = round(dur * req.fs)
    if n < 3:
        raise ValueError(f"duration {dur:g} s gives fewer than 3 samples at fs={req.fs:g} Hz")
    return n, np.arange(n) / req.fs, req.positive("amplitude")


def _grid_fmax(req: _Request) -> tuple[int, np.ndarray, float, float]:
    """:func:`_grid` and the signal's frequency ``fmax`` [Hz], below fs/2."""
    n, t, amp = _grid(req)
    f = req.positive("fmax")
    if f >= req.fs / 2:
        raise ValueError(f"fmax={f:g} Hz must be below fs/2 = {req.fs / 2:g} Hz")
    return n, t, amp, f


def _generator(req: _Request, params: dict) -> np.random.Generator:
    """The BLWN draw's generator; records in ``params`` what reproduces it."""
    if req.rng is not None:
        params["seed"] = "caller's numpy Generator"
        return as_generator(req.rng)
    seq = as_seed_sequence(req.seed)
    params["seed"] = seq.entropy  # reproduces the draw: make_signal(..., seed=this)
    if seq.spawn_key:  # a spawned child needs its key too
        params["seed_spawn_key"] = list(seq.spawn_key)
    return as_generator(seq)


# --- builders: (request, params to complete) → (x, v, a) ------------------------
def _build_earthquake(req: _Request, params: dict) -> Kinematics:
    scale = req.positive("scale")
    if req.opts["baseline"] not in BASELINES:
        raise ValueError(f"baseline must be one of {BASELINES}, got {req.opts['baseline']!r}")
    dur = None if req.opts["duration"] is None else req.positive("duration")
    xva, info = earthquake(req.name, req.fs, scale, dur, req.opts["baseline"])
    params.update(info, record=req.name)
    return xva


def _build_step(req: _Request, params: dict) -> Kinematics:
    n, _, amp = _grid(req)
    xva, params["ramp_time"] = step(n, req.fs, amp, req.positive("ramp_time"))
    return xva


def _build_blwn(req: _Request, params: dict) -> Kinematics:
    n, _, amp, f = _grid_fmax(req)
    xva, params["taper_s"] = blwn(n, req.fs, amp, f, _generator(req, params))
    params["rms"] = float(np.sqrt(np.mean(xva[0] * xva[0])))
    return xva


def _build_amp_sweep_up_down(req: _Request, params: dict) -> Kinematics:
    n, t, amp, f = _grid_fmax(req)
    cycles = f * n / req.fs
    if abs(cycles - round(cycles)) > 1e-6:
        good = round(cycles) / f
        raise ValueError(
            f"amp-sweep-up-down: fmax·duration = {cycles:g} must be an integer so the "
            f"amplitude turns at a zero of the sine; e.g. duration={good:g} s"
        )
    return amp_sweep(t, amp, f, n / req.fs, down=True)


def _sweep(generator: Callable) -> Callable[[_Request, dict], Kinematics]:
    """Builder of a sweep ``generator(t, amplitude, fmax, duration)`` with no further option."""

    def build(req: _Request, params: dict) -> Kinematics:
        n, t, amp, f = _grid_fmax(req)
        return generator(t, amp, f, n / req.fs)

    return build


@dataclass(frozen=True)
class _Spec:
    description: str
    defaults: dict  # every option the signal takes, with its thesis default
    thesis: str
    build: Callable[[_Request, dict], Kinematics]


def _table(amplitude: float, fmax: float) -> dict:
    """Options of a shake-table motion of Table 5.1: 40 s at 4096 Hz."""
    return {"amplitude": amplitude, "fmax": fmax, "duration": 40.0, "fs": THESIS_FS}


def _record(duration: float | None) -> dict:
    """Options of an earthquake of Table 5.1: 0.4 × the record, baseline corrected."""
    return {"scale": 0.4, "duration": duration, "fs": THESIS_FS, "baseline": "cubic"}


_SPECS: dict[str, _Spec] = {
    "blwn": _Spec("band-limited white-noise displacement, RMS = amplitude, zero-phase low-pass at fmax",
                  _table(3e-3, 20.0), "Table 5.1 signal I", _build_blwn),
    "amp-sweep-up-down": _Spec("sine at fmax, amplitude ramps 0 -> amplitude -> 0 (turn at duration/2)",
                               _table(2e-3, 4.0), "Table 5.1 signal II", _build_amp_sweep_up_down),
    "elcentro": _Spec("El Centro 1940 N-S ground acceleration x scale (linear resampling, baseline corrected)",
                      _record(42.0), "Table 5.1 signal III", _build_earthquake),
    "loma-prieta": _Spec("Loma Prieta 1989 Corralitos 000 x scale, stands in for Kobe (whole record by default)",
                         _record(None), "Table 5.1 signal IV (Kobe replaced)", _build_earthquake),
    "step": _Spec("ramp to amplitude over ramp_time, then hold until duration",
                  {"amplitude": 10e-3, "ramp_time": 0.1, "duration": 5.0, "fs": THESIS_FS},
                  "Table 5.1 signal V", _build_step),
    "amp-sweep-up": _Spec("sine at fmax, amplitude ramps linearly 0 -> amplitude over duration",
                          _table(2e-3, 4.0), "Table 5.1 signal VI", _sweep(partial(amp_sweep, down=False))),
    "freq-sweep-up": _Spec("chirp A sin(pi fmax t^2/T), frequency 0 -> fmax over duration (eq. 3-71)",
                           _table(0.75e-3, 20.0), "Table 5.1 signal VII", _sweep(freq_sweep_up)),
    "freq-sweep-up-down": _Spec("chirp 0 -> fmax -> 0 Hz, turn at duration/2 (eq. 3-71, frequency-continuous)",
                                _table(0.5e-3, 20.0), "Table 5.1 signal VIII", _sweep(freq_sweep_up_down)),
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
        Sampling rate [Hz] (default 4096). Earthquakes: at least the record's own rate.
    amplitude : float, optional
        Sweeps: peak displacement [m]; step: final displacement [m]; BLWN:
        RMS displacement [m]. Not for earthquakes.
    fmax : float, optional
        Sweeps: highest (frequency sweeps) or fixed (amplitude sweeps)
        frequency [Hz]; BLWN: low-pass corner [Hz]. Below fs/2.
    scale : float, optional
        Earthquakes: factor on the recorded acceleration (thesis 0.4; signal II 0.5).
    seed : int or SeedSequence, optional
        Seed of the BLWN draw (ignored by deterministic signals, so a command
        line can pass ``--seed`` to every signal). With neither ``seed`` nor
        ``rng``, fresh entropy is drawn and stored in ``params["seed"]``.
    rng : numpy.random.Generator, optional
        Alternative to ``seed``; not both.
    ramp_time : float, optional
        Step only: ramp time T_r [s] (thesis 0.1 s), rounded to whole samples.
    baseline : {"cubic", "none"}, optional
        Earthquakes only: ``"cubic"`` (default) removes the drift of the
        integrated record, ``"none"`` keeps the thesis's raw acceleration;
        see :mod:`bayes_mr.signals.earthquake`.

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
            raise ValueError(f"signal {name!r} does not take {key!r}; it takes {', '.join(spec.defaults)}")
    opts = {k: (given[k] if given[k] is not None else d) for k, d in spec.defaults.items()}
    if seed is not None and rng is not None:
        raise ValueError("pass seed or rng, not both")
    req = _Request(name, opts, _check_positive("fs", opts["fs"]), seed, rng)
    params: dict = {"thesis": spec.thesis, **opts}
    x, v, a = spec.build(req, params)
    n = len(x)
    params["duration"] = n / req.fs
    return Signal(np.arange(n) / req.fs, x, v, a, name, params)


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
