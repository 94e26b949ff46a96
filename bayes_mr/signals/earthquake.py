"""Earthquake ground motions as signals: resampled, scaled and baseline corrected.

Table 5.1 writes ``x_g = A · ElCentro(S k Δt)`` with A = 0.1 and S = 0.4 —
S sits inside the argument, which reads like a time scale. We follow
``docs/CONTRACT.md`` and §3.8.1 ("set at 50 % of the original earthquake
acceleration"): the ground ACCELERATION is ``scale`` × the record, on the
record's own time axis, resampled to ``fs`` by linear interpolation (MATLAB
``interp1``, as the thesis did). A is not used. The table's T (42 s for El
Centro) is the default ``duration``; the Kobe record (T = 51 s) is not
available and Loma Prieta (39.97 s) stands in for it, in full by default.

Velocity and displacement are the exact integrals from rest of the
acceleration, linear between samples. ``baseline="cubic"`` (the default of
:func:`bayes_mr.signals.make_signal`) first subtracts from the resampled
acceleration the cubic polynomial in time that minimises the mean square
ground displacement subject to the ground being at rest (v = x = 0) at the
last sample. This removes the metres of drift that integrating a raw record
gives (El Centro: 2.5 m → 0.19 m peak at full scale) while changing its
acceleration by 0.4 % of the PGA at most for the whole record or the default
42 s (up to ~2 % when a record is cut short mid-shaking; the value is in
``params["baseline_max_correction"]`` [m/s²]). The already processed Loma
Prieta record is left unchanged to 1e-6 m/s². ``"none"``: the thesis's raw
``scale × interp1`` acceleration, exactly; displacement then drifts.
"""

from __future__ import annotations

import numpy as np

from bayes_mr.data.ground_motions import load_ground_motion
from bayes_mr.signals.signal import integrate_acceleration

#: Baseline corrections applied to earthquake records.
BASELINES = ("cubic", "none")


def earthquake(
    record: str, fs: float, scale: float, duration: float | None, baseline: str
) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], dict]:
    """``scale`` × a packaged ground motion, resampled to ``fs`` [Hz], ``duration`` [s] long (None: whole).

    Returns (displacement [m], velocity [m/s], acceleration [m/s²]) and the
    baseline settings for the signal's ``params`` (see the module docstring).
    """
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
        a, coef = cubic_baseline(t, a, v, x, dt)
        v, x = integrate_acceleration(a, dt)
        corr = np.polynomial.polynomial.polyval(t / t[-1], coef)
        info.update(baseline_coefficients=[float(c) for c in coef],
                    baseline_max_correction=float(np.abs(corr).max()))
    return (x, v, a), info


def cubic_baseline(
    t: np.ndarray, a: np.ndarray, v: np.ndarray, x: np.ndarray, dt: float
) -> tuple[np.ndarray, np.ndarray]:
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

