"""The AR residual model: its conditional density, its order choice, and least squares under it."""

import numpy as np
import pytest
from scipy.linalg import toeplitz
from scipy.signal import lfilter
from scipy.stats import multivariate_normal, norm

from bayes_mr.likelihood import noise_model as nm


def _ar_autocovariance(a: np.ndarray, s2: float, n: int) -> np.ndarray:
    """γ_0..γ_{n−1} of a stationary AR process (long impulse response)."""
    psi = lfilter([1.0], np.r_[1.0, -a], np.r_[1.0, np.zeros(20000)])
    return s2 * np.array([np.dot(psi[: psi.size - k], psi[k:]) for k in range(n)])


@pytest.mark.parametrize("a", [np.array([0.7]), np.array([0.5, -0.3])])
def test_conditional_density_equals_the_gaussian_of_the_ar_covariance_given_the_first_p(a):
    """ln p(e_{p+1..n} | e_{1..p}) from the prewhitening equals the multivariate normal with the
    AR's Toeplitz covariance, conditioned on the first p samples (joint minus marginal)."""
    p, n, s = a.size, 12, 0.3
    rng = np.random.default_rng(1)
    e = lfilter([1.0], np.r_[1.0, -a], s * rng.standard_normal(n + 200))[200:]
    # the density at given coefficients: whiten with a, then the innovations' normal terms
    X = np.column_stack([np.r_[np.zeros(k + 1), e[: n - k - 1]] for k in range(p)])
    w = (e - X @ a)[p:]
    by_whitening = norm.logpdf(w, 0.0, s).sum()
    gamma = _ar_autocovariance(a, s * s, n)
    joint = multivariate_normal(np.zeros(n), toeplitz(gamma)).logpdf(e)
    first = multivariate_normal(np.zeros(p), toeplitz(gamma[:p])).logpdf(e[:p])
    assert by_whitening == pytest.approx(joint - first, rel=1e-9)
    # and the module's density at the profiled coefficients is the same formula at them
    valid = np.ones(n, bool)
    w_mod, a_hat, _, use = nm.profile(e[None], valid, p)
    assert use.sum() == n - p and np.all(w_mod[0, ~use] == 0)
    direct = norm.logpdf((e - X @ a_hat[0])[p:], 0.0, s).sum()
    total = nm.log_density(e[None, :, None], np.array([[s]]), valid, (p,))[0]
    assert total == pytest.approx(direct, rel=1e-12)


def test_the_recursion_restarts_after_a_masked_gap():
    rng = np.random.default_rng(2)
    e = rng.standard_normal(40)
    valid = np.ones(40, bool)
    valid[15:18] = False
    use = nm.usable(valid, 2)
    # conditioned on: the first 2 of each run; never a lag inside the gap
    assert not use[:2].any() and use[2:15].all() and not use[15:20].any() and use[20:].all()
    w, a, _, _ = nm.profile(e[None], valid, 2)
    e_gap = e.copy()
    e_gap[15:18] = 1e6  # a masked sample may hold anything
    w2, a2, _, _ = nm.profile(e_gap[None], valid, 2)
    np.testing.assert_allclose(w2, w)
    np.testing.assert_allclose(a2, a)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_bic_picks_zero_on_white_and_at_least_one_on_ar1_residuals(seed):
    rng = np.random.default_rng(seed)
    valid = np.ones(3000, bool)
    white = rng.standard_normal(3000)
    ar1 = lfilter([1.0], [1.0, -0.6], rng.standard_normal(3000))
    assert nm.select_order(white, valid) == 0
    assert nm.select_order(ar1, valid) >= 1


def test_effective_samples_of_an_ar1_is_the_textbook_formula():
    n, a = 5000, 0.8
    assert nm.effective_samples([np.array([a])], np.array([n]))[0] == pytest.approx(n * (1 - a) / (1 + a), rel=1e-6)
    assert nm.effective_samples([np.zeros(0)], np.array([n]))[0] == n


def test_the_iid_likelihood_is_unchanged_and_ar_with_order_zero_equals_it(masked_record):
    from bayes_mr.likelihood.output_error import OutputError
    from bayes_mr.likelihood.noise_model import ResidualModel

    iid = OutputError("dahl", masked_record)
    ar0 = OutputError("dahl", masked_record, residual=ResidualModel("ar", (0, 0)))
    x = ((iid.lower + iid.upper) / 2)[None]
    assert ar0(x)[0] == pytest.approx(iid(x)[0], rel=1e-12)
    assert OutputError("dahl", masked_record, residual="ar").residual.label() == "ar"
    with pytest.raises(ValueError, match="not chosen"):
        OutputError("dahl", masked_record, residual="ar")(x)


@pytest.fixture(scope="module")
def masked_record():
    from records import masked_structure_record

    return masked_structure_record()
