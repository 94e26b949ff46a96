"""Fault detectors of quality control, one channel at a time.

Each detector returns ``(flag mask, threshold, reason)``; thresholds are
robust statistics of the channel itself (see :class:`~bayes_mr.data.quality.QualityConfig`).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from bayes_mr.numerics.stats import robust_sd


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) ranges of True runs."""
    m = np.concatenate([[False], mask.astype(bool), [False]])
    edges = np.flatnonzero(np.diff(m.astype(np.int8)))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))


def dilate(mask: np.ndarray, k: int) -> np.ndarray:
    if k <= 0 or not mask.any():
        return mask.copy()
    return ndimage.binary_dilation(mask, structure=np.ones(2 * k + 1, bool))


def _equal_runs(x: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Start index and length of every run of (within ``tol``) equal consecutive values."""
    same = np.abs(np.diff(x)) <= tol
    brk = np.flatnonzero(~same) + 1
    starts = np.concatenate([[0], brk])
    lengths = np.diff(np.concatenate([starts, [x.size]]))
    return starts, lengths



# ------------------------------------------------------------------ detectors
# Each returns (flag mask, threshold, reason) for one channel.


def _saturated(x, start, stop, value, tol) -> bool:
    """True if a run of equal values is approached or left smoothly.

    A noise-free signal that saturates (a simulated Dahl state reaching ±1 in
    floating point) creeps up to its constant value: the sample next to the
    run on that side lies within ``tol`` of it. A clipped or dropped-out
    measured channel arrives and leaves with ordinary steps (noise, or the
    jump to zero) on both sides.
    """
    sides = [x[i] for i in (start - 1, stop) if 0 <= i < x.size]
    return any(abs(v - value) <= tol for v in sides)


def rails(x, cfg):
    r = np.ptp(x)
    tol = cfg.clip_tol * r
    flag = np.zeros(x.size, bool)
    rails, needs = [], []
    for side, sign in (("max", 1.0), ("min", -1.0)):
        y = sign * x
        ext = y.max()
        hit = y >= ext - tol
        longest = 0
        for a, b in runs(hit):
            if _saturated(y, a, b, ext, cfg.approach_tol * r):
                hit[a:b] = False
            else:
                longest = max(longest, b - a)
        # how often values next to the extreme repeat: a continuous signal is
        # rare out there (a quantised one repeats there about as often as at
        # its extreme); a rail collects every excursion beyond it
        near = y[(y >= ext - cfg.clip_zone * r) & (y < ext - tol)]
        _, counts = np.unique(near, return_counts=True)
        m_near = int(counts.max()) if counts.size else 1
        need = max(cfg.clip_min_count, cfg.clip_ratio * m_near)
        needs.append(need)
        if hit.sum() >= need and longest >= cfg.clip_min_run:
            flag |= hit
            rails.append(f"{side} {x[hit][0]:.6g} hit {int(hit.sum())}× (values near it repeat ≤ {m_near}×)")
    reason = f"rail value(s): {'; '.join(rails)}"
    return flag, float(min(needs)), reason


def flats(x, cfg, skip):
    starts, lengths = _equal_runs(x, 0.0)
    base = float(np.quantile(lengths, cfg.flat_quantile))
    need = max(cfg.flat_min_run, cfg.flat_ratio * base)
    flag = np.zeros(x.size, bool)
    tol = cfg.approach_tol * np.ptp(x)
    for s, n in zip(starts[lengths >= need], lengths[lengths >= need]):
        if s == 0 or s + n == x.size or skip[s : s + n].all():
            continue
        if _saturated(x, s, s + n, x[s], tol):
            continue
        flag[s : s + n] = True
    flag &= ~skip
    reason = f"runs of ≥ {need:g} identical values mid-record (typical run {base:g})"
    return flag, float(need), reason


def _spike_stats(x, cfg):
    """Residual from the running median, its global scale and the local step scale.

    The local scale of sample i is the largest |Δx| among the steps j with
    i - reach ≤ j < i - w or i + w ≤ j < i + reach (w = spike_width): every
    step that touches a spike of ≤ w samples covering i is left out.
    """
    w = cfg.spike_width
    # scale: residual from the median of the 2w neighbours (the sample itself
    # left out); unlike a plain running median it is not the sample itself on
    # every monotone stretch, so its MAD is not zero on fast, clean signals
    foot = np.ones(2 * w + 1, bool)
    foot[w] = False
    lo = ndimage.rank_filter(x, w - 1, footprint=foot, mode="nearest")
    hi = ndimage.rank_filter(x, w, footprint=foot, mode="nearest")
    r_out = x - 0.5 * (lo + hi)
    s_glob = robust_sd(r_out)
    # the tested residual is from the plain running median, which follows a
    # monotone edge exactly: a sharp force flip is not a spike
    r = x - ndimage.median_filter(x, size=2 * w + 1, mode="nearest")
    step = np.abs(np.diff(x))
    reach = max(cfg.spike_reach, w + 1)
    length = reach - w
    pad = reach + 1
    padded = np.concatenate([np.zeros(pad), step, np.zeros(pad)])
    window_max = np.lib.stride_tricks.sliding_window_view(padded, length).max(axis=1)
    i = np.arange(x.size)
    local = np.maximum(window_max[i - reach + pad], window_max[i + w + pad])
    return r, s_glob, local


def _grazes(x, r, flag, u, polarity, reach, bounds):
    """Flagged samples that are a damper force following a brief near-reversal of velocity.

    When the piston velocity u dips towards zero and comes back on the same
    side within a few samples, a damper's force (whose sign follows u) makes
    a short excursion towards its reversed-velocity level: physics, not a
    spike. Such a sample has u clearly of one sign at both ends of its
    neighbourhood (``reach`` samples each side; |u| ≥ 5 % of its 99th
    percentile, so noise around rest does not count), |u| inside dipping
    below half of both ends, a residual of sign −polarity·sgn(u) (polarity −1
    for an acceleration, which is −force/m), and a value inside the channel's
    robust range ``bounds`` (a damper cannot overshoot its own force range).
    """
    n = u.size
    level = 0.05 * float(np.quantile(np.abs(u), 0.99))
    out = np.zeros(n, bool)
    for i in np.flatnonzero(flag):
        a, b = max(i - reach, 0), min(i + reach, n - 1)
        ua, ub = u[a], u[b]
        if np.sign(ua) != np.sign(ub) or min(abs(ua), abs(ub)) < level or level == 0:
            continue  # a full reversal (the force flips monotonically) or a rig at rest
        dip = np.abs(u[a : b + 1]).min() < 0.5 * min(abs(ua), abs(ub))
        inside = bounds[0] <= x[i] <= bounds[1]
        if dip and inside and np.sign(r[i]) == -polarity * np.sign(ua):
            out[i] = True
    return out


def spikes(x, cfg, u=None, polarity=1.0):
    r, s_glob, local = _spike_stats(x, cfg)
    lo, hi = np.quantile(x, [cfg.range_quantile, 1.0 - cfg.range_quantile])
    # floor: a noise-free channel has σ_r ≈ 0, and an excursion of 0.1 % of the
    # range is no fault worth masking
    thr = max(cfg.spike_c * s_glob, cfg.spike_floor * float(hi - lo))
    if thr <= 0:
        # σ_r = 0 and R_rob = 0: the channel is exactly constant on ≥ 99 % of the
        # record and noise-free (a step's ground acceleration is two one-sample
        # pulses and zeros); there is no scale to call an excursion a spike against
        return np.zeros(x.size, bool), 0.0, "not tested: noise-free and constant on ≥ 99 % of the record"
    flag = (np.abs(r) > thr) & (np.abs(r) > cfg.spike_local_c * local)
    if u is not None and flag.any():
        flag &= ~_grazes(x, r, flag, u, polarity, cfg.spike_reach, (lo, hi))
    reason = (
        f"|x − running median({2 * cfg.spike_width + 1})| > {cfg.spike_c:g} σ_r = {thr:.4g} "
        f"and > {cfg.spike_local_c:g} × the neighbouring steps"
    )
    return flag, float(thr), reason


def jumps(x, cfg, skip, continuous):
    step = np.abs(np.diff(x))
    if continuous:
        thr = cfg.jump_c * float(np.quantile(step, cfg.jump_quantile))
        reason = f"|Δx| > {cfg.jump_c:g} × q{cfg.jump_quantile:g}(|Δx|) = {thr:.4g}"
    else:
        lo, hi = np.quantile(x, [cfg.range_quantile, 1.0 - cfg.range_quantile])
        thr = cfg.jump_range * float(hi - lo)
        reason = f"|Δx| > {cfg.jump_range:g} × the robust range = {thr:.4g}"
    if thr <= 0:  # noise-free and constant almost everywhere: no scale to judge a step against (see spikes)
        return np.zeros(x.size, bool), 0.0, "not tested: noise-free and constant on ≥ 99 % of the record"
    big = step > thr
    big &= ~(skip[:-1] | skip[1:])  # a step into or out of a known fault is that fault
    flag = np.zeros(x.size, bool)
    flag[:-1] |= big
    flag[1:] |= big
    return flag, float(thr), reason


def velocity_range(x, cfg):
    dev = np.abs(x - np.median(x))
    thr = cfg.velocity_c * float(np.quantile(dev, cfg.velocity_quantile))
    flag = dev > thr
    reason = f"|v − median| > {cfg.velocity_c:g} × q{cfg.velocity_quantile:g} = {thr:.4g}"
    return flag, float(thr), reason


def end_events(x, cfg, body_ok, use_values=True):
    """Samples in the final part that break the record's history (see QualityConfig.end_c)."""
    n = x.size
    i_end = n - max(int(round(cfg.end_fraction * n)), 2 * cfg.spike_reach)
    body = x[:i_end][body_ok[:i_end]]
    step = np.abs(np.diff(x))
    body_steps = step[: i_end - 1][body_ok[: i_end - 1] & body_ok[1:i_end]]
    if body.size < 2 or body_steps.size < 1:
        return np.zeros(n, bool), np.inf
    med = np.median(body)
    step_thr = cfg.end_c * body_steps.max()
    dev_thr = cfg.end_c * np.abs(body - med).max()
    ev = np.zeros(n, bool)
    tail_steps = (step[i_end - 1 :] > step_thr) & body_ok[i_end - 1 : -1]
    ev[i_end:] |= tail_steps  # a step flags the sample it lands on
    if use_values:
        ev[i_end:] |= np.abs(x[i_end:] - med) > dev_thr
    ev &= body_ok  # samples already explained (spike, clip, flat-line) are not events
    return ev, float(step_thr)

