"""emcee posterior: start the walkers, adapt the proposal, run the chain until the stopping rule holds.

:func:`sample` draws from any vectorised log-density ``f(X (B, d)) -> (B,)`` in four stages, one module each:

1. **start** (:mod:`.start`): seeds, and walkers drawn inside the prior box around a centre;
2. **adapt** (:mod:`.adapt`): a pilot of local moves and rounds that fit the independence proposal q to the
   walkers' draws (skipped when a ``proposal`` is given or no move needs one);
3. **chain** (:mod:`.chain`): the emcee ensemble with its HDF5 checkpoint, q frozen, so the chain is exact;
4. **stop** (:mod:`.convergence`): burn-in from a pilot τ, then ≥ 50 τ after it *and* R-hat < 1.01 over the
   walkers, plus the Pareto k̂ of q's importance weights for a chain of the independence move alone.

:func:`fit_mcmc` applies it to an :class:`~bayes_mr.likelihood.output_error.OutputError` posterior started at
the least-squares optimum; :func:`bayes_mr.inference.mcmc_posterior.mcmc_posterior` turns the chain into the
engines' common :class:`~bayes_mr.inference.base.Posterior`.

Why these moves and walkers:

* The chain proper proposes from q alone (a t₂₀ with a defensive t₄ share, :class:`~.moves.Independence`): on
  the bench's dahl posterior (:mod:`bayes_mr.bench`; ``moves`` set to compare) its integrated time is 3–4 steps
  against 21–24 with differential evolution and snooker. q fitted to the Laplace approximation instead gave
  τ ≈ 35: that posterior's mean sits 1–2 SD from the optimum, so q must come from the chain.
* The adaptation mixes q (70 %) with differential evolution (20 %, γ₀ = 2.38/√(2d), optimal for Gaussian
  targets where the stretch move's efficiency falls with d) and the DE snooker update (10 %, which keeps the
  Monte Carlo errors honest and follows curved ridges; emcee 3.1.6's own is biased, :class:`~.moves.Snooker`).
* With the independence move alone every walker is an exact chain of its own, so 8 walkers
  (:data:`~.settings.INDEPENDENT_WALKERS`) suffice whatever d: R-hat asks ~125 τ of *every* walker, so more
  walkers do not shorten the chain but cost one evaluation each per step.
* That chain can be too narrow where q underweights p without τ or R-hat showing it; the defensive t₄ bounds
  p/q there, and the Pareto k̂ check stops such a chain unconverged (``stopped`` "q_tails";
  ``tests/inference/test_proposal_tails.py``).

With a work budget (``max_evaluations``, :mod:`.budget`) a run that cannot hold its pilot, one adaptation round and
the shortest chain the rule has held in is not started (:class:`~.budget.OverBudget`), and the rounds and the chain
spend it by counted evaluations, so the same seed gives the same chain on any machine. The wall-time cap
(``max_seconds``) is a safety net: the chain is checked once more where it acts; a chain that meets the rule there
is converged, else it stopped on "max_seconds", a machine limit.
"""

from __future__ import annotations

import time as _time
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from bayes_mr.inference.mcmc.adapt import adapt
from bayes_mr.inference.mcmc.budget import check_budget
from bayes_mr.inference.mcmc.chain import MCMCResult, run_chain
from bayes_mr.inference.mcmc.settings import MCMCSettings
from bayes_mr.inference.mcmc.start import LogDensity, start_from_lsq

__all__ = ["fit_mcmc", "sample"]


def sample(
    log_prob: LogDensity,
    x0_center: np.ndarray,
    x0_cov: np.ndarray,
    settings: MCMCSettings = MCMCSettings(),
    *,
    names: Sequence[str] | None = None,
    initial: np.ndarray | None = None,
    group: str = "mcmc",
    proposal: tuple | None = None,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
) -> MCMCResult:
    """Sample a vectorised log-density with emcee until the stopping rule holds.

    Parameters
    ----------
    log_prob : callable
        ``f(X) -> lp`` with X of shape (B, d) and lp of shape (B,); −inf
        outside the support. Called once per half-ensemble per step.
    x0_center : ndarray (d,)
        Centre of the initial walker cloud.
    x0_cov : ndarray (d, d)
        Covariance of the initial walker cloud.
    settings : MCMCSettings
    names : sequence of str, optional
        Coordinate names (default x0, x1, …).
    initial : ndarray (n_walkers, d), optional
        Start from these walker positions instead of drawing them.
    group : str
        HDF5 group of the chain inside ``settings.backend`` (several chains
        can share one file, e.g. the temperatures of an evidence ladder).
    proposal : (mean (d,), cov (d, d)[, edges]), optional
        The independence move's fixed proposal (:class:`~.moves.Independence`; default: fitted by
        :func:`~.adapt.adapt`).
    bounds : (ndarray (d,), ndarray (d,)), optional
        The support's box: initial walkers are drawn inside it (:func:`~.start.initial_walkers`), and the
        adapted proposal is fitted with it (:func:`~.proposal.fit_proposal`).

    Returns
    -------
    MCMCResult
        With ``settings.resume`` and a checkpoint, the chain continued from its last stored step and
        random state (the seed and walker count must match the checkpoint's).

    Raises
    ------
    OverBudget
        With ``settings.max_evaluations``, before any evaluation, when the pilot, one adaptation round and
        :data:`~.budget.MIN_CHAIN_STEPS` steps of the chain do not fit in it (:func:`~.budget.check_budget`).
    """
    t0 = _time.perf_counter()
    x0_center = np.asarray(x0_center, float)
    d = x0_center.size
    names = tuple(names) if names is not None else tuple(f"x{j}" for j in range(d))
    pilot = proposal is None and settings.pilot_length > 0
    if settings.max_evaluations is not None:
        n = settings.walkers(d) if initial is None else int(np.shape(initial)[0])
        check_budget(n, settings.pilot_length if pilot else 0, settings.max_evaluations,
                     settings.walkers_after_pilot(d) if pilot else None)
    given, pilot_steps, adapt_acceptance, spent = settings, 0, (), 0
    if pilot:
        initial, proposal, pilot_steps, adapt_acceptance, settings, spent = adapt(
            log_prob, x0_center, x0_cov, settings, names, initial, group, bounds)
    res = run_chain(log_prob, x0_center, x0_cov, settings, names, initial=initial, group=group,
                    proposal=proposal, bounds=bounds)
    return replace(res, wall_s=_time.perf_counter() - t0, pilot_steps=pilot_steps,
                   adapt_acceptance=adapt_acceptance, evaluations=spent + res.evaluations,
                   max_evaluations=given.max_evaluations, max_seconds=given.max_seconds)


def fit_mcmc(lik, *, lsq=None, settings: MCMCSettings = MCMCSettings(), lsq_settings=None) -> MCMCResult:
    """emcee posterior of an :class:`~bayes_mr.likelihood.output_error.OutputError`, started at least squares.

    Parameters
    ----------
    lik : OutputError
        Log-posterior x = [φ, ln σ_c] (vectorised over walkers).
    lsq : LSQResult, optional
        A least-squares fit of the same ``lik`` (run here if not given).
    settings : MCMCSettings
    lsq_settings : LSQSettings, optional
        Settings of the least-squares fit when it is run here.

    Returns
    -------
    MCMCResult
        Coordinates named ``lik.names`` (φ of the free parameters, then
        ``sigma_<channel>`` holding ln σ_c).
    """
    if lsq is None:
        from bayes_mr.inference.lsq.joint import fit_any
        from bayes_mr.inference.lsq.least_squares import LSQSettings

        lsq = fit_any(lik, lsq_settings or LSQSettings(seed=settings.seed))
    center, cov = start_from_lsq(lik, lsq)
    return sample(lik, center, cov, settings, names=lik.names, bounds=(lik.lower, lik.upper))
