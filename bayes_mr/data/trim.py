"""Trim a record to its excited part (thesis practice), with a report of what was cut.

The thesis trimmed every record to the part where the shake table moved;
:func:`trim_excited` finds that part from the moving standard deviation of
the record's input channel (:func:`bayes_mr.data.noise_floor.moving_sd`).
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from bayes_mr.data.noise_floor import WINDOW_S, input_activity, input_channel
from bayes_mr.data.schema import MIN_SAMPLES


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
    sd, w = input_activity(ds, window_s)
    n = sd.size
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
    bounds, why = _excited_bounds(sd, w, level, contrast)
    if bounds is None:
        report["reason"] = why
        return ds, report
    a, b = bounds
    out = _cut(ds, a, b)
    t = ds["time"].values
    dt = float(ds.attrs["dt"])
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


def _excited_bounds(sd: np.ndarray, w: int, level: float, contrast: float) -> tuple[tuple[int, int] | None, str]:
    """``(start, stop)`` samples of the excited part widened by one window ``w``, or None and why not."""
    n = sd.size
    q = float(sd.min())
    excited = sd > level
    if sd.max() < contrast * q or excited.all():
        return None, (
            f"no quiet part: the input's moving SD varies only {sd.max() / max(q, 1e-300):.3g}-fold "
            f"(< {contrast:g}) or never falls below the threshold"
        )
    idx = np.flatnonzero(excited)
    a = max(int(idx[0]) - w, 0)
    b = min(int(idx[-1]) + w + 1, n)
    if b - a < MIN_SAMPLES:
        return None, f"excited part has {b - a} samples < {MIN_SAMPLES}: not trimmed"
    if a == 0 and b == n:
        return None, "excited from start to end: nothing to cut"
    return (a, b), ""


def _cut(ds: xr.Dataset, a: int, b: int) -> xr.Dataset:
    """Samples ``a:b`` of a record, its clock restarted at 0 (``trim_offset_s`` keeps the shift)."""
    t = ds["time"].values
    out = ds.isel(time=slice(a, b)).copy(deep=True)
    out = out.assign_coords(time=("time", t[a:b] - t[a], dict(ds["time"].attrs)))
    out.attrs["trim_offset_s"] = float(ds.attrs.get("trim_offset_s", 0.0)) + float(t[a])
    if "valid" in out:
        out.attrs["masked"] = int((~out["valid"].values.astype(bool)).sum())
    return out
