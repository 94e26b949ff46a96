"""emcee posterior: vectorised ensemble sampling until 50 autocorrelation times.

:func:`sample` draws from any vectorised log-density ``f(X (B, d)) -> (B,)``
with :class:`emcee.EnsembleSampler` (``vectorize=True``: every proposal of a
half-ensemble is one call, so one compiled batched simulation serves all
walkers); :func:`fit_mcmc` applies it to an
:class:`~bayes_mr.likelihood.output_error.OutputError` posterior, starting the walkers at
the least-squares optimum; :func:`bayes_mr.inference.mcmc_posterior.mcmc_posterior`
turns the chain into the engines' common :class:`~bayes_mr.inference.base.Posterior`.

Run length (checked every ``check_every`` steps, at multiples of it, so an
interrupted and resumed run takes the same decisions):

1. a pilot autocorrelation time τ₀ = max over coordinates of the integrated
   time of the *second half* of the chain (the start-up transient lives in
   the first half once the chain is a few τ long);
2. burn-in b = ⌈``burn_tau_multiple`` · τ₀⌉, at most half the chain;
3. τ = the integrated times of the chain after b (``emcee.autocorr.
   integrated_time`` with ``tol=0``: it never refuses, the rule below decides);
4. converged when N − b ≥ ``min_tau_multiple`` · max τ *and* the
   rank-normalised split R-hat (ArviZ; walkers as chains) of every coordinate
   is below ``rhat_max``; otherwise continue, up to ``max_steps``.

With a wall-time budget (``max_seconds``) the chain is checked once more
where the budget runs out, off the grid; a chain that meets the rule there is
converged (``stopped`` "converged"), else it stopped on "max_seconds".

Moves: the chain proper proposes from an independence proposal (a t₂₀ with a defensive t₄
share, :class:`~bayes_mr.inference.mcmc.moves.Independence`) alone (``moves``); the adaptation
rounds mix it (70 %) with differential evolution (20 %, emcee ``DEMove``, γ₀ = 2.38/√(2d))
and the DE snooker update (10 %, :class:`~bayes_mr.inference.mcmc.moves.Snooker`)
(``adapt_moves``). Without a ``proposal`` the
run starts with a pilot of ``pilot_steps`` steps of the rounds' local moves alone; the
mean and covariance of its second half, frozen from then on (a fixed
proposal keeps the chain exact), make the proposal — a coordinate piled
against a bound of the box in log-distance to it where that fits the pilot
jointly better (``bounds``; normalized-bouc-wen's n on the compare record:
τ 10 → 5; :func:`~bayes_mr.inference.mcmc.proposal.fit_proposal`), a non-Gaussian marginal mapped onto the
normal's quantiles and a curved ridge straightened by a shear where either fits the pilot clearly better
(:mod:`bayes_mr.inference.mcmc.proposal`), drawn only inside the box (a draw outside is drawn
again: exact, and no evaluation is spent on a point the prior rejects; normalized-bouc-wen on
the packaged damper: 1300 → 850 steps) — and the chain proper starts from the pilot's last
walkers (the pilot and the rounds are not part of the result).
Measured on the bench's dahl posterior (6-d, 24 walkers, 25 s at 1 kHz):
integrated time 21–24 steps with DE + snooker (3000 steps, 54 s) and 3.0–3.4
with the pilot-fitted independence move (500 steps after a 500-step pilot,
acceptance 0.53). A 200-step pilot (the default) serves as well: τ 3.5–3.9,
R-hat < 1.01 after 400–500 steps, 13–15 s in all against 20–21 s with 500
(three seeds each; a 100-step pilot gave τ ≈ 5). With τ of a few steps the
binding rule is R-hat (every walker is a chain of a few hundred steps), so
the check falls every 50 steps (``check_every``), not 250. A proposal from
the least-squares Laplace approximation
instead made it *worse* (τ ≈ 35, acceptance 0.16): that posterior's mean sits
1–2 SD from the optimum in two coordinates and its ln σ correlate with φ, so
q must come from the chain. In the rounds the local moves carry the walkers
where q fits badly (a curved valley, a posterior piled against a bound) and
the next q is fitted to where they went. DE and the
snooker update (measured before the independence move): both are affine-invariant
like the stretch move, but DE's scale is the optimal one for Gaussian targets
in d dimensions while the stretch move's efficiency falls with d. Measured on
a correlated 6-d Gaussian (scales over three decades, 24 walkers): integrated
time ≈ 19 steps (DE alone), ≈ 23 (DE + snooker), ≈ 70 (stretch). The snooker
share is kept because it makes the Monte Carlo errors honest: over 24 seeds
on a 4-d Gaussian at 50 τ, (mean − truth)/MCSE has SD 1.3–1.4 with DE alone
(τ of a pure-DE ensemble is underestimated) and 1.0–1.2 with the mixture;
and it moves along lines through other walkers, which helps on curved ridges.
emcee 3.1.6's own ``DESnookerMove`` is wrong (see :class:`~bayes_mr.inference.mcmc.moves.Snooker`) and is
not used.

Adaptation rounds. Where the posterior is long or has many dimensions, a
200-step pilot of the local moves has not mixed, and a proposal fitted to it
fits the target poorly: spencer on the packaged damper (14-d, 56 walkers,
1 kHz) accepted 0.07 with it, and its τ kept growing with the chain (41
steps at 600, 60 at 1000; R-hat 1.30 after 1000). So up to ``adapt_rounds``
rounds of ``adapt_steps`` steps follow the pilot, each run with the proposal
and the local moves and each refitting the proposal to its own second half
(walkers the last proposal has moved); the adaptation ends when a round
accepts :data:`ADAPT_ACCEPT` or more, or less than :data:`ADAPT_GAIN` times
the round before. A round's proposal is fixed while it runs and the chain
proper's throughout, so every part is an exact Metropolis–Hastings chain; the
rounds are not part of the result. Measured: the bench's dahl posterior ends its adaptation after one
round and converges in 300–350 steps (τ 3.1–3.6) against 450 (4.1) without it (three seeds); on the
packaged damper bouc-wen's walkers spread along its β₁ ≈ −γ ridge round after round, accepting 0.04 → 0.07
→ 0.12 → 0.24 → 0.35 → 0.38 over six rounds, and its chain then converged in 2750 steps (τ ≤ 31), where
after three rounds it had not in 4000 (τ 25–56) — hence up to ten rounds.
The chain proper proposes from q alone only where the adaptation *settled* (a whole round
reached :data:`ADAPT_ACCEPT`, or gained less than :data:`ADAPT_GAIN` at :data:`ADAPT_FLOOR` or above; a
round the budget cuts short is not refitted from); where the rounds or the budget ran out first, q may
still be far from the target, and independent walkers would sit where it underweights it, so the chain keeps the rounds' mixture
(``adapt_moves``, on 2·d + 2 walkers). Measured on the Bouc–Wen benchmark's posterior
(the bench's case, 480 s, seed 0), where the budget leaves time for a round or two: run
alone, after one round (accepting 0.08), a chain of 8 independent walkers reached τ 6.6
and R-hat 1.013 in 954 steps; in the bench run its walkers stayed apart (R-hat 69 after
650 steps, τ 31) — a q that depends on how many rounds the clock allowed. All five
posteriors of the main job settle (each by one rule or the other). So with a wall-time
budget the rounds may spend what it leaves after the chain proper's first
:data:`~bayes_mr.inference.mcmc.wall_time.MIN_CHAIN_STEPS` steps at the pilot's cost per walker
(the projection the run was started on), not a fixed share of it: with half the budget
(until stop 57) that same posterior settled in two rounds (0.07 → 0.40; then 400 steps of
8 walkers, R-hat 1.0099, 305 s) in one bench run and, an hour later on the same machine,
had its second round cut at 240 s and stopped unconverged on the mixture (625 steps of 16
walkers, R-hat 1.0147, 480 s); with the reserve it ended its rounds by the rules above
and converged as in the first (324 s, the second hour).

Walkers. The pilot and the rounds run 4·d walkers: differential evolution and the
snooker update explore with the differences between walkers, and the proposal is
fitted to their draws. The chain proper then keeps the first
:data:`~bayes_mr.inference.mcmc.settings.INDEPENDENT_WALKERS` (8) of them
(``chain_walkers``): with the independence move alone every walker is a
Metropolis–Hastings chain of its own, exact for the frozen q, so no rule ties their
number to d; and the rule's R-hat < 1.01 asks ~125 τ of *every* walker (the walkers
are its chains), so the chain's steps do not shrink with more walkers while each
step costs one evaluation per walker. Measured on the main job's part A (seed 0,
unbudgeted, the same pilot and rounds before each chain): spencer met the rule in
1000 steps of 8 walkers (τ 11, acceptance 0.49) where the mixture above with 30
walkers took 850–1300 (τ 8.5–11), 8000 likelihood evaluations against 26 000–39 000;
normalized-bouc-wen 350 of 8 against 400 of 16 (τ 3.2 against 3.4); bouc-wen 550
of 8 (τ 6.9, acceptance 0.52) against 4100 of 14 (τ 41). Posterior means agree
within 0.1 posterior SD, and spencer's and normalized-bouc-wen's SDs within 7 %;
bouc-wen's SDs of β₁, γ and n were 20 % *narrower* than the mixture's, and two
checks say the mixture's were wrong: the same chain run to 3800 steps (τ 9.2) kept
them, and importance sampling from q with its scale doubled (12 000 draws, ESS 886,
no draw above 0.6 % of the weight) gave 0.56 against the chain's 0.55 and the
mixture's 0.68 on β₁ — the mixture's 14 walkers drifting along the β₁ ≈ −γ ridge,
slowly enough that R-hat over them passed. The failure the independence move alone
risks is the opposite (a region q underweights, rarely visited, so the chain is too
narrow and its τ does not show it); the defensive t₄ bounds p/q there, and the
importance check above is the measurement on the posterior where it mattered. The
chain checks it too: its proposals are draws of q, and where τ and R-hat pass but
the Pareto k̂ of their weights p/q exceeds the bound the chain stops unconverged
(``stopped`` "q_tails"; :func:`~bayes_mr.inference.mcmc.convergence.tail_index`). On the
banana of ``tests/inference/test_proposal_tails.py`` two of ten seeds met τ and R-hat
with means 10 and 12 MCSE off; they were the two with k̂ above 0.7 (0.72, 1.3; the
others −0.04 to 0.48). It is a check, not a proof: with t₂₀ alone (no defensive
share) two chains 8 and 13 MCSE off had k̂ 0.31 and 0.62 — a region q hardly ever
proposes leaves no weight to see.

Randomness (:mod:`bayes_mr.inference.mcmc.checkpoint`): ``seed`` seeds the initial
walkers and the RandomState of emcee's moves, whose state the HDF5 backend
stores after every step, so resuming from a checkpoint continues the same
random stream: an interrupted and resumed run equals the uninterrupted one bit for bit.
"""

from __future__ import annotations

import time as _time
from collections.abc import Sequence
from dataclasses import replace

import emcee
import numpy as np

from bayes_mr.numerics.synthetic_noise import as_seed_sequence
from bayes_mr.inference.mcmc.wall_time import MIN_CHAIN_STEPS
from bayes_mr.inference.mcmc.chain import MCMCResult
from bayes_mr.inference.mcmc.checkpoint import open_backend, run_seeds
from bayes_mr.inference.mcmc.convergence import run_until_converged, tail_index
from bayes_mr.inference.mcmc.settings import MCMCSettings
from bayes_mr.inference.mcmc.moves import local_moves
from bayes_mr.inference.mcmc.proposal import fit_proposal
from bayes_mr.inference.mcmc.walkers import LogDensity, start_walkers

__all__ = ["MCMCResult", "MCMCSettings", "fit_mcmc", "sample", "start_from_lsq"]


# --- sampling --------------------------------------------------------------------


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
        The independence move's fixed proposal (:class:`~.moves.Independence`; default: fitted to a pilot).
    bounds : (ndarray (d,), ndarray (d,)), optional
        The support's box: initial walkers are drawn inside it (:func:`~.walkers.initial_walkers`), and the pilot's
        proposal is fitted with it (:func:`~.proposal.fit_proposal`).

    Returns
    -------
    MCMCResult
        With ``settings.resume`` and a checkpoint, the chain continued from its last stored step and
        random state (the seed and walker count must match the checkpoint's).
    """
    t0 = _time.perf_counter()
    x0_center = np.asarray(x0_center, float)
    d = x0_center.size
    names = tuple(names) if names is not None else tuple(f"x{j}" for j in range(d))
    pilot_steps, adapt_acceptance = 0, ()
    if proposal is None and settings.pilot_length:
        initial, proposal, pilot_steps, adapt_acceptance, settings = _pilot(
            log_prob, x0_center, x0_cov, settings, names, initial, group, bounds)
    n_walkers = settings.walkers(d) if initial is None else int(np.shape(initial)[0])
    init_rng, move_state, entropy = run_seeds(settings.seed)
    backend, resuming = open_backend(settings, group, (n_walkers, d), entropy)
    moves = settings.make_moves(proposal)
    # a chain of the independence move alone is also checked on its proposals' importance weights
    tail = None if settings.ensemble else (lambda: tail_index(moves[0][0].log_weights))
    sampler = emcee.EnsembleSampler(n_walkers, d, log_prob, moves=moves, backend=backend, vectorize=True)
    if resuming:
        state = sampler.backend.get_last_sample()  # carries the stored random state
    else:
        coords, lp0 = start_walkers(log_prob, x0_center, x0_cov, n_walkers, init_rng, initial, bounds)
        state = emcee.State(coords, log_prob=lp0, random_state=move_state)
    diag, history = run_until_converged(sampler, state, settings, resuming, tail)
    tau = diag["tau"]
    return MCMCResult(
        chain=np.array(sampler.get_chain()),
        log_prob=np.array(sampler.get_log_prob()),
        burn=int(diag["burn"]),
        thin=max(1, int(0.5 * float(np.min(tau)))) if np.all(np.isfinite(tau)) else 1,
        tau=tau, rhat=diag["rhat"], ess=diag["ess"],
        acceptance=np.array(sampler.acceptance_fraction),
        converged=bool(diag["converged"]), stopped=diag["stopped"],
        wall_s=_time.perf_counter() - t0, seed_entropy=entropy, names=names, history=history,
        pilot_steps=pilot_steps, adapt_acceptance=adapt_acceptance, projection=diag.get("projection"),
        pareto_k=float(diag.get("pareto_k", np.nan)),
    )


def _pilot(log_prob, x0_center, x0_cov, settings: MCMCSettings, names, initial, group: str, bounds=None):
    """Run the pilot chain (the moves that need no proposal), fit the proposal to its second half, and refit
    it over the adaptation rounds (module docstring: :data:`ADAPT_ACCEPT`, :data:`ADAPT_GAIN`).

    Each part's seed is a fixed child of the run's and has its own HDF5 group (``<group>_pilot``,
    ``<group>_adapt<k>``), so a resumed run refits the same proposal. With a wall-time budget the rounds may
    spend what it leaves after :data:`~bayes_mr.inference.mcmc.wall_time.MIN_CHAIN_STEPS` steps of the chain proper
    at the pilot's measured cost per walker (:func:`_chain_reserve`): the projection
    :func:`~bayes_mr.inference.mcmc.wall_time.check_budget` started the run on. Their number is then set by the
    rules above, not by the machine's speed, unless the budget is too tight for them.

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
        moves (``adapt_moves``) where the adaptation did not settle (module docstring).
    """
    pilot_settings = replace(settings, moves=local_moves(settings.adapt_moves),
                             max_steps=settings.pilot_steps, check_every=settings.pilot_steps,
                             seed=_child(settings.seed, PILOT_KEY))
    part = sample(log_prob, x0_center, x0_cov, pilot_settings, names=names, initial=initial,
                  group=group + "_pilot", bounds=bounds)
    proposal = fit_proposal(_second_half(part), bounds)
    spent, steps, acceptance, settled = part.wall_s, part.n_steps, [], False
    allowance = None if settings.max_seconds is None else settings.max_seconds - _chain_reserve(part, settings)
    for k in range(settings.adapt_rounds):
        left = None if allowance is None else allowance - spent
        if left is not None and left <= 0:
            break
        n = settings.adapt_steps
        round_settings = replace(settings, moves=settings.adapt_moves, max_seconds=left, max_steps=n, check_every=n,
                                 seed=_child(settings.seed, PILOT_KEY - 1 - k))
        part = sample(log_prob, x0_center, x0_cov, round_settings, names=names, initial=part.chain[-1],
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


def _chain_reserve(pilot: MCMCResult, settings: MCMCSettings) -> float:
    """Seconds the chain proper's first :data:`~bayes_mr.inference.mcmc.wall_time.MIN_CHAIN_STEPS` steps cost at the
    pilot's measured cost per step and walker (its walkers after the pilot: ``settings.walkers_after_pilot``)."""
    n_steps, n_walkers, d = pilot.chain.shape
    per_walker_step = pilot.wall_s / max(n_steps * n_walkers, 1)
    return MIN_CHAIN_STEPS * settings.walkers_after_pilot(d) * per_walker_step


def _second_half(res: MCMCResult) -> np.ndarray:
    """Every walker's draws of the second half of a chain, flattened (n, d)."""
    return res.chain[res.n_steps // 2:].reshape(-1, res.chain.shape[-1])


def _child(seed, key: int) -> np.random.SeedSequence:
    """The child of ``seed`` with spawn key ``key`` appended (not one ``SeedSequence.spawn`` gives)."""
    seq = as_seed_sequence(seed)
    return np.random.SeedSequence(seq.entropy, spawn_key=seq.spawn_key + (key,))


#: Spawn key of the pilot chain's seed; the adaptation rounds' are the keys below it.
PILOT_KEY = 2**31 - 1
#: An adaptation round whose mean acceptance reaches this ends the adaptation: the proposal fits well
#: enough that another round would buy little (the bench's dahl posterior: ~0.5 with the pilot's proposal).
ADAPT_ACCEPT = 0.4
#: A round whose acceptance is less than this factor above the previous round's ends the adaptation.
#: Only spencer's posterior of the main job is affected among the packaged damper's forms (seed 0, rounds
#: accepting 0.13 → 0.31 → 0.34 → 0.39 → 0.42; at 1.2 the adaptation ends after the third, at 1.1 after the
#: fifth). With a chain proper of 56 walkers rounds four and five bought nothing (900 steps after either, τ 5.6–7.6
#: and 7.2); with the chain's 30 walkers (``chain_walkers``) they cost what they save: three rounds and 1300
#: steps (τ 11) against five and 850 (τ 8.5), 67 000 against 64 700 walker evaluations in all. The rule that ends
#: the adaptation sooner is kept. bouc-wen's rounds (0.04 → 0.07 → 0.12 → 0.24 → 0.35 → 0.38) end where they did.
ADAPT_GAIN = 1.2
#: A round that gains less than :data:`ADAPT_GAIN` ends the adaptation only if it accepts at least this: a q that
#: stalls below it is not settled but poor (an independence chain accepting a has τ ≳ 2/a − 1, and sticks where q
#: underweights p), so the rounds go on and, if they run out, the chain keeps their mixture. On the packaged
#: damper's bouc-wen (β₁ ≈ −γ ridge, correlation −0.9999999) a fresh clone's run, whose least-squares optimum
#: differed from a warm run's in the ninth digit, had its rounds accept 0.048 then 0.036: the plain gain rule called
#: that settled, and 8 independent walkers accepting 0.034 stopped unconverged (τ 80, R-hat 1.5 after 1600 steps);
#: the warm run's rounds had gone 0.04 → 0.07 → 0.12 → 0.24 → 0.35 → 0.38. Every plateau measured on the
#: packaged forms was above 0.3 (spencer 0.31 → 0.34, bouc-wen 0.35 → 0.38).
ADAPT_FLOOR = 0.2


# --- the package's posterior ----------------------------------------------------------

#: Standard deviations of the LSQ (HAC) covariance are widened by this factor for the walker cloud:
#: a cloud a little wider than the posterior contracts in a few τ; a narrower one expands slowly.
INIT_INFLATION = 1.5


def start_from_lsq(lik, lsq) -> tuple[np.ndarray, np.ndarray]:
    """Centre and covariance of the initial walkers from a least-squares fit.

    The centre is (φ̂, ln σ̂); the covariance is the HAC sandwich of φ̂ (wider
    than the iid posterior when residuals are autocorrelated — a safe start)
    and, for ln σ_c, 1/(2 N_c) (the curvature of the Gaussian likelihood in
    ln σ), both widened by :data:`INIT_INFLATION`; the cloud is centred inside
    the prior box.

    Parameters
    ----------
    lik : OutputError
    lsq : LSQResult

    Returns
    -------
    center : ndarray (ndim,)
    cov : ndarray (ndim, ndim)
    """
    p = lik.n_params
    center = np.array(lsq.phi, float)
    cov_phi = np.array(lsq.cov_phi, float)
    if not np.all(np.isfinite(cov_phi)) or np.any(np.diag(cov_phi) <= 0):
        cov_phi = np.array(lsq.cov_phi_iid, float)
    blocks = [cov_phi]
    if lik.noise == "sampled":
        center = np.concatenate([center, np.log(lsq.sigma)])
        blocks.append(np.eye(lik.ndim - p) / (2.0 * lik.n_valid))
    cov = np.zeros((lik.ndim, lik.ndim))
    cov[:p, :p] = blocks[0]
    if len(blocks) > 1:
        cov[p:, p:] = blocks[1]
    cov *= INIT_INFLATION**2
    lo, hi = lik.lower, lik.upper
    center = np.clip(center, lo + 1e-6 * (hi - lo), hi - 1e-6 * (hi - lo))
    return center, cov


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
        from bayes_mr.inference.lsq.least_squares import LSQSettings, fit_lsq

        lsq = fit_lsq(lik, lsq_settings or LSQSettings(seed=settings.seed))
    center, cov = start_from_lsq(lik, lsq)
    return sample(lik, center, cov, settings, names=lik.names, bounds=(lik.lower, lik.upper))

