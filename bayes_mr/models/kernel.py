"""Compiled right-hand sides of every model form and effect (numba).

One kernel serves all models: the model's *layout* (an int64 array built by
:meth:`bayes_mr.models.Model.layout`) says which form is active, where its
parameters and states sit, and which effects are switched on. Compiling one
kernel instead of one per combination keeps the first call of any
``FORM+EFFECT+EFFECT`` model as fast as the thousandth, and lets numba cache
the machine code on disk.

Conventions
-----------
State ``s`` of a structure or forced test: ``[x, ẋ, form states…, effect
states…]``; of a device test: ``[form states…, effect states…]`` (x and ẋ
are inputs). Input row ``a`` (3,): structure ``[ẍ_g, 0, v]``; forced
``[p, 0, v]`` (applied force [N]); device ``[x, ẋ, v]``, linear in time
between samples; ``v`` is the damper command (voltage or current). ``p`` holds natural (SI) parameters.
Time ``t`` is measured from the first sample.

Equations are those of ``docs/CONTRACT.md`` (thesis 3-31/32, 3-52..3-70,
Spencer et al. 1997) with ``|z|^{n-1} z`` written ``sgn(z)|z|^n``.
"""

from __future__ import annotations

import math

from bayes_mr._compile.jit import hot
from bayes_mr.models.term_kernel import TERM_LAW, term_basis

# --- form codes -------------------------------------------------------------
NBW, DAHL, LUGRE, BW, SPENCER = 0, 1, 2, 3, 4
# --- kinds ------------------------------------------------------------------
STRUCT, DEVICE, FORCED = 0, 1, 2
# --- measured-channel codes (layout slots L_OBS…) ----------------------------------
OBS_X, OBS_V, OBS_A, OBS_F = 0, 1, 2, 3

# --- layout slots (int64 array) ---------------------------------------------
L_FORM = 0  # form code
L_KIND = 1  # STRUCT or DEVICE
L_PFORM = 2  # index in p of the form's first parameter
L_PFRAME = 3  # index of frame c (k at +1) when the form has no c, k of its own; else -1
L_SFORM = 4  # index in s of the form's first state
L_NS = 5  # number of states
L_F0 = 6  # force_offset: f0
L_VD = 7  # voltage_dependence: a_v, c_v, eta
L_SU = 8  # state index of the filtered voltage (voltage_dependence)
L_DRIFT = 9  # stiffness_drift: drift
L_ASYM = 10  # asymmetry: asym
L_SA = 11  # small_amplitude_regime: r_s, x_s
L_SE = 12  # state index of the amplitude envelope
L_LVR = 13  # low_velocity_rolloff: c_s
L_K3 = 14  # cubic_stiffness: k3
L_NP = 15  # number of parameters
L_MASS = 16  # forced test: index in p of the mass m [kg]
L_OBS = 17  # codes (OBS_*) of the measured channels, L_OBS..L_OBS+N_OBS-1, -1 = unused
N_OBS = 3
L_CSAT = 20  # command_saturation: u_s
L_FD = 21  # field_dynamics: tau_c
L_SC = 22  # state index of the coil current (field_dynamics)
L_ST = 23  # shear_thinning: c_p, m_hb, v_p
L_SF = 24  # stribeck_friction: F_st, v_s
L_FDEC = 25  # field_decay: r_d
# library terms (bayes_mr.models.terms): up to N_TERMS terms θ_j·b_j, b_j chosen by a code
L_TP = L_FDEC + 1  # index in p of term j's θ_j, L_TP..L_TP+N_TERMS-1, -1 = unused
N_TERMS = 3
L_TC = L_TP + N_TERMS  # code of term j's basis and target (TERM_* below)
L_SUL = L_TC + N_TERMS  # state index of the lagged command (spencer's or voltage_dependence's u), -1 = none
L_CPOLY = L_SUL + 1  # command_polynomial: b2, b3
L_CEXP = L_SUL + 2  # exponential_saturation: u_e
LAYOUT_SIZE = L_SUL + 3

# --- constants (float64 array) ----------------------------------------------
K_MASS = 0  # storey mass [kg] (structure tests)
K_TENV = 1  # amplitude-envelope decay time [s]
K_CACC = 2  # accuracy bound h·λ ≤ c_acc for choosing RK4 sub-steps
K_NMAX = 3  # most sub-steps per sample
K_SMOOTH = 4  # stribeck_friction: width of the smoothed sgn ẋ relative to v_s
K_IMASS = 5  # 1 / K_MASS [1/kg]. Products, not divisions, per stage and in the step control: divisions by the
#              mass, c_acc and n_sub made the specialised dahl structure step 66 ns per sample against 35
#              (bayes_mr.bench.kernels.simulate_ns_per_step)
K_STIFF = 6  # RK4 sub-steps per interval above which the interval is tried with ROS2 (models.integrate)
K_RTOL = 7  # relative error a ROS2 interval may have, else it is taken by RK4
K_BRANCH = 8  # 1: the hysteretic state is held at its saturation on a loading branch (on_branch); 0: integrated
CONST_SIZE = 9


# --- effects: the command's saturation and lags, velocity-only friction ------------
@hot(inline="always")
def _sgn(v):
    if v > 0.0:
        return 1.0
    if v < 0.0:
        return -1.0
    return 0.0


@hot(inline="always")
def _saturate(lay, p, u):
    """The command as the field-dependent coefficients see it, g(u): the current law.

    u itself (the linear law of Spencer et al. 1997) unless shaped, in this order, by
    command_polynomial (u·(1 + b2·u + b3·u²)), command_saturation (u_s·tanh(u/u_s)) and
    exponential_saturation (sgn(u)·u_e·(1 − e^{−|u|/u_e})).
    """
    if lay[L_CPOLY] >= 0:
        j = lay[L_CPOLY]
        u = u * (1.0 + p[j] * u + p[j + 1] * u * u)
    if lay[L_CSAT] >= 0:
        us = p[lay[L_CSAT]]
        u = us * math.tanh(u / us)
    if lay[L_CEXP] >= 0:
        ue = p[lay[L_CEXP]]
        u = _sgn(u) * ue * (1.0 - math.exp(-abs(u) / ue))
    return u


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
def coil_step(lay, p, s, v0, v1, hs):
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


@hot(inline="always")
def _terms(lay, p, s, x, xd, v, iz, ds):
    """Add the library terms: law terms to ds[iz] (ż), and return the sum of the force terms [N]."""
    f = 0.0
    z = s[iz]
    ul = s[lay[L_SUL]] if lay[L_SUL] >= 0 else 0.0
    for j in range(N_TERMS):
        jp = lay[L_TP + j]
        if jp < 0:
            continue
        code = lay[L_TC + j]
        val = p[jp] * term_basis(code, x, xd, z, v, ul)
        if code // 4096 == TERM_LAW:
            ds[iz] += val
        else:
            f += val
    return f


@hot(inline="always")
def _zdot(form, w, z, q1, q2, q3, zn):
    """Hysteretic state rate of the four single-state forms driven by velocity w.

    Scalars only: passing arrays into helpers makes numba reference-count them,
    which costs more than the physics here. (q1, q2, q3) are
    NBW: (ρ, n, σ); Dahl: (σ, –, –); LuGre: (α, –, –); Bouc–Wen: (β₁, γ, n).
    ``zn`` is |z|ⁿ when the caller has it (:func:`deriv_pow`), else negative.
    """
    if form == NBW:
        if zn < 0.0:
            zn = math.pow(abs(z), q2)
        return q1 * (w - q3 * abs(w) * _sgn(z) * zn + (q3 - 1.0) * w * zn)
    if form == DAHL:
        return q1 * w * (1.0 - z * _sgn(w))
    if form == LUGRE:
        return w - q1 * abs(w) * z
    rn = math.pow(abs(z), q3) if zn < 0.0 else zn
    return w - q1 * abs(w) * _sgn(z) * rn - q2 * w * rn


@hot(inline="always")
def _spencer(p, o, us, m_s):
    """Spencer's coefficients at filtered voltage ``us`` (parameters from ``p[o]``).

    Returns α (× strength multiplier ``m_s``), c0, c1, k0 and the Bouc–Wen
    γ, β, A, n and the current-driver rate η, in that order; shared by
    :func:`deriv` and :func:`rate` so both read the same parameter layout.
    """
    alpha = (p[o] + p[o + 1] * us) * m_s
    c0 = p[o + 2] + p[o + 3] * us
    c1 = p[o + 5] + p[o + 6] * us
    return alpha, c0, c1, p[o + 4], p[o + 9], p[o + 10], p[o + 11], p[o + 12], p[o + 13]


@hot
def deriv(lay, cst, p, t, a, s, ds):
    """Evaluate ṡ = f(s, a(t); p) into ``ds``.

    Returns
    -------
    f_r : float
        Total restoring force [N] (frame + damper + effects).
    f_d : float
        Damper force [N] (the hysteretic part of f_r, with preload and
        voltage-dependent viscous term when those effects are on).
    """
    return _state_rates(lay, cst, p, t, a, s, ds, True, -1.0)


@hot
def deriv_pow(lay, cst, p, t, a, s, ds, zn):
    """:func:`deriv` with the power |z|ⁿ of the hysteretic rate given: ``zn`` = |s[iz]|^p[ip] for
    (iz, ip) = :func:`power_slot` (unused by forms without one).

    A caller with many states to evaluate computes their powers together, in
    one loop the compiler vectorises (:func:`bayes_mr.models.power.pow_nonneg`),
    instead of one C-library call per state (:func:`bayes_mr.models.integrate.advance_points`).
    """
    return _state_rates(lay, cst, p, t, a, s, ds, True, zn)


@hot(inline="always")
def power_slot(lay):
    """(index of the state z, index of the parameter n) of the form's |z|ⁿ; (-1, -1) for Dahl and LuGre."""
    form = lay[L_FORM]
    if form == NBW or form == BW:
        return lay[L_SFORM], lay[L_PFORM] + 4
    if form == SPENCER:
        return lay[L_SFORM] + 1, lay[L_PFORM] + 12  # _spencer's n
    return -1, -1


@hot
def forces(lay, cst, p, t, a, s, ds):
    """The forces (f_r, f_d) [N] of :func:`deriv` without the hysteretic state's rate; ``ds`` is scratch.

    The output map of a filter's measurement update: the power |z|ⁿ of the
    Bouc–Wen family's ż is most of a right-hand side's cost and no force
    needs it (LuGre's force holds ε ż, so there it is computed).
    """
    return _state_rates(lay, cst, p, t, a, s, ds, False, -1.0)


@hot(inline="always")
def _state_rates(lay, cst, p, t, a, s, ds, rates, zn):
    """:func:`deriv` (``rates`` True) or :func:`forces` (False; ``ds``'s hysteretic entries left unset);
    ``zn``: |z|ⁿ if the caller has it (:func:`deriv_pow`), else negative."""
    form = lay[L_FORM]
    kind = lay[L_KIND]
    if kind != DEVICE:
        x = s[0]
        xd = s[1]
    else:
        x = a[0]
        xd = a[1]
    v = a[2]
    if lay[L_FD] >= 0:
        # field_dynamics: the field lags follow the coil current i = v + d; advance() updates d exactly
        v += s[lay[L_SC]]
        ds[lay[L_SC]] = 0.0
    o = lay[L_PFORM]
    i = lay[L_SFORM]

    # strength multiplier m_s (hysteretic force) and stiffness multiplier m_k
    m_s = 1.0
    m_k = 1.0
    if lay[L_DRIFT] >= 0:
        g = 1.0 + p[lay[L_DRIFT]] * t
        m_s *= g
        m_k = g
    u = 0.0
    if lay[L_VD] >= 0:
        j = lay[L_VD]
        iu = lay[L_SU]
        ds[iu] = _lag_rate(lay, p, p[j + 2], v, s[iu])
        u = _saturate(lay, p, s[iu])  # the field-dependent coefficients see the saturated command
        m_s *= 1.0 + p[j] * u
    if lay[L_SA] >= 0:
        j = lay[L_SA]
        ie = lay[L_SE]
        ds[ie] = 0.0  # the envelope is updated discretely after each sub-step
        rs = p[j]
        xs = p[j + 1]
        arg = (s[ie] - xs) / (0.1 * xs)
        if arg > 40.0:
            sw = 1.0
        elif arg < -40.0:
            sw = 0.0
        else:
            sw = 1.0 / (1.0 + math.exp(-arg))
        m_s *= rs + (1.0 - rs) * sw
    asym = 0.0
    if lay[L_ASYM] >= 0:
        asym = p[lay[L_ASYM]]

    if form == SPENCER:
        k1 = p[o + 7]
        f_pre = p[o + 8]  # the preload k1·x0 (forms.SPENCER estimates it in place of x0)
        y = s[i]
        z = s[i + 1]
        us = s[i + 2]
        alpha, c0, c1, k0, gam, bet, A, n, eta = _spencer(p, o, _saturate(lay, p, us), m_s)
        ds[i + 2] = _lag_rate(lay, p, eta, v, us)
        yd = (alpha * z * (1.0 + asym * _sgn(z)) + c0 * xd + k0 * (x - y)) / (c0 + c1)
        r = xd - yd
        ds[i] = yd
        if rates:
            if zn < 0.0:
                zn = math.pow(abs(z), n)
            ds[i + 1] = -gam * abs(r) * _sgn(z) * zn - bet * r * zn + A * r
        f_d = c1 * yd + m_k * (k1 * x - f_pre)
        jf = lay[L_PFRAME]
        if jf >= 0:
            f_frame = p[jf] * xd + m_k * p[jf + 1] * x
        else:
            f_frame = 0.0
    else:
        c = p[o]
        k = p[o + 1]
        z = s[i]
        if form == NBW:
            coef, q1, q2, q3 = p[o + 2], p[o + 3], p[o + 4], p[o + 5]
        elif form == DAHL:
            coef, q1, q2, q3 = p[o + 2], p[o + 3], 0.0, 0.0
        elif form == LUGRE:
            coef, q1, q2, q3 = p[o + 2], p[o + 4], 0.0, 0.0
        else:
            coef, q1, q2, q3 = p[o + 1], p[o + 2], p[o + 3], p[o + 4]
        f_s = m_s * coef * z * (1.0 + asym * _sgn(z))
        w = xd
        if lay[L_LVR] >= 0:
            # series dashpot c_s: the hysteretic element moves at ẋ − F/c_s
            w = xd - f_s / p[lay[L_LVR]]
        zd = _zdot(form, w, z, q1, q2, q3, zn) if rates or form == LUGRE else 0.0
        ds[i] = zd
        f_d = f_s
        if form == LUGRE:
            f_d += m_s * p[o + 3] * zd  # ε ż
        f_frame = c * xd + m_k * k * x

    if lay[L_TP] >= 0:
        f_d += _terms(lay, p, s, x, xd, v, i + 1 if form == SPENCER else i, ds)
    if lay[L_F0] >= 0:
        f_d += p[lay[L_F0]]
    if lay[L_VD] >= 0:
        f_d += p[lay[L_VD] + 1] * u * xd
    if lay[L_ST] >= 0 or lay[L_SF] >= 0:
        f_d += _fluid_friction(lay, cst, p, xd)
    f_r = f_frame + f_d
    if lay[L_K3] >= 0:
        f_r += p[lay[L_K3]] * x * x * x
    if kind == STRUCT:
        ds[0] = xd
        ds[1] = -a[0] - f_r * cst[K_IMASS]
    elif kind == FORCED:
        ds[0] = xd
        ds[1] = (a[0] - f_r) / p[lay[L_MASS]]
    return f_r, f_d


@hot(inline="always")
def mass(lay, cst, p):
    """The moving mass [kg]: a forced test's parameter m, else the constant (structure tests)."""
    if lay[L_MASS] >= 0:
        return p[lay[L_MASS]]
    return cst[K_MASS]


@hot(inline="always")
def inv_mass(lay, cst, p):
    """1/m [1/kg] of :func:`mass`: one division for a forced test's parameter m, none for the constant."""
    if lay[L_MASS] >= 0:
        return 1.0 / p[lay[L_MASS]]
    return cst[K_IMASS]


@hot(inline="always")
def acceleration(lay, cst, p, a, f_r):
    """Absolute acceleration [m/s²]: structure −f_r/m (= ẍ + ẍ_g); forced (p − f_r)/m (= ẍ)."""
    if lay[L_KIND] == FORCED:
        return (a[0] - f_r) / mass(lay, cst, p)
    return -f_r * cst[K_IMASS]


@hot(inline="always")
def channel(lay, cst, p, a, s, f_r, code):
    """Measured channel ``code`` (OBS_*) at state ``s`` with restoring force ``f_r``."""
    if code == OBS_X:
        return s[0]
    if code == OBS_V:
        return s[1]
    if code == OBS_A:
        return acceleration(lay, cst, p, a, f_r)
    return f_r


@hot
def rate(lay, cst, p, t, s, vmax, branch):
    """Upper estimate of the fastest local rate |λ| [1/s] of the dynamics.

    Used to choose sub-steps per sample (h·λ ≤ c_acc, :mod:`bayes_mr.models.integrate`). ``vmax`` is the
    largest |ẋ| expected over the step [m/s]; ``t`` the time [s]. ``branch`` scales the hysteretic state's
    rates (its own rate and its couplings): 0 where it is held on its branch (:func:`bayes_mr.models.branch.on_branch`), 1 elsewhere.
    """
    form = lay[L_FORM]
    o = lay[L_PFORM]
    i = lay[L_SFORM]
    asym = abs(p[lay[L_ASYM]]) if lay[L_ASYM] >= 0 else 0.0
    m_s = 1.0 + asym
    m_k = 1.0
    if lay[L_DRIFT] >= 0:
        m_k = 1.0 + abs(p[lay[L_DRIFT]]) * t
        m_s *= m_k
    u = 0.0
    if lay[L_VD] >= 0:
        u = abs(s[lay[L_SU]])
        m_s *= 1.0 + abs(p[lay[L_VD]]) * u
    lam = 0.0
    coupling = 0.0
    if form == SPENCER:
        alpha, c0, c1, k0, gam, bet, A, n, eta = _spencer(p, o, abs(s[i + 2]), m_s)
        z = abs(s[i + 1])
        zsat = math.pow(A / (gam + bet), 1.0 / n)
        zf = max(z, 0.1 * zsat) if n < 1.0 else max(z, zsat)
        yd = (alpha * z + c0 * vmax + k0 * abs(s[i])) / (c0 + c1)
        rr = vmax + abs(yd)
        zn1 = math.pow(zf, n - 1.0)
        lam = n * zn1 * (gam + bet) * rr
        lam += (A + (gam + bet) * zn1 * zf) * alpha / (c0 + c1)
        lam *= branch
        lam += k0 / (c0 + c1) + _lag_bound(lay, p, eta)
        damp = c0 * c1 / (c0 + c1)
        if lay[L_PFRAME] >= 0:
            damp += p[lay[L_PFRAME]]
            stiff = p[lay[L_PFRAME] + 1]
        else:
            stiff = 0.0
        coupling = alpha * A * branch
    else:
        z = abs(s[i])
        coef = (p[o + 1] if form == BW else p[o + 2]) * m_s
        damp = p[o]
        stiff = p[o + 1]
        if form == DAHL:
            sig = p[o + 3]
            lam = sig * vmax
            slope = sig * (1.0 + z)
        elif form == LUGRE:
            alp = p[o + 4]
            lam = alp * vmax
            slope = 1.0 + alp * z
            damp += p[o + 3] * m_s * slope
        elif form == NBW:
            rho = p[o + 3]
            n = p[o + 4]
            sg = p[o + 5]
            zf = max(z, 0.1) if n < 1.0 else max(z, 1.0)
            # pow(1, ·) is 1 exactly, and zf is 1 whenever n ≥ 1 and |z| ≤ 1 (σ ≥ 1/2): a pow per call saved
            zn1 = 1.0 if zf == 1.0 else math.pow(zf, n - 1.0)
            lam = rho * n * zn1 * vmax * (sg + abs(sg - 1.0))
            slope = rho * (1.0 + (sg + abs(sg - 1.0)) * zn1 * zf)
        else:
            beta1 = p[o + 2]
            gam = p[o + 3]
            n = p[o + 4]
            bg = beta1 + abs(gam)
            rsat = math.pow(1.0 / bg, 1.0 / n)
            zf = max(z, 0.1 * rsat) if n < 1.0 else max(z, rsat)
            zn1 = math.pow(zf, n - 1.0)
            lam = n * zn1 * vmax * bg
            slope = 1.0 + bg * zn1 * zf
        if lay[L_LVR] >= 0:
            lam += slope * coef / p[lay[L_LVR]]
        lam *= branch
        coupling = coef * slope * branch
    if lay[L_VD] >= 0:
        lam += _lag_bound(lay, p, p[lay[L_VD] + 2])
        damp += abs(p[lay[L_VD] + 1]) * u
    if lay[L_ST] >= 0 or lay[L_SF] >= 0:
        damp += _fluid_slope(lay, cst, p, vmax)
    stiff *= m_k
    if lay[L_KIND] != DEVICE:
        im = inv_mass(lay, cst, p)  # products, not divisions
        if lay[L_K3] >= 0:
            stiff += 3.0 * abs(p[lay[L_K3]]) * s[0] * s[0]
        lam += damp * im + math.sqrt(abs(stiff) * im) + math.sqrt(abs(coupling) * im)
    return lam
