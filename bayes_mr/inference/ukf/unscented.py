"""Compiled sigma-point arithmetic of the UKF (:mod:`bayes_mr.inference.ukf.kernel`).

:func:`cholesky` of a small covariance, :func:`sigma_points` (the 2L + 1
points m ± spread·chol(P), with a bounded jitter ladder when P has lost
positive definiteness), :func:`moments` (the unscented mean and
cross-covariance of transformed points, summed about the central point or
with the raw weights; see :mod:`bayes_mr.inference.ukf.sigma_points` for why), and
:func:`sigma_thetas` (the model parameters at every sigma point). None of
them allocates: the filter loop owns every buffer.
"""

from __future__ import annotations

import math

from bayes_mr._compile.jit import hot
from bayes_mr.models.power import exp_dd


@hot
def cholesky(A, Lo, n):
    """Lower Cholesky factor of A[:n,:n] into Lo; False if not positive definite."""
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s -= Lo[j, k] * Lo[j, k]
        if not (s > 0.0) or not math.isfinite(s):
            return False
        d = math.sqrt(s)
        Lo[j, j] = d
        for i in range(j + 1, n):
            s = A[i, j]
            for k in range(j):
                s -= Lo[i, k] * Lo[j, k]
            Lo[i, j] = s / d
        for i in range(j):
            Lo[i, j] = 0.0
    return True


@hot
def sigma_points(m, P, S, Pj, X, spread, L):
    """X ← m ± spread·chol(P) columns, with a bounded jitter ladder.

    Returns 0 (no jitter), 1 (jitter was added) or -1 (not positive definite).
    """
    jittered = 0
    ok = cholesky(P, S, L)
    if not ok:
        tr = 0.0
        for q in range(L):
            tr += abs(P[q, q])
        eps = 1e-9 * tr / L
        for attempt in range(5):
            for q in range(L):
                for r in range(L):
                    Pj[q, r] = P[q, r]
                Pj[q, q] += eps
            ok = cholesky(Pj, S, L)
            if ok:
                jittered = 1
                break
            eps *= 10.0
    if not ok:
        return -1
    for q in range(L):
        X[0, q] = m[q]
    for i in range(L):
        for q in range(L):
            X[1 + i, q] = m[q] + spread * S[q, i]
            X[1 + L + i, q] = m[q] - spread * S[q, i]
    return jittered


@hot(inline="always")
def _about_central(A, nsig, n, wi, m, dm, D):
    """Deviations D[i] = A[i] − A[0] (i ≥ 1), δ = wi Σ D[i] into dm, and the mean m = A[0] + δ (n columns)."""
    for q in range(n):  # a column at a time, its sum in a register (summed in ascending i, as the formula reads)
        a0 = A[0, q]
        acc = 0.0
        for i in range(1, nsig):
            v = A[i, q] - a0
            D[i, q] = v
            acc += v
        dm[q] = acc * wi
        m[q] = a0 + dm[q]


@hot(inline="always")
def _raw_mean(A, nsig, n, w0m, wi, m):
    """The mean of the rows of A with the raw weights, m = w0m A[0] + wi Σ_{i≥1} A[i] (thesis, filterpy)."""
    for q in range(n):
        acc = w0m * A[0, q]
        for i in range(1, nsig):
            acc += wi * A[i, q]
        m[q] = acc


@hot
def moments(A, B, nsig, na, nb, w0m, w0c, wi, ab, central, ma, mb, Pab, da, db, same, DA, DB):
    """Unscented mean of the first ``na`` (``nb``) columns of the rows of A (and B) and their cross-covariance Pab.

    ``central`` sums about the first (central) point:
    m = A₀ + δ, P = Σ_{i≥1} W_i ΔA_i ΔB_iᵀ + (β − α²) δ_A δ_Bᵀ;
    otherwise with the raw weights (thesis, filterpy). When ``same`` only the
    lower triangle is computed and mirrored, and B, mb, db, DB must be the
    same arrays as A, ma, da, DA. DA, DB are scratch (nsig, ·): the
    deviations are formed once, not once per covariance entry. The sizes are
    arguments, not the arrays' shapes, so that a kernel compiled for one
    state size (:mod:`bayes_mr.inference.ukf.kernel`) knows them as constants.
    """
    if central:
        # when ``same``, B is A and db, mb, DB alias da, ma, DA: fill them once
        _about_central(A, nsig, na, wi, ma, da, DA)
        if not same:
            _about_central(B, nsig, nb, wi, mb, db, DB)
        _products(DA, DB, 1, nsig, na, nb, 1.0, Pab, True, same)
        for q in range(na):
            for r in range(q + 1 if same else nb):
                v = wi * Pab[q, r] + ab * da[q] * db[r]
                Pab[q, r] = v
                if same:
                    Pab[r, q] = v
    else:
        _raw_mean(A, nsig, na, w0m, wi, ma)
        if not same:
            _raw_mean(B, nsig, nb, w0m, wi, mb)
        for i in range(nsig):
            for q in range(na):
                DA[i, q] = A[i, q] - ma[q]
            if not same:
                for q in range(nb):
                    DB[i, q] = B[i, q] - mb[q]
        _products(DA, DB, 0, 1, na, nb, w0c, Pab, True, same)
        _products(DA, DB, 1, nsig, na, nb, wi, Pab, False, same)
        if same:
            for q in range(na):
                for r in range(q):
                    Pab[r, q] = Pab[q, r]


@hot(inline="always")
def _products(DA, DB, i0, i1, na, nb, w, Pab, first, tri):
    """Pab[q, r] (+)= Σ_{i0 ≤ i < i1} w·DA[i, q]·DB[i, r] for r < nb (r ≤ q: ``tri``), every entry summed in
    ascending i (``first``: from 0, else from Pab's value).

    Four entries at a time (:func:`_block4`) — along a row, or down a column where rows are shorter than four
    (a cross-covariance with one or two measured channels): four independent chains of additions the processor
    overlaps and the compiler packs, where one entry at a time is one chain of dependent additions. Each entry adds
    the same terms in the same order, so the numbers are those of the entry-by-entry sum."""
    if not tri and nb < 4:
        for r in range(nb):
            q = 0
            while q + 4 <= na:
                _block4(DA, DB, i0, i1, q, r, 1, 0, w, Pab, first)
                q += 4
            for qq in range(q, na):
                _one(DA, DB, i0, i1, qq, r, w, Pab, first)
        return
    for q in range(na):
        top = q + 1 if tri else nb
        r = 0
        while r + 4 <= top:
            _block4(DA, DB, i0, i1, q, r, 0, 1, w, Pab, first)
            r += 4
        for rr in range(r, top):
            _one(DA, DB, i0, i1, q, rr, w, Pab, first)


@hot(inline="always")
def _block4(DA, DB, i0, i1, q, r, dq, dr, w, Pab, first):
    """The entries Pab[q + k·dq, r + k·dr] (k < 4) as :func:`_one` sums each, in four accumulators at once."""
    if first:
        a0 = a1 = a2 = a3 = 0.0
    else:
        a0, a1, a2, a3 = Pab[q, r], Pab[q + dq, r + dr], Pab[q + 2 * dq, r + 2 * dr], Pab[q + 3 * dq, r + 3 * dr]
    for i in range(i0, i1):
        a0 += (w * DA[i, q]) * DB[i, r]
        a1 += (w * DA[i, q + dq]) * DB[i, r + dr]
        a2 += (w * DA[i, q + 2 * dq]) * DB[i, r + 2 * dr]
        a3 += (w * DA[i, q + 3 * dq]) * DB[i, r + 3 * dr]
    Pab[q, r] = a0
    Pab[q + dq, r + dr] = a1
    Pab[q + 2 * dq, r + 2 * dr] = a2
    Pab[q + 3 * dq, r + 3 * dr] = a3


@hot(inline="always")
def _one(DA, DB, i0, i1, q, r, w, Pab, first):
    """Pab[q, r] (+)= Σ_{i0 ≤ i < i1} w·DA[i, q]·DB[i, r], summed in ascending i."""
    acc = 0.0 if first else Pab[q, r]
    for i in range(i0, i1):
        acc += (w * DA[i, q]) * DB[i, r]
    Pab[q, r] = acc


@hot(inline="always")
def _coord(c, v):
    """θ·scale of one free parameter from its coordinate v (Coordinates.code c: 1 log, 2 signed-log, 0 linear)."""
    if c == 1:
        return math.exp(v)
    if c == 2:
        return math.sinh(v)
    return v


@hot(inline="always")
def thetas_scratch(ns, L):
    """Shape of :func:`sigma_thetas`' scratch: 2 × the free parameters' rows of the factor ((L − ns)·L entries),
    padded to a multiple of the vector width (8; the padding's exp(0) is unused)."""
    return 2, ((L - ns) * L + 7) // 8 * 8


@hot
def sigma_thetas(free_idx, is_log, scale, phi_lo, phi_hi, m, S, spread, ns, L, TH, ED):
    """TH[i] ← θ of the free parameters at every sigma point m, m ± spread·S[:, i] (clipped to the box, mapped to θ).

    A log coordinate's pair of points costs one exponential, not two:
    exp(m ± d)/scale = (exp(m)/scale)·exp(±d) (d = spread·S[q, i]), and the
    exponentials of every parameter's deviations are taken in one loop of
    :func:`~bayes_mr.models.power.exp_dd` that the compiler vectorises (into
    ``ED``, scratch of shape :func:`thetas_scratch`), where one C-library
    call each ran one after another: ~45 exponentials per call, twice per
    filter step (normalized-bouc-wen on signal I, batched over 100 priors:
    1.84 → 1.45 µs per run and sample, ``ukf_us_per_step`` of
    ``bayes-mr bench``). The lower
    point divides by exp(d) once. A column of the lower-triangular factor
    that is zero in a parameter's row leaves that parameter at the centre's
    value; where m ± d leaves the box the point is clipped and evaluated
    directly. The products differ from exp(m ± d)/scale by rounding only
    (≤ 3 ulp: exp(d) within 1 ulp, three roundings). ``L`` is the augmented
    state's size (``ns`` model states and L − ns free parameters). The
    fixed parameters' columns of TH are left alone: the filter fills them
    with their θ once per run.
    """
    for j in range(L - ns):  # the arguments, then one flat loop over a multiple of the vector width
        for i in range(L):
            ED[1, j * L + i] = spread * S[ns + j, i]
    for e in range(ED.shape[1]):
        ED[0, e] = exp_dd(ED[1, e])
    for j in range(L - ns):
        c, k, sc = is_log[j], free_idx[j], scale[j]
        lo, hi, mq = phi_lo[j], phi_hi[j], m[ns + j]
        centre = _coord(c, min(max(mq, lo), hi)) / sc
        TH[0, k] = centre
        inside = c == 1 and lo <= mq <= hi and centre > 0.0  # exp(mq)/scale: the centre's own θ, not a second exp
        for i in range(L):
            d = ED[1, j * L + i]  # spread·S[q, i]
            if d == 0.0:
                TH[1 + i, k] = centre
                TH[1 + L + i, k] = centre
                continue
            up, dn = mq + d, mq - d
            if inside and lo <= up <= hi and lo <= dn <= hi:
                TH[1 + i, k] = centre * ED[0, j * L + i]
                TH[1 + L + i, k] = centre / ED[0, j * L + i]
            else:
                TH[1 + i, k] = _coord(c, min(max(up, lo), hi)) / sc
                TH[1 + L + i, k] = _coord(c, min(max(dn, lo), hi)) / sc
