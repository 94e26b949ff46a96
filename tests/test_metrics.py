"""Thesis metrics (eqs. 3-44 … 3-49) on small hand-computed cases."""

from __future__ import annotations

import numpy as np
import pytest

from bayes_mr.scores import force_errors, force_nrmse, mse

# displacement errors 0, 0, 0, 1; acceleration errors 0, 2, 0, 0
X = np.array([1.0, 2.0, 3.0, 4.0])
X_HAT = np.array([1.0, 2.0, 3.0, 5.0])
A = np.zeros(4)
A_HAT = np.array([0.0, 2.0, 0.0, 0.0])

# force errors e = 1, 0, 0, −2; mean f_exp = 0, σ_f² = (1 + 1 + 9 + 9)/4 = 5
F_EXP = np.array([1.0, -1.0, 3.0, -3.0])
F_PRE = np.array([0.0, -1.0, 3.0, -1.0])
XDOT = np.array([4.0, 7.0, 9.0, -1.0])
XDDOT = np.array([-9.0, 1.0, 1.0, 0.25])
MASK = np.array([True, True, True, False])


def test_mse_by_hand():
    # σ_d² = 0.25, σ_a² = 4: Σ = 1/0.25 + 4/4 = 5 → 100/4 · 5 = 125
    assert mse(X, X_HAT, A, A_HAT, sigma_d=0.5, sigma_a=2.0) == pytest.approx(125.0, rel=1e-15)
    # last sample masked: Σ = 4/4 = 1, N = 3 → 100/3
    assert mse(X, X_HAT, A, A_HAT, 0.5, 2.0, valid=MASK) == pytest.approx(100.0 / 3.0, rel=1e-15)


def test_mse_of_pure_noise_is_about_200():
    rng = np.random.default_rng(0)
    n = 200_000
    x, a = rng.normal(0, 1e-3, n), rng.normal(0, 1e-3, n)
    score = mse(x, x + rng.normal(0, 2e-5, n), a, a + rng.normal(0, 0.3, n), 2e-5, 0.3)
    assert score == pytest.approx(200.0, rel=0.01)


def test_force_errors_by_hand():
    e = force_errors(F_EXP, F_PRE, XDOT, XDDOT)
    # ε_t² = (1 + 4)/4 = 1.25 → E_t = √(1.25/5) = 0.5
    assert e["E_t"] == pytest.approx(0.5, rel=1e-15)
    # ε_x² = (1·4 + 4·1)/4 = 2 → E_x = √(2/5)
    assert e["E_x"] == pytest.approx(np.sqrt(0.4), rel=1e-15)
    # ε_ẋ² = (1·9 + 4·0.25)/4 = 2.5 → E_ẋ = √(2.5/5)
    assert e["E_xdot"] == pytest.approx(np.sqrt(0.5), rel=1e-15)
    assert set(e) == {"E_t", "E_x", "E_xdot"}


def test_force_errors_with_mask():
    # valid f_exp = 1, −1, 3: mean 1, σ_f² = (0 + 4 + 4)/3 = 8/3; e² = 1, 0, 0
    e = force_errors(F_EXP, F_PRE, XDOT, XDDOT, valid=MASK)
    assert e["E_t"] == pytest.approx(np.sqrt((1 / 3) / (8 / 3)), rel=1e-14)
    assert e["E_x"] == pytest.approx(np.sqrt((4 / 3) / (8 / 3)), rel=1e-14)
    assert e["E_xdot"] == pytest.approx(np.sqrt((9 / 3) / (8 / 3)), rel=1e-14)


def test_force_nrmse_by_hand():
    assert force_nrmse(F_EXP, F_PRE) == pytest.approx(0.5, rel=1e-15)
    assert force_nrmse(F_EXP, F_PRE) == pytest.approx(force_errors(F_EXP, F_PRE, XDOT, XDDOT)["E_t"])
    assert force_nrmse(F_EXP, np.zeros(4)) == pytest.approx(1.0)  # the mean force scores 1
    assert force_nrmse(F_EXP, F_EXP) == 0.0
    assert force_nrmse(F_EXP, F_PRE, valid=MASK) == pytest.approx(np.sqrt(1 / 8), rel=1e-14)


def test_masked_samples_may_hold_nan():
    bad = F_PRE.copy()
    bad[3] = np.nan
    assert force_nrmse(F_EXP, bad, valid=MASK) == pytest.approx(np.sqrt(1 / 8), rel=1e-14)
    x_hat = X_HAT.copy()
    x_hat[3] = np.inf
    assert mse(X, x_hat, A, A_HAT, 0.5, 2.0, valid=MASK) == pytest.approx(100.0 / 3.0)


def test_errors():
    with pytest.raises(ValueError, match="shape mismatch"):
        mse(X, X_HAT[:3], A, A_HAT, 1.0, 1.0)
    with pytest.raises(ValueError, match="shape mismatch"):
        force_errors(F_EXP, F_PRE, XDOT, XDDOT, valid=MASK[:3])
    with pytest.raises(ValueError, match="1-D"):
        force_nrmse(np.ones((2, 2)), np.ones((2, 2)))
    with pytest.raises(ValueError, match="non-finite valid samples .*index 1"):
        force_nrmse(F_EXP, np.array([0.0, np.nan, 0.0, 0.0]))
    with pytest.raises(ValueError, match="x_hat"):
        mse(X, np.array([np.nan, 2, 3, 4]), A, A_HAT, 1.0, 1.0)
    with pytest.raises(ValueError, match="sigma_d"):
        mse(X, X_HAT, A, A_HAT, 0.0, 1.0)
    with pytest.raises(ValueError, match="sigma_a"):
        mse(X, X_HAT, A, A_HAT, 1.0, np.nan)
    with pytest.raises(ValueError, match="no valid samples"):
        force_nrmse(F_EXP, F_PRE, valid=np.zeros(4, bool))
    with pytest.raises(ValueError, match="boolean"):
        force_nrmse(F_EXP, F_PRE, valid=np.ones(4))
    with pytest.raises(ValueError, match="constant"):
        force_errors(np.ones(4), F_PRE, XDOT, XDDOT)
    with pytest.raises(ValueError, match="constant"):
        force_nrmse(F_EXP, F_PRE, valid=np.array([True, False, False, False]))
