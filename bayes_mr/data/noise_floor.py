"""Noise floor of a record: the measurement-noise SD of each channel (thesis practice).

The thesis took its noise covariances from a separate 60-s "no input" run
(NoInput-Hydraulic: the standard deviation of each channel). :func:`noise_floor`
does this from a no-input record if one is given, else from a quiet segment of
the record itself (found automatically), else from a differencing estimate.
Both the record and the no-input record are record Datasets (read them with
:func:`bayes_mr.data.load`). This module *estimates* noise; synthetic noise
for simulations is *generated* by :mod:`bayes_mr.numerics.synthetic_noise`.
"""

from __future__ import annotations

import json

import numpy as np
import xarray as xr
from scipy import ndimage

from bayes_mr.numerics.stats import robust_sd
from bayes_mr.data.schema import STRUCTURE

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
    """The channel that drives a test: ground acceleration (structure), applied force (forced) or displacement."""
    return {STRUCTURE: "ground_acceleration", "forced": "applied_force"}.get(ds.attrs.get("kind"), "displacement")


def moving_sd(x: np.ndarray, window: int) -> np.ndarray:
    """Standard deviation of ``x`` in a centred moving window of ``window`` samples, shape (n,)."""
    x = np.asarray(x, float)
    x = x - np.median(x)  # keeps E[x²] − E[x]² well conditioned for offset signals
    m1 = ndimage.uniform_filter1d(x, window, mode="nearest")
    m2 = ndimage.uniform_filter1d(x * x, window, mode="nearest")
    return np.sqrt(np.maximum(m2 - m1 * m1, 0.0))


def input_activity(ds: xr.Dataset, window_s: float = WINDOW_S) -> tuple[np.ndarray, int]:
    """Moving SD of a record's input channel and its window length.

    Parameters
    ----------
    ds : xarray.Dataset
        The record (attribute ``dt`` [s]).
    window_s : float
        Window length [s]; at least 8 samples are used.

    Returns
    -------
    sd : ndarray, shape (n,)
        Moving standard deviation of :func:`input_channel` (its units).
    window : int
        Window length [samples].
    """
    w = max(8, int(round(window_s / float(ds.attrs["dt"]))))
    return moving_sd(ds[input_channel(ds)].values, w), w


def differencing_sd(x: np.ndarray) -> float:
    """White-noise SD from the third difference: robust_sd(Δ³x) = 1.4826 · MAD(Δ³x), over √20.

    For white noise of SD σ the third difference has SD σ√20; the MAD makes
    the estimate ignore the few large differences at sharp features. This
    is a *lower bound* of the measurement noise for oversampled smooth
    signals: noise that the sensor or anti-alias filter has coloured (low-pass)
    has less power at the highest frequencies than white noise of the same SD.
    (A signal that is not oversampled leaks into Δ³ and biases it upwards.)
    """
    d3 = np.diff(np.asarray(x, float), 3)
    return float(robust_sd(d3) / np.sqrt(20.0))


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
    sd, w = input_activity(ds, window_s)
    n = sd.size
    dt = float(ds.attrs["dt"])
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
    noise_record: xr.Dataset | None = None,
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
    noise_record : xarray.Dataset, optional
        A record of the same rig with no input (from a file:
        ``load(path, quality=False, velocity=None)``, or ``load(record_path,
        noise_record=path)`` which does that for you).

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


def with_noise_floor(ds: xr.Dataset, floor: NoiseFloor) -> xr.Dataset:
    """A copy of ``ds`` carrying ``floor``: ``noise_sd_<channel>`` and ``noise_floor`` (how each SD was found)."""
    out = ds.copy()
    for name, sd in floor.items():
        out.attrs[f"noise_sd_{name}"] = float(sd)
    out.attrs["noise_floor"] = json.dumps({"methods": floor.methods, "segment": floor.segment})
    return out
