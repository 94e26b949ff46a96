"""Scores of a prediction by test condition: what a lab reports of each test of a matrix.

A damper's test matrix is sine tests at several displacement amplitudes,
frequencies and constant currents. Besides the thesis's force errors (E_t =
force NRMSE, 3-45..3-46, :mod:`bayes_mr.scores.metrics`), labs report two
figures of each test (Spencer et al. 1997; Yang et al. 2002):

* the **peak force** error: ``(max|F̂| − max|F|) / max|F|`` over the scored
  samples, signed (positive: the model over-predicts the peak). The measured
  peak carries the noise's largest excursion (about 3 noise SDs over a
  thousand samples), so a model right to the noise scores slightly negative;
* the **energy dissipated per cycle**, ``E = ∮ F dx`` per cycle (the area of the
  force–displacement loop, [J]), measured and predicted over the same whole
  cycles, and its error ``(Ê − E) / |E|``, signed.

The test's conditions are read from its manifest where given (``amplitude``,
``frequency`` columns, in the manifest's units) and otherwise estimated from
the record's displacement (:func:`motion_of`): the dominant frequency from its
spectrum, the amplitude as half its peak-to-peak over the steady part (after
the first period, the transient from rest of the rig and of every simulation).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import xarray as xr

from bayes_mr.data.schema import COMMANDS, Where, command_of
from bayes_mr.data.units import factor

#: Units a manifest's ``frequency`` column may carry → factor to Hz.
FREQUENCY_UNITS = {"": 1.0, "hz": 1.0, "khz": 1e3, "rad/s": 1.0 / (2.0 * np.pi)}


def _bridged(x: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """x with masked samples replaced by linear interpolation between valid neighbours."""
    if valid.all() or not valid.any():
        return x
    idx = np.arange(x.size)
    return np.interp(idx, idx[valid], x[valid])


def _sine_power(x: np.ndarray, t: np.ndarray, f: float) -> float:
    """The variance of ``x`` a sine of frequency ``f`` [Hz] explains (least squares of a sine, a cosine and a
    constant)."""
    w = 2.0 * np.pi * f * t
    basis = np.column_stack([np.sin(w), np.cos(w), np.ones_like(t)])
    coef = np.linalg.lstsq(basis, x, rcond=None)[0]
    return float(np.sum((basis @ coef) ** 2))


def dominant_frequency(x: np.ndarray, fs: float) -> float:
    """The frequency of the sine that explains most of ``x`` [Hz]: the maximum-likelihood frequency of one
    sinusoid in white noise.

    A spectrum zero-padded to 16 times the record finds the largest peak; the
    frequency is then refined within one bin of it by maximising the variance a
    fitted sine explains (a 2 s test has bins 0.5 Hz apart, and the spectral peak
    of a test of one or two cycles is biased by its own window).

    Parameters
    ----------
    x : array, shape (n,)
        Displacement [m] (any unit: only the shape of the signal is read).
    fs : float
        Sampling rate [Hz].

    Returns
    -------
    float
        Frequency [Hz]; NaN for a constant signal.
    """
    from scipy.optimize import minimize_scalar

    x = np.asarray(x, float) - np.mean(x)
    n_fft = 16 * x.size
    mag = np.abs(np.fft.rfft(x, n_fft))
    if mag.size < 3 or not np.any(mag[1:] > 0):
        return float("nan")
    step = fs / n_fft
    coarse = (1 + int(np.argmax(mag[1:]))) * step  # the DC bin is the mean, already removed
    t = np.arange(x.size) / fs
    width = fs / x.size  # the main lobe's half-width: a record of few cycles biases the padded peak within it
    found = minimize_scalar(lambda f: -_sine_power(x, t, f), bounds=(max(coarse - width, step), coarse + width),
                            method="bounded", options={"xatol": 1e-6 * coarse})
    return float(found.x)


def motion_of(x: np.ndarray, fs: float, valid: np.ndarray | None = None) -> tuple[float, float, int]:
    """The amplitude and frequency of a test's motion, and where its steady part starts.

    Parameters
    ----------
    x : array, shape (n,)
        Displacement [m].
    fs : float
        Sampling rate [Hz].
    valid : bool array, shape (n,), optional
        Samples quality control kept; masked ones are bridged linearly.

    Returns
    -------
    amplitude : float
        Half the peak-to-peak displacement over the steady part [m].
    frequency : float
        Dominant frequency [Hz] (:func:`dominant_frequency`).
    start : int
        First sample of the steady part: one period after the first sample,
        or 0 when the record is shorter than two periods.
    """
    valid = np.ones(len(x), bool) if valid is None else np.asarray(valid, bool)
    x = _bridged(np.asarray(x, float), valid)
    freq = dominant_frequency(x, fs)
    period = int(round(fs / freq)) if np.isfinite(freq) and freq > 0 else 0
    start = period if 0 < period and 2 * period <= x.size else 0
    steady = x[start:][valid[start:]]
    return float(0.5 * (steady.max() - steady.min())), freq, start


def energy_per_cycle(force: np.ndarray, x: np.ndarray, fs: float, frequency: float,
                     start: int = 0) -> tuple[float | None, int]:
    """Energy dissipated per cycle, ∮ F dx averaged over the whole cycles after ``start``.

    The cycles counted are the last ``n = ⌊(N − start)·f/fs⌋`` whole periods of the
    record (its end is the steadiest part), integrated by the trapezoidal rule,
    ``Σ ½(F_i + F_{i+1})(x_{i+1} − x_i) / n``.

    Parameters
    ----------
    force, x : array, shape (n,)
        Force [N] and displacement [m], masked samples already bridged.
    fs : float
        Sampling rate [Hz].
    frequency : float
        The motion's frequency [Hz].
    start : int
        First sample of the steady part.

    Returns
    -------
    energy : float or None
        [J] per cycle; None when not one whole cycle fits after ``start``.
    cycles : int
        The number of whole cycles integrated.
    """
    if not (np.isfinite(frequency) and frequency > 0):
        return None, 0
    period = fs / frequency
    # a record of whole periods ends a sample short of its last one: a 2 % tolerance counts that cycle
    cycles = int(np.floor((len(x) - 1 - start) / period + 0.02))
    if cycles < 1:
        return None, 0
    first = max(0, len(x) - 1 - int(round(cycles * period)))
    f, d = np.asarray(force, float)[first:], np.asarray(x, float)[first:]
    return float(np.sum(0.5 * (f[1:] + f[:-1]) * np.diff(d)) / cycles), cycles


def _given(conditions: Mapping, units: Mapping, name: str, src: str) -> float | None:
    """A manifest's ``amplitude`` [m] or ``frequency`` [Hz] condition in SI, or None when not given."""
    value = conditions.get(name)
    if not isinstance(value, (int, float, np.number)):
        return None
    unit = (units.get(name) or "").strip()
    if name == "amplitude":
        return float(value) * factor("displacement", unit or None, Where(src, name))
    if unit.lower() not in FREQUENCY_UNITS:
        raise Where(src, name).error(f"unknown frequency unit '{unit}'", "use one of Hz, kHz, rad/s")
    return float(value) * FREQUENCY_UNITS[unit.lower()]


def command_value(record: xr.Dataset, conditions: Mapping) -> tuple[str | None, float | None]:
    """The test's constant command: (``current`` or ``voltage``, its value [A or V]), from its conditions,
    else from a command channel that does not vary; (name, None) for a varying command, (None, None) without."""
    for name in COMMANDS:
        if isinstance(conditions.get(name), (int, float, np.number)):
            return name, float(conditions[name])
    name = command_of(record)
    if name is None:
        return None, None
    u = record[name].values
    return name, (float(u[0]) if np.ptp(u) <= 1e-9 * max(1.0, float(np.max(np.abs(u)))) else None)


def condition_of(record: xr.Dataset, conditions: Mapping | None = None, units: Mapping | None = None,
                   source: str = "") -> dict:
    """The condition a test ran at: its motion's amplitude and frequency, and its constant command.

    Parameters
    ----------
    record : xarray.Dataset
        A record with ``displacement`` [m] (``valid`` honoured).
    conditions, units : mapping, optional
        The manifest's conditions of the test and their units; an ``amplitude`` or
        ``frequency`` there wins over the estimate from the record (:func:`motion_of`).
    source : str
        The manifest, named in an error about a condition's unit.

    Returns
    -------
    dict
        ``amplitude`` [m], ``amplitude_from`` (``manifest`` or ``record``), ``frequency`` [Hz],
        ``frequency_from``, ``command`` (``current``, ``voltage`` or None), ``command_value`` [A or V;
        None when it varies] (:func:`command_value`), and ``start``, the first sample of the steady part.
    """
    conditions, units = conditions or {}, units or {}
    valid = record["valid"].values.astype(bool) if "valid" in record else np.ones(record.sizes["time"], bool)
    fs = 1.0 / float(record["time"].values[1] - record["time"].values[0])
    amplitude, frequency, start = motion_of(record["displacement"].values, fs, valid)
    given = {n: _given(conditions, units, n, source) for n in ("amplitude", "frequency")}
    name, value = command_value(record, conditions)
    return {
        "amplitude": given["amplitude"] if given["amplitude"] is not None else amplitude,
        "amplitude_from": "manifest" if given["amplitude"] is not None else "record",
        "frequency": given["frequency"] if given["frequency"] is not None else frequency,
        "frequency_from": "manifest" if given["frequency"] is not None else "record",
        "command": name, "command_value": value, "start": start,
    }


def condition_row(record: xr.Dataset, force_hat: np.ndarray, *, conditions: Mapping | None = None,
                  units: Mapping | None = None, source: str = "") -> dict:
    """A test's conditions and the prediction's force scores there (the module docstring's table row).

    Parameters
    ----------
    record : xarray.Dataset
        A record with ``displacement`` [m] and ``force`` [N] (``valid`` honoured).
    force_hat : array, shape (n,)
        The predicted force [N].
    conditions, units, source
        As :func:`condition_of`.

    Returns
    -------
    dict
        :func:`condition_of`'s keys but ``start``; ``force_nrmse``, ``peak_force`` and
        ``peak_force_predicted`` [N], ``peak_force_error`` [-], ``energy_per_cycle`` and
        ``energy_per_cycle_predicted`` [J], ``energy_error`` [-] (None when no whole cycle is scored),
        ``cycles``.
    """
    from bayes_mr.scores.metrics import force_nrmse

    row = condition_of(record, conditions, units, source)
    start = row.pop("start")
    valid = record["valid"].values.astype(bool) if "valid" in record else np.ones(record.sizes["time"], bool)
    fs = 1.0 / float(record["time"].values[1] - record["time"].values[0])
    x = _bridged(record["displacement"].values.astype(float), valid)
    f = _bridged(record["force"].values.astype(float), valid)
    f_hat = np.asarray(force_hat, float)
    peak, peak_hat = float(np.max(np.abs(f[valid]))), float(np.max(np.abs(f_hat[valid])))
    e, cycles = energy_per_cycle(f, x, fs, row["frequency"], start)
    e_hat, _ = energy_per_cycle(f_hat, x, fs, row["frequency"], start)
    return {
        **row, "force_nrmse": force_nrmse(record["force"].values, f_hat, valid),
        "peak_force": peak, "peak_force_predicted": peak_hat, "peak_force_error": (peak_hat - peak) / peak,
        "energy_per_cycle": e, "energy_per_cycle_predicted": e_hat,
        "energy_error": None if e is None or e == 0 else (e_hat - e) / abs(e), "cycles": cycles,
    }
