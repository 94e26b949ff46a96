"""The independence proposal's tails: the settings reach the move, q is the normalised t₂₀ + t₄ mixture, a
target heavier tailed than q is sampled exactly, the defensive t₄ bounds the importance weights' tail, and a chain
whose proposals' importance weights have a heavy tail is not called converged."""

import numpy as np
import pytest
from scipy import stats

from bayes_mr.inference.mcmc.convergence import TAIL_MIN_DRAWS, tail_bound, tail_index
from bayes_mr.inference.mcmc.settings import MCMCSettings
from bayes_mr.inference.mcmc.sampler import sample
from bayes_mr.inference.mcmc.moves import DEFENSIVE_DF, DEFENSIVE_SHARE, PROPOSAL_DF, Independence
from inference.test_shear import B, log_banana

NU = 3.0  # the target's degrees of freedom: heavier tailed than any proposal the sampler fits
SD = np.sqrt([1.0, 4.0, 0.1])
SCALE = np.array([[1.0, 0.6, 0.0], [0.6, 1.0, 0.3], [0.0, 0.3, 1.0]]) * np.outer(SD, SD)
PREC = np.linalg.inv(SCALE)


def log_t3(X):
    """A correlated 3-d Student t with ν = 3 (scale matrix SCALE, centred at 0)."""
    X = np.atleast_2d(X)
    q = np.einsum("ij,jk,ik->i", X, PREC, X)
    return -0.5 * (NU + 3) * np.log1p(q / NU)


def test_the_settings_reach_the_independence_move():
    """``MCMCSettings.proposal_df`` and ``defensive_share`` make the move's mixture (default
    :data:`PROPOSAL_DF` with :data:`DEFENSIVE_SHARE` of t₄)."""
    proposal = (np.zeros(2), np.eye(2))
    cases = ((MCMCSettings(), ((1 - DEFENSIVE_SHARE, PROPOSAL_DF), (DEFENSIVE_SHARE, DEFENSIVE_DF))),
             (MCMCSettings(proposal_df=4.0, defensive_share=0.0), ((1.0, 4.0),)))
    for settings, components in cases:
        move = next(m for m, _ in settings.make_moves(proposal) if isinstance(m, Independence))
        assert move.components == components


def test_a_heavy_tailed_target_is_sampled_exactly_with_the_default_proposal():
    """The default sampler (pilot, adaptation rounds, chain; ν = 20 against the target's 3) keeps the target's
    tails: every coordinate's share of draws beyond 3 scale units (about 5.8 % for a t₃) and its median are
    within Monte Carlo error of the exact values. Where q's tails are lighter than the target's a walker out
    there is rarely moved by q: it is held there, a weighted visit, so the chain stays exact (only slower; the
    weights' Pareto tail is k = 1/4 against the defensive t₄, well inside the chain's tail bound). Measured,
    seeds 4-6: shares 0.051-0.069 against 0.058 (3 SD: 0.016-0.022); mutation: without the move's Hastings factor
    q(x)/q(x') the shares fall to 0-0.002."""
    res = sample(log_t3, np.zeros(3), SCALE, MCMCSettings(seed=4, progress=False))
    assert res.converged, (res.tau, res.rhat)
    post = res.chain[res.burn:] / SD  # (steps, walkers, d) in scale units
    share = np.mean(np.abs(post) > 3.0, axis=(0, 1))
    exact = 2 * stats.t.sf(3.0, NU)
    # MC error of a share: binomial SD over the effective sample size of the chain
    ess = post.shape[0] * post.shape[1] / np.max(res.tau)
    assert np.all(np.abs(share - exact) < 3 * np.sqrt(exact * (1 - exact) / ess)), (share, exact, ess)
    assert np.all(np.abs(np.median(post, axis=(0, 1))) < 3 * np.sqrt(np.pi / 2 / ess)), np.median(post, axis=(0, 1))


def test_the_defensive_mixture_is_the_normalised_mixture_of_two_ts():
    """ln q of the move is ln((1 − ε) t_ν + ε t₄) up to one constant (scipy's multivariate t), and its draws
    have that mixture's share beyond a radius; a wrong weight or an unnormalised component fails both."""
    mean, cov = np.array([0.5, -1.0, 2.0]), SCALE
    move = Independence(mean, cov, df=20.0, defensive=0.2)
    x = np.random.default_rng(0).standard_normal((200, 3)) * 3.0 + mean
    exact = np.logaddexp(np.log(0.8) + stats.multivariate_t(mean, cov, df=20.0).logpdf(x),
                         np.log(0.2) + stats.multivariate_t(mean, cov, df=4.0).logpdf(x))
    diff = move.log_density(x) - exact
    assert np.ptp(diff) < 1e-9, np.ptp(diff)
    draws = move._draw(200_000, np.random.RandomState(1))
    r2 = np.einsum("ij,jk,ik->i", draws - mean, PREC, draws - mean)
    share = np.mean(r2 > 16.0)  # beyond Mahalanobis radius 4: F(3, ν)·3 tails of each component
    want = 0.8 * stats.f.sf(16.0 / 3, 3, 20.0) + 0.2 * stats.f.sf(16.0 / 3, 3, 4.0)
    assert abs(share - want) < 4 * np.sqrt(want / 200_000), (share, want)


def _banana(seed, **kw):
    """The default sampler on the banana of ``test_shear`` (a tail along the parabola that the fitted map does not
    fully straighten), and its means' errors in Monte Carlo standard errors."""
    res = sample(log_banana, np.array([0.0, B]), np.eye(2) * 0.1, MCMCSettings(seed=seed, progress=False, **kw))
    return res, (res.mean() - np.array([0.0, B])) / res.mcse()


def test_the_defensive_component_bounds_the_weights_of_a_heavier_tailed_target():
    """Against the t₃ target the importance weights p/q of t₂₀ alone grow as |x|¹⁷ where q's draws thin as
    |x|⁻²⁰: a Pareto tail k = 17/20 = 0.85, beyond the chain's tail bound (0.7), so such a chain would stop on
    q's tails (or, shorter, stick where q underweights p). With the defensive t₄ share the weights grow as |x|
    where q thins as |x|⁻⁴: k = 1/4. Measured on 200 000 draws of q, seeds 0-4 (k̂ is biased low at finite n):
    t₂₀ alone 0.64-0.77, with the default share −0.01 to 0.13. A proposal without the t₄, or one whose t₄ is
    not in its density, fails. (Whole chains on the banana of ``test_shear`` do not separate the two: over seeds
    0-29, both call 2-3 chains converged with means over 8 MCSE off — the rule's blind spot on a target's
    unvisited tail.)"""
    for seed in range(5):
        k = {}
        for share in (DEFENSIVE_SHARE, 0.0):
            move = Independence(np.zeros(3), SCALE, df=PROPOSAL_DF, defensive=share)
            x = move._draw(200_000, np.random.RandomState(seed))
            k[share], _ = tail_index([log_t3(x) - move.log_density(x)])
        assert k[DEFENSIVE_SHARE] < 0.3 and k[0.0] > 0.5, (seed, k)


def test_a_chain_whose_proposal_underweights_the_target_is_not_converged():
    """The two of ten default banana chains that met τ and R-hat with means 10 and 12 MCSE off (seeds 1 and 8)
    are the two whose proposals' importance weights have a Pareto k̂ above 0.7 (0.72 and 1.3; the other eight
    −0.04 to 0.48): seed 8's chain stops on q's tails, unconverged, and says so."""
    res, _ = _banana(8, max_steps=3000)
    assert res.stopped == "q_tails" and not res.converged and res.pareto_k > 0.7, (res.stopped, res.pareto_k)
    assert res.history[-1]["pareto_k"] == res.pareto_k and res.history[-1]["tau_max"] * 50 < res.n_steps


def test_the_tail_index_of_gaussian_importance_weights():
    """Weights p/q of N(0, 3²) against q = N(0, 1) have a Pareto tail of shape k = 1 − 1/9 = 0.89 (above every
    bound: flagged; estimated 0.80 from these 4000 draws: k̂ is biased low at finite n); of N(0, 1) against
    q = N(0, 2²) they are bounded (k < 0: passes); fewer than
    :data:`TAIL_MIN_DRAWS` draws give no index. The bound is min(1 − 1/log₁₀ n, 0.7)."""
    x = np.random.default_rng(0).standard_normal(4000)
    lw = stats.norm(0, 3).logpdf(x) - stats.norm.logpdf(x)
    heavy, n = tail_index([lw[:2000], lw[2000:]])
    assert n == 4000 and abs(heavy - 8 / 9) < 0.15 and heavy > tail_bound(n), heavy
    light, _ = tail_index([stats.norm.logpdf(2 * x) - stats.norm(0, 2).logpdf(2 * x)])
    assert light < 0.2, light
    assert np.isnan(tail_index([x[:TAIL_MIN_DRAWS - 1]])[0])
    assert tail_bound(400) == pytest.approx(1 - 1 / np.log10(400)) and tail_bound(2200) == 0.7
