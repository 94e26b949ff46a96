"""The input between samples: linear, or band-limited reconstruction.

The simulator's RK4 needs the input inside each sample interval. Linear
interpolation between samples (the package's historical convention) acts on
a sinusoid of frequency f as the triangle filter of gain sinc²(f·Δt): at a
fifth of the sampling rate (the Bouc–Wen benchmark's 150 Hz multisine at
750 Hz) the drive is 12.5 % too weak. A sampled band-limited input is
better read as the band-limited signal through its samples:
``"bandlimited"`` upsamples the continuous drive columns by an integer factor
S with a polyphase windowed-sinc filter (:func:`scipy.signal.resample_poly`,
not a periodic FFT — records are not periodic; its sinc has zeros at every
S-th tap so the recorded samples are kept exactly) and the simulator runs the
same kernel at Δt/S, keeping every S-th output. Between the fine samples the
input is again linear, with gain sinc²(f·Δt/S); S is the smallest factor that
brings that error under :data:`TOLERANCE` at the record's bandwidth.

The damper command column (voltage or current: a switching square wave) is
never reconstructed band-limited — a sinc through a step rings (Gibbs) and
would drive the damper with a voltage it never saw. Between the record's
samples it is linear, or held (``command_interp="hold"``, attribute
``command_interp``): a DAC holds each sample until the next (zero-order hold),
and read linear such a command leads the one the damper saw by half a sample
on average — a lag a fit then puts on the field's own dynamics. Held, sample
k's command drives the whole interval [t_k, t_k+1) (on a fine grid, fine rows
S·k … S·k+S−1), and the simulator ends each interval on the command it started
with (:func:`bayes_mr.models.drivers.run_one`'s ``hold``).

``"auto"`` picks per record: a record that says how its input is to be read
(attribute ``input_interp``, written by :func:`bayes_mr.simulation.simulate.synthesize`
— its outputs were simulated that way — or set by ``--input-interp``) is read
that way; otherwise band-limited when linear interpolation's gain error at the
drive's bandwidth (the frequency below which :data:`POWER_SHARE` of its
spectral power lies) exceeds :data:`THRESHOLD`.
"""

from __future__ import annotations

import numpy as np

from bayes_mr.data.schema import COMMAND_INTERPS

#: The two reconstructions, and what a caller may ask for.
INTERPS = ("linear", "bandlimited")
CHOICES = ("auto",) + INTERPS
#: What a caller may ask of the command between samples (:data:`COMMAND_INTERPS`, or "auto": the record's
#: ``command_interp`` attribute, else linear).
COMMAND_CHOICES = ("auto",) + COMMAND_INTERPS
#: Share of the drive's spectral power (mean removed) below its bandwidth.
POWER_SHARE = 0.99
#: "auto" reconstructs band-limited when 1 − sinc²(f_bw·Δt) exceeds this (0.5 %: f_bw ≳ 0.039 fs).
THRESHOLD = 5e-3
#: Upsampling factor: the smallest S with 1 − sinc²(f_bw·Δt/S) ≤ this (S = 8 at f_bw = fs/5: the
#: benchmark's output error 57× below linear's, 1.3e-7 m against 7.5e-6 m; S = 4 gives 14×, S = 16 290×).
TOLERANCE = 2.5e-3
#: Most upsampling (cost grows about linearly with S).
S_MAX = 32
#: Half-length of the polyphase filter in input samples (scipy's default is 10).
HALF_LEN = 24
#: Kaiser window β of the polyphase filter (stop-band about −90 dB).
KAISER_BETA = 9.0


#: How the UKF reads the input (see :func:`describe`).
UKF_NOTE = ("the filter propagates sample to sample with the drive linear between samples and the command as "
            "command_interp says; the point's simulation and scores use input_interp")


def describe(interp: str, engine: str, command_interp: str = "linear") -> dict:
    """The JSON keys of a fit's input reconstruction: ``input_interp``, ``command_interp`` (and the UKF's own).

    The UKF stays on the record's grid with the drive linear (``filter_input_interp``):
    a band-limited predict would run the filter S times per sample (S up to
    32) for each of its training runs and put its state histories, reset
    marks and per-step process noise on a grid nothing else reads; its process
    noise on x, ẋ already absorbs an input error between samples. A held
    command costs nothing there, and the filter holds it.
    """
    out = {"input_interp": interp, "command_interp": command_interp}
    if engine == "ukf":
        out.update(filter_input_interp="linear", input_interp_note=UKF_NOTE)
    return out


def bandwidth(x: np.ndarray, dt: float, share: float = POWER_SHARE) -> float:
    """Frequency [Hz] below which ``share`` of the spectral power of ``x`` (mean removed) lies.

    Parameters
    ----------
    x : ndarray, shape (N,)
        A sampled drive (any unit).
    dt : float
        Sample interval [s].
    share : float
        Power share, in (0, 1].

    Returns
    -------
    float
        0 for a constant signal.
    """
    x = np.asarray(x, float)
    power = np.abs(np.fft.rfft(x - x.mean())) ** 2
    total = power.sum()
    if not total > 0:
        return 0.0
    f = np.fft.rfftfreq(x.size, dt)
    return float(f[min(np.searchsorted(np.cumsum(power), share * total), f.size - 1)])


def linear_gain_error(f: float, dt: float) -> float:
    """1 − sinc²(f·dt): the relative amplitude lost by linear interpolation at ``f`` [Hz]."""
    return float(1.0 - np.sinc(f * dt) ** 2)


def drive_bandwidth(rows: np.ndarray, kind: str, dt: float) -> float:
    """Bandwidth [Hz] (:func:`bandwidth`) of the continuous drive columns of input rows (the widest).

    Structure and forced tests: the drive (column 0); device tests: the
    displacement and velocity (columns 0 and 1). The command is not a drive here.
    """
    cols = (0, 1) if kind == "device" else (0,)
    return max(bandwidth(np.asarray(rows)[:, j], dt) for j in cols)


def choose(rows: np.ndarray, kind: str, dt: float, declared: str | None = None) -> str:
    """The reconstruction "auto" gives a record: ``declared`` when it names one, else by bandwidth.

    Parameters
    ----------
    rows : ndarray, shape (N, 3)
        Input rows of :class:`bayes_mr.simulation.inputs.Inputs`.
    kind : {"structure", "device", "forced"}
    dt : float
        Sample interval [s].
    declared : str, optional
        The record's ``input_interp`` attribute (or a caller's choice).

    Returns
    -------
    {"linear", "bandlimited"}
    """
    if declared is not None and check(declared) != "auto":
        return declared
    f = drive_bandwidth(rows, kind, dt)
    return "bandlimited" if linear_gain_error(f, dt) > THRESHOLD else "linear"


def check(interp: str) -> str:
    """``interp`` if it is a known choice, else a ValueError naming the valid ones."""
    if interp not in CHOICES:
        raise ValueError(f"input interpolation {interp!r}: valid: {', '.join(CHOICES)}")
    return interp


def command(declared: str | None, attribute: str | None = None, where: str = "record") -> str:
    """How the command reads between samples: ``declared`` ("linear", "hold"), else the record's attribute.

    Parameters
    ----------
    declared : str or None
        A caller's choice; None or "auto" defers to ``attribute``.
    attribute : str or None
        The record's ``command_interp`` attribute (None: the record has none: linear).
    where : str
        The record's name, for the error.

    Returns
    -------
    {"linear", "hold"}

    Raises
    ------
    ValueError
        An unknown value, naming where it came from and the valid ones.
    """
    if declared not in (None, "auto"):
        if declared not in COMMAND_INTERPS:
            raise ValueError(f"command interpolation {declared!r}: valid: {', '.join(COMMAND_CHOICES)}")
        return declared
    if attribute is None:
        return "linear"
    if attribute not in COMMAND_INTERPS:
        raise ValueError(f"{where}: attribute command_interp={attribute!r}: valid: {', '.join(COMMAND_INTERPS)} "
                         "(hold: the command was held between samples, as a DAC holds it); set one or drop it")
    return str(attribute)


def factor(rows: np.ndarray, kind: str, dt: float) -> int:
    """Upsampling factor S for a band-limited reconstruction of input rows (2 ≤ S ≤ :data:`S_MAX`).

    The smallest S for which linear interpolation between the fine samples
    loses at most :data:`TOLERANCE` of the amplitude at the drive's bandwidth
    (:func:`drive_bandwidth`).
    """
    f = drive_bandwidth(rows, kind, dt)
    for s in range(2, S_MAX + 1):
        if linear_gain_error(f, dt / s) <= TOLERANCE:
            return s
    return S_MAX


def upsample(rows: np.ndarray, kind: str, s: int, command_interp: str = "linear") -> np.ndarray:
    """Kernel input rows on the grid Δt/S: (S(N−1)+1, 3), fine row S·k equal to row k.

    Parameters
    ----------
    rows : ndarray, shape (N, 3)
        Input rows of :class:`bayes_mr.simulation.inputs.Inputs` (drive, device
        velocity, command).
    kind : {"structure", "device", "forced"}
        Device tests reconstruct displacement and velocity, the others their
        drive (see the module notes).
    s : int
        Upsampling factor.
    command_interp : {"linear", "hold"}
        The command column interpolated linearly, or held: fine rows S·k …
        S·k+S−1 take row k's command (the simulator then holds it across each
        fine interval too).
    """
    from scipy.signal import firwin, resample_poly

    rows = np.asarray(rows, float)
    n = rows.shape[0]
    m = s * (n - 1) + 1
    out = np.empty((m, rows.shape[1]))
    if command_interp == "hold":
        out[:, 2] = np.repeat(rows[:, 2], s)[:m]
    else:
        out[:, 2] = np.interp(np.arange(m), np.arange(n) * float(s), rows[:, 2])
    if s == 1:
        out[:, :2] = rows[:, :2]
        return out
    # a windowed sinc cut at the coarse Nyquist rate (resample_poly scales it by S): zero at every S-th
    # tap, so the recorded samples stay
    taps = firwin(2 * HALF_LEN * s + 1, 1.0 / s, window=("kaiser", KAISER_BETA))
    for j in (0, 1) if kind == "device" else (0,):
        # 'line' pads with the straight line through the ends: no step at either end to ring on
        out[:, j] = resample_poly(rows[:, j], s, 1, window=taps, padtype="line")[:m]
        out[::s, j] = rows[:, j]  # exactly: the window's DC normalisation moves them by ~1e-5
    if kind != "device":
        out[:, 1] = 0.0
    return out
