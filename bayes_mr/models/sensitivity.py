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
evaluation whose schedule holds a ROS2 interval (:class:`bayes_mr.inference.lsq.refine.Residuals`). An
interval where the hysteretic state was held on its loading branch (:mod:`bayes_mr.models.branch`) is RK4 with
that state's rate at 0 and the state set to ±z_s(θ) at its end: its sensitivity there is z_s's
(:func:`~bayes_mr.models.partials.saturation_partials`).

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
says; fits side by side (a search's starts, diagnose's candidates) and a busy machine gain all of it. A
structure test's run costs about eight generic simulations (dahl, 30 s at 1 kHz: 772 ns per sample against
~100): three states and their sensitivities, and the frame's rows in J_s.

Kernels: :func:`bayes_mr.simulation.sensitivity.output_sensitivities` chooses this kernel through
:func:`bayes_mr._compile.specialise.kernel`, as the simulator's is chosen. With the layout constant it runs 2.3×
faster (that dahl run: 772 → 332 ns per sample, best of 30 interleaved runs), but a layout's compile takes
from under a minute (that dahl layout, 51 s) to many minutes (the test suite's spencer device and dahl structure
cases, 21 min together), and its "quick" variant is no quicker, since this module inlines its per-stage
physics itself; the any-layout inlined tier gains nothing (778 ns) for the same reason. So ``auto`` runs a
specialised sensitivity kernel where one is on disk but never starts its compile (no work is counted towards
:data:`~bayes_mr._compile.specialise.AUTO_WORK`, and the kernel is not in
:data:`~bayes_mr._compile.specialise.INLINED_TIER`); ``BAYES_MR_KERNELS=specialised`` compiles it.

Covered (:func:`bayes_mr.simulation.sensitivity.covered`): every form
(:func:`~bayes_mr.models.partials.spencer_partials`, :func:`~bayes_mr.models.partials.thesis_partials`) in a
device, structure or forced test, with any of the effects whose partials they have: ``force_offset``,
``stiffness_drift``, ``asymmetry``, ``voltage_dependence`` (thesis forms), the current laws
(``command_polynomial``, ``command_saturation``, ``exponential_saturation``), ``field_decay``,
``low_velocity_rolloff`` (thesis forms), ``cubic_stiffness``, ``shear_thinning``, ``stribeck_friction``;
``inertia`` and ``sensor_delay`` act on the output and are applied by :mod:`bayes_mr.simulation.sensitivity`. The
others keep finite differences: the effects with discrete updates between sub-steps (``field_dynamics``,
``small_amplitude_regime``) and the library terms. A structure or forced test's damper-force output has no
derivatives here.
Where the law has a kink (``|ẋ − ẏ|``, ``sgn z``, ``sgn w``) the derivative is that of the side the state is
on, which is what a finite difference of a step that does not cross it sees.
"""

from __future__ import annotations

import math

import numpy as np

from bayes_mr._compile.jit import driver, hot
from bayes_mr.models import kernel
from bayes_mr.models.branch import branch_state, saturation
from bayes_mr.models.drivers import _write_out
from bayes_mr.models.integrate import BRANCH_CODE
from bayes_mr.models.kernel import DEVICE, FORCED, K_IMASS, L_KIND, L_MASS, L_NS, power_slot
from bayes_mr.models.partials import partials, saturation_partials

#: :func:`bayes_mr.models.kernel.deriv_pow` inlined into this module's loops at numba-IR level, as the simulator's
#: inlined and specialised kernels inline it (:data:`bayes_mr._compile.specialise.INLINE`): with the partials
#: inlined too, the run's CPU time went from 4.6 to 3.4 simulations of the generic kernel; ~30 s more compile,
#: once per machine (numba's disk cache).
deriv_pow = hot(inline="always")(kernel.deriv_pow.py_func)


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
    so its sensitivity there is that of z_s (:func:`~bayes_mr.models.partials.saturation_partials`), not that of the
    state it had.
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
        saturation_partials(lay, p, s[iz], S, iz, n_th)


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
