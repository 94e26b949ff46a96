"""The adaptation: a pilot of local moves and rounds that refit the independence move's proposal q.

A proposal fitted to the walkers' own draws mixes far better than one from the least-squares Laplace
approximation, whose mean can sit 1–2 SD from the posterior's. The pilot runs the moves that need no
proposal (differential evolution and the DE snooker update) and q is fitted to its second half
(:func:`~bayes_mr.inference.mcmc.proposal.fit_proposal`). Where the posterior is long or has many dimensions
the pilot has not mixed, so up to ``adapt_rounds`` rounds follow, each run with q and the local moves and
each refitting q to its own second half; they end when q fits (:data:`ADAPT_ACCEPT`) or stops improving
(:data:`ADAPT_GAIN`, above :data:`ADAPT_FLOOR`). Every part holds its proposal fixed, so each is an exact
Metropolis–Hastings chain; none is part of the result. Where the adaptation *settled* the chain proper
proposes from q alone on ``chain_walkers`` independent walkers; where the rounds or the budget ran out first
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
from bayes_mr.inference.mcmc.wall_time import MIN_CHAIN_STEPS

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
    ``<group>_adapt<k>``), so a resumed run refits the same proposal. With a wall-time budget the rounds may
    spend what it leaves after the chain proper's first steps (:func:`chain_reserve`), so their number is set
    by the rules above, not by the machine's speed, unless the budget is too tight for them.

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
        The chain's settings, its wall-time budget less what the pilot and rounds spent, and the rounds'
        moves (``adapt_moves``) where the adaptation did not settle.
    """
    pilot_settings = replace(settings, moves=local_moves(settings.adapt_moves),
                             max_steps=settings.pilot_steps, check_every=settings.pilot_steps,
                             seed=child_seed(settings.seed, PILOT_KEY))
    part = run_chain(log_prob, x0_center, x0_cov, pilot_settings, names, initial=initial,
                     group=group + "_pilot", bounds=bounds)
    proposal = fit_proposal(_second_half(part), bounds)
    spent, steps, acceptance, settled = part.wall_s, part.n_steps, [], False
    allowance = None if settings.max_seconds is None else settings.max_seconds - chain_reserve(part, settings)
    for k in range(settings.adapt_rounds):
        left = None if allowance is None else allowance - spent
        if left is not None and left <= 0:
            break
        n = settings.adapt_steps
        round_settings = replace(settings, moves=settings.adapt_moves, max_seconds=left, max_steps=n, check_every=n,
                                 seed=child_seed(settings.seed, PILOT_KEY - 1 - k))
        part = run_chain(log_prob, x0_center, x0_cov, round_settings, names, initial=part.chain[-1],
                         group=f"{group}_adapt{k}", proposal=proposal, bounds=bounds)
        spent, steps = spent + part.wall_s, steps + part.n_steps
        if part.n_steps < n:  # the budget ran out in the round: too short to refit q from or to judge it by
            break
        proposal = fit_proposal(_second_half(part), bounds)
        acceptance.append(float(np.mean(part.acceptance)))
        settled = acceptance[-1] >= ADAPT_ACCEPT or (k and acceptance[-1] < ADAPT_GAIN * acceptance[-2]
                                                     and acceptance[-1] >= ADAPT_FLOOR)
        if settled:
            break
    if settings.max_seconds is not None:
        settings = replace(settings, max_seconds=max(settings.max_seconds - spent, 0.0))
    if not settled:  # q may still be far from the target: the chain keeps the rounds' local moves
        settings = replace(settings, moves=settings.adapt_moves)
    chain_start = part.chain[-1, :settings.walkers_after_pilot(part.chain.shape[-1])]
    return chain_start, proposal, steps, tuple(acceptance), settings


def chain_reserve(pilot: MCMCResult, settings: MCMCSettings) -> float:
    """Seconds the chain proper's first :data:`~bayes_mr.inference.mcmc.wall_time.MIN_CHAIN_STEPS` steps cost at
    the pilot's measured cost per step and walker (its walkers after the pilot: ``settings.walkers_after_pilot``):
    the projection :func:`~bayes_mr.inference.mcmc.wall_time.check_budget` started the run on."""
    n_steps, n_walkers, d = pilot.chain.shape
    per_walker_step = pilot.wall_s / max(n_steps * n_walkers, 1)
    return MIN_CHAIN_STEPS * settings.walkers_after_pilot(d) * per_walker_step


def _second_half(res: MCMCResult) -> np.ndarray:
    """Every walker's draws of the second half of a chain, flattened (n, d)."""
    return res.chain[res.n_steps // 2:].reshape(-1, res.chain.shape[-1])
