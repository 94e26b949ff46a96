"""The adaptation: a pilot of local moves and rounds that refit the independence move's proposal q.

A proposal fitted to the walkers' own draws mixes far better than one from the least-squares Laplace
approximation, whose mean can sit 1–2 SD from the posterior's. The pilot runs the moves that need no
proposal (differential evolution and the DE snooker update) and q is fitted to its second half
(:func:`~bayes_mr.inference.mcmc.proposal.fit_proposal`). Where the posterior is long or has many dimensions
the pilot has not mixed, so up to ``adapt_rounds`` rounds follow, each run with q and the local moves and
each refitting q to its own second half; they end when q fits (:data:`ADAPT_ACCEPT`) or stops improving
(:data:`ADAPT_GAIN`, above :data:`ADAPT_FLOOR`). Every part holds its proposal fixed, so each is an exact
Metropolis–Hastings chain; none is part of the result. Where the adaptation *settled* the chain proper
proposes from q alone on ``chain_walkers`` independent walkers; where the rounds or the work budget ran out first
q may still underweight part of the target, and the chain keeps the rounds' mixture on 2·d + 2 walkers.
``tests/inference/test_mcmc.py`` runs both outcomes.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from bayes_mr.inference.mcmc.chain import MCMCResult, run_chain
from bayes_mr.inference.mcmc.moves import local_moves
from bayes_mr.inference.mcmc.proposal import fit_proposal
from bayes_mr.inference.mcmc.settings import MCMCSettings
from bayes_mr.inference.mcmc.start import child_seed
from bayes_mr.inference.mcmc.budget import MIN_CHAIN_STEPS

#: Spawn key of the pilot chain's seed; the adaptation rounds' are the keys below it.
PILOT_KEY = 2**31 - 1
#: An adaptation round whose mean acceptance reaches this ends the adaptation: the proposal fits well enough
#: that another round would buy little (the bench's dahl posterior accepts ~0.5 with the pilot's proposal).
ADAPT_ACCEPT = 0.4
#: A round whose acceptance is less than this factor above the previous round's ends the adaptation: on the
#: main job's spencer posterior (rounds accepting 0.13 → 0.31 → 0.34 → 0.39 → 0.42) the rounds past the third
#: cost about the walker evaluations they save in the chain proper.
ADAPT_GAIN = 1.2
#: A round that gains less than :data:`ADAPT_GAIN` ends the adaptation only if it accepts at least this: a q that
#: stalls below it is poor, not settled (an independence chain accepting a has τ ≳ 2/a − 1 and sticks where q
#: underweights p), so the rounds go on. Every plateau of the packaged damper's forms lies above 0.3, while
#: bouc-wen's first rounds on its β₁ ≈ −γ ridge have accepted 0.05 then 0.04, which the gain rule alone calls
#: settled (``tests/inference/test_mcmc.py`` runs both sides of the floor).
ADAPT_FLOOR = 0.2


def adapt(log_prob, x0_center, x0_cov, settings: MCMCSettings, names, initial, group: str, bounds=None):
    """Run the pilot, fit the proposal to its second half, and refit it over the adaptation rounds.

    Each part's seed is a fixed child of the run's and has its own HDF5 group (``<group>_pilot``,
    ``<group>_adapt<k>``), so a resumed run refits the same proposal. With a work budget
    (``max_evaluations``) a round runs only if it fits, whole, in what the budget leaves after the chain proper's
    first steps (:func:`chain_reserve`): the number of rounds is set by the rules above and by counted
    evaluations, never by the machine's speed. The wall-time cap (``max_seconds``) only ends the adaptation
    where it cuts a round short (the chain proper then stops on it at once, flagged).

    Returns
    -------
    initial : ndarray (n, d)
        Where the chain proper starts: the first n = ``settings.walkers_after_pilot(d)`` of the last walkers.
    proposal : tuple
        (mean, cov, map) of :func:`~bayes_mr.inference.mcmc.proposal.fit_proposal`.
    pilot_steps : int
        Steps of the pilot and the rounds.
    acceptance : tuple of float
        Mean acceptance of each adaptation round.
    settings : MCMCSettings
        The chain's settings: its work budget and wall-time cap less what the pilot and rounds spent, and the
        rounds' moves (``adapt_moves``) where the adaptation did not settle.
    evaluations : int
        Log-density evaluations of the pilot and the rounds (walker-steps).
    """
    pilot_settings = replace(settings, moves=local_moves(settings.adapt_moves), max_evaluations=None,
                             max_steps=settings.pilot_steps, check_every=settings.pilot_steps,
                             seed=child_seed(settings.seed, PILOT_KEY))
    part = run_chain(log_prob, x0_center, x0_cov, pilot_settings, names, initial=initial,
                     group=group + "_pilot", bounds=bounds)
    proposal = fit_proposal(_second_half(part), bounds)
    d = part.chain.shape[-1]
    spent, wall, steps, acceptance, settled = _work(part), part.wall_s, part.n_steps, [], False
    allowance = None if settings.max_evaluations is None else settings.max_evaluations - chain_reserve(d, settings)
    capped = part.stopped == "max_seconds"
    for k in range(settings.adapt_rounds):
        n = settings.adapt_steps
        if capped or (allowance is not None and spent + n * part.n_walkers > allowance):
            break
        cap = None if settings.max_seconds is None else max(settings.max_seconds - wall, 0.0)
        round_settings = replace(settings, moves=settings.adapt_moves, max_evaluations=None, max_seconds=cap,
                                 max_steps=n, check_every=n, seed=child_seed(settings.seed, PILOT_KEY - 1 - k))
        part = run_chain(log_prob, x0_center, x0_cov, round_settings, names, initial=part.chain[-1],
                         group=f"{group}_adapt{k}", proposal=proposal, bounds=bounds)
        spent, wall, steps = spent + _work(part), wall + part.wall_s, steps + part.n_steps
        if part.n_steps < n:  # the cap cut the round: too short to refit q from or to judge it by
            capped = True
            break
        proposal = fit_proposal(_second_half(part), bounds)
        acceptance.append(float(np.mean(part.acceptance)))
        settled = acceptance[-1] >= ADAPT_ACCEPT or (k and acceptance[-1] < ADAPT_GAIN * acceptance[-2]
                                                     and acceptance[-1] >= ADAPT_FLOOR)
        if settled:
            break
    # check_budget's count leaves the chain at least its reserve: the rounds never spend into it
    settings = replace(settings, max_evaluations=None if settings.max_evaluations is None else (
        settings.max_evaluations - spent), max_seconds=None if settings.max_seconds is None else (
        0.0 if capped else max(settings.max_seconds - wall, 0.0)))
    if not settled:  # q may still be far from the target: the chain keeps the rounds' local moves
        settings = replace(settings, moves=settings.adapt_moves)
    chain_start = part.chain[-1, :settings.walkers_after_pilot(d)]
    return chain_start, proposal, steps, tuple(acceptance), settings, spent


def chain_reserve(ndim: int, settings: MCMCSettings) -> int:
    """Log-density evaluations of the chain proper's first :data:`~bayes_mr.inference.mcmc.budget.MIN_CHAIN_STEPS`
    steps on its walkers (``settings.walkers_after_pilot``): what the adaptation leaves the chain at least, the
    count :func:`~bayes_mr.inference.mcmc.budget.check_budget` started the run on."""
    return MIN_CHAIN_STEPS * settings.walkers_after_pilot(ndim)


def _work(part: MCMCResult) -> int:
    """Log-density evaluations of one part: every walker once per step (walker-steps)."""
    return part.n_steps * part.n_walkers


def _second_half(res: MCMCResult) -> np.ndarray:
    """Every walker's draws of the second half of a chain, flattened (n, d)."""
    return res.chain[res.n_steps // 2:].reshape(-1, res.chain.shape[-1])
