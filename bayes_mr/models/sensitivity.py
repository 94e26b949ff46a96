"""Forward sensitivities of a simulation: its outputs and their derivatives ∂y/∂θ in one compiled pass.

A least-squares step needs the Jacobian of the simulated outputs with respect to the parameters. Finite
differences cost p + 1 simulations (14 for ``spencer``); integrating the sensitivities S = ∂s/∂θ beside the
states costs one, a few times a plain simulation's price, and is exact. Differentiating the discrete RK4
step, not the continuous law, on the sub-step schedule of the base simulation (replayed, as the finite
differences replay it), the stage sensitivities are

    K_i = J_s(t_i, s_i) T_i + J_θ(t_i, s_i),   T_i = S + c_i h K_{i−1},   S ← S + h/6 (K₁ + 2K₂ + 2K₃ + K₄),

with J_s = ∂ṡ/∂s and J_θ = ∂ṡ/∂θ at each stage's state: for an explicit Runge–Kutta method with fixed steps,
discretising the variational equations and differentiating the discretisation give the same numbers (Hairer,
Nørsett & Wanner, *Solving ODEs I*, §I.14), so S is the derivative of what the simulator computes, to
rounding. A device test's output is the force, ∂f_r/∂θ = (∂f_r/∂s) S + ∂f_r/∂θ|_s; a structure or forced
test's are x and ẋ (rows of S) and the absolute acceleration −f_r/m or (p − f_r)/m. The states themselves are
advanced by the same operations as :func:`bayes_mr.models.integrate.advance` (same numbers, bit for bit).

ROS2. A device test's stiff intervals of the four thesis forms may be taken by the Rosenbrock step of
:mod:`bayes_mr.models.integrate` (a negative count in the schedule). That step depends on θ and s also through
its W = I − γhJ, J a forward-difference Jacobian, whose exact derivative would need the difference quotient's
own derivative in θ and s; it is not implemented. The rule instead: a schedule is differentiated only when it
took every interval by RK4 (:func:`bayes_mr.simulation.sensitivity.replayable`, always so in structure and
forced tests and in device tests without stiff intervals), and least squares takes finite differences for an
evaluation whose schedule holds a ROS2 interval (:class:`bayes_mr.inference.lsq.refine.Residuals`).

Cost, in CPU time on one thread (the generic kernel for both; best of 7 × 10 runs on a shared two-core
machine at load 3.5-3.9). A dahl device test of 20 s at 1 kHz, 8 mm of five-sine motion, the thesis's
parameters (one RK4 sub-step per interval): a run with the sensitivities of p = 4, 5, 6 parameters (``dahl``,
``+force_offset``, ``+force_offset+asymmetry``) took 2.5, 2.4 and 2.9 simulations (7.0-9.6 ms against
2.5-3.6 ms), against p for a forward-difference Jacobian (the base is the step's own residual). Spencer (4 s
at 1 kHz, published parameters, 5.5 sub-steps per interval, 14 sensitivities): 2.9-3.1 simulations, against 13.
Per stage, about a third is the rates, a third the partials, a third the products J_s T
(ns × ns × n_θ). What brought it there: the power |z|ⁿ computed once per stage and shared by the rates and the
partials, the coefficients' columns written out instead of a loop with a branch per coefficient, and the
rates and partials inlined (:data:`deriv_pow`). The run is one thread where the finite differences' batch
runs on all cores, so on an idle two-core machine a single refinement's Jacobian gains less than its CPU time
says; fits side by side (a search's starts, diagnose's candidates) and a busy machine gain all of it.

Covered (:func:`bayes_mr.simulation.sensitivity.covered`): every form (:func:`spencer_partials`,
:func:`thesis_partials`) in a device, structure or forced test, with any of the effects whose partials they
have: ``force_offset``, ``stiffness_drift``, ``asymmetry``, ``voltage_dependence`` (thesis forms),
``command_saturation``, ``field_decay``, ``low_velocity_rolloff`` (thesis forms), ``cubic_stiffness``,
``shear_thinning``, ``stribeck_friction``; ``inertia`` and ``sensor_delay`` act on the output and are applied
by :mod:`bayes_mr.simulation.sensitivity`. The others keep finite differences: the effects with discrete
updates between sub-steps (``field_dynamics``, ``small_amplitude_regime``), the other command laws
(``command_polynomial``, ``exponential_saturation``) and the library terms. A structure or forced test's
damper-force output has no derivatives here.
Where the law has a kink (``|ẋ − ẏ|``, ``sgn z``, ``sgn w``) the derivative is that of the side the state is
on, which is what a finite difference of a step that does not cross it sees.
"""

from __future__ import annotations

import math

import numpy as np

from bayes_mr._compile.jit import driver, hot
from bayes_mr.models import kernel
from bayes_mr.models.drivers import _write_out
from bayes_mr.models.integrate import BRANCH_CODE
from bayes_mr.models.kernel import (
    BW, DAHL, DEVICE, FORCED, K_IMASS, K_SMOOTH, L_ASYM, L_CSAT, L_DRIFT, L_F0, L_FDEC, L_FORM, L_K3, L_KIND, L_LVR,
    L_MASS, L_NS, L_PFORM, L_PFRAME, L_SF, L_SFORM, L_ST, L_SU, L_VD, LUGRE, NBW, SPENCER, branch_state, power_slot,
    saturation,
)

#: :func:`bayes_mr.models.kernel.deriv_pow` inlined into this module's loops at numba-IR level, as the simulator's
#: inlined and specialised kernels inline it (:data:`bayes_mr._compile.specialise.INLINE`): with the partials
#: inlined too, the run's CPU time went from 4.6 to 3.4 simulations of the generic kernel; ~30 s more compile,
#: once per machine (numba's disk cache).
deriv_pow = hot(inline="always")(kernel.deriv_pow.py_func)


_sgn = kernel._sgn


@hot(inline="always")
def _column(jp, fp, i, j, d, g_r, c1):
    """Column j of a parameter that enters through ẏ only, given d = ∂ẏ/∂θ_j: ẏ's, ż's through r = ẋ − ẏ,
    and f_r's through c1 ẏ (called once per parameter with its d written out, not from a loop with a branch
    per parameter)."""
    jp[i, j] = d
    jp[i + 1, j] = -g_r * d
    fp[j] = c1 * d


@hot(inline="always")
def _saturation(lay, p, u):
    """(u_e, ∂u_e/∂u, ∂u_e/∂u_s): the command the coefficients see (u_s tanh(u/u_s) with command_saturation,
    else u; :func:`bayes_mr.models.kernel._saturate`) and its derivatives."""
    if lay[L_CSAT] < 0:
        return u, 1.0, 0.0
    us = p[lay[L_CSAT]]
    q = u / us
    th = math.tanh(q)
    return us * th, 1.0 - th * th, th - q * (1.0 - th * th)


@hot(inline="always")
def _fluid_partials(lay, cst, p, xd, fp):
    """∂f_r/∂θ of the velocity-only forces (kernel._fluid_friction): shear_thinning's c_p, m_hb, v_p and
    stribeck_friction's F_st, v_s."""
    if lay[L_ST] >= 0:
        j = lay[L_ST]
        cp, mh, vp = p[j], p[j + 1], p[j + 2]
        q = abs(xd) / vp
        pw = math.pow(1.0 + q, mh)
        sg = _sgn(xd)
        fp[j] = vp * sg * (pw - 1.0) / mh
        fp[j + 1] = cp * vp * sg * (pw * math.log(1.0 + q) / mh - (pw - 1.0) / (mh * mh))
        fp[j + 2] = cp * sg * ((pw - 1.0) / mh - pw / (1.0 + q) * q)
    if lay[L_SF] >= 0:
        j = lay[L_SF]
        r = xd / p[j + 1]
        rr = r * r
        if rr < 700.0:
            e = math.exp(-rr)
            th = math.tanh(r / cst[K_SMOOTH])
            fp[j] = e * th
            dfdr = p[j] * e * (-2.0 * r * th + (1.0 - th * th) / cst[K_SMOOTH])
            fp[j + 1] = -dfdr * r / p[j + 1]


@hot(inline="always")
def _fluid_slope(lay, cst, p, xd):
    """∂/∂ẋ of the velocity-only forces (kernel._fluid_friction) [N·s/m]: a structure or forced test's ẋ is a
    state."""
    g = 0.0
    if lay[L_ST] >= 0:
        j = lay[L_ST]
        g += p[j] * math.pow(1.0 + abs(xd) / p[j + 2], p[j + 1] - 1.0)
    if lay[L_SF] >= 0:
        j = lay[L_SF]
        r = xd / p[j + 1]
        rr = r * r
        if rr < 700.0:
            th = math.tanh(r / cst[K_SMOOTH])
            g += p[j] * math.exp(-rr) * (-2.0 * r * th + (1.0 - th * th) / cst[K_SMOOTH]) / p[j + 1]
    return g


@hot(inline="always")
def _effect_partials(lay, cst, p, t, x, xd, v, us, z, sz, eta, alpha0, a_z, m_s, force, bracket, inv_d, g_r,
                     c1, c1b, yd, jp, fp, i):
    """The effects' columns (:data:`bayes_mr.simulation.sensitivity.COVERED_EFFECTS` of the kernel's):
    stiffness_drift, asymmetry, command_saturation, field_decay, force_offset, cubic_stiffness and the fluid
    forces. ``force`` is k1 x − F_pre (what the drift scales besides α), ``bracket`` ∂ẏ/∂u_e."""
    if lay[L_DRIFT] >= 0:
        j = lay[L_DRIFT]
        _column(jp, fp, i, j, alpha0 * t * z * a_z * inv_d, g_r, c1)
        fp[j] += t * force
    if lay[L_ASYM] >= 0:
        _column(jp, fp, i, lay[L_ASYM], alpha0 * m_s * z * sz * inv_d, g_r, c1)
    if lay[L_CSAT] >= 0:
        j = lay[L_CSAT]
        _, _, due = _saturation(lay, p, us)
        _column(jp, fp, i, j, bracket * due, g_r, c1)
        fp[j] += c1b * due * yd
    if lay[L_FDEC] >= 0:
        jp[i + 2, lay[L_FDEC]] = eta * (v - us) if abs(v) < abs(us) else 0.0
    if lay[L_F0] >= 0:
        fp[lay[L_F0]] = 1.0
    if lay[L_K3] >= 0:
        fp[lay[L_K3]] = x * x * x
    _fluid_partials(lay, cst, p, xd, fp)


@hot(inline="always")
def spencer_partials(lay, cst, p, t, a, s, js, jp, fs, fp, zn):
    """Partial derivatives of spencer's rates and force at time ``t``, inputs ``a`` and state ``s``: in a device
    test x and ẋ are inputs; in a structure or forced test states 0 and 1, and the frame's c ẋ + m_k k x adds
    to the force (the rows of x and ẋ are :func:`partials`').

    Writes J_s = ∂ṡ/∂s into ``js`` (ns, ns), J_θ = ∂ṡ/∂θ into ``jp`` (ns, n_θ), ∂f_r/∂s into ``fs`` (ns)
    and ∂f_r/∂θ into ``fp`` (n_θ); only the entries that can be nonzero (the caller zeroes the arrays once).
    ``zn`` is |z|ⁿ, computed once per stage by the caller and shared with
    :func:`~bayes_mr.models.kernel.deriv_pow` (the power is most of a stage's cost).
    The law (:func:`bayes_mr.models.kernel.deriv`): ẏ = (α a_z z + c0 ẋ + k0 (x − y))/(c0 + c1), r = ẋ − ẏ,
    ż = −γ|r| sgn(z)|z|ⁿ − β r |z|ⁿ + A r, u̇ = ρ η (v − u), f_r = c1 ẏ + m_k (k1 x − F_pre) + f0 + k3 x³ +
    the fluid forces, with α = m_s (α_a + α_b u_e), c0, c1 linear in u_e (the saturated command), m_s = m_k
    = 1 + drift·t, a_z = 1 + asym·sgn z, ρ = r_d while the field falls (field_decay), else 1.
    d(sgn(z)|z|ⁿ)/dz = n|z|ⁿ⁻¹, finite at z = 0 for n ≥ 1 (the form's range).
    """
    o = lay[L_PFORM]
    i = lay[L_SFORM]
    if lay[L_KIND] == DEVICE:
        x, xd = a[0], a[1]
    else:
        x, xd = s[0], s[1]
    v = a[2]
    y, z, us = s[i], s[i + 1], s[i + 2]
    ab, c0b, k0, c1b = p[o + 1], p[o + 3], p[o + 4], p[o + 6]
    gam, bet, A, n, eta = p[o + 9], p[o + 10], p[o + 11], p[o + 12], p[o + 13]
    m_s = 1.0 + p[lay[L_DRIFT]] * t if lay[L_DRIFT] >= 0 else 1.0
    sz = _sgn(z)
    a_z = 1.0 + p[lay[L_ASYM]] * sz if lay[L_ASYM] >= 0 else 1.0
    ue, due, _ = _saturation(lay, p, us)
    alpha0 = p[o] + ab * ue
    alpha = alpha0 * m_s
    c0 = p[o + 2] + c0b * ue
    c1 = p[o + 5] + c1b * ue
    inv_d = 1.0 / (c0 + c1)
    yd = (alpha * z * a_z + c0 * xd + k0 * (x - y)) * inv_d
    r = xd - yd
    az = abs(z)
    if az > 0.0:
        zn1 = zn / az  # |z|ⁿ⁻¹ without a second pow
    else:
        zn1 = 1.0 if n == 1.0 else 0.0
    g_r = -gam * _sgn(r) * sz * zn - bet * zn + A  # ∂ż/∂r
    g_z = -n * zn1 * (gam * abs(r) + bet * r * sz)  # ∂ż/∂z at fixed r
    bracket = (ab * m_s * z * a_z + c0b * xd - yd * (c0b + c1b)) * inv_d  # ∂ẏ/∂u_e
    d_y = -k0 * inv_d  # ∂ẏ/∂y, ∂ẏ/∂z, ∂ẏ/∂u
    d_z = alpha * a_z * inv_d
    d_u = bracket * due
    rho = p[lay[L_FDEC]] if lay[L_FDEC] >= 0 and abs(v) < abs(us) else 1.0
    js[i, i], js[i, i + 1], js[i, i + 2] = d_y, d_z, d_u
    js[i + 1, i], js[i + 1, i + 1], js[i + 1, i + 2] = -g_r * d_y, g_z - g_r * d_z, -g_r * d_u
    js[i + 2, i + 2] = -rho * eta
    fs[i], fs[i + 1], fs[i + 2] = c1 * d_y, c1 * d_z, c1 * d_u + c1b * due * yd
    w = m_s * z * a_z * inv_d
    _column(jp, fp, i, o, w, g_r, c1)
    _column(jp, fp, i, o + 1, ue * w, g_r, c1)
    _column(jp, fp, i, o + 2, r * inv_d, g_r, c1)
    _column(jp, fp, i, o + 3, ue * r * inv_d, g_r, c1)
    _column(jp, fp, i, o + 4, (x - y) * inv_d, g_r, c1)
    _column(jp, fp, i, o + 5, -yd * inv_d, g_r, c1)
    _column(jp, fp, i, o + 6, -ue * yd * inv_d, g_r, c1)
    fp[o + 5] += yd  # f_r's own c1 ẏ
    fp[o + 6] += ue * yd
    fp[o + 7] = m_s * x  # m_k = m_s: the drift scales both
    fp[o + 8] = -m_s
    jp[i + 1, o + 9] = -abs(r) * sz * zn
    jp[i + 1, o + 10] = -r * zn
    jp[i + 1, o + 11] = r
    jp[i + 1, o + 12] = -(gam * abs(r) * sz + bet * r) * zn * math.log(az) if az > 0.0 else 0.0
    jp[i + 2, o + 13] = rho * (v - us)
    _effect_partials(lay, cst, p, t, x, xd, v, us, z, sz, eta, alpha0, a_z, m_s, p[o + 7] * x - p[o + 8], bracket,
                     inv_d, g_r, c1, c1b, yd, jp, fp, i)
    if lay[L_KIND] != DEVICE:
        # x and ẋ are states 0 and 1: ẏ = (… + c0 ẋ + k0 (x − y))/(c0 + c1), and the frame's c ẋ + m_k k x
        jf = lay[L_PFRAME]
        js[i, 0], js[i, 1] = k0 * inv_d, c0 * inv_d
        js[i + 1, 0], js[i + 1, 1] = -g_r * k0 * inv_d, g_r * (1.0 - c0 * inv_d)
        fs[0] = c1 * k0 * inv_d + m_s * (p[o + 7] + p[jf + 1])
        fs[1] = c1 * c0 * inv_d + p[jf] + _fluid_slope(lay, cst, p, xd)
        if lay[L_K3] >= 0:
            fs[0] += 3.0 * p[lay[L_K3]] * x * x
        fp[jf] = xd
        fp[jf + 1] = m_s * x
        if lay[L_DRIFT] >= 0:
            fp[lay[L_DRIFT]] += t * p[jf + 1] * x


@hot(inline="always")
def _via_force(jp, fp, i, j, dfs, dms, g_w, inv_cs, eps_ms, eps_zd):
    """Column j of a parameter that enters a thesis form through its hysteretic force f_s = m_s·coef·z·a_z only,
    given dfs = ∂f_s/∂θ_j and dms = ∂m_s/∂θ_j: ż's through the series dashpot's w = ẋ − f_s/c_s
    (``inv_cs`` = 1/c_s, 0 without low_velocity_rolloff), and f_r's through f_s and LuGre's m_s ε ż
    (``eps_ms`` = m_s ε, ``eps_zd`` = ε ż; both 0 for the other forms)."""
    d = -g_w * dfs * inv_cs
    jp[i, j] = d
    fp[j] = dfs + eps_ms * d + dms * eps_zd


@hot(inline="always")
def thesis_partials(lay, cst, p, t, a, s, js, jp, fs, fp, zn):
    """Partial derivatives of a thesis form's rates and force (normalized-bouc-wen, dahl, lugre, bouc-wen), as
    :func:`spencer_partials` writes spencer's; x and ẋ are the inputs of a device test, else states 0 and 1
    (their rows are :func:`partials`').

    The law (:func:`bayes_mr.models.kernel.deriv`): f_s = m_s coef z a_z (coef = k_z, F_d, β or, for
    bouc-wen, k), w = ẋ − f_s/c_s (ẋ without low_velocity_rolloff), ż = g(w, z; q) of the form
    (:func:`bayes_mr.models.kernel._zdot`), f_r = c ẋ + m_k k x + f_s [+ m_s ε ż, lugre] + f0 + c_v u_e ẋ +
    k3 x³ + the fluid forces; m_k = 1 + drift·t, m_s = m_k (1 + a_v u_e), a_z = 1 + asym·sgn z, u_e the
    (saturated) filtered command of voltage_dependence, u̇ = ρ η (v − u) (ρ = r_d while the field falls).
    The kinks (sgn w, sgn z, |w|) are differentiated on the side the state is on; d(sgn(z)|z|ⁿ)/dz = n|z|ⁿ⁻¹,
    finite at z = 0 for n ≥ 1 (the forms' range); ``zn`` = |z|ⁿ (unused by dahl and lugre).
    """
    form = lay[L_FORM]
    o = lay[L_PFORM]
    i = lay[L_SFORM]
    if lay[L_KIND] == DEVICE:
        x, xd = a[0], a[1]
    else:
        x, xd = s[0], s[1]
    v = a[2]
    z = s[i]
    m_k = 1.0 + p[lay[L_DRIFT]] * t if lay[L_DRIFT] >= 0 else 1.0
    ue, due, dus = 0.0, 0.0, 0.0
    gain = 0.0
    vdf = 1.0
    if lay[L_VD] >= 0:
        gain = p[lay[L_VD]]
        ue, due, dus = _saturation(lay, p, s[lay[L_SU]])
        vdf = 1.0 + gain * ue
    m_s = m_k * vdf
    sz = _sgn(z)
    a_z = 1.0 + p[lay[L_ASYM]] * sz if lay[L_ASYM] >= 0 else 1.0
    jc = o + 1 if form == BW else o + 2  # coef's index
    coef = p[jc]
    f_s = m_s * coef * z * a_z
    inv_cs = 1.0 / p[lay[L_LVR]] if lay[L_LVR] >= 0 else 0.0
    w = xd - f_s * inv_cs
    aw = abs(w)
    sw = _sgn(w)
    az = abs(z)
    if az > 0.0:
        zn1 = zn / az  # |z|ⁿ⁻¹ without a second pow
        lz = math.log(az)
    else:
        zn1 = 1.0 if (form == NBW or form == BW) and p[o + 4] == 1.0 else 0.0  # n at o + 4 in both
        lz = 0.0
    # ż = g(w, z; q): g_w = ∂g/∂w, g_z = ∂g/∂z at fixed w, and the columns of q written here
    if form == NBW:
        rho, n, sg = p[o + 3], p[o + 4], p[o + 5]
        shape = w - sg * aw * sz * zn + (sg - 1.0) * w * zn
        zd = rho * shape
        g_w = rho * (1.0 - sg * sw * sz * zn + (sg - 1.0) * zn)
        g_z = rho * n * zn1 * (-sg * aw + (sg - 1.0) * w * sz)
        jp[i, o + 3] = shape
        jp[i, o + 4] = rho * (-sg * aw * sz + (sg - 1.0) * w) * zn * lz
        jp[i, o + 5] = rho * (w - aw * sz) * zn
    elif form == DAHL:
        sig = p[o + 3]
        q = 1.0 - z * sw
        zd = sig * w * q
        g_w = sig * q
        g_z = -sig * aw
        jp[i, o + 3] = w * q
    elif form == LUGRE:
        alp = p[o + 4]
        zd = w - alp * aw * z
        g_w = 1.0 - alp * sw * z
        g_z = -alp * aw
        jp[i, o + 4] = -aw * z
    else:
        b1, gm, n = p[o + 2], p[o + 3], p[o + 4]
        zd = w - b1 * aw * sz * zn - gm * w * zn
        g_w = 1.0 - b1 * sw * sz * zn - gm * zn
        g_z = -n * zn1 * (b1 * aw + gm * w * sz)
        jp[i, o + 2] = -aw * sz * zn
        jp[i, o + 3] = -w * zn
        jp[i, o + 4] = -(b1 * aw * sz + gm * w) * zn * lz
    eps_ms = 0.0
    eps_zd = 0.0
    if form == LUGRE:
        eps = p[o + 3]
        eps_ms = m_s * eps
        eps_zd = eps * zd
        fp[o + 3] = m_s * zd
        fp[o + 4] = eps_ms * jp[i, o + 4]
    # the state z: through g directly and through w
    dzz = g_z - g_w * m_s * coef * a_z * inv_cs
    js[i, i] = dzz
    fs[i] = m_s * coef * a_z + eps_ms * dzz
    # c, k and the hysteretic force's coefficient
    fp[o] = xd
    _via_force(jp, fp, i, jc, m_s * z * a_z, 0.0, g_w, inv_cs, eps_ms, eps_zd)
    if form == BW:
        fp[o + 1] += m_k * x  # bouc-wen's k is also the elastic stiffness
    else:
        fp[o + 1] = m_k * x
    fz = coef * z * a_z  # ∂f_s/∂m_s
    if lay[L_DRIFT] >= 0:
        j = lay[L_DRIFT]
        _via_force(jp, fp, i, j, t * vdf * fz, t * vdf, g_w, inv_cs, eps_ms, eps_zd)
        fp[j] += t * p[o + 1] * x
    if lay[L_ASYM] >= 0:
        _via_force(jp, fp, i, lay[L_ASYM], m_s * coef * z * sz, 0.0, g_w, inv_cs, eps_ms, eps_zd)
    if lay[L_VD] >= 0:
        j = lay[L_VD]
        iu = lay[L_SU]
        us = s[iu]
        eta = p[j + 2]
        rho_d = p[lay[L_FDEC]] if lay[L_FDEC] >= 0 and abs(v) < abs(us) else 1.0
        _via_force(jp, fp, i, j, m_k * ue * fz, m_k * ue, g_w, inv_cs, eps_ms, eps_zd)
        fp[j + 1] = ue * xd
        jp[iu, j + 2] = rho_d * (v - us)
        js[iu, iu] = -rho_d * eta
        # the state u, through u_e in m_s and in c_v u_e ẋ
        dfs = m_k * gain * due * fz
        d = -g_w * dfs * inv_cs
        js[i, iu] = d
        fs[iu] = dfs + eps_ms * d + m_k * gain * due * eps_zd + p[j + 1] * due * xd
        if lay[L_CSAT] >= 0:
            jq = lay[L_CSAT]
            _via_force(jp, fp, i, jq, m_k * gain * dus * fz, m_k * gain * dus, g_w, inv_cs, eps_ms, eps_zd)
            fp[jq] += p[j + 1] * dus * xd
        if lay[L_FDEC] >= 0:
            jp[iu, lay[L_FDEC]] = eta * (v - us) if abs(v) < abs(us) else 0.0
    if lay[L_LVR] >= 0:
        j = lay[L_LVR]
        d = g_w * f_s * inv_cs * inv_cs  # ∂w/∂c_s = f_s/c_s²
        jp[i, j] = d
        fp[j] = eps_ms * d
    if lay[L_F0] >= 0:
        fp[lay[L_F0]] = 1.0
    if lay[L_K3] >= 0:
        fp[lay[L_K3]] = x * x * x
    _fluid_partials(lay, cst, p, xd, fp)
    if lay[L_KIND] != DEVICE:
        # x and ẋ are states 0 and 1: ż sees ẋ through w, f_r sees both
        js[i, 1] = g_w
        fs[0] = m_k * p[o + 1]
        fs[1] = p[o] + eps_ms * g_w + _fluid_slope(lay, cst, p, xd)
        if lay[L_VD] >= 0:
            fs[1] += p[lay[L_VD] + 1] * ue
        if lay[L_K3] >= 0:
            fs[0] += 3.0 * p[lay[L_K3]] * x * x


@hot(inline="always")
def partials(lay, cst, p, t, a, s, ds, js, jp, fs, fp, zn):
    """:func:`spencer_partials` or :func:`thesis_partials`, by the layout's form, and in a structure or forced
    test the rows of x and ẋ: ẋ' = ẋ, ẍ = −ẍ_g − f_r/m (structure) or (p − f_r)/m (forced, m a parameter).
    ``ds`` holds the rates at ``s`` (:func:`~bayes_mr.models.kernel.deriv_pow`'s), the forced test's ẍ there."""
    if lay[L_FORM] == SPENCER:
        spencer_partials(lay, cst, p, t, a, s, js, jp, fs, fp, zn)
    else:
        thesis_partials(lay, cst, p, t, a, s, js, jp, fs, fp, zn)
    if lay[L_KIND] != DEVICE:
        ns = lay[L_NS]
        im = 1.0 / p[lay[L_MASS]] if lay[L_KIND] == FORCED else cst[K_IMASS]
        js[0, 1] = 1.0
        for q in range(ns):
            js[1, q] = -fs[q] * im
        for j in range(p.size):
            jp[1, j] = -fp[j] * im
        if lay[L_KIND] == FORCED:
            jp[1, lay[L_MASS]] = -ds[1] * im  # ∂/∂m of (p − f_r)/m


@hot(inline="always")
def _power(lay, p, s):
    """|z|ⁿ of the form's power (:func:`~bayes_mr.models.kernel.power_slot`) at state ``s``; −1 for a form
    without one (dahl, lugre), which :func:`~bayes_mr.models.kernel.deriv_pow` then ignores."""
    iz, ip = power_slot(lay)
    if iz < 0:
        return -1.0
    return math.pow(abs(s[iz]), p[ip])


@hot(inline="always")
def _stage(js, jp, T, K, ns, n_th):
    """K = J_s T + J_θ (ns, n_θ)."""
    for q in range(ns):
        for j in range(n_th):
            acc = jp[q, j]
            for r in range(ns):
                acc += js[q, r] * T[r, j]
            K[q, j] = acc


@hot
def _interval(lay, cst, p, t, h, a0, a1, n_sub, held, s, S, k, K, T, tmp, am, js, jp, fs, fp):
    """RK4 over one sample interval in ``n_sub`` sub-steps, states ``s`` and sensitivities ``S`` in place.

    ``k[0]``, ``K[0]`` hold the rates and their sensitivities at (t, s) on entry. The states follow the
    operations of :func:`bayes_mr.models.integrate.advance` one for one (same nodes, same inputs, same sums);
    ``held``: its ``BRANCH`` mode, the hysteretic state's rate held at 0 and the state set to ±z_s(θ) at the end,
    so its sensitivity there is that of z_s (:func:`_saturation_partials`), no longer of the state it had.
    """
    ns = lay[L_NS]
    n_th = p.size
    iz = branch_state(lay) if held else -1
    if iz >= 0:
        _hold(k[0], K[0], iz, n_th)
    inv_n = 1.0 / n_sub
    hs = h * inv_n
    hs6 = hs / 6.0
    for j in range(n_sub):
        tj = t + j * hs
        for st in range(4):
            if st == 0 and j == 0:
                continue
            c = 0.0 if st == 0 else (1.0 if st == 3 else 0.5)
            f = (j + c) * inv_n
            for q in range(3):
                am[q] = a0[q] + f * (a1[q] - a0[q])
            for q in range(ns):
                if st == 0:
                    tmp[q] = s[q]
                else:
                    tmp[q] = s[q] + c * hs * k[st - 1, q]
                for jj in range(n_th):
                    T[q, jj] = S[q, jj] if st == 0 else S[q, jj] + c * hs * K[st - 1, q, jj]
            zn = _power(lay, p, tmp)
            deriv_pow(lay, cst, p, tj + c * hs, am, tmp, k[st], zn)
            partials(lay, cst, p, tj + c * hs, am, tmp, k[st], js, jp, fs, fp, zn)
            _stage(js, jp, T, K[st], ns, n_th)
            if held:
                _hold(k[st], K[st], iz, n_th)
        for q in range(ns):
            s[q] += hs6 * (k[0, q] + 2.0 * k[1, q] + 2.0 * k[2, q] + k[3, q])
            for jj in range(n_th):
                S[q, jj] += hs6 * (K[0, q, jj] + 2.0 * K[1, q, jj] + 2.0 * K[2, q, jj] + K[3, q, jj])
    if held:
        s[iz] = math.copysign(saturation(lay, p), s[iz])
        _saturation_partials(lay, p, s[iz], S, iz, n_th)


@hot(inline="always")
def _saturation_partials(lay, p, sz, S, iz, n_th):
    """Row ``iz`` of S after a ``BRANCH`` interval: the state is ±z_s(θ) (``sz``, :func:`~bayes_mr.models.kernel
    .saturation`), so its derivatives are z_s's and by no state: spencer's (A/(γ+β))^{1/n} by γ, β, A, n; Bouc–Wen's
    (β₁+γ)^{−1/n} by β₁, γ, n; LuGre's 1/α by α; Dahl's and the normalized Bouc–Wen's 1 by nothing."""
    for jj in range(n_th):
        S[iz, jj] = 0.0
    form = lay[L_FORM]
    o = lay[L_PFORM]
    if form == SPENCER:
        gb = p[o + 9] + p[o + 10]
        n = p[o + 12]
        S[iz, o + 9] = -sz / (n * gb)
        S[iz, o + 10] = -sz / (n * gb)
        S[iz, o + 11] = sz / (n * p[o + 11])
        S[iz, o + 12] = -sz * math.log(p[o + 11] / gb) / (n * n)
    elif form == BW:
        bg = p[o + 2] + p[o + 3]
        n = p[o + 4]
        S[iz, o + 2] = -sz / (n * bg)
        S[iz, o + 3] = -sz / (n * bg)
        S[iz, o + 4] = sz * math.log(bg) / (n * n)
    elif form == LUGRE:
        S[iz, o + 4] = -sz / p[o + 4]


@hot(inline="always")
def _hold(k, K, iz, n_th):
    """The hysteretic state's rate and its sensitivities held at 0 (a ``BRANCH`` interval)."""
    k[iz] = 0.0
    for jj in range(n_th):
        K[iz, jj] = 0.0


@hot(inline="always")
def _write(lay, cst, p, a, s, out, dout, o, f_r, f_d, fs, fp, S, ns, n_th):
    """Sample ``o``'s outputs (as :func:`~bayes_mr.models.drivers.run_one` writes them) and their derivatives:
    a device test's ∂f_r/∂θ = (∂f_r/∂s) S + ∂f_r/∂θ|_s; a structure or forced test's ∂x/∂θ, ∂ẋ/∂θ (rows of
    S) and the absolute acceleration's, −(∂f_r/∂θ)/m (a forced test's ∂/∂m also −ẍ/m)."""
    _write_out(lay, cst, p, a, s, f_r, f_d, out[o])
    if lay[L_KIND] == DEVICE:
        for j in range(n_th):
            acc = fp[j]
            for q in range(ns):
                acc += fs[q] * S[q, j]
            dout[o, 0, j] = acc
        return
    im = 1.0 / p[lay[L_MASS]] if lay[L_KIND] == FORCED else cst[K_IMASS]
    for j in range(n_th):
        acc = fp[j]
        for q in range(ns):
            acc += fs[q] * S[q, j]
        dout[o, 0, j] = S[0, j]
        dout[o, 1, j] = S[1, j]
        dout[o, 2, j] = -acc * im
    if lay[L_KIND] == FORCED:
        dout[o, 2, lay[L_MASS]] -= out[o, 2] * im


@driver(nogil=True)  # nogil: fits side by side on threads (executor.local_threads)
def run_sensitivities(lay, cst, p, h, inputs, out, dout, schedule, every=1, hold=False):
    """Simulate one parameter set from rest with the sensitivities of its force (module docstring).

    Parameters
    ----------
    lay, cst, p : ndarray
        The model's layout, constants and full parameter vector [SI] (as for
        :func:`~bayes_mr.models.drivers.run_one`).
    h : float
        Simulation step [s] (the sample interval over the input's upsampling).
    inputs : ndarray, shape (N, 3)
        Input rows as for :func:`~bayes_mr.models.drivers.run_one`.
    out : ndarray, shape ((N-1)//every + 1, n_out)
        The outputs of :func:`~bayes_mr.models.drivers.run_one` at every ``every``-th row: a device test's
        force f_r and damper force f_d [N]; a structure or forced test's x [m], ẋ [m/s], absolute
        acceleration [m/s²] and damper force [N].
    dout : ndarray, shape ((N-1)//every + 1, C, n_θ)
        Derivatives at the same rows [output unit per parameter unit]: C = 1, ∂f_r/∂θ (device); C = 3, the
        derivatives of x, ẋ and the acceleration (structure, forced; not of the damper force).
    schedule : int64 ndarray, shape (N-1,)
        RK4 sub-steps of each interval, replayed (a base simulation's: no ROS2; plus ``BRANCH_CODE`` where z was held
        on its branch).
    every, hold : as for :func:`~bayes_mr.models.drivers.run_one`.

    Returns
    -------
    failed_at : int
        Input row where the state became non-finite, or -1.
    """
    ns = lay[L_NS]
    n_th = p.size
    N = inputs.shape[0]
    s, tmp, am, end = np.zeros(ns), np.zeros(ns), np.zeros(3), np.zeros(3)
    k = np.zeros((4, ns))
    S, T, K = np.zeros((ns, n_th)), np.zeros((ns, n_th)), np.zeros((4, ns, n_th))
    js, jp, fs, fp = np.zeros((ns, ns)), np.zeros((ns, n_th)), np.zeros(ns), np.zeros(n_th)
    for row in range(N):
        t = row * h
        zn = _power(lay, p, s)
        f_r, f_d = deriv_pow(lay, cst, p, t, inputs[row], s, k[0], zn)
        partials(lay, cst, p, t, inputs[row], s, k[0], js, jp, fs, fp, zn)
        if row % every == 0:
            _write(lay, cst, p, inputs[row], s, out, dout, row // every, f_r, f_d, fs, fp, S, ns, n_th)
        if not math.isfinite(f_r):
            out[(row + every - 1) // every:] = np.nan
            dout[(row + every - 1) // every:] = np.nan
            return row
        if row == N - 1:
            break
        _stage(js, jp, S, K[0], ns, n_th)
        a1 = inputs[row + 1]
        if hold:  # the command held from row to row + 1 (drivers._integrate)
            end[0], end[1], end[2] = a1[0], a1[1], inputs[row, 2]
            a1 = end
        n_sub = schedule[row]
        held = n_sub >= BRANCH_CODE
        if held:
            n_sub -= BRANCH_CODE
        _interval(lay, cst, p, t, h, inputs[row], a1, n_sub, held, s, S, k, K, T, tmp, am, js, jp, fs, fp)
    return -1
