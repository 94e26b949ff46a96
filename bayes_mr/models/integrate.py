"""One sample interval of a model's states: the step control and the two integrators.

:func:`substeps` turns the local rate λ of :func:`bayes_mr.models.kernel.rate` into RK4 sub-steps
per interval (h·λ ≤ c_acc, at most n_max). :func:`advance` integrates the interval

* with **RK4** (thesis 3-9) in that many sub-steps — every interval of a structure or forced test,
  and the non-stiff ones of a device test;
* or, in a device test where RK4 would need more than :data:`ROS2_ABOVE` sub-steps, tries
  **ROS2**, the two-stage Rosenbrock W-method of Verwer, Spee, Blom & Hundsdorfer (1999, SIAM J. Sci.
  Comput. 20(4), γ = 1 + 1/√2), in m steps of h/m (m = 1 first)::

      W k₁ = f(t, s),   W k₂ = f(t + h, s + h k₁) − 2 k₁,   s ← s + (3/2) h k₁ + (1/2) h k₂,
      W = I − γ h J.

  It is second order for *any* matrix J (a W-method), so J is a forward-difference Jacobian at the
  step's start, and the inputs' time dependence (linear in the interval, interpolated at the steps'
  ends) needs no term of its own: time is a state whose column of J is zero. With J the true
  Jacobian it is L-stable. Over most stiff intervals a hysteretic state sits on its branch (z at its
  saturation while the piston moves fast: h·λ is large only because the branch attracts it fast), and
  one step follows it where RK4 needs h·λ ≤ 2.8, tens of sub-steps. Where a state is in transition (a
  velocity reversal) one step cannot follow it, and an L-stable step is not accurate there either
  (R(−3) = 0.22 against e⁻³ = 0.05), so each step is tested: the embedded first-order solution
  s + h k₁ differs from it by ½h(k₁ + k₂), and every state must have that within 1/m of
  :data:`ROS2_RTOL` of its scale (the largest |s_q| met so far in the simulation, so a state crossing
  zero is not rejected for that; 1/m: the error per unit step, so the interval's is bounded as one
  step's is). A single step that fails by a ratio r is tried again in m = ⌈r⌉ ≥ 2 steps (the estimate
  shrinks as the step squared, so each has about r/m² of it) when those cost fewer right-hand sides,
  m·(ns + 2), than RK4's 4·n_sub; else, or where that fails too, the interval is integrated with RK4.
  On the packaged damper's bouc-wen optimum at 1 kHz the retry took 79 % of the intervals by ROS2
  instead of 49 % and halved the simulation's cost (9.2 → 4.5 ms; RK4 alone 18 ms) at the same error
  against a fine RK4 reference (5.9e-4 → 6.0e-4 of the SD; ``tests/test_integrate.py`` checks the accuracy,
  ``bayes_mr.bench`` times the simulation).

Why device tests only: there every state is a driven hysteretic or lag state and the test reads them
all. In a structure test the stiff state couples into the frame (ẍ depends on z, ż on ẋ), whose
states such a test cannot read — the first-order estimate of a smooth state is ½h²ẍ, which would
reject every interval of a 10-Hz response at 1 kHz — and measured against solve_ivp the adaptive
step lost one to four orders of accuracy there, with or without the frame's states under the test
(dahl σ = 2e5: 5.8e-4 → 3.1e-3 to 4.1e-3 of the SD; with six effects 7.8e-6 → 1.5e-2 to 0.83),
while on device tests it held RK4's error on every form and effect tried (``tests/test_integrate.py``)
and cut the cost of the packaged damper's least-squares optima 2.5–5×. ``spencer`` opts out
(``Form.ros2``).

``spencer``'s own stiff intervals are cheaper another way: where its z sits at saturation on a loading branch, a
fixed point of the law at any velocity, the driver (:func:`bayes_mr.models.drivers._integrate`) holds z there
(:data:`BRANCH` mode; :func:`bayes_mr.models.branch.on_branch`) and integrates the other states at their own pace
(a quarter of the sub-steps of the bench's spencer tests at the same error against a fine reference).

Each integrator evaluates the right-hand side from one call site, and ROS2 is a function of its own
(not inlined into :func:`advance`), so a kernel that inlines :func:`~bayes_mr.models.kernel.deriv`
(:mod:`bayes_mr._compile.specialise`) inlines it once in each. The method an interval took is returned, and
the drivers store it in the schedule (minus the number of ROS2 steps), so a replayed schedule (finite
differences on one grid, :mod:`bayes_mr.simulation.simulate`) replays the method.
"""

from __future__ import annotations

import math

import numpy as np

from bayes_mr._compile.jit import hot
from bayes_mr.models.branch import branch_state, saturation
from bayes_mr.models.kernel import (
    DEVICE, K_CACC, K_NMAX, K_RTOL, K_STIFF, K_TENV, L_FD, L_KIND, L_NS, L_SA, L_SE, coil_step, deriv, deriv_pow,
)
from bayes_mr.models.power import point_powers

#: γ of ROS2 (Verwer et al. 1999): 1 + 1/√2, the root that makes the method L-stable.
GAMMA = 1.0 + 1.0 / math.sqrt(2.0)
#: Scratch rows :func:`advance` needs besides the ns × ns W: RK4's stages k₂..k₄ (ROS2's k₂, k₁ and the
#: pivots), the stage state, the inputs, the largest |s_q| met so far in the simulation (the error test's
#: scale; kept from interval to interval), and ROS2's state at the interval's start, f at a step's start and
#: the inputs at a step's two ends.
WORK_ROWS = 10


@hot(inline="always")
def work_shape(ns):
    """Shape of :func:`advance`'s scratch for a model of ``ns`` states: :data:`WORK_ROWS` rows and the ns × ns W."""
    return WORK_ROWS + ns, max(ns, 3)


@hot
def substeps(lay, cst, lam, h):
    """Number of RK4 sub-steps for a sample interval h with local rate λ."""
    hl = h * lam
    if hl <= cst[K_CACC]:
        return 1  # the common case, without the division (ceil(hl/c) ≤ 1 exactly when hl ≤ c)
    n = int(math.ceil(hl / cst[K_CACC]))
    if n < 1:
        n = 1
    nmax = int(cst[K_NMAX])
    if n > nmax:
        n = nmax
    return n


@hot(inline="always")
def _lu(work, ns):
    """LU factorisation with partial pivoting of W = work[WORK_ROWS:, :ns] in place; pivots in work[2]."""
    for c in range(ns):
        pr = c
        best = abs(work[WORK_ROWS + c, c])
        for r in range(c + 1, ns):
            v = abs(work[WORK_ROWS + r, c])
            if v > best:
                best = v
                pr = r
        work[2, c] = pr
        if pr != c:
            for q in range(ns):
                tmp = work[WORK_ROWS + c, q]
                work[WORK_ROWS + c, q] = work[WORK_ROWS + pr, q]
                work[WORK_ROWS + pr, q] = tmp
        inv = 1.0 / work[WORK_ROWS + c, c]
        for r in range(c + 1, ns):
            f = work[WORK_ROWS + r, c] * inv
            work[WORK_ROWS + r, c] = f
            for q in range(c + 1, ns):
                work[WORK_ROWS + r, q] -= f * work[WORK_ROWS + c, q]


@hot(inline="always")
def _solve(work, ns, b):
    """Solve W x = b in place with the factors of :func:`_lu`."""
    for c in range(ns):
        pr = int(work[2, c])
        if pr != c:
            tmp = b[c]
            b[c] = b[pr]
            b[pr] = tmp
        for r in range(c + 1, ns):
            b[r] -= work[WORK_ROWS + r, c] * b[c]
    for c in range(ns - 1, -1, -1):
        acc = b[c]
        for q in range(c + 1, ns):
            acc -= work[WORK_ROWS + c, q] * b[q]
        b[c] = acc / work[WORK_ROWS + c, c]


@hot(inline="always")
def _after_substep(lay, cst, p, s, a0, a1, am, j, inv_n, hs):
    """The discrete updates between sub-steps: the coil's exact lag and the amplitude envelope."""
    if lay[L_FD] >= 0:
        coil_step(lay, p, s, a0[2] + (j * inv_n) * (a1[2] - a0[2]), am[2], hs)
    if lay[L_SA] >= 0:
        # amplitude envelope: follows peaks at once, decays with time constant T_env
        ie = lay[L_SE]
        xa = abs(am[0]) if lay[L_KIND] == DEVICE else abs(s[0])
        decayed = s[ie] * math.exp(-hs / cst[K_TENV])
        s[ie] = xa if xa > decayed else decayed


#: RK4 sub-steps an interval must need before ROS2 is tried on it: at 1 or 2, RK4 (4 or 8 evaluations of the
#: right-hand side) costs about what a ROS2 trial does (ns + 1, and RK4's on top when the test rejects it and
#: no retry in several steps, :func:`_try_ros2`, is cheaper or passes).
ROS2_ABOVE = 2
#: Relative error test of a ROS2 interval (module docstring). Measured against RK4 at c_acc = 0.05 on the
#: packaged damper's device test at each form's least-squares optimum (1 kHz): the force error of RK4 at
#: c_acc = 1 (1.2e-3 to 2.8e-3 of the SD; bouc-wen 1.7e-4 → 2.6e-4) with ROS2 kept in 54-68 % of the
#: intervals; 1e-4 kept fewer for no gain, and at 1e-2 a stiff spencer device test's error grew five-fold.
ROS2_RTOL = 1e-3

#: ``mode`` of :func:`advance`: choose by the error test, RK4, or ROS2 (the last two replay a schedule), or RK4 with
#: the hysteretic state held on its loading branch (:func:`~bayes_mr.models.branch.on_branch`).
DECIDE, RK4, ROS2, BRANCH = 0, 1, 2, 3
#: A schedule's entry for an interval taken in ``BRANCH`` mode: this plus its RK4 sub-steps (above any sub-step cap).
BRANCH_CODE = 1 << 20


def steps(schedule: np.ndarray) -> np.ndarray:
    """The integrator steps of each interval of a schedule (:attr:`~bayes_mr.simulation.simulate.Simulation.schedule`):
    RK4 sub-steps, ROS2 steps (stored negative) and the sub-steps of a ``BRANCH`` interval (stored plus
    :data:`BRANCH_CODE`), all as positive counts."""
    schedule = np.asarray(schedule)
    return np.where(schedule >= BRANCH_CODE, schedule - BRANCH_CODE, np.abs(schedule))


@hot(inline="always")
def _step_ends(a0, a1, i, m, b0, b1):
    """The inputs at the ends of step i of m equal steps over an interval, linear between its ends a0 and a1
    (those exactly, so one step is ROS2 over the interval)."""
    for q in range(3):
        b0[q] = a0[q] if i == 0 else a0[q] + (i / m) * (a1[q] - a0[q])
        b1[q] = a1[q] if i == m - 1 else a0[q] + ((i + 1) / m) * (a1[q] - a0[q])


@hot(inline="always")
def _error_ratio(cst, s, kr, k2, hm, smax, m, ns):
    """Largest ratio over the states of a ROS2 step's error estimate ½hm(k₁ + k₂) to its tolerance: 1/m of
    ROS2_RTOL of the state's scale (module docstring), the m steps sharing the interval's tolerance."""
    worst = 0.0
    for q in range(ns):
        d = 1.5 * hm * kr[q] + 0.5 * hm * k2[q]
        err = abs(0.5 * hm * (kr[q] + k2[q]))
        tol = cst[K_RTOL] * max(abs(s[q]), abs(s[q] + d), smax[q]) / m
        if err > tol:
            worst = max(worst, err / tol)
    return worst


@hot
def _ros2(lay, cst, p, t, h, a0, a1, s, k1, check, work, m):
    """``m`` ROS2 steps of h/m over [t, t+h] (module docstring), the inputs linear between a0 and a1. ``k1`` =
    f(s, a0) is read, not overwritten.

    Returns the largest ratio of a step's error estimate to its tolerance (``check``; 0.0 without): at most 1,
    the steps were taken and ``s`` advanced; above 1, the step that failed ended the trial and ``s`` is back
    where it was. Not inlined into :func:`advance` (:data:`bayes_mr._compile.specialise.INLINE`): a second
    inlined copy of ``deriv`` there would double the compile of every specialised kernel, and the RK4 loop keeps
    its own shape (its four stages unrolled: a shared evaluation loop cost the dahl structure step 31 → 41 ns,
    :func:`bayes_mr.bench.kernels.simulate_ns_per_step`).
    """
    ns = lay[L_NS]
    kr = work[1]  # ROS2's k₁ (solved in place), the caller's k1 kept for RK4
    tmp = work[3]
    am = work[4]
    smax = work[5]  # the largest |s_q| met so far in this scratch's simulation: the error test's scale
    s0 = work[6]  # the state at t, restored when a step fails
    kf = work[7]  # f at the start of the step
    b0 = work[8]  # the inputs at the start and the end of the step
    b1 = work[9]
    hm = h / m
    worst = 0.0
    for q in range(ns):
        s0[q] = s[q]
        kf[q] = k1[q]
    for i in range(m):
        ti = t + i * hm
        _step_ends(a0, a1, i, m, b0, b1)
        for q in range(ns):
            if abs(s[q]) > smax[q]:
                smax[q] = abs(s[q])
        # one call site of deriv: e = −1 f at a later step's start (the first step's is k1), e = 0..ns−1 the
        # columns of J (forward differences at (ti, s)), e = ns the second stage at (ti + hm, s + hm k₁)
        dq = 1.0
        for e in range(-1 if i > 0 else 0, ns + 1):
            for q in range(ns):
                tmp[q] = s[q]
            if e < ns:
                if e >= 0:
                    dq = 1e-7 * abs(s[e]) + 1e-9
                    tmp[e] += dq
                for q in range(3):
                    am[q] = b0[q]
                tc = ti
            else:
                for q in range(ns):
                    kr[q] = kf[q]
                _lu(work, ns)
                _solve(work, ns, kr)
                for q in range(ns):
                    tmp[q] += hm * kr[q]
                for q in range(3):
                    am[q] = b1[q]
                tc = ti + hm if i < m - 1 else t + h
            deriv(lay, cst, p, tc, am, tmp, work[0])
            if e < 0:
                for q in range(ns):
                    kf[q] = work[0, q]
            elif e < ns:
                w = -GAMMA * hm / dq
                for r in range(ns):  # W = I − γ h J, a column at a time
                    work[WORK_ROWS + r, e] = w * (work[0, r] - kf[r])
                work[WORK_ROWS + e, e] += 1.0
        k2 = work[0]
        for q in range(ns):
            k2[q] -= 2.0 * kr[q]
        _solve(work, ns, k2)
        if check:
            worst = max(worst, _error_ratio(cst, s, kr, k2, hm, smax, m, ns))
            if worst > 1.0:
                for q in range(ns):
                    s[q] = s0[q]
                return worst
        for q in range(ns):
            s[q] += 1.5 * hm * kr[q] + 0.5 * hm * k2[q]
        _after_substep(lay, cst, p, s, b0, b1, am, 0, 1.0, hm)
    return worst


@hot
def _try_ros2(lay, cst, p, t, h, a0, a1, s, k1, n_sub, work):
    """ROS2 steps an interval was taken with (≥ 1, ``s`` advanced), or 0 when RK4's ``n_sub`` sub-steps must
    take it (``s`` untouched).

    One step over the interval first; where its error test fails, ratio r of error to tolerance, the interval
    is tried once more in m = ⌈r⌉ equal steps, when those cost fewer right-hand sides (m·(ns + 2)) than RK4's
    4·n_sub. Each of the m steps must pass 1/m of the interval's tolerance (error per unit step: the interval's
    error is bounded as a single step's is), and the embedded first-order estimate shrinks as the step squared,
    so a step of h/m has about r/m² of it.
    """
    r = _ros2(lay, cst, p, t, h, a0, a1, s, k1, True, work, 1)
    if r <= 1.0:
        return 1
    most = 4.0 * n_sub / (lay[L_NS] + 2.0)  # steps that cost what RK4 does
    if not r < most:  # also an infinite or NaN ratio
        return 0
    m = int(math.ceil(r))  # ≥ 2: r > 1
    if m < most and _ros2(lay, cst, p, t, h, a0, a1, s, k1, True, work, m) <= 1.0:
        return m
    return 0


@hot(inline="always")
def _stage_inputs(st, j, inv_n, a0, a1, am):
    """RK4 stage ``st`` of sub-step ``j``: its node c = 0, ½, ½, 1 (returned) and the inputs there into ``am`` (linear
    between a0 and a1 over the interval of 1/inv_n sub-steps)."""
    if st == 0:
        c = 0.0
    elif st == 3:
        c = 1.0
    else:
        c = 0.5
    f = (j + c) * inv_n
    for q in range(3):
        am[q] = a0[q] + f * (a1[q] - a0[q])
    return c


@hot
def advance(lay, cst, p, t, h, a0, a1, s, k1, n_sub, mode, work):
    """Integrate ``s`` in place over one sample interval [t, t+h] (module docstring).

    ``k1`` must hold f(s, a0) on entry (it is reused for the first sub-step).
    ``work`` is scratch of shape :func:`work_shape` (ns). Inputs are linear in
    time. ``n_sub`` is the RK4 sub-step count of :func:`substeps`; ``mode``
    :data:`DECIDE` tries ROS2 in a device test where n_sub > ``cst[K_STIFF]``
    and keeps it where its error test passes (:func:`_try_ros2`), else takes
    RK4; :data:`RK4` and :data:`ROS2` force a method (a replayed schedule;
    with ROS2, ``n_sub`` is its number of steps); :data:`BRANCH` is RK4 with
    the hysteretic state's rate held at 0 and the state set to its saturation
    at the end (an interval on a loading branch, where that is the law's own
    solution: :func:`~bayes_mr.models.branch.on_branch`). Returns the number of ROS2
    steps the interval took, 0 for RK4. RK4's four stages run in one loop
    with one call of :func:`deriv`, so a compiler that inlines it does so
    once, not four times.
    """
    # the kind first: in a kernel specialised to a structure test it is a constant and the ROS2 branch folds away
    if lay[L_KIND] == DEVICE:
        if mode == ROS2:
            _ros2(lay, cst, p, t, h, a0, a1, s, k1, False, work, n_sub)
            return n_sub
        if mode == DECIDE and n_sub > cst[K_STIFF]:
            m = _try_ros2(lay, cst, p, t, h, a0, a1, s, k1, n_sub, work)
            if m > 0:
                return m
    ns = lay[L_NS]
    tmp = work[3]
    am = work[4]
    iz = branch_state(lay) if mode == BRANCH else -1
    if iz >= 0:
        k1[iz] = 0.0
    inv_n = 1.0 / n_sub  # products below, no division per stage
    hs = h * inv_n
    hs6 = hs / 6.0
    for j in range(n_sub):
        tj = t + j * hs
        for st in range(4):
            if st == 0 and j == 0:
                continue  # k1 = f(s, a0) was handed in
            # stage st: the state s + c·hs·k_{st-1} at the time tj + c·hs
            c = _stage_inputs(st, j, inv_n, a0, a1, am)
            if st == 0:
                for q in range(ns):
                    tmp[q] = s[q]
            else:
                kp = k1 if st == 1 else work[st - 2]
                for q in range(ns):
                    tmp[q] = s[q] + c * hs * kp[q]
            kn = k1 if st == 0 else work[st - 1]
            deriv(lay, cst, p, tj + c * hs, am, tmp, kn)
            if iz >= 0:
                kn[iz] = 0.0
        k2 = work[0]
        k3 = work[1]
        k4 = work[2]
        for q in range(ns):
            s[q] += hs6 * (k1[q] + 2.0 * k2[q] + 2.0 * k3[q] + k4[q])
        _after_substep(lay, cst, p, s, a0, a1, am, j, inv_n, hs)
    if iz >= 0:
        s[iz] = math.copysign(saturation(lay, p), s[iz])
    return 0


@hot
def advance_points(lay, cst, TH, t, h, a0, a1, X, K1, n_pts, n_sub, work, stages, taken, pw):
    """:func:`advance` (mode :data:`DECIDE`) of ``n_pts`` state vectors over one interval, stage by stage across them.

    Point i has the states X[i, :ns], the parameters TH[i] and f(X[i], a0) in K1[i]; all share ``n_sub``. The
    numbers are those of n_pts calls of :func:`advance` in turn (the same operations on each point, and ROS2's
    error scale in ``work`` met in the same order), but RK4's stage k is evaluated for every point before stage
    k + 1 of any: the points' right-hand sides are independent, so the processor overlaps their evaluations —
    a |z|ⁿ of one point need not finish before the next point's starts, as it must within one point's chain of
    stages. The sigma points of the UKF (:mod:`bayes_mr.inference.ukf.kernel`) are such a set.

    The powers |z|ⁿ of a stage's points (the Bouc–Wen family's costliest operation) are computed together first
    (:func:`point_powers`, vectorised) and handed to :func:`~bayes_mr.models.kernel.deriv_pow`: they differ
    from the C library's ``pow`` of :func:`advance` by at most 1 ulp (:mod:`bayes_mr.models.power`), so the
    points' numbers are those of :func:`advance` to rounding, no longer bit for bit.

    ``stages`` is scratch (≥ n_pts, 3, ns) for RK4's k₂..k₄ of every point, ``taken`` (≥ n_pts,) bool receives
    whether a point's interval took ROS2 (a device test where n_sub > ``cst[K_STIFF]``), ``pw`` is
    :func:`point_powers`' scratch.
    """
    ns = lay[L_NS]
    if lay[L_KIND] == DEVICE and n_sub > cst[K_STIFF]:
        for i in range(n_pts):
            taken[i] = _try_ros2(lay, cst, TH[i], t, h, a0, a1, X[i, :ns], K1[i], n_sub, work) > 0
    else:
        for i in range(n_pts):
            taken[i] = False
    tmp = work[3]
    am = work[4]
    inv_n = 1.0 / n_sub
    hs = h * inv_n
    hs6 = hs / 6.0
    for j in range(n_sub):
        tj = t + j * hs
        for st in range(4):
            if st == 0 and j == 0:
                continue  # every k1 = f(s, a0) was handed in
            c = _stage_inputs(st, j, inv_n, a0, a1, am)
            point_powers(lay, TH, X, K1, stages, st, c * hs, n_pts, taken, pw)
            for i in range(n_pts):
                if taken[i]:
                    continue
                if st == 0:
                    for q in range(ns):
                        tmp[q] = X[i, q]
                else:
                    kp = K1[i] if st == 1 else stages[i, st - 2]
                    for q in range(ns):
                        tmp[q] = X[i, q] + c * hs * kp[q]
                kn = K1[i] if st == 0 else stages[i, st - 1]
                deriv_pow(lay, cst, TH[i], tj + c * hs, am, tmp, kn, pw[0, i])
        for i in range(n_pts):
            if taken[i]:
                continue
            s = X[i]
            k1 = K1[i]
            k2 = stages[i, 0]
            k3 = stages[i, 1]
            k4 = stages[i, 2]
            for q in range(ns):
                s[q] += hs6 * (k1[q] + 2.0 * k2[q] + 2.0 * k3[q] + k4[q])
            _after_substep(lay, cst, TH[i], s, a0, a1, am, j, inv_n, hs)
