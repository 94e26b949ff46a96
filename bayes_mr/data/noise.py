"""Noise floor of a record and trimming to its excited part (thesis practice).

The thesis took its noise covariances from a separate 60-s "no input" run
(NoInput-Hydraulic: the standard deviation of each channel) and trimmed every
record to the part where the shake table moved. :func:`noise_floor` does the
first from a no-input record if one is given, else from a quiet segment of
the record itself (found automatically), else from a differencing estimate;
:func:`trim_excited` does the second with a report of what was cut.
"""

from __future__ import annotations

import os

import numpy as np
import xarray as xr
from scipy import ndimage

from .schema import MIN_SAMPLES, STRUCTURE

_MAD = 1.4826

#: Window of the moving standard deviation that finds quiet and excited parts [s].
WINDOW_S = 0.25


class NoiseFloor(dict):
    """Channel → noise standard deviation (channel units), with how each was found.

    Attributes
    ----------
    methods : dict
        Channel → ``"noise_record"``, ``"quiet_segment"`` or ``"differencing"``.
    segment : tuple of float or None
        Quiet segment used, ``(t_start, t_stop)`` [s], if any.
    """

    def __init__(self, values=(), methods=None, segment=None):
        super().__init__(values)
        self.methods: dict[str, str] = dict(methods or {})
        self.segment: tuple[float, float] | None = segment


def input_channel(ds: xr.Dataset) -> str:
    """The channel that drives a test: ground acceleration (structure) or displacement (device)."""
    return "ground_acceleration" if ds.attrs.get("kind") == STRUCTURE else "displacement"


def moving_sd(x: np.ndarray, window: int) -> np.ndarray:
    """Standard deviation of ``x`` in a centred moving window of ``window`` samples, shape (n,)."""
    x = np.asarray(x, float)
    x = x - np.median(x)  # keeps E[x²] − E[x]² well conditioned for offset signals
    m1 = ndimage.uniform_filter1d(x, window, mode="nearest")
    m2 = ndimage.uniform_filter1d(x * x, window, mode="nearest")
    return np.sqrt(np.maximum(m2 - m1 * m1, 0.0))


def differencing_sd(x: np.ndarray) -> float:
    """White-noise SD from the third difference: 1.4826 · MAD(Δ³x) / √20.

    For white noise of SD σ the third difference has SD σ√20; the MAD makes
    the estimate ignore the few large differences at sharp features. This
    is a *lower bound* of the measurement noise for oversampled smooth
    signals: noise that the sensor or anti-alias filter has coloured (low-pass)
    has less power at the highest frequencies than white noise of the same SD.
    (A signal that is not oversampled leaks into Δ³ and biases it upwards.)
    """
    d3 = np.diff(np.asarray(x, float), 3)
    return float(_MAD * np.median(np.abs(d3 - np.median(d3))) / np.sqrt(20.0))


def block_sd(x: np.ndarray, block: int) -> float:
    """Median over consecutive blocks of the block standard deviation.

    For stationary noise this is the standard deviation (the thesis's
    estimate from a no-input run); unlike one SD over the whole segment it
    ignores a slow drift or a single step (a relaxing damper force), which
    are not measurement noise.
    """
    x = np.asarray(x, float)
    nb = max(1, x.size // block)
    if nb == 1:
        return float(np.std(x, ddof=1))
    blocks = x[: nb * block].reshape(nb, block)
    return float(np.median(np.std(blocks, axis=1, ddof=1)))


def find_quiet(
    ds: xr.Dataset,
    *,
    window_s: float = WINDOW_S,
    factor: float = 3.0,
    fraction: float = 0.01,
    contrast: float = 20.0,
    min_s: float = 1.0,
) -> slice | None:
    """A quiet segment at the start or the end of a record, or None.

    The input channel's moving SD (window ``window_s``) is compared with its
    smallest value s_min and its largest s_max. Samples with moving SD ≤
    max(``factor`` · s_min, ``fraction`` · s_max) are quiet (the second term
    lets a rig at rest settle or twitch by a percent of the test's motion).
    The quiet run touching the start or the end (the longer of the two)
    is returned, less one window next to the excited part (decay transients),
    if it lasts at least ``min_s`` and the record is excited elsewhere (largest
    moving SD ≥ ``contrast`` · s_min); otherwise None.

    Returns
    -------
    slice or None
        Sample slice of the quiet segment.
    """
    x = ds[input_channel(ds)].values
    n = x.size
    dt = float(ds.attrs["dt"])
    w = max(8, int(round(window_s / dt)))
    sd = moving_sd(x, w)
    s_min = float(sd.min())
    if not sd.max() >= contrast * s_min or sd.max() == 0:
        return None
    quiet = sd <= max(factor * s_min, fraction * sd.max())
    head = int(np.argmin(quiet)) if not quiet.all() else n  # quiet samples at the start
    tail = int(np.argmin(quiet[::-1])) if not quiet.all() else n
    candidates = []
    if head:
        candidates.append(slice(0, max(head - w, 0)))
    if tail:
        candidates.append(slice(min(n - tail + w, n), n))
    candidates = [c for c in candidates if (c.stop - c.start) * dt >= min_s]
    if not candidates:
        return None
    return max(candidates, key=lambda c: c.stop - c.start)


def noise_floor(
    ds: xr.Dataset,
    channels: list[str] | tuple[str, ...] | None = None,
    quiet: slice | tuple[float, float] | bool | None = None,
    noise_record: xr.Dataset | str | os.PathLike | None = None,
) -> NoiseFloor:
    """Measurement-noise standard deviation of each channel.

    In order of preference:

    1. ``noise_record`` (a "no input" run, thesis: NoInput-Hydraulic, 60 s):
       the standard deviation of each channel (:func:`block_sd`, blocks of
       0.25 s) over its valid samples;
    2. a quiet segment of the record: ``quiet`` as a sample slice or a
       ``(t_start, t_stop)`` pair in seconds, or found by :func:`find_quiet`
       when ``quiet`` is None (``quiet=False`` skips this step);
       :func:`block_sd` over the segment's valid samples;
    3. :func:`differencing_sd` over the valid samples — a lower bound for
       oversampled smooth signals.

    Parameters
    ----------
    ds : xarray.Dataset
        The record.
    channels : sequence of str, optional
        Default: every data channel.
    quiet : slice, (float, float), bool or None
    noise_record : xarray.Dataset or path, optional
        A record of the same rig with no input.

    Returns
    -------
    NoiseFloor
        Channel → SD in the channel's units; ``.methods`` and ``.segment`` say how.
    """
    names = list(channels) if channels is not None else [
        str(v) for v, da in ds.data_vars.items() if v != "valid" and da.dims == ("time",)
    ]
    valid = ds["valid"].values.astype(bool) if "valid" in ds else np.ones(ds.sizes["time"], bool)
    dt = float(ds.attrs["dt"])
    block = max(8, int(round(WINDOW_S / dt)))
    out = NoiseFloor()
    if noise_record is not None:
        if not isinstance(noise_record, xr.Dataset):
            from .io import read_record  # io imports this module

            noise_record = read_record(
                noise_record, mass=ds.attrs.get("mass", 1.0), quality=False, velocity=None
            )
        nv = noise_record["valid"].values.astype(bool) if "valid" in noise_record else None
        nblock = max(8, int(round(WINDOW_S / float(noise_record.attrs["dt"]))))
        for name in names:
            if name in noise_record:
                y = noise_record[name].values
                out[name] = block_sd(y[nv] if nv is not None else y, nblock)
                out.methods[name] = "noise_record"
    seg = None
    if quiet is not False and any(name not in out for name in names):
        if quiet is None or quiet is True:
            seg = find_quiet(ds)
        elif isinstance(quiet, slice):
            seg = quiet
        else:
            t = ds["time"].values
            seg = slice(int(np.searchsorted(t, quiet[0])), int(np.searchsorted(t, quiet[1])))
        if seg is not None:
            t = ds["time"].values
            out.segment = (float(t[seg.start]), float(t[seg.stop - 1]))
            for name in names:
                if name in out:
                    continue
                y = ds[name].values[seg][valid[seg]]
                if y.size >= 8:
                    out[name] = block_sd(y, block)
                    out.methods[name] = "quiet_segment"
    for name in names:
        if name not in out:
            out[name] = differencing_sd(ds[name].values[valid])
            out.methods[name] = "differencing"
    return out


def trim_excited(
    ds: xr.Dataset,
    threshold: float = 5.0,
    *,
    fraction: float = 0.02,
    contrast: float = 20.0,
    window_s: float = WINDOW_S,
) -> tuple[xr.Dataset, dict]:
    """Trim a record to the part where its input moves (thesis practice).

    The input channel's moving SD (window ``window_s``) is compared with its
    quiet level q = the smallest moving SD in the record; the excited part
    runs from the first to the last sample whose moving SD exceeds
    max(``threshold`` · q, ``fraction`` · largest moving SD) — the second
    term ignores a twitch of the rig at rest — widened by one window on each
    side so that the onset and the decay are kept. A record that is never
    quiet (largest moving SD < ``contrast`` · q: then q is motion, not rest) is
    not trimmed. The trimmed record's time
    starts again at 0 (every simulation starts from rest at the first sample);
    its attribute ``trim_offset_s`` holds the original time of its first
    sample. Sample indices in an earlier quality report (attribute
    ``quality``) still count from the untrimmed start (``start_index``).

    Parameters
    ----------
    ds : xarray.Dataset
    threshold : float
        Multiple of the quiet level that counts as excited.
    fraction : float
        Fraction of the largest moving SD that counts as excited at least.
    contrast : float
        Smallest ratio of the largest to the smallest moving SD for a record
        to have a quiet part at all.
    window_s : float
        Moving-window length [s].

    Returns
    -------
    record : xarray.Dataset
    report : dict
        ``trimmed``, ``channel``, ``start_index``, ``stop_index`` (exclusive),
        ``cut_start_s``, ``cut_end_s``, ``quiet_level``, ``threshold``, ``reason``.
    """
    name = input_channel(ds)
    x = ds[name].values
    n = x.size
    dt = float(ds.attrs["dt"])
    w = max(8, int(round(window_s / dt)))
    sd = moving_sd(x, w)
    q = float(sd.min())
    level = max(threshold * q, fraction * float(sd.max()))
    report = {
        "trimmed": False,
        "channel": name,
        "start_index": 0,
        "stop_index": n,
        "cut_start_s": 0.0,
        "cut_end_s": 0.0,
        "quiet_level": q,
        "threshold": level,
        "window_s": window_s,
    }
    excited = sd > level
    if sd.max() < contrast * q or excited.all():
        report["reason"] = (
            f"no quiet part: the input's moving SD varies only {sd.max() / max(q, 1e-300):.3g}-fold "
            f"(< {contrast:g}) or never falls below the threshold"
        )
        return ds, report
    idx = np.flatnonzero(excited)
    a = max(int(idx[0]) - w, 0)
    b = min(int(idx[-1]) + w + 1, n)
    if b - a < MIN_SAMPLES:
        report["reason"] = f"excited part has {b - a} samples < {MIN_SAMPLES}: not trimmed"
        return ds, report
    if a == 0 and b == n:
        report["reason"] = "excited from start to end: nothing to cut"
        return ds, report
    t = ds["time"].values
    out = ds.isel(time=slice(a, b)).copy(deep=True)
    out = out.assign_coords(time=("time", t[a:b] - t[a], dict(ds["time"].attrs)))
    out.attrs["trim_offset_s"] = float(ds.attrs.get("trim_offset_s", 0.0)) + float(t[a])
    if "valid" in out:
        out.attrs["masked"] = int((~out["valid"].values.astype(bool)).sum())
    report.update(
        trimmed=True,
        start_index=a,
        stop_index=b,
        cut_start_s=float(a * dt),
        cut_end_s=float((n - b) * dt),
        reason=(
            f"kept {t[a]:.3f}–{t[b - 1]:.3f} s where the moving SD of {name} exceeds "
            f"{level:.3g} (max of {threshold:g} × its quiet level {q:.3g} and {fraction:g} × its peak), "
            f"plus one {window_s:g}-s window each side"
        ),
    )
    return out, report
