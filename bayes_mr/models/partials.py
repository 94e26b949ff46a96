"""Partial derivatives of each form's right-hand side and force: J_s = ∂ṡ/∂s, J_θ = ∂ṡ/∂θ, ∂f/∂s, ∂f/∂θ.

What the forward sensitivities of :mod:`bayes_mr.models.sensitivity` integrate, at one state and time:
:func:`spencer_partials` and :func:`thesis_partials` (the four thesis forms) with the effects they cover
(that module's docstring lists them), :func:`partials` choosing by form; and :func:`saturation_partials`, the
derivatives of a state held at its branch's saturation (:mod:`bayes_mr.models.branch`). Where the law has a
kink (``|ẋ − ẏ|``, ``sgn z``, ``sgn w``) the derivative is that of the side the state is on, which is what a
finite difference of a step that does not cross it sees.
"""

from __future__ import annotations

import math

from bayes_mr._compile.jit import hot
from bayes_mr.models import kernel
from bayes_mr.models.kernel import (
    BW, DAHL, DEVICE, FORCED, K_IMASS, K_SMOOTH, L_ASYM, L_CEXP, L_CPOLY, L_CSAT, L_DRIFT, L_F0, L_FDEC, L_FORM,
    L_K3, L_KIND, L_LVR, L_MASS, L_NS, L_PFORM, L_PFRAME, L_SF, L_SFORM, L_ST, L_SU, L_VD, LUGRE, NBW, SPENCER,
)

_sgn = kernel._sgn


@hot(inline="always")
def _motion(lay, a, s):
    """(x [m], ẋ [m/s]): the imposed motion of a device test, else the frame's states."""
    if lay[L_KIND] == DEVICE:
        return a[0], a[1]
    return s[0], s[1]


@hot(inline="always")
def _column(jp, fp, i, j, d, g_r, c1):
    """Column j of a parameter that enters through ẏ only, given d = ∂ẏ/∂θ_j: ẏ's, ż's through r = ẋ − ẏ,
    and f_r's through c1 ẏ (called once per parameter with its d written out, not from a loop with a branch
    per parameter)."""
    jp[i, j] = d
    jp[i + 1, j] = -g_r * d
    fp[j] = c1 * d


@hot(inline="always")
def _law(lay, p, u):
    """The current law g(u) the coefficients see (:func:`bayes_mr.models.kernel._saturate`: command_polynomial,
    then command_saturation, then exponential_saturation; u itself without them) and its derivatives:
    (g, ∂g/∂u, (∂g/∂b2, ∂g/∂b3, ∂g/∂u_s, ∂g/∂u_e)), each of the last four 0 where the model lacks its law."""
    g, dg, db2, db3, dus, dsc = u, 1.0, 0.0, 0.0, 0.0, 0.0
    if lay[L_CPOLY] >= 0:
        j = lay[L_CPOLY]
        db2, db3 = u * u, u * u * u
        dg = 1.0 + 2.0 * p[j] * u + 3.0 * p[j + 1] * u * u
        g = u * (1.0 + p[j] * u + p[j + 1] * u * u)
    if lay[L_CSAT] >= 0:
        us = p[lay[L_CSAT]]
        q = g / us
        th = math.tanh(q)
        slope = 1.0 - th * th
        dus = th - q * slope
        dg, db2, db3 = dg * slope, db2 * slope, db3 * slope
        g = us * th
    if lay[L_CEXP] >= 0:
        scale = p[lay[L_CEXP]]  # exponential_saturation's u_e
        r = abs(g) / scale
        e = math.exp(-r)
        dsc = _sgn(g) * (1.0 - e - r * e)
        dg, db2, db3, dus = dg * e, db2 * e, db3 * e, dus * e
        g = _sgn(g) * scale * (1.0 - e)
    return g, dg, (db2, db3, dus, dsc)


@hot(inline="always")
def _law_columns(lay, law, jp, fp, i, a, b, c, g_w, inv_cs, eps_ms, eps_zd, spencer):
    """The columns of the current laws' parameters (b2, b3, u_s, u_e), given ``law``: g's derivatives by them
    (:func:`_law`).

    g(u) enters spencer (``spencer`` True) through ẏ, by ``a`` = ∂ẏ/∂g, and its force besides by ``b`` =
    c1b ẏ (:func:`_column`, with ``g_w`` = g_r and ``c`` = c1); it enters a thesis form's hysteretic force by
    ``a`` = ∂f_s/∂g, the strength multiplier by ``b`` (:func:`_via_force`) and the force by ``c`` = c_v ẋ.
    """
    db2, db3, dus, dsc = law
    if lay[L_CPOLY] >= 0:
        j = lay[L_CPOLY]
        _law_column(jp, fp, i, j, db2, a, b, c, g_w, inv_cs, eps_ms, eps_zd, spencer)
        _law_column(jp, fp, i, j + 1, db3, a, b, c, g_w, inv_cs, eps_ms, eps_zd, spencer)
    if lay[L_CSAT] >= 0:
        _law_column(jp, fp, i, lay[L_CSAT], dus, a, b, c, g_w, inv_cs, eps_ms, eps_zd, spencer)
    if lay[L_CEXP] >= 0:
        _law_column(jp, fp, i, lay[L_CEXP], dsc, a, b, c, g_w, inv_cs, eps_ms, eps_zd, spencer)


@hot(inline="always")
def _law_column(jp, fp, i, j, d, a, b, c, g_w, inv_cs, eps_ms, eps_zd, spencer):
    """Column j of a current law's parameter with ∂g/∂θ_j = ``d`` (:func:`_law_columns`)."""
    if spencer:
        _column(jp, fp, i, j, a * d, g_w, c)
        fp[j] += b * d
    else:
        _via_force(jp, fp, i, j, a * d, b * d, g_w, inv_cs, eps_ms, eps_zd)
        fp[j] += c * d


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
def _effect_partials(lay, cst, p, t, x, xd, v, us, law, z, sz, eta, alpha0, a_z, m_s, force, bracket, inv_d,
                     g_r, c1, c1b, yd, jp, fp, i):
    """The effects' columns (:data:`bayes_mr.simulation.sensitivity.COVERED_EFFECTS` of the kernel's):
    stiffness_drift, asymmetry, the current laws, field_decay, force_offset, cubic_stiffness and the fluid
    forces. ``force`` is k1 x − F_pre (what the drift scales besides α), ``bracket`` ∂ẏ/∂u_e, ``law`` the current
    law's derivatives by its parameters (:func:`_law`)."""
    if lay[L_DRIFT] >= 0:
        j = lay[L_DRIFT]
        _column(jp, fp, i, j, alpha0 * t * z * a_z * inv_d, g_r, c1)
        fp[j] += t * force
    if lay[L_ASYM] >= 0:
        _column(jp, fp, i, lay[L_ASYM], alpha0 * m_s * z * sz * inv_d, g_r, c1)
    _law_columns(lay, law, jp, fp, i, bracket, c1b * yd, c1, g_r, 0.0, 0.0, 0.0, True)
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
    x, xd = _motion(lay, a, s)
    v = a[2]
    y, z, us = s[i], s[i + 1], s[i + 2]
    ab, c0b, k0, c1b = p[o + 1], p[o + 3], p[o + 4], p[o + 6]
    gam, bet, A, n, eta = p[o + 9], p[o + 10], p[o + 11], p[o + 12], p[o + 13]
    m_s = 1.0 + p[lay[L_DRIFT]] * t if lay[L_DRIFT] >= 0 else 1.0
    sz = _sgn(z)
    a_z = 1.0 + p[lay[L_ASYM]] * sz if lay[L_ASYM] >= 0 else 1.0
    ue, due, law = _law(lay, p, us)
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
    _effect_partials(lay, cst, p, t, x, xd, v, us, law, z, sz, eta, alpha0, a_z, m_s, p[o + 7] * x - p[o + 8], bracket,
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
    x, xd = _motion(lay, a, s)
    v = a[2]
    z = s[i]
    m_k = 1.0 + p[lay[L_DRIFT]] * t if lay[L_DRIFT] >= 0 else 1.0
    ue, due, dus = 0.0, 0.0, 0.0
    gain = 0.0
    vdf = 1.0
    if lay[L_VD] >= 0:
        gain = p[lay[L_VD]]
        ue, due, law = _law(lay, p, s[lay[L_SU]])
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
        _law_columns(lay, law, jp, fp, i, m_k * gain * fz, m_k * gain, p[j + 1] * xd, g_w, inv_cs, eps_ms, eps_zd,
                     False)
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
def saturation_partials(lay, p, sz, S, iz, n_th):
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
