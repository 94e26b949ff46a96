"""Agreement between a measured displacement and a measured velocity.

A device test with both channels measured carries a physical check that no
single-channel statistic has: the velocity integrates to the displacement.
A fast transient (the ramp of a step test, a hard start) makes large steps
and out-of-range values in the velocity that single-channel tests would call
jumps; when the displacement moved by the same amount the samples are
physics, not faults. :func:`consistent` finds such runs; :func:`repair_pair`
repairs the two inputs so that they keep agreeing after a repair.
"""

from __future__ import annotations

import numpy as np

from bayes_mr.numerics.stats import robust_sd
from bayes_mr.data.quality.detectors import runs


def mismatch(x: np.ndarray, v: np.ndarray, dt: float) -> np.ndarray:
    """e_i = x_i − x_0 − ∫_0^{t_i} v dt (trapezoid) [m]: constant where the two channels agree."""
    return x - x[0] - _cumtrapz(v, dt)


def _cumtrapz(v: np.ndarray, dt: float) -> np.ndarray:
    """∫_0^{t_i} v dt by the trapezoid rule, 0 at the first sample."""
    return np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * dt)])


def consistent(flag: np.ndarray, x: np.ndarray, v: np.ndarray, dt: float, c: float, reach: int,
               floor: float) -> np.ndarray:
    """Flagged samples whose run the two channels agree on.

    For a run [a, b) of flagged samples the window [a − reach, b + reach]
    (clipped to the record) is judged by the change of :func:`mismatch` across
    it, Δe. The reference is the same change over every window of that length
    in the record: a run agrees when |Δe − median| ≤ ``c`` × max(robust SD,
    ``floor``). Noise and a calibration mismatch of the two transducers move
    Δe by as much anywhere in the record; a velocity that steps, rings or
    spikes without the displacement following it moves Δe by its own integral.

    Parameters
    ----------
    flag : ndarray of bool, shape (n,)
        Samples a single-channel test flagged (in either channel).
    x, v : ndarray, shape (n,)
        Displacement [m] and velocity [m/s], finite.
    dt : float
        Sample interval [s].
    c : float
        Multiple of the reference scale that still agrees.
    reach : int
        Samples added on either side of a run [samples].
    floor : float
        Smallest reference scale [m] (a noise-free record has none).

    Returns
    -------
    ndarray of bool, shape (n,)
        True on flagged samples of runs that agree.
    """
    n = x.size
    e = mismatch(x, v, dt)
    out = np.zeros(n, bool)
    scales: dict[int, tuple[float, float]] = {}
    for a, b in runs(flag):
        lo, hi = max(a - reach, 0), min(b + reach, n - 1)
        length = hi - lo
        if length <= 0 or length >= n // 2:
            continue  # a run over half the record has no reference of its own length
        if length not in scales:
            ref = e[length:] - e[:-length]
            scales[length] = (float(np.median(ref)), float(robust_sd(ref)))
        med, sd = scales[length]
        if abs(e[hi] - e[lo] - med) <= c * max(sd, floor):
            out[a:b] = True
    return out


def repair_pair(x: np.ndarray, v: np.ndarray, bad_x: np.ndarray, bad_v: np.ndarray, dt: float,
                window: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Displacement and velocity repaired so that they still agree.

    * Displacement bad where the velocity is good: the velocity integrated
      across the run from its left end, the closure error at the right end
      spread linearly over the run (so the repaired run meets both ends).
    * Both bad: the displacement bridged by a straight line between the valid
      neighbours (held at the record's ends), the velocity the slope of that
      bridge (zero where held).
    * Velocity bad where the displacement is good (after the above): a bridge
      continuous with the valid velocities on either side whose integral is the
      displacement's change across the run (:func:`_bridge_velocity`).

    Parameters
    ----------
    x, v : ndarray, shape (n,)
        Displacement [m] and velocity [m/s].
    bad_x, bad_v : ndarray of bool, shape (n,)
        Samples to replace in each.
    dt : float
        Sample interval [s].

    Returns
    -------
    x, v : ndarray, shape (n,)
        Repaired copies.
    """
    n = x.size
    x, v = x.astype(float).copy(), v.astype(float).copy()
    idx = np.arange(n)
    both = bad_x & bad_v
    x_only = bad_x & ~bad_v
    if both.any() and (~bad_x).any():
        good = ~bad_x
        x[both] = np.interp(idx[both], idx[good], x[good])
        v[both] = np.gradient(x, dt)[both]
        for a, b in runs(both):  # held past the record's ends: at rest
            if a == 0 or b == n or not good[:a].any() or not good[b:].any():
                v[a:b] = 0.0
    if x_only.any():
        integral = _cumtrapz(v, dt)
        for a, b in runs(x_only):
            _integrate_run(x, integral, a, b)
    for a, b in runs(bad_v & ~bad_x):
        _bridge_velocity(x, v, a, b, dt)
    return x, v


def _bridge_velocity(x: np.ndarray, v: np.ndarray, a: int, b: int, dt: float) -> None:
    """v[a:b] continuous with its valid neighbours and integrating to the displacement's change (in place).

    Between anchors a − 1 and b: the straight line between the two velocities
    plus the parabolic bump (zero at both anchors) whose integral makes the
    mismatch e = x − ∫v dt level on both sides of the run — its mean over up to
    max(b − a, 8) samples each side (fewer at a record end), so that the displacement's noise at one sample does not set the
    bridge. At a record end: the displacement's mean slope over the run.
    """
    n = x.size
    left, right = a - 1, b
    if left < 0 or right >= n:
        lo, hi = max(left, 0), min(right, n - 1)
        v[a:b] = (x[hi] - x[lo]) / ((hi - lo) * dt) if hi > lo else 0.0
        return
    i = np.arange(left, right + 1)
    v[a:b] = v[left] + (v[right] - v[left]) * (i[1:-1] - left) / (right - left)
    k = max(b - a, 8)
    e = mismatch(x, v, dt)
    gap = np.mean(e[right:min(right + k, n)]) - np.mean(e[max(left - k + 1, 0):left + 1])
    bump = ((i - left) * (right - i)).astype(float)
    v[a:b] += (bump * gap / (dt * bump.sum()))[1:-1]


def _integrate_run(x: np.ndarray, integral: np.ndarray, a: int, b: int) -> None:
    """x[a:b] from the velocity's integral, anchored at x[a − 1] and x[b] where they exist (in place)."""
    left, right = a - 1, b
    i = np.arange(a, b)
    if left >= 0 and right < x.size:
        closure = x[left] + integral[right] - integral[left] - x[right]
        x[a:b] = x[left] + integral[a:b] - integral[left] - closure * (i - left) / (right - left)
    elif left >= 0:
        x[a:b] = x[left] + integral[a:b] - integral[left]
    elif right < x.size:
        x[a:b] = x[right] - (integral[right] - integral[a:b])
