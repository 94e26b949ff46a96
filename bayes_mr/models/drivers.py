"""Driver loops of the compiled simulator: one parameter set, or a batch in parallel.

They allocate their buffers once and call the per-sub-step functions of
:mod:`bayes_mr.models.kernel` (:func:`~bayes_mr.models.kernel.deriv`,
:func:`~bayes_mr.models.kernel.rate`, :func:`~bayes_mr.models.integrate.advance`)
over every sample of a record; :func:`bayes_mr.simulation.simulate.simulate` is their
Python face.
"""

from __future__ import annotations

import math

import numpy as np
from numba import prange

from bayes_mr._compile.jit import driver, hot
from bayes_mr.models.integrate import BRANCH, BRANCH_CODE, DECIDE, RK4, ROS2, advance, substeps, work_shape
from bayes_mr.models.branch import on_branch
from bayes_mr.models.kernel import DEVICE, L_KIND, L_NS, acceleration, deriv, rate


@hot(inline="always")
def _vmax(lay, cst, s, k1, a0, a1, h):
    if lay[L_KIND] == DEVICE:
        return max(abs(a0[1]), abs(a1[1]))
    return abs(s[1]) + abs(k1[1]) * h


@hot(inline="always")
def _velocity(lay, a, s):
    """ẋ [m/s] at inputs ``a`` and state ``s``: the imposed velocity of a device test, else the state's."""
    if lay[L_KIND] == DEVICE:
        return a[1]
    return s[1]


@hot(inline="always")
def _write_out(lay, cst, p, a, s, f_r, f_d, out):
    if lay[L_KIND] != DEVICE:
        out[0] = s[0]
        out[1] = s[1]
        out[2] = acceleration(lay, cst, p, a, f_r)
        out[3] = f_d
    else:
        out[0] = f_r
        out[1] = f_d


@hot
def _integrate(lay, cst, p, h, inputs, out, schedule, use_schedule, s, k1, work, every, hold, end, s0, k0):
    """Every interval of a record (:func:`run_one`); ``s0``, ``k0`` keep an interval's start for a retry.

    Where the hysteretic state starts an interval on a loading branch at saturation
    (:func:`~bayes_mr.models.branch.on_branch`), the interval is taken with that state held there and the
    sub-steps the other states' rates need, and kept if the state ends it on the branch too; else (a reversal
    inside the interval) it is taken again from its start as any other. The schedule records it
    (:data:`~bayes_mr.models.integrate.BRANCH_CODE` plus its sub-steps), so a replay takes the same steps.
    """
    ns = lay[L_NS]
    N = inputs.shape[0]
    for q in range(ns):
        s[q] = 0.0
    ready = False  # the rates at the next row were computed by a branch interval's test
    f_next = 0.0
    d_next = 0.0
    for k in range(N):
        t = k * h
        if ready:
            f_r, f_d = f_next, d_next
            ready = False
        else:
            f_r, f_d = deriv(lay, cst, p, t, inputs[k], s, k1)
        if k % every == 0:
            _write_out(lay, cst, p, inputs[k], s, f_r, f_d, out[k // every])
        if not math.isfinite(f_r):
            for kk in range((k + every - 1) // every, out.shape[0]):
                for j in range(out.shape[1]):
                    out[kk, j] = np.nan
            return k
        if k == N - 1:
            break
        a1 = inputs[k + 1]
        if hold:
            # a command held between samples (a DAC's zero-order hold): the interval ends on row k's command,
            # the drive columns stay linear; the next interval starts on row k + 1's
            end[0] = a1[0]
            end[1] = a1[1]
            end[2] = inputs[k, 2]
            a1 = end
        if use_schedule:  # a negative count replays an interval taken in that many ROS2 steps
            n_sub = abs(schedule[k])
            mode = ROS2 if schedule[k] < 0 else RK4
            if n_sub >= BRANCH_CODE:
                n_sub -= BRANCH_CODE
                mode = BRANCH
        else:
            vmax = _vmax(lay, cst, s, k1, inputs[k], a1, h)
            n_sub = substeps(lay, cst, rate(lay, cst, p, t, s, vmax, 1.0), h)
            mode = DECIDE
            if n_sub > 1 and on_branch(lay, cst, p, s, k1, _velocity(lay, inputs[k], s)):
                n_br = substeps(lay, cst, rate(lay, cst, p, t, s, vmax, 0.0), h)
                if n_br < n_sub:
                    for q in range(ns):
                        s0[q] = s[q]
                        k0[q] = k1[q]
                    advance(lay, cst, p, t, h, inputs[k], a1, s, k1, n_br, BRANCH, work)
                    f_next, d_next = deriv(lay, cst, p, (k + 1) * h, inputs[k + 1], s, k1)
                    if on_branch(lay, cst, p, s, k1, _velocity(lay, inputs[k + 1], s)):
                        schedule[k] = BRANCH_CODE + n_br
                        ready = True
                        continue
                    for q in range(ns):
                        s[q] = s0[q]
                        k1[q] = k0[q]
        n_ros2 = advance(lay, cst, p, t, h, inputs[k], a1, s, k1, n_sub, mode, work)
        if not use_schedule:
            schedule[k] = -n_ros2 if n_ros2 > 0 else n_sub
    return -1


@driver
def run_one(lay, cst, p, h, inputs, out, schedule, use_schedule, every=1, hold=False):
    """Simulate one parameter set from rest over all input rows.

    Parameters
    ----------
    inputs : ndarray, shape (N, 3)
        Input rows (drive [m/s², N or m], device velocity [m/s], command [V or A]), linear between rows
        (the command held instead with ``hold``).
    out : ndarray, shape ((N-1)//every + 1, n_out)
        Structure and forced: displacement, velocity, absolute acceleration, damper force.
        Device: force (total), damper force. Written at every ``every``-th
        input row (a band-limited input upsampled by ``every``, see
        :mod:`bayes_mr.simulation.input_grid`).
    schedule : int64 ndarray, shape (N-1,)
        Sub-steps per interval: written when ``use_schedule`` is False, read
        when True (so perturbed parameter sets integrate on the same grid).
    hold : bool
        The command (column 2) held from each row to the next instead of
        linear (:class:`bayes_mr.simulation.inputs.Inputs` ``command_interp="hold"``).

    Returns
    -------
    failed_at : int
        Input row where the state became non-finite, or -1.
    """
    # the state and k1 as two more rows of advance()'s scratch, one allocation: where _integrate is inlined here
    # with the layout constant (bayes_mr._compile.specialise) every row sits at a constant offset from one pointer, so
    # the compiler can prove them apart and keep RK4's stages in registers between right-hand sides instead of
    # storing and reloading each (three allocations are three pointers it must assume may overlap). Measured,
    # specialised structure step: dahl 31.8 -> 25.7 ns, lugre 41 -> 35; device tests at the packaged damper's
    # optima (56 walkers): bouc-wen 0.312 -> 0.286 s, spencer 0.243 -> 0.232, normalized-bouc-wen 0.191 ->
    # 0.187; spencer's structure step went 135 -> 152 ns. Same arithmetic, same numbers in every tier.
    # a third row (width ≥ 3) holds an interval's end inputs when the command is held
    rows, width = work_shape(lay[L_NS])
    # and two more an interval's start state and rates, for a branch interval taken again (_integrate)
    work = np.zeros((rows + 5, width))
    s = work[rows]
    k1 = work[rows + 1]
    return _integrate(lay, cst, p, h, inputs, out, schedule, use_schedule, s, k1, work, every, hold, work[rows + 2],
                      work[rows + 3], work[rows + 4])


@driver(parallel=True, nogil=True)  # nogil: fits side by side on threads (executor.local_threads)
def run_batch(lay, cst, P, h, inputs, out, schedules, use_schedule, failed, every=1, hold=False):
    """Simulate each row of ``P`` (B, n_p) independently; see :func:`run_one`.

    ``out`` has shape (B, (N-1)//every + 1, n_out), ``schedules`` (B, N-1), ``failed`` (B,).
    When ``use_schedule`` is True every member uses ``schedules[0]``.
    """
    B = P.shape[0]
    for b in prange(B):
        if use_schedule:
            failed[b] = run_one(lay, cst, P[b], h, inputs, out[b], schedules[0], True, every, hold)
        else:
            failed[b] = run_one(lay, cst, P[b], h, inputs, out[b], schedules[b], False, every, hold)
