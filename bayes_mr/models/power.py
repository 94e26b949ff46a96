"""x^y for x ≥ 0 in branch-free arithmetic, so that a loop of them compiles to SIMD instructions.

``math.pow`` is a call into the C library: a loop over the UKF's sigma points
that calls it once per point runs one power after another (≈ 8–11 ns each on
the bench machine), and |z|ⁿ is the costliest operation of the Bouc–Wen
family's right-hand side. :func:`pow_nonneg` computes the same number from
multiplications, additions, one division, fused multiply-adds and bit
manipulation only, every special case a select rather than a branch, so that
LLVM vectorises a loop of independent calls (AVX2/AVX-512: 4–8 powers per
instruction). :func:`point_powers` evaluates the powers of all the UKF's sigma
points in one such loop, for each RK4 stage of
:func:`bayes_mr.models.integrate.advance_points` (12–14 % off a normalized
Bouc–Wen filter step, one run on signal I: 2.89 → 2.55 µs per sample on the
bench machine).

The method (as in the C libraries, without their tables):

* ln x = e ln 2 + ln m with x = m·2ᵉ, m ∈ [√2/2, √2), and
  ln m = 2 atanh(s) = 2s + 2s³/3 + 2s⁵/5 + …, s = (m − 1)/(m + 1), |s| ≤ 0.172,
  carried as a double-double (hi + lo: s's own rounding error from an FMA);
* y ln x as a double-double (the product's rounding error from an FMA), so
  that the exponent's error is not multiplied by |y ln x| (up to ~700);
* exp(P + Pl) = 2ᵏ exp(r), k = round(P / ln 2), |r| ≤ ln 2 / 2, exp(r) by its
  Taylor series to r¹³ (truncation < 1e-17 relative).

Measured against the C library's ``pow`` (``tests/test_power.py``): within
1 ulp over x from 1e-300 to 1e10 and y from 0.05 to 8, and the C library's
special cases (0, 1, inf, NaN; subnormal and overflowing results).
"""

from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from bayes_mr._compile.jit import hot
from bayes_mr.models.kernel import power_slot


@intrinsic
def _bits(typingctx, x):
    """The IEEE-754 bits of a float64 as an int64 (a bit cast: no memory, no instruction)."""
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.IntType(64))
    return types.int64(types.float64), codegen


@intrinsic
def _from_bits(typingctx, b):
    """The float64 whose IEEE-754 bits are the int64 b (a bit cast)."""
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.DoubleType())
    return types.float64(types.int64), codegen


@intrinsic
def _fma(typingctx, a, b, c):
    """a·b + c rounded once (``llvm.fma``: one instruction on x86-64 with FMA, vectorisable)."""
    def codegen(context, builder, signature, args):
        return builder.fma(*args)
    return types.float64(types.float64, types.float64, types.float64), codegen


_LN2_HI = 6.93147180369123816490e-01  # ln 2's leading 32 bits: e·_LN2_HI is exact for |e| < 2²¹
_LN2_LO = 1.90821492927058770002e-10  # ln 2 − _LN2_HI
_INV_LN2 = 1.44269504088896338700e+00
_ROUND = 6755399441055744.0  # 1.5·2⁵²: (v + _ROUND) − _ROUND rounds v to the nearest integer (|v| < 2⁵¹)
_MANTISSA = (1 << 52) - 1
_ONE = 1023 << 52  # the exponent bits of 1.0
_SQRT2 = 0x3FF6A09E667F3BCD  # the bits of √2
_TINY = 2.2250738585072014e-308  # the smallest normal float64
_TWO54 = 18014398509481984.0  # 2⁵⁴: scales a subnormal x into the normal range
_LG1, _LG2, _LG3, _LG4, _LG5, _LG6, _LG7 = (  # fdlibm e_log.c: R(z) ≈ 2z/3 + 2z²/5 + … on z = s² ≤ 0.0295
    6.666666666666735130e-01, 3.999999999940941908e-01, 2.857142874366239149e-01, 2.222219843214978396e-01,
    1.818357216161805012e-01, 1.531383769920937332e-01, 1.479819860511658591e-01)


@hot(inline="always")
def _log_dd(x):
    """ln x for a finite x > 0 as a double-double (hi, lo), |lo| ≤ ulp(hi)."""
    sub = x < _TINY
    b = _bits(x * _TWO54 if sub else x)
    e = (b >> 52) - (1023 + 54 if sub else 1023)
    mb = (b & _MANTISSA) | _ONE  # m ∈ [1, 2)
    big = (mb > _SQRT2) * 1  # m > √2: m/2, e + 1
    mb -= big << 52
    e += big
    f = _from_bits(mb) - 1.0  # exact (Sterbenz)
    t = 2.0 + f
    tl = (2.0 - t) + f  # t + tl = 2 + f exactly (|f| < 2)
    inv = 1.0 / t
    s = f * inv
    sl = (_fma(-s, t, f) - s * tl) * inv  # s + sl = f / (2 + f) to ~1e-32 (s itself need not be rounded right)
    z = s * s
    w = z * z
    # 2 atanh(s) − 2s = s·R(z): fdlibm's minimax R (error < 2⁻⁵⁸·⁴⁵), in two halves for a shorter chain
    r = z * (_LG1 + w * (_LG3 + w * (_LG5 + w * _LG7))) + w * (_LG2 + w * (_LG4 + w * _LG6))
    dk = float(e)
    a = dk * _LN2_HI  # exact
    c = 2.0 * s
    hi = a + c
    err = (a - (hi - (hi - a))) + (c - (hi - a))  # TwoSum: hi + err = a + c exactly
    lo = err + (dk * _LN2_LO + 2.0 * sl + s * r)
    h2 = hi + lo
    return h2, lo - (h2 - hi)


@hot(inline="always")
def _exp_dd(p, pl):
    """exp(p + pl) for |pl| ≤ ulp(p); 0 below −746 and inf above 710 (p is clamped there)."""
    p = min(max(p, -746.0), 710.0)
    kf = (p * _INV_LN2 + _ROUND) - _ROUND
    r = (p - kf * _LN2_HI) - kf * _LN2_LO + pl
    r4 = (r * r) * (r * r)
    # exp(r) − 1 to r¹³ (truncation < 4e-18 at |r| = ln 2 / 2) in three short chains (r..r⁴, r⁵..r⁸, r⁹..r¹³)
    p1 = 1.0 + r * (1.0 / 2 + r * (1.0 / 6 + r * (1.0 / 24)))
    p2 = 1.0 / 120 + r * (1.0 / 720 + r * (1.0 / 5040 + r * (1.0 / 40320)))
    p3 = 1.0 / 362880 + r * (1.0 / 3628800 + r * (1.0 / 39916800 + r * (1.0 / 479001600 + r * (1.0 / 6227020800))))
    q = r * (p1 + r4 * (p2 + r4 * p3))
    k = int(kf)
    k1 = k >> 1  # 2ᵏ as 2^k1 · 2^k2: each factor normal for k down to −2044, so no subnormal scale is formed
    return ((1.0 + q) * _from_bits((k1 + 1023) << 52)) * _from_bits((k - k1 + 1023) << 52)


@hot(inline="always")
def exp_dd(x):
    """exp(x) [–] within 1 ulp of the C library's, branch-free (a loop of them vectorises); 0 below −746, inf
    above 710."""
    return _exp_dd(x, 0.0)


@hot(inline="always")
def pow_nonneg(x, y):
    """x^y [–] for x ≥ 0 (or NaN), as the C library's ``pow`` gives it to within 1 ulp; branch-free.

    Parameters
    ----------
    x : float
        The base, ≥ 0 (a magnitude: |z| of a hysteretic state); NaN propagates.
    y : float
        The exponent.

    Returns
    -------
    float
        x^y; 1 when y = 0 or x = 1 (also for NaN x or y, as C's pow), 0 or inf for x = 0 by the sign of y,
        inf or 0 for x = inf.
    """
    finite = (x > 0.0) & (x < 1.7976931348623157e308)
    lh, ll = _log_dd(x if finite else 1.0)
    p = y * lh
    v = _exp_dd(p, _fma(y, lh, -p) + y * ll)
    edge = 0.0 if (x == 0.0) == (y > 0.0) else 1.7976931348623157e308 * 2.0  # x = 0 or inf: 0 or inf
    v = v if finite else (edge if x == x else x)
    return 1.0 if (y == 0.0) | (x == 1.0) else v


@hot
def point_powers(lay, TH, X, K1, stages, st, step, n_pts, taken, pw):
    """pw[0, i] ← |z|ⁿ of point i's RK4 stage ``st`` state ((iz, ip) = :func:`power_slot`, n = TH[i, ip]) for
    every point not ``taken``, all in one loop the compiler vectorises; -1 for a form without a power.

    The stage state's z is X[i, iz] (st 0) or X[i, iz] + step·k[iz] with k = K1[i] (st 1) or stages[i, st − 2],
    formed as :func:`~bayes_mr.models.integrate.advance_points` forms it (the same operations, so the same bits).
    ``pw`` is scratch (3, n_pad), n_pad ≥ n_pts a multiple of the vector width (8): rows 1 and 2 hold the
    bases and exponents, row 0 the powers; the padding's entries are 1¹.
    """
    iz, ip = power_slot(lay)
    if iz < 0:
        for i in range(n_pts):
            pw[0, i] = -1.0
        return
    for i in range(pw.shape[1]):
        b = 1.0
        e = 1.0
        if i < n_pts and not taken[i]:
            if st == 0:
                b = abs(X[i, iz])
            else:
                b = abs(X[i, iz] + step * (K1[i, iz] if st == 1 else stages[i, st - 2, iz]))
            e = TH[i, ip]
        pw[1, i] = b
        pw[2, i] = e
    for i in range(pw.shape[1]):
        pw[0, i] = pow_nonneg(pw[1, i], pw[2, i])
