"""Compiled augmented-state UKF (thesis 3-10..3-30), batched over priors.

Augmented state X = [model states s, φ] with φ the free parameters in the
thesis's log-scaled coordinates (3-37). The transition integrates s over one
sample with the model's RK4 (sub-steps shared by all sigma points, so the
transform sees the model and not the step control; evaluated stage by stage
across the sigma points, :func:`~bayes_mr.models.integrate.advance_points`) and
keeps φ; the observation is the measured channels at the new sample:
[x, ẍ+ẍ_g] for a structure test, [F] for a device test. Noise is additive
(Q, R); the observation is evaluated at sigma points drawn again about the
prediction, so that it sees Q (filterpy re-uses the propagated ones, its
issue #172), and the innovation log-likelihood Σ log N(y_k; ŷ_k⁻, P_yy,k) is
accumulated as the UKF's evidence.

Robustness (DESIGN.md "Numerics"): P is symmetrised every step; a failed
Cholesky gets jitter 1e-9·tr(P)/L ×10 up to five times, then the run stops
with a status code naming the step. φ of the mean is kept inside a box
(the plausible range widened by a margin) so that one wild update cannot
push exp(φ) to overflow; every such projection is counted.
"""

from __future__ import annotations

import math

import numpy as np
from numba import prange

from bayes_mr._compile.jit import driver, hot
from bayes_mr.models.integrate import DECIDE, advance, advance_points, substeps, work_shape
from bayes_mr.models.kernel import DEVICE, L_KIND, L_NS, L_OBS, LAYOUT_SIZE, channel, deriv, deriv_pow, forces, rate
from bayes_mr.models.power import point_powers
from bayes_mr.inference.ukf.unscented import cholesky, moments, sigma_points, sigma_thetas, thetas_scratch

# status codes of a run
OK = 0
CHOL_FAILED = 1
NON_FINITE = 2
INNOVATION_NOT_PD = 3
NAMES = {
    OK: "ok",
    CHOL_FAILED: "state covariance not positive definite after jitter",
    NON_FINITE: "state or covariance became non-finite",
    INNOVATION_NOT_PD: "innovation covariance not positive definite",
}
# info slots
I_STATUS, I_STEP, I_LOGLIK, I_JITTER, I_NSUB, I_CLIP, I_NUPD = range(7)
INFO_SIZE = 7
# the filter's layout: the model's (models.kernel) and, after it, the augmented state's size L and the number of
# measured channels ny. A kernel specialised to the layout (bayes_mr._compile.specialise) then knows every loop bound of
# the filter step at compile time, as it knows the model's branches.
U_L = LAYOUT_SIZE
U_NY = LAYOUT_SIZE + 1
UKF_LAYOUT_SIZE = LAYOUT_SIZE + 2


def ukf_layout(lay: np.ndarray, L: int, ny: int) -> np.ndarray:
    """The filter's layout: the model's layout ``lay`` followed by the sizes L and ny."""
    return np.concatenate([np.asarray(lay, np.int64)[:LAYOUT_SIZE], np.array([L, ny], np.int64)])


@hot
def observe(lay, cst, th, t, a, s, ds, y, ny):
    """The ny measured channels predicted from state s: those the layout's L_OBS slots name, in order."""
    f_r, f_d = forces(lay, cst, th, t, a, s, ds)
    for q in range(ny):
        y[q] = channel(lay, cst, th, a, s, f_r, lay[L_OBS + q])


@hot(inline="always")
def _add_noise(P, Q, n):
    """P += Q (the additive process or measurement noise of one step; n × n)."""
    for q in range(n):
        for r in range(n):
            P[q, r] += Q[q, r]


@hot(inline="always")  # inlined: a call per sample measured ~7 % slower
def _predict(model, weights, sig, pbuf, m, P, Q, h, a0, a1, t):
    """Sigma points about (m, P) propagated over [t, t+h]; (m, P) ← their moments + Q.

    ``a0``, ``a1`` are the inputs at t and t + h; ``sig`` and ``pbuf`` the
    scratch arrays of :func:`ukf_run`.

    Returns (code, jitter, n_sub): code OK, CHOL_FAILED (P not positive
    definite after jitter; nothing else done) or NON_FINITE (a propagated
    state is not finite); jitter 1 if P needed it; the RK4 sub-steps used.
    """
    lay, cst, free_idx, is_log, scale, phi_lo, phi_hi = model
    w0m, w0c, wi, spread, ab, central = weights
    S, Pj, X, TH, d, DX, ED = sig
    K1, work, stages, taken, pw = pbuf
    ns = lay[L_NS]
    L = lay[U_L]
    nsig = 2 * L + 1
    jit = sigma_points(m, P, S, Pj, X, spread, L)
    if jit < 0:
        return CHOL_FAILED, 0, 0
    lam = 0.0
    sigma_thetas(free_idx, is_log, scale, phi_lo, phi_hi, m, S, spread, ns, L, TH, ED)
    for i in range(nsig):
        taken[i] = False
    point_powers(lay, TH, X, K1, stages, 0, 0.0, nsig, taken, pw)  # every point's |z|ⁿ at once (vectorised)
    for i in range(nsig):
        deriv_pow(lay, cst, TH[i], t, a0, X[i, :ns], K1[i], pw[0, i])
        if lay[L_KIND] == DEVICE:
            vmax = max(abs(a0[1]), abs(a1[1]))
        else:
            vmax = abs(X[i, 1]) + abs(K1[i, 1]) * h
        r_i = rate(lay, cst, TH[i], t, X[i, :ns], vmax, 1.0)
        if r_i > lam:
            lam = r_i
    n_sub = substeps(lay, cst, lam, h)
    advance_points(lay, cst, TH, t, h, a0, a1, X, K1, nsig, n_sub, work, stages, taken, pw)
    finite = True
    for i in range(nsig):
        for q in range(ns):
            if not math.isfinite(X[i, q]):
                finite = False
    if not finite:
        return NON_FINITE, jit, n_sub
    moments(X, X, nsig, L, L, w0m, w0c, wi, ab, central, m, m, P, d, d, True, DX, DX)
    _add_noise(P, Q, L)
    return OK, jit, n_sub


@hot(inline="always")
def _update(model, weights, sig, ubuf, m, P, R, y, a1, t1):
    """Kalman update of (m, P) with the measurement y and input a1 at time t1.

    Returns (code, jitter, log-likelihood increment): code OK, CHOL_FAILED,
    NON_FINITE (a predicted measurement is not finite) or INNOVATION_NOT_PD;
    the increment ln N(y; ŷ⁻, P_yy) is meaningful only when OK.
    """
    lay, cst, free_idx, is_log, scale, phi_lo, phi_hi = model
    w0m, w0c, wi, spread, ab, central = weights
    S, Pj, X, TH, d, DX, ED = sig
    Y, dsbuf, mx, dy, yhat, Pyy, Syy, Pxy, Kg, nu, z, DY = ubuf
    ns = lay[L_NS]
    L = lay[U_L]
    ny = lay[U_NY]
    nsig = 2 * L + 1
    finite = True
    jit = sigma_points(m, P, S, Pj, X, spread, L)
    if jit < 0:
        return CHOL_FAILED, 0, 0.0
    sigma_thetas(free_idx, is_log, scale, phi_lo, phi_hi, m, S, spread, ns, L, TH, ED)
    for i in range(nsig):
        observe(lay, cst, TH[i], t1, a1, X[i, :ns], dsbuf, Y[i], ny)
        for q in range(ny):
            if not math.isfinite(Y[i, q]):
                finite = False
    if not finite:
        return NON_FINITE, jit, 0.0
    moments(Y, Y, nsig, ny, ny, w0m, w0c, wi, ab, central, yhat, yhat, Pyy, dy, dy, True, DY, DY)
    moments(X, Y, nsig, L, ny, w0m, w0c, wi, ab, central, mx, yhat, Pxy, d, dy, False, DX, DY)
    _add_noise(Pyy, R, ny)
    if not cholesky(Pyy, Syy, ny):
        return INNOVATION_NOT_PD, jit, 0.0
    for q in range(ny):
        nu[q] = y[q] - yhat[q]
    # z = Syy⁻¹ ν (forward substitution)
    logdet = 0.0
    for q in range(ny):
        acc = nu[q]
        for r in range(q):
            acc -= Syy[q, r] * z[r]
        z[q] = acc / Syy[q, q]
        logdet += 2.0 * math.log(Syy[q, q])
    maha = 0.0
    for q in range(ny):
        maha += z[q] * z[q]
    ll = -0.5 * (ny * math.log(2.0 * math.pi) + logdet + maha)
    # K = Pxy Pyy⁻¹: solve Syy Syyᵀ Kᵀ = Pxyᵀ row by row
    for q in range(L):
        for r in range(ny):
            acc = Pxy[q, r]
            for c in range(r):
                acc -= Syy[r, c] * Kg[q, c]
            Kg[q, r] = acc / Syy[r, r]
        for r in range(ny - 1, -1, -1):
            acc = Kg[q, r]
            for c in range(r + 1, ny):
                acc -= Syy[c, r] * Kg[q, c]
            Kg[q, r] = acc / Syy[r, r]
    for q in range(L):
        acc = 0.0
        for r in range(ny):
            acc += Kg[q, r] * nu[r]
        m[q] += acc
    # P ← P − K Pxyᵀ, symmetrised
    for q in range(L):
        for r in range(q + 1):
            acc = 0.0
            for c in range(ny):
                acc += 0.5 * (Kg[q, c] * Pxy[r, c] + Kg[r, c] * Pxy[q, c])
            v = P[q, r] - acc
            P[q, r] = v
            P[r, q] = v
    return OK, jit, ll


@hot
def _ukf_loop(model, record, state, weights, out, sig, pbuf, ubuf, P0s):
    """The filter loop proper (no allocation; see :func:`ukf_run`).

    The arguments are tuples in the order :func:`ukf_run` builds them:
    ``model`` (lay, cst, free_idx, is_log, scale, phi_lo, phi_hi),
    ``record`` (h, inputs, yobs, valid, reset, hold, end), ``state`` (m, P, Q, R),
    ``weights`` (w0m, w0c, wi, spread, ab, central), ``out`` (stride, hist_m,
    hist_sd, states_m, store_states, info); ``sig``, ``pbuf``, ``ubuf`` are
    the scratch arrays :func:`ukf_run` allocates for the sigma points, the
    prediction and the update, and P0s the states' prior covariance. ``end``
    (3,) is scratch for an interval's end inputs when ``hold``.

    Per sample: sigma points about (m, P); propagate the model states of each;
    predicted moments + Q; sigma points redrawn about the prediction (so the
    measurement sees Q, as in the exact Kalman filter — filterpy #172);
    measurement moments + R; Kalman update; box the mean of φ.

    Where ``reset[k]`` sample k starts another record: the model states go
    back to rest (mean 0, covariance block P0s, no state–parameter
    covariance), time restarts at 0, and there is no transition (and no
    update) from sample k−1 to k. φ and its covariance carry over.
    """
    lay, _, _, _, _, phi_lo, phi_hi = model
    h, inputs, yobs, valid, reset, hold, end = record
    m, P, Q, R = state
    stride, hist_m, hist_sd, states_m, store_states, info = out
    N = inputs.shape[0]
    ns = lay[L_NS]
    L = lay[U_L]
    npf = L - ns
    loglik = 0.0
    n_jitter = 0
    n_clip = 0
    n_upd = 0
    max_nsub = 0
    status = OK
    step = -1
    i_hist = 0
    k_seg = 0  # first sample of the current record (time restarts there)
    for k in range(N):
        if reset[k]:
            k_seg = k
            for q in range(ns):
                m[q] = 0.0
                for r in range(L):
                    P[q, r] = 0.0
                    P[r, q] = 0.0
            for q in range(ns):
                for r in range(ns):
                    P[q, r] = P0s[q, r]
        if store_states:
            for q in range(L):
                states_m[k, q] = m[q]
        if k % stride == 0 and i_hist < hist_m.shape[0]:
            for q in range(L):
                hist_m[i_hist, q] = m[q]
                hist_sd[i_hist, q] = math.sqrt(max(P[q, q], 0.0))
            i_hist += 1
        if k == N - 1:
            break
        if reset[k + 1]:
            continue  # the next record starts from rest: nothing links k to k+1
        t = (k - k_seg) * h
        a1 = inputs[k + 1]
        if hold:  # the command held to the next sample, as the simulator's drivers hold it (drive linear)
            end[0] = a1[0]
            end[1] = a1[1]
            end[2] = inputs[k, 2]
            a1 = end
        code, jit, n_sub = _predict(model, weights, sig, pbuf, m, P, Q, h, inputs[k], a1, t)
        n_jitter += jit
        if n_sub > max_nsub:
            max_nsub = n_sub
        if code == CHOL_FAILED:
            status = code
            step = k
            break
        if code == OK and valid[k + 1]:
            code, jit, ll = _update(model, weights, sig, ubuf, m, P, R, yobs[k + 1], inputs[k + 1], t + h)
            n_jitter += jit
            if code == OK:
                loglik += ll
                n_upd += 1
        if code != OK:
            status = code
            step = k + 1
            break
        # keep the mean of φ inside its box
        for j in range(npf):
            q = ns + j
            if m[q] < phi_lo[j]:
                m[q] = phi_lo[j]
                n_clip += 1
            elif m[q] > phi_hi[j]:
                m[q] = phi_hi[j]
                n_clip += 1
        bad = False
        for q in range(L):
            if not math.isfinite(m[q]) or not math.isfinite(P[q, q]):
                bad = True
        if bad:
            status = NON_FINITE
            step = k + 1
            break
    info[I_STATUS] = status
    info[I_STEP] = step
    info[I_LOGLIK] = loglik
    info[I_JITTER] = n_jitter
    info[I_NSUB] = max_nsub
    info[I_CLIP] = n_clip
    info[I_NUPD] = n_upd


@driver(nogil=True)
def ukf_run(
    lay, cst, tmpl, free_idx, is_log, scale, phi_lo, phi_hi,
    h, inputs, yobs, valid, reset, hold, m, P, Q, R,
    w0m, w0c, wi, spread, ab, central,
    stride, hist_m, hist_sd, states_m, store_states, info,
):
    """Filter one record from prior (m, P); m and P are updated in place.

    Parameters
    ----------
    lay : the filter's layout (:func:`ukf_layout`: the model's, then L and ny).
    cst : model constants (see models.kernel).
    tmpl : (n_full,) parameter template (fixed parameters at their values).
    free_idx, is_log, scale : free-parameter positions and coordinates.
    phi_lo, phi_hi : box kept by the mean of φ and by sigma-point evaluation.
    h : sample interval [s]. inputs : (N, 3). yobs : (N, ny). valid : (N,) bool.
    reset : (N,) bool
        True where a sample starts another record filtered in the same run
        (thesis method 3, both signals at once). There the model states go
        back to rest — mean 0, their block of P back to its value on entry,
        state–parameter covariance zeroed — time restarts, and no transition
        or update links the sample to the one before; φ and its covariance
        carry over. This is sequential, not the thesis's stacked state vector
        [s_A, s_B, φ] (Lund et al. 2020): given φ the two records' states are
        independent (separate inputs and noise), so p(y_A, y_B | φ) =
        p(y_A | φ) p(y_B | φ) and Bayes' rule gives the same posterior of φ
        whichever order the records are conditioned on. The parameters see
        the same data through the same likelihood; what differs is the
        Gaussian approximation (linearised at later φ estimates for the
        second record) and the random walk of φ, which lets the later record
        weigh slightly more. In exchange the state has L = n_s + p, not
        2n_s + p, entries (2L+1 sigma points, O(L³) per step) and the records
        need not be the same length. The innovation log-likelihood summed
        over both records is ln p(y_A) + ln p(y_B | y_A) = ln p(y_A, y_B).
    hold : bool
        The command (inputs' column 2) held from each sample to the next
        instead of linear, in the prediction (the update reads the sample's own row).
    m, P : (L,), (L, L) prior mean/covariance on entry, posterior on exit.
    Q, R : (L, L), (ny, ny) additive process and measurement noise per step.
    w0m, w0c, wi, spread, ab : sigma-point weights, √(L+λ), β − α².
    central : sum about the central sigma point (True) or with raw weights.
    stride : history every ``stride`` samples into hist_m, hist_sd (n_hist, L).
    states_m : (N, L) full mean history when ``store_states``.
    info : (INFO_SIZE,) float array written on exit.
    """
    ns = lay[L_NS]
    L = lay[U_L]
    ny = lay[U_NY]
    nsig = 2 * L + 1
    nfull = tmpl.shape[0]
    S = np.zeros((L, L))
    Pj = np.zeros((L, L))
    X = np.zeros((nsig, L))
    TH = np.zeros((nsig, nfull))
    for i in range(nsig):  # the fixed parameters' θ, once: sigma_thetas writes the free ones
        TH[i] = tmpl
    K1 = np.zeros((nsig, ns))
    Y = np.zeros((nsig, ny))
    work = np.zeros(work_shape(ns))
    stages = np.zeros((nsig, 3, ns))
    taken = np.zeros(nsig, np.bool_)
    pw = np.ones((3, (nsig + 7) // 8 * 8))  # point_powers' scratch, padded to the vector width
    dsbuf = np.zeros(ns)
    d = np.zeros(L)
    mx = np.zeros(L)
    dy = np.zeros(ny)
    yhat = np.zeros(ny)
    Pyy = np.zeros((ny, ny))
    Syy = np.zeros((ny, ny))
    Pxy = np.zeros((L, ny))
    Kg = np.zeros((L, ny))
    nu = np.zeros(ny)
    z = np.zeros(ny)
    DX = np.zeros((nsig, L))
    ED = np.zeros(thetas_scratch(ns, L))
    DY = np.zeros((nsig, ny))
    P0s = P[:ns, :ns].copy()  # the states' prior covariance, restored at every reset
    _ukf_loop(
        (lay, cst, free_idx, is_log, scale, phi_lo, phi_hi),  # tmpl is in TH's fixed columns already
        (h, inputs, yobs, valid, reset, hold, np.zeros(3)),
        (m, P, Q, R),
        (w0m, w0c, wi, spread, ab, central),
        (stride, hist_m, hist_sd, states_m, store_states, info),
        (S, Pj, X, TH, d, DX, ED),
        (K1, work, stages, taken, pw),
        (Y, dsbuf, mx, dy, yhat, Pyy, Syy, Pxy, Kg, nu, z, DY),
        P0s,
    )


@driver(parallel=True, nogil=True)
def ukf_batch(
    lay, cst, tmpl, free_idx, is_log, scale, phi_lo, phi_hi,
    h, inputs, yobs, valid, reset, hold, M, PP, Q, R,
    w0m, w0c, wi, spread, ab, central,
    stride, HM, HS, INFO,
):
    """Run :func:`ukf_run` for every prior (M[r], PP[r]) in parallel."""
    n_runs = M.shape[0]
    dummy = np.zeros((1, M.shape[1]))
    for r in prange(n_runs):
        ukf_run(
            lay, cst, tmpl, free_idx, is_log, scale, phi_lo, phi_hi,
            h, inputs, yobs, valid, reset, hold, M[r], PP[r], Q, R,
            w0m, w0c, wi, spread, ab, central,
            stride, HM[r], HS[r], dummy, False, INFO[r],
        )


@driver
def propagate(lay, cst, th, t, h, a0, a1, s, n_sub):
    """One sample interval of the model for one state vector (for references).

    Returns the new model state; ``s`` is not modified.
    """
    ns = lay[L_NS]
    out = s.copy()
    k1 = np.zeros(ns)
    work = np.zeros(work_shape(ns))
    deriv(lay, cst, th, t, a0, out, k1)
    advance(lay, cst, th, t, h, a0, a1, out, k1, n_sub, DECIDE, work)
    return out


@driver
def measure(lay, cst, th, t, a, s, ny):
    """The measured channels predicted from one state vector (for references)."""
    y = np.zeros(ny)
    ds = np.zeros(lay[L_NS])
    observe(lay, cst, th, t, a, s, ds, y, ny)
    return y
