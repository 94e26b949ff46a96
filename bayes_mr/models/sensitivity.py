"""Forward sensitivities of a simulation: the force and its derivatives ∂f_r/∂θ in one compiled pass.

A least-squares step needs the Jacobian of the simulated outputs with respect to the parameters. Finite
differences cost p + 1 simulations (14 for ``spencer``); integrating the sensitivities S = ∂s/∂θ beside the
states costs one, a few times a plain simulation's price, and is exact. Differentiating the discrete RK4
step, not the continuous law, on the sub-step schedule of the base simulation (replayed, as the finite
differences replay it), the stage sensitivities are

    K_i = J_s(t_i, s_i) T_i + J_θ(t_i, s_i),   T_i = S + c_i h K_{i−1},   S ← S + h/6 (K₁ + 2K₂ + 2K₃ + K₄),

with J_s = ∂ṡ/∂s and J_θ = ∂ṡ/∂θ at each stage's state: for an explicit Runge–Kutta method with fixed steps,
discretising the variational equations and differentiating the discretisation give the same numbers (Hairer,
Nørsett & Wanner, *Solving ODEs I*, §I.14), so S is the derivative of what the simulator computes, to
rounding, and the output's is ∂f_r/∂θ = (∂f_r/∂s) S + ∂f_r/∂θ|_s. The states themselves are advanced by the
same operations as :func:`bayes_mr.models.integrate.advance` (same numbers, bit for bit).

Cost: a run with the 14 sensitivities of spencer costs 1.7 simulations of the generic kernel on a 4 s random
device test at 1 kHz (18.7 RK4 sub-steps per interval), against 14 for a forward-difference Jacobian (13
free parameters and the base). Two things halved it from 3.0: the power |z|ⁿ computed once per stage and
shared by the rates (:func:`~bayes_mr.models.kernel.deriv_pow`) and the partials, and the coefficients'
columns written out instead of a loop with a branch per coefficient.

Covered: the ``spencer`` form in a device test, alone or with ``force_offset``
(:func:`bayes_mr.simulation.sensitivity.covered` says which models; the others keep finite differences).
Where the law has a kink (``|ẋ − ẏ|``, ``sgn z``) the derivative is that of the side the state is on, which
is what a finite difference of a step that does not cross it sees.
"""

from __future__ import annotations

import math

import numpy as np

from bayes_mr._compile.jit import driver, hot
from bayes_mr.models.kernel import L_F0, L_NS, L_PFORM, L_SFORM, deriv_pow


@hot(inline="always")
def _sgn(v):
    if v > 0.0:
        return 1.0
    if v < 0.0:
        return -1.0
    return 0.0


@hot(inline="always")
def _coefficient_column(jp, fp, i, o, j, d, g_r, c1):
    """Column of spencer's coefficient j = 0..6 (alpha_a, alpha_b, c0a, c0b, k0, c1a, c1b), given d = ∂ẏ/∂θ_j:
    ẏ's, ż's through r = ẋ − ẏ, and f_r's through c1 ẏ (called once per coefficient with its d written out,
    not from a loop over j with a branch per coefficient)."""
    jp[i, o + j] = d
    jp[i + 1, o + j] = -g_r * d
    fp[o + j] = c1 * d


@hot
def spencer_partials(lay, p, a, s, js, jp, fs, fp, zn):
    """Partial derivatives of spencer's device-test rates and force at inputs ``a`` and state ``s``.

    Writes J_s = ∂ṡ/∂s into ``js`` (ns, ns), J_θ = ∂ṡ/∂θ into ``jp`` (ns, n_θ), ∂f_r/∂s into ``fs`` (ns)
    and ∂f_r/∂θ into ``fp`` (n_θ); only the entries that can be nonzero (the caller zeroes the arrays once).
    ``zn`` is |z|ⁿ, computed once per stage by the caller and shared with
    :func:`~bayes_mr.models.kernel.deriv_pow` (the power is most of a stage's cost).
    The law (:func:`bayes_mr.models.kernel.deriv`): ẏ = (α z + c0 ẋ + k0 (x − y))/(c0 + c1), r = ẋ − ẏ,
    ż = −γ|r| sgn(z)|z|ⁿ − β r |z|ⁿ + A r, u̇ = η (v − u), f_r = c1 ẏ + k1 x − F_pre (+ f0), with α, c0,
    c1 linear in u. d(sgn(z)|z|ⁿ)/dz = n|z|ⁿ⁻¹, finite at z = 0 for n ≥ 1 (the form's range).
    """
    o = lay[L_PFORM]
    i = lay[L_SFORM]
    x, xd, v = a[0], a[1], a[2]
    y, z, us = s[i], s[i + 1], s[i + 2]
    ab, c0b, k0, c1b = p[o + 1], p[o + 3], p[o + 4], p[o + 6]
    gam, bet, A, n, eta = p[o + 9], p[o + 10], p[o + 11], p[o + 12], p[o + 13]
    alpha = p[o] + ab * us
    c0 = p[o + 2] + c0b * us
    c1 = p[o + 5] + c1b * us
    inv_d = 1.0 / (c0 + c1)
    yd = (alpha * z + c0 * xd + k0 * (x - y)) * inv_d
    r = xd - yd
    az = abs(z)
    if az > 0.0:
        zn1 = zn / az  # |z|ⁿ⁻¹ without a second pow
    else:
        zn1 = 1.0 if n == 1.0 else 0.0
    sz = _sgn(z)
    g_r = -gam * _sgn(r) * sz * zn - bet * zn + A  # ∂ż/∂r
    g_z = -n * zn1 * (gam * abs(r) + bet * r * sz)  # ∂ż/∂z at fixed r
    d_y = -k0 * inv_d  # ∂ẏ/∂y, ∂ẏ/∂z, ∂ẏ/∂u
    d_z = alpha * inv_d
    d_u = (ab * z + c0b * xd - yd * (c0b + c1b)) * inv_d
    js[i, i], js[i, i + 1], js[i, i + 2] = d_y, d_z, d_u
    js[i + 1, i], js[i + 1, i + 1], js[i + 1, i + 2] = -g_r * d_y, g_z - g_r * d_z, -g_r * d_u
    js[i + 2, i + 2] = -eta
    fs[i], fs[i + 1], fs[i + 2] = c1 * d_y, c1 * d_z, c1 * d_u + c1b * yd
    _coefficient_column(jp, fp, i, o, 0, z * inv_d, g_r, c1)
    _coefficient_column(jp, fp, i, o, 1, us * z * inv_d, g_r, c1)
    _coefficient_column(jp, fp, i, o, 2, r * inv_d, g_r, c1)
    _coefficient_column(jp, fp, i, o, 3, us * r * inv_d, g_r, c1)
    _coefficient_column(jp, fp, i, o, 4, (x - y) * inv_d, g_r, c1)
    _coefficient_column(jp, fp, i, o, 5, -yd * inv_d, g_r, c1)
    _coefficient_column(jp, fp, i, o, 6, -us * yd * inv_d, g_r, c1)
    fp[o + 5] += yd  # f_r's own c1 ẏ
    fp[o + 6] += us * yd
    fp[o + 7] = x
    fp[o + 8] = -1.0
    jp[i + 1, o + 9] = -abs(r) * sz * zn
    jp[i + 1, o + 10] = -r * zn
    jp[i + 1, o + 11] = r
    jp[i + 1, o + 12] = -(gam * abs(r) * sz + bet * r) * zn * math.log(az) if az > 0.0 else 0.0
    jp[i + 2, o + 13] = v - us
    if lay[L_F0] >= 0:
        fp[lay[L_F0]] = 1.0


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
def _interval(lay, cst, p, t, h, a0, a1, n_sub, s, S, k, K, T, tmp, am, js, jp, fs, fp):
    """RK4 over one sample interval in ``n_sub`` sub-steps, states ``s`` and sensitivities ``S`` in place.

    ``k[0]``, ``K[0]`` hold the rates and their sensitivities at (t, s) on entry. The states follow the
    operations of :func:`bayes_mr.models.integrate.advance` one for one (same nodes, same inputs, same sums).
    """
    ns = lay[L_NS]
    n_th = p.size
    iz = lay[L_SFORM] + 1
    ip = lay[L_PFORM] + 12
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
            zn = math.pow(abs(tmp[iz]), p[ip])
            deriv_pow(lay, cst, p, tj + c * hs, am, tmp, k[st], zn)
            spencer_partials(lay, p, am, tmp, js, jp, fs, fp, zn)
            _stage(js, jp, T, K[st], ns, n_th)
        for q in range(ns):
            s[q] += hs6 * (k[0, q] + 2.0 * k[1, q] + 2.0 * k[2, q] + k[3, q])
            for jj in range(n_th):
                S[q, jj] += hs6 * (K[0, q, jj] + 2.0 * K[1, q, jj] + 2.0 * K[2, q, jj] + K[3, q, jj])


@hot(inline="always")
def _write(out, dout, o, f_r, f_d, fs, fp, S, ns, n_th):
    """Sample ``o``'s forces and ∂f_r/∂θ = (∂f_r/∂s) S + ∂f_r/∂θ|_s."""
    out[o, 0] = f_r
    out[o, 1] = f_d
    for j in range(n_th):
        acc = fp[j]
        for q in range(ns):
            acc += fs[q] * S[q, j]
        dout[o, j] = acc


@driver(nogil=True)  # nogil: fits side by side on threads (executor.local_threads)
def run_sensitivities(lay, cst, p, h, inputs, out, dout, schedule, every=1, hold=False):
    """Simulate one parameter set from rest with the sensitivities of its force (module docstring).

    Parameters
    ----------
    lay, cst, p : the model's layout, constants and full parameter vector [SI] (:func:`~bayes_mr.models.drivers.run_one`).
    h : float
        Simulation step [s] (the sample interval over the input's upsampling).
    inputs : ndarray, shape (N, 3)
        Input rows as for :func:`~bayes_mr.models.drivers.run_one`.
    out : ndarray, shape ((N-1)//every + 1, 2)
        Device test's force f_r and damper force f_d [N] at every ``every``-th row.
    dout : ndarray, shape ((N-1)//every + 1, n_θ)
        ∂f_r/∂θ [N per parameter unit] at the same rows.
    schedule : int64 ndarray, shape (N-1,)
        RK4 sub-steps of each interval, replayed (a base simulation's; all positive: RK4).
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
        zn = math.pow(abs(s[lay[L_SFORM] + 1]), p[lay[L_PFORM] + 12])
        f_r, f_d = deriv_pow(lay, cst, p, t, inputs[row], s, k[0], zn)
        spencer_partials(lay, p, inputs[row], s, js, jp, fs, fp, zn)
        if row % every == 0:
            _write(out, dout, row // every, f_r, f_d, fs, fp, S, ns, n_th)
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
        _interval(lay, cst, p, t, h, inputs[row], a1, schedule[row], s, S, k, K, T, tmp, am, js, jp, fs, fp)
    return -1
