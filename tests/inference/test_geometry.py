"""What makes a chain slow (inference.geometry): coordinates spread over their prior, ridges, slowest τ."""

import numpy as np

from bayes_mr.inference.mcmc.geometry import RIDGE_CORRELATION, SPREAD_FRACTION, chain_geometry
from bayes_mr.inference.mcmc.settings import MCMCSettings
from bayes_mr.inference.mcmc.sampler import sample

NAMES = ("a", "b", "c", "d")
LOWER, UPPER = np.full(4, -10.0), np.full(4, 10.0)


def _chain(x, walkers=20):
    """(n_steps, walkers, d) from draws (n, d)."""
    return x.reshape(-1, walkers, x.shape[1])


def test_an_informed_posterior_shows_no_spread_and_no_ridge():
    """Independent N(0, 1) coordinates in a box of ±10: each spans ~4.7 of 20 (0.23) and correlates ~0."""
    x = np.random.default_rng(0).standard_normal((4000, 4))
    g = chain_geometry(_chain(x), LOWER, UPPER, NAMES, np.array([2.0, 5.0, np.nan, 3.0]))
    assert g == {"slowest": [["b", 5.0], ["d", 3.0], ["a", 2.0]], "spread_over_prior": {}, "ridges": []}


def test_a_flat_coordinate_and_a_ridge_are_named_on_either_side_of_the_thresholds():
    rng = np.random.default_rng(1)
    n = 4000
    flat = rng.uniform(-10.0, 10.0, n)  # the record says nothing: 0.98 of the range
    half = rng.uniform(-4.0, 4.0, n)  # 0.4 of the range × 0.98: below SPREAD_FRACTION
    u = rng.standard_normal(n)
    ridge = -u + 0.1 * rng.standard_normal(n)  # correlation −0.995 with u
    x = np.column_stack([flat, half, u, ridge])
    g = chain_geometry(_chain(x), LOWER, UPPER, NAMES, np.ones(4))
    assert list(g["spread_over_prior"]) == ["a"] and g["spread_over_prior"]["a"] > 0.95
    (a, b, r), = g["ridges"]
    assert (a, b) == ("c", "d") and r < -0.99
    # just under the thresholds: nothing
    weak = np.column_stack([flat * (SPREAD_FRACTION - 0.05), half, u, -u + 0.5 * rng.standard_normal(n)])
    assert np.corrcoef(weak[:, 2], weak[:, 3])[0, 1] > -RIDGE_CORRELATION
    g = chain_geometry(_chain(weak), LOWER, UPPER, NAMES, np.ones(4))
    assert g["spread_over_prior"] == {} and g["ridges"] == []


def test_a_coordinate_that_never_moved_and_a_chain_of_one_draw_are_handled():
    x = np.random.default_rng(2).standard_normal((400, 4))
    x[:, 1] = 3.0
    g = chain_geometry(_chain(x), LOWER, UPPER, NAMES, np.ones(4))
    assert g["ridges"] == [] and g["spread_over_prior"] == {}
    assert chain_geometry(x[:1, None, :], LOWER, UPPER, NAMES, np.ones(4))["ridges"] == []


def test_the_sampler_s_own_chain_shows_a_flat_coordinate_and_a_ridge():
    """emcee on a target the data inform in one coordinate, leave flat in a second (uniform in its box) and fix
    only the difference of two others (correlation 0.995): the geometry of the chain names exactly those."""
    lower, upper = np.array([-5.0, -5.0, -5.0, -5.0]), np.array([5.0, 5.0, 5.0, 5.0])
    cov = np.array([[1.0, 0.995], [0.995, 1.0]])
    prec = np.linalg.inv(cov)

    def log_prob(X):
        X = np.atleast_2d(X)
        inside = np.all((X >= lower) & (X <= upper), axis=1)
        r = X[:, 2:]
        lp = -0.5 * (X[:, 0] / 0.2) ** 2 - 0.5 * np.einsum("bi,ij,bj->b", r, prec, r)
        return np.where(inside, lp, -np.inf)

    res = sample(log_prob, np.zeros(4), 0.1 * np.eye(4), MCMCSettings(seed=3, progress=False, max_steps=1500),
                 bounds=(lower, upper))
    g = chain_geometry(res.chain[res.burn:], lower, upper, NAMES, res.tau)
    assert list(g["spread_over_prior"]) == ["b"]
    assert [(a, b) for a, b, _ in g["ridges"]] == [("c", "d")] and g["ridges"][0][2] > 0.98
