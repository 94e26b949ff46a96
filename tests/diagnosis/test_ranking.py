"""Which passing effect explains the record: ranking by the log-likelihood added, and ambiguity by Vuong's test."""

import math

import numpy as np
import pytest

from bayes_mr.diagnosis import ranking
from bayes_mr.diagnosis.screen import Candidate
from bayes_mr.models import EFFECTS


def _candidate(name, *, score, dll, kappa, mse_ratio, fit=object()):
    return Candidate(name, EFFECTS[name], fit, score, kappa=kappa, delta_loglik=dll, mse_ratio=mse_ratio)


def test_passing_candidates_are_ranked_by_what_they_explain_not_by_their_own_kappa():
    """A candidate that removes 90 % of the residual ranks above one that removes 13 %, however the κ each
    estimated for itself moved their significance scores."""
    narrow = _candidate("shear_thinning", score=408.0, dll=416.0, kappa=1.0, mse_ratio=0.874)
    broad = _candidate("small_amplitude_regime", score=184.0, dll=6833.0, kappa=35.6, mse_ratio=0.095)
    weak = _candidate("cubic_stiffness", score=18.0, dll=1172.0, kappa=54.7, mse_ratio=0.631)
    failed = _candidate("force_offset", score=-math.inf, dll=0.0, kappa=1.0, mse_ratio=1.0, fit=None)
    below = _candidate("asymmetry", score=3.0, dll=900.0, kappa=300.0, mse_ratio=0.7)
    order = ranking.rank([narrow, failed, below, weak, broad], threshold=8.0)
    assert [c.name for c in order] == ["small_amplitude_regime", "cubic_stiffness", "shear_thinning", "asymmetry",
                                       "force_offset"]


@pytest.mark.parametrize("phi", [0.0, 0.6])
def test_the_long_run_variance_is_that_of_an_ar1_mean(phi):
    """Var(Σ d_t)/N → σ²/(1 − φ)² for AR(1) innovations of variance σ² (here σ = 1)."""
    n = 40000
    values = []
    for seed in range(5):
        e = np.random.default_rng(seed).standard_normal(n)
        d = np.empty(n)
        d[0] = e[0]
        for t in range(1, n):
            d[t] = phi * d[t - 1] + e[t]
        values.append(ranking.long_run_variance(d))
    assert np.mean(values) == pytest.approx(1.0 / (1.0 - phi) ** 2, rel=0.15)


class _Lik:
    """A likelihood of two channels whose pointwise density is iid Gaussian (what ranking.pointwise reads)."""

    channels = ("displacement", "acceleration")

    def __init__(self, y):
        self.y = y
        self.valid = np.ones(len(y), bool)

    def log_density(self, yhat, sigma, ok, *, pointwise=False):
        r = (self.y[None] - yhat) / sigma[:, None, :]
        terms = -0.5 * r * r - np.log(sigma)[:, None, :] - 0.5 * math.log(2 * math.pi)
        return terms.sum(axis=(1, 2)), terms


class _Result:
    def __init__(self, sigma):
        self.sigma = np.asarray(sigma, float)


class _Fit:
    def __init__(self, lik, yhat):
        self.lik = lik
        self.predicted = {c: yhat[:, j] for j, c in enumerate(lik.channels)}
        self.result = _Result(np.sqrt(np.mean((lik.y - yhat) ** 2, axis=0)))


def test_two_fits_the_record_cannot_tell_apart_are_ambiguous_and_a_clear_winner_is_not():
    rng = np.random.default_rng(3)
    n = 4000
    truth = np.column_stack([np.sin(np.arange(n) / 40.0), np.cos(np.arange(n) / 25.0)])
    lik = _Lik(truth + 0.1 * rng.standard_normal((n, 2)))
    good = _Fit(lik, truth)
    twin = _Fit(lik, truth + 0.002 * rng.standard_normal((n, 2)))  # as good, within the noise of the test
    poor = _Fit(lik, truth + 0.05 * np.sin(np.arange(n) / 7.0)[:, None])
    tie = ranking.compare_fits(good, twin)
    clear = ranking.compare_fits(good, poor)
    assert abs(tie["z"]) < ranking.Z_AMBIGUOUS
    assert clear["z"] > 10 and clear["difference"] > 0
    assert ranking.compare_fits(poor, good)["z"] == pytest.approx(-clear["z"])
