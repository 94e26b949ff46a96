"""The output-error likelihood: its summed form equals the per-sample Gaussian terms, masked samples excluded."""

import numpy as np
import pytest
from scipy.stats import norm

from bayes_mr.likelihood.output_error import OutputError
from records import masked_structure_record


@pytest.fixture(scope="module")
def masked_record():
    rec = masked_structure_record()
    rec["displacement"].values[60] = np.nan  # a masked sample may hold anything
    return rec


@pytest.mark.parametrize("noise", ["sampled", "fixed"])
def test_total_equals_the_sum_of_gaussian_terms_over_valid_samples(masked_record, noise):
    lik = OutputError("dahl", masked_record, noise=noise)
    rng = np.random.default_rng(0)
    x = (lik.lower + (lik.upper - lik.lower) * rng.uniform(0.3, 0.7, (5, lik.ndim)))
    total = lik.log_likelihood(x)
    total_pw, terms = lik.log_likelihood(x, pointwise=True)
    np.testing.assert_allclose(total, total_pw, rtol=1e-10)
    np.testing.assert_allclose(total, terms.sum(axis=(1, 2)), rtol=1e-10)
    # by hand, with scipy's normal density, for the first draw
    phi, sigma = lik.split(x[:1])
    yhat, _ = lik.predict(phi)
    v = lik.valid
    by_hand = sum(norm.logpdf(lik.y[v, c], yhat[0, v, c], sigma[0, c]).sum() for c in range(len(lik.channels)))
    assert total[0] == pytest.approx(by_hand, rel=1e-10)
    assert np.all(terms[:, ~v, :] == 0.0)


def test_outside_the_support_is_minus_inf_and_a_nan_parameter_is_an_error(masked_record):
    lik = OutputError("dahl", masked_record)
    assert np.isfinite(lik((lik.lower + lik.upper)[None] / 2)[0])
    with pytest.raises(ValueError, match="non-finite"):
        lik(np.full((1, lik.ndim), np.nan))
    assert lik(lik.upper[None] + 1.0)[0] == -np.inf
