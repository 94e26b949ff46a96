"""Compiled pieces of the issue-15 effects, called from :mod:`bayes_mr.models.kernel`.

They sit in their own module so the kernel keeps its size; their layout
slots follow the kernel's measured-channel block (``kernel.L_OBS +
kernel.N_OBS`` = 20, which the kernel asserts on import) so that every
older slot keeps its index. Equations and citations: ``docs/CONTRACT.md``
(Effects) and :mod:`bayes_mr.models.effects`.
"""

from __future__ import annotations

import math

from bayes_mr._compile.jit import hot

# --- layout slots (int64 array; see kernel.L_*) ---------------------------------
L_CSAT = 20  # command_saturation: u_s
L_FD = 21  # field_dynamics: tau_c
L_SC = 22  # state index of the coil current (field_dynamics)
L_ST = 23  # shear_thinning: c_p, m_hb, v_p
L_SF = 24  # stribeck_friction: F_st, v_s
L_FDEC = 25  # field_decay: r_d
# --- constants (float64 array; see kernel.K_*) -----------------------------------
K_SMOOTH = 4  # stribeck_friction: width of the smoothed sgn ẋ relative to v_s


@hot(inline="always")
def _sgn(v):
    if v > 0.0:
        return 1.0
    if v < 0.0:
        return -1.0
    return 0.0


@hot(inline="always")
def _saturate(lay, p, u):
    """The command as the field-dependent coefficients see it: u_s·tanh(u/u_s) with command_saturation, else u."""
    if lay[L_CSAT] < 0:
        return u
    us = p[lay[L_CSAT]]
    return us * math.tanh(u / us)


@hot(inline="always")
def _fluid_friction(lay, cst, p, xd):
    """Velocity-only damper forces [N]: shear_thinning and stribeck_friction (0 when off)."""
    f = 0.0
    if lay[L_ST] >= 0:
        j = lay[L_ST]
        cp, mh, vp = p[j], p[j + 1], p[j + 2]
        # Herschel–Bulkley power law |ẋ|^m above v_p, slope c_p at rest (regularised)
        f += cp * vp * _sgn(xd) * (math.pow(1.0 + abs(xd) / vp, mh) - 1.0) / mh
    if lay[L_SF] >= 0:
        j = lay[L_SF]
        r = xd / p[j + 1]
        rr = r * r
        if rr < 700.0:
            f += p[j] * math.exp(-rr) * math.tanh(r / cst[K_SMOOTH])
    return f


@hot(inline="always")
def _fluid_slope(lay, cst, p, vmax):
    """Upper bound of d(_fluid_friction)/dẋ [N·s/m] for |ẋ| ≤ vmax (the rate of structure tests)."""
    slope = 0.0
    if lay[L_ST] >= 0:
        j = lay[L_ST]
        slope += p[j] * max(1.0, math.pow(1.0 + vmax / p[j + 2], p[j + 1] - 1.0))
    if lay[L_SF] >= 0:
        j = lay[L_SF]
        slope += abs(p[j]) / (cst[K_SMOOTH] * p[j + 1])
    return slope


@hot(inline="always")
def _coil_step(lay, p, s, v0, v1, hs):
    """Advance the coil's lag d = i − v over a sub-step, exact for a command linear from v0 to v1.

    With i̇ = (v − i)/τ_c, d obeys ḋ = −d/τ_c − v̇, so d(hs) = −τ·v̇ + (d0 + τ·v̇)·e^{−hs/τ},
    v̇ = (v1 − v0)/hs: stable for any τ_c, and d → 0 (the one-lag model) as τ_c → 0.
    The field lags read i = v(t) + d with d held over the sub-step (``deriv`` sets its
    rate to 0), as the amplitude envelope is updated between sub-steps.
    """
    ic = lay[L_SC]
    tau = p[lay[L_FD]]
    vd = (v1 - v0) / hs
    e = math.exp(-hs / tau) if hs < 700.0 * tau else 0.0
    s[ic] = -tau * vd + (s[ic] + tau * vd) * e


@hot(inline="always")
def _lag_rate(lay, p, eta, v, u):
    """Rate u̇ [V/s] of a command-to-field lag of rate η driven by v: η·(v − u), and with
    field_decay r_d·η·(v − u) while the field's magnitude falls (|v| < |u|)."""
    if lay[L_FDEC] >= 0 and abs(v) < abs(u):
        return eta * p[lay[L_FDEC]] * (v - u)
    return eta * (v - u)


@hot(inline="always")
def _lag_bound(lay, p, eta):
    """Upper bound of a field lag's rate [1/s] (η, or η·max(1, r_d) with field_decay)."""
    if lay[L_FDEC] >= 0:
        return abs(eta) * max(1.0, p[lay[L_FDEC]])
    return abs(eta)
