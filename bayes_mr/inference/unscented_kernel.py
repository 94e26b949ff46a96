"""Compiled sigma-point arithmetic of the UKF (:mod:`bayes_mr.inference.ukf_kernel`).

:func:`cholesky` of a small covariance, :func:`sigma_points` (the 2L + 1
points m ± spread·chol(P), with a bounded jitter ladder when P has lost
positive definiteness) and :func:`moments` (the unscented mean and
cross-covariance of transformed points, summed about the central point or
with the raw weights; see :mod:`bayes_mr.inference.sigma` for why). None of
them allocates: the filter loop owns every buffer.
"""

from __future__ import annotations

import math

from .._jit import hot


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
def _about_central(A, nsig, wi, m, dm, D):
    """Deviations D[i] = A[i] − A[0] (i ≥ 1), δ = wi Σ D[i] into dm, and the mean m = A[0] + δ."""
    n = A.shape[1]
    for q in range(n):
        dm[q] = 0.0
    for i in range(1, nsig):
        for q in range(n):
            v = A[i, q] - A[0, q]
            D[i, q] = v
            dm[q] += v
    for q in range(n):
        dm[q] *= wi
        m[q] = A[0, q] + dm[q]


@hot(inline="always")
def _raw_mean(A, nsig, w0m, wi, m):
    """The mean of the rows of A with the raw weights, m = w0m A[0] + wi Σ_{i≥1} A[i] (thesis, filterpy)."""
    for q in range(A.shape[1]):
        acc = w0m * A[0, q]
        for i in range(1, nsig):
            acc += wi * A[i, q]
        m[q] = acc


@hot
def moments(A, B, nsig, w0m, w0c, wi, ab, central, ma, mb, Pab, da, db, same, DA, DB):
    """Unscented mean of the rows of A (and B) and their cross-covariance Pab.

    ``central`` sums about the first (central) point:
    m = A₀ + δ, P = Σ_{i≥1} W_i ΔA_i ΔB_iᵀ + (β − α²) δ_A δ_Bᵀ;
    otherwise with the raw weights (thesis, filterpy). When ``same`` only the
    lower triangle is computed and mirrored, and B, mb, db, DB must be the
    same arrays as A, ma, da, DA. DA, DB are scratch (nsig, ·): the
    deviations are formed once, not once per covariance entry.
    """
    na = A.shape[1]
    nb = B.shape[1]
    if central:
        # when ``same``, B is A and db, mb, DB alias da, ma, DA: fill them once
        _about_central(A, nsig, wi, ma, da, DA)
        if not same:
            _about_central(B, nsig, wi, mb, db, DB)
        for q in range(na):
            top = q + 1 if same else nb
            for r in range(top):
                acc = 0.0
                for i in range(1, nsig):
                    acc += DA[i, q] * DB[i, r]
                v = wi * acc + ab * da[q] * db[r]
                Pab[q, r] = v
                if same:
                    Pab[r, q] = v
    else:
        _raw_mean(A, nsig, w0m, wi, ma)
        if not same:
            _raw_mean(B, nsig, w0m, wi, mb)
        for i in range(nsig):
            for q in range(na):
                DA[i, q] = A[i, q] - ma[q]
            if not same:
                for q in range(nb):
                    DB[i, q] = B[i, q] - mb[q]
        for q in range(na):
            top = q + 1 if same else nb
            for r in range(top):
                acc = w0c * DA[0, q] * DB[0, r]
                for i in range(1, nsig):
                    acc += wi * DA[i, q] * DB[i, r]
                Pab[q, r] = acc
                if same:
                    Pab[r, q] = acc
