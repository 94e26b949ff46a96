"""Settings of an emcee run (:func:`bayes_mr.inference.mcmc.sampler.sample`): run length, moves, pilot, walkers, seed.

The rules these settings steer are described where they act: the start in :mod:`.start`, the pilot and rounds in
:mod:`.adapt`, the chain and its checkpoint in :mod:`.chain`, the stopping rule in :mod:`.convergence`, and why
these moves and walkers in :mod:`.sampler`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bayes_mr.inference.mcmc.moves import DEFENSIVE_SHARE, MOVES, NEEDS_PROPOSAL, PROPOSAL_DF

#: Walkers of a chain proper whose moves are all independence proposals (``chain_walkers``' default there):
#: each walker is then a Metropolis–Hastings chain of its own, and R-hat compares them; at least
#: :data:`MIN_CHAINS` (Vehtari et al. 2021 ask four chains of R-hat), eight so that its between-chain
#: variance has 15 degrees of freedom over the split halves.
INDEPENDENT_WALKERS = 8
MIN_CHAINS = 4


def _even_ensemble(name: str, n: int, ndim: int) -> int:
    """``n`` walkers if even and ≥ 2·d + 2 (red–blue half-ensembles spanning the space), else ValueError."""
    if n % 2 or n < 2 * ndim + 2:
        raise ValueError(f"{name} must be even and at least 2·d + 2 = {2 * ndim + 2} "
                         f"(red–blue half-ensembles spanning the space), got {n}")
    return n


@dataclass(frozen=True)
class MCMCSettings:
    """Settings of an ensemble run.

    Attributes
    ----------
    n_walkers : int or None
        Walkers; default 4·d rounded up to even. Must be even and ≥ 2·d + 2
        (differential evolution needs enough complementary walkers to span
        the space).
    min_tau_multiple : float
        Stop when the post-burn-in chain is this many integrated
        autocorrelation times long (emcee's advice: 50).
    burn_tau_multiple : float
        Burn-in in pilot autocorrelation times (:mod:`bayes_mr.inference.mcmc.convergence`).
    rhat_max : float
        Every coordinate's rank-normalised split R-hat must be below this.
    max_steps : int
        Hard limit on steps (the result is then flagged not converged).
    max_evaluations : int or None
        Work budget of the call [log-density evaluations]: walker-steps, one evaluation per walker and step, of
        the pilot, the adaptation rounds and the chain (:mod:`~.budget`). The rounds may spend what it leaves after
        the chain proper's first :data:`~.budget.MIN_CHAIN_STEPS` steps (:func:`~.adapt.adapt`); the chain stops at
        the check where its own integrated time projects the rule past what is left (``"projected"``,
        :func:`~.convergence.projection`) or where it is spent (``"max_evaluations"``), flagged not converged.
        Counted, not timed: what it lets the run compute is the same on any machine. None (default): no budget.
    max_seconds : float or None
        Wall-time cap of the call [s]: a safety net for a machine far slower than the work budget was set for,
        deciding nothing else. The run stops after the step that exceeds it (``"max_seconds"``, flagged not
        converged: a machine limit, not a result); an adaptation round it cuts short ends the adaptation. None
        (default): no cap.
    check_every : int
        Steps between convergence checks (at multiples of it).
    moves : tuple of (str, float)
        Move names (:data:`~.moves.MOVES`) and weights of the chain (after a pilot: of the chain proper).
        Default: the independence move alone, every walker a Metropolis–Hastings chain of its own
        (:mod:`bayes_mr.inference.mcmc.sampler`).
    adapt_moves : tuple of (str, float)
        Moves of the adaptation rounds; the pilot runs those of them that need no proposal
        (:func:`~.moves.local_moves`).
    pilot_steps : int
        Steps of the pilot chain that fits the independence move's proposal
        when :func:`~bayes_mr.inference.mcmc.sampler.sample` is given none (:mod:`bayes_mr.inference.mcmc.adapt`).
    adapt_rounds : int
        At most this many adaptation rounds after the pilot, each refitting the proposal to the
        second half of a round that used it (:mod:`bayes_mr.inference.mcmc.adapt`); 0: the pilot's proposal is kept.
    adapt_steps : int
        Steps of each adaptation round.
    proposal_df : float
        Degrees of freedom ν of the independence move's t (:data:`~.moves.PROPOSAL_DF`, where it is measured).
    defensive_share : float
        Share of the independence move's proposals drawn from its heavy-tailed defensive component
        (:data:`~.moves.DEFENSIVE_SHARE`; 0: none).
    chain_walkers : int or None
        Walkers of the chain proper after a pilot: the first this many of the ensemble the pilot and rounds
        leave (:mod:`bayes_mr.inference.mcmc.sampler`). Default: :data:`INDEPENDENT_WALKERS` when ``moves``
        are all independence proposals, else the fewest differential evolution allows, 2·d + 2 (at most the
        pilot's). At least :data:`MIN_CHAINS`, and with ensemble moves even and ≥ 2·d + 2; without a pilot
        the chain has :meth:`walkers` walkers.
    seed : int or SeedSequence
        Seed of the run (walker initialisation and moves).
    backend : str or Path or None
        HDF5 checkpoint file (emcee ``HDFBackend``), or None for memory only.
    resume : bool
        Continue the chain in ``backend`` instead of starting afresh.
    progress : bool or None
        Progress bar on stderr; None shows it when stderr is a terminal.
    """

    n_walkers: int | None = None
    min_tau_multiple: float = 50.0
    burn_tau_multiple: float = 5.0
    rhat_max: float = 1.01
    max_steps: int = 20000
    max_evaluations: int | None = None
    max_seconds: float | None = None
    check_every: int = 50
    moves: tuple[tuple[str, float], ...] = (("independence", 1.0),)
    adapt_moves: tuple[tuple[str, float], ...] = (("independence", 0.7), ("de", 0.2), ("snooker", 0.1))
    pilot_steps: int = 200
    adapt_rounds: int = 10
    adapt_steps: int = 100
    proposal_df: float = PROPOSAL_DF
    defensive_share: float = DEFENSIVE_SHARE
    chain_walkers: int | None = None
    seed: int | np.random.SeedSequence = 0
    backend: str | Path | None = None
    resume: bool = False
    progress: bool | None = None

    def __post_init__(self):
        if self.max_steps < 1 or self.check_every < 1:
            raise ValueError(f"max_steps and check_every must be positive, got {self.max_steps}, {self.check_every}")
        if self.max_evaluations is not None and not self.max_evaluations > 0:
            raise ValueError(f"max_evaluations must be a positive number of log-density evaluations or None, "
                             f"not {self.max_evaluations!r}")
        if self.adapt_rounds < 0 or self.adapt_steps < 2:
            raise ValueError(f"adapt_rounds must be ≥ 0 and adapt_steps ≥ 2, got {self.adapt_rounds}, "
                             f"{self.adapt_steps}")

    @property
    def pilot_length(self) -> int:
        """Fewest steps :func:`~bayes_mr.inference.mcmc.sampler.sample` runs before the chain proper when given no
        proposal: the pilot and one adaptation round (0 when no move needs a proposal)."""
        if self.pilot_steps < 1 or not any(name in NEEDS_PROPOSAL for name, _ in self.moves):
            return 0
        return self.pilot_steps + (self.adapt_steps if self.adapt_rounds > 0 else 0)

    def walkers(self, ndim: int) -> int:
        """Number of walkers for a ``ndim``-dimensional target."""
        if self.n_walkers is None:
            return max(4 * ndim, 2 * ndim + 2)
        return _even_ensemble("n_walkers", int(self.n_walkers), ndim)

    @property
    def ensemble(self) -> bool:
        """Whether a move of the chain uses the other walkers (all but the independence move do)."""
        return any(name not in NEEDS_PROPOSAL for name, _ in self.moves)

    def walkers_after_pilot(self, ndim: int) -> int:
        """Walkers of the chain proper when a pilot ran (``chain_walkers``; at most :meth:`walkers`)."""
        if self.ensemble:
            n = 2 * ndim + 2 if self.chain_walkers is None else _even_ensemble("chain_walkers", int(self.chain_walkers),
                                                                               ndim)
        else:
            n = INDEPENDENT_WALKERS if self.chain_walkers is None else int(self.chain_walkers)
            if n < MIN_CHAINS:
                raise ValueError(f"chain_walkers must be at least {MIN_CHAINS} (R-hat compares the walkers as "
                                 f"chains), got {n}")
        return min(n, self.walkers(ndim))

    def make_moves(self, proposal: tuple | None = None) -> list:
        """Fresh emcee move objects (moves keep per-run state; never share them).

        ``proposal`` is the (mean, cov[, map]) of the moves that need one (the independence move).
        """
        moves = []
        for name, w in self.moves:
            if name not in MOVES:
                raise ValueError(f"unknown move '{name}'; valid: {', '.join(MOVES)}")
            if name in NEEDS_PROPOSAL:
                if proposal is None:
                    raise ValueError(f"the move '{name}' needs a proposal (mean, cov)")
                moves.append((MOVES[name](*proposal, df=self.proposal_df, defensive=self.defensive_share), float(w)))
            else:
                moves.append((MOVES[name](), float(w)))
        return moves
