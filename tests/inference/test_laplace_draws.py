"""Laplace posterior draws are the Gaussian truncated to the prior box, not clipped onto it."""

import numpy as np
from scipy import stats

from bayes_mr.inference.base import laplace_draws


def test_draws_are_truncated_not_clipped():
    """A Gaussian centred on a bound: no draw piles up on it, and the mean is the truncated normal's."""
    rng = np.random.default_rng(0)
    draws, clipped = laplace_draws(np.array([0.0, 5.0]), np.diag([1.0, 0.01]), np.array([0.0, 0.0]),
                                   np.array([10.0, 10.0]), 4000, rng)
    assert clipped == 0 and draws.shape == (4000, 2)
    assert np.all(draws[:, 0] > 0.0)  # clipping would put ~half of them at exactly 0
    mean = stats.truncnorm(0.0, np.inf).mean()  # √(2/π)
    assert abs(draws[:, 0].mean() - mean) < 4 * draws[:, 0].std() / np.sqrt(4000)


def test_inside_the_box_the_draws_are_the_plain_gaussian():
    """When the box holds the Gaussian, the draws are those of one multivariate_normal call (same stream)."""
    phi, cov = np.array([1.0, 2.0]), np.array([[0.01, 0.002], [0.002, 0.02]])
    draws, clipped = laplace_draws(phi, cov, phi - 10, phi + 10, 500, np.random.default_rng(3))
    plain = np.random.default_rng(3).multivariate_normal(phi, cov, size=500, method="eigh")
    assert clipped == 0 and np.array_equal(draws, plain)


def test_a_box_without_mass_falls_back_to_clipping_and_says_so():
    draws, clipped = laplace_draws(np.array([50.0]), np.array([[1.0]]), np.array([0.0]), np.array([1.0]), 10,
                                   np.random.default_rng(1), max_rounds=3)
    assert clipped == 10 and np.all(draws == 1.0)
