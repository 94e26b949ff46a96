"""The vectorisable power and exponential (models.power.pow_nonneg, exp_dd) against the C library's, and vectorised
they are."""

import math
import re

import numpy as np
import pytest
from numba import njit

from bayes_mr.models.power import exp_dd, pow_nonneg


@njit(error_model="numpy")
def _ours(x, y, out):
    for i in range(x.shape[0]):
        out[i] = pow_nonneg(x[i], y[i])


@njit(error_model="numpy")
def _libm(x, y, out):
    for i in range(x.shape[0]):
        out[i] = math.pow(x[i], y[i])


def _both(x, y):
    ours, ref = np.empty_like(x), np.empty_like(x)
    _ours(x, y, ours)
    _libm(x, y, ref)
    return ours, ref


_RNG = np.random.default_rng(20261129)
_N = 200_000
CASES = {
    "hysteretic |z| and n": (10.0 ** _RNG.uniform(-6, 0.5, _N), _RNG.uniform(0.3, 4.0, _N)),
    "wide range": (10.0 ** _RNG.uniform(-300, 10, _N), _RNG.uniform(0.05, 8.0, _N)),
    "near 1, either sign of y": (_RNG.uniform(0.5, 2.0, _N), _RNG.uniform(-8.0, 8.0, _N)),
    "1 + 1e-9 noise": (1.0 + 1e-9 * _RNG.standard_normal(_N), _RNG.uniform(0.5, 3.0, _N)),
    "integer y": (10.0 ** _RNG.uniform(-5, 5, _N), np.round(_RNG.uniform(-4, 4, _N))),
    "subnormal x": (_RNG.uniform(1e-320, 1e-308, _N), _RNG.uniform(0.1, 1.0, _N)),
    "overflowing result": (10.0 ** _RNG.uniform(100, 300, _N), _RNG.uniform(1.0, 8.0, _N)),
    "underflowing result": (10.0 ** _RNG.uniform(-300, -30, _N), _RNG.uniform(2.0, 30.0, _N)),
}


@pytest.mark.parametrize("case", CASES)
def test_within_one_ulp_of_the_c_library(case):
    """≤ 1 ulp from the C library's pow on every draw (most equal), and the same zeros and infinities."""
    x, y = CASES[case]
    ours, ref = _both(x, y)
    normal = np.isfinite(ref) & (ref != 0.0)
    np.testing.assert_array_equal(ours[~normal], ref[~normal])
    ulp = np.abs(ours[normal] - ref[normal]) / np.spacing(np.abs(ref[normal]))
    assert ulp.max() <= 1.0, f"{case}: {ulp.max():.2f} ulp"
    assert np.mean(ulp == 0.0) > 0.8


def test_special_values_as_the_c_library():
    """0, inf, NaN and 1 as bases, 0 and ±inf as exponents, and a subnormal result: C's pow's answers."""
    x = np.array([0.0, 0.0, 0.0, np.inf, np.inf, np.inf, np.nan, np.nan, 1.0, 1.0, 2.0, 0.5, 2.0 ** -1074, 1e-300])
    y = np.array([1.5, -1.5, 0.0, 2.0, -2.0, 0.0, 2.0, 0.0, np.inf, np.nan, 0.0, 1074.0, 0.5, 1.05])
    ours, ref = _both(x, y)
    np.testing.assert_array_equal(ours, ref)


def test_a_loop_of_powers_compiles_to_vector_instructions():
    """The point of the function: LLVM vectorises a loop of calls (packed double instructions, no call into libm).

    Checked on the machine code of ``_ours``: at least SSE2's packed form (``pd`` on xmm/ymm/zmm registers) of
    the FMA-free core operations, and no call to ``pow``."""
    x, y = CASES["hysteretic |z| and n"]
    _both(x[:8], y[:8])
    asm = _ours.inspect_asm(_ours.signatures[0])
    assert not re.search(r"[\s$*]pow\b", asm), "the loop calls the C library's pow"
    assert any(op in asm for op in ("vmulpd", "mulpd")), "the loop was not vectorised"


@njit(error_model="numpy")
def _exp_ours(x, out):
    for i in range(x.shape[0]):
        out[i] = exp_dd(x[i])


@njit(error_model="numpy")
def _exp_libm(x, out):
    for i in range(x.shape[0]):
        out[i] = math.exp(x[i])


@pytest.mark.parametrize("lo, hi", [(-1.0, 1.0), (-40.0, 40.0), (-745.0, 709.0)])
def test_exp_within_one_ulp_of_the_c_library(lo, hi):
    """exp_dd (the UKF's sigma-point parameters, unscented_kernel.sigma_thetas) ≤ 1 ulp from the C library's exp,
    most equal, over the deviations of a log parameter (|d| ≤ 1), a wide range and the whole finite range."""
    x = _RNG.uniform(lo, hi, _N)
    ours, ref = np.empty_like(x), np.empty_like(x)
    _exp_ours(x, ours)
    _exp_libm(x, ref)
    normal = ref >= np.finfo(float).tiny
    ulp = np.abs(ours[normal] - ref[normal]) / np.spacing(ref[normal])
    assert ulp.max() <= 1.0, f"[{lo}, {hi}]: {ulp.max():.2f} ulp"
    assert np.mean(ulp == 0.0) > 0.8
    np.testing.assert_allclose(ours[~normal], ref[~normal], rtol=1e-12, atol=1e-320)  # subnormal results


def test_exp_limits_and_a_vectorised_loop():
    """0 below the underflow, inf above the overflow, exp(0) = 1; a loop of them uses packed instructions."""
    x = np.array([-800.0, -746.5, 0.0, 710.5, 800.0, -np.inf, np.inf])
    ours = np.empty_like(x)
    _exp_ours(x, ours)
    np.testing.assert_array_equal(ours, [0.0, 0.0, 1.0, np.inf, np.inf, 0.0, np.inf])
    asm = _exp_ours.inspect_asm(_exp_ours.signatures[0])
    assert not re.search(r"[\s$*]exp\b", asm), "the loop calls the C library's exp"
    assert any(op in asm for op in ("vmulpd", "mulpd")), "the loop was not vectorised"
