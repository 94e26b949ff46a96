"""Running the chain: an emcee ensemble with its HDF5 checkpoint, advanced until the stopping rule, and its result.

:func:`run_chain` draws from a vectorised log-density ``f(X (B, d)) -> (B,)`` with
:class:`emcee.EnsembleSampler` (``vectorize=True``: every proposal of a half-ensemble is one call, so one
compiled batched simulation serves all walkers) and fixed moves, from walkers of :mod:`.start`, until the rule
of :mod:`.convergence` holds. The checkpoint (emcee's ``HDFBackend``) stores the chain and the moves' random
state after every step, and the seed's entropy and the settings as attributes of its group, so a resumed run is
checked against the seed it continues and equals the uninterrupted run bit for bit.
"""

from __future__ import annotations

import json
import time as _time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import emcee
import numpy as np

from bayes_mr.inference.mcmc.convergence import run_until_converged, tail_index
from bayes_mr.inference.mcmc.settings import MCMCSettings
from bayes_mr.inference.mcmc.start import LogDensity, run_seeds, start_walkers


@dataclass
class MCMCResult:
    """An ensemble chain and its diagnostics.

    Attributes
    ----------
    chain : ndarray, shape (n_steps, n_walkers, d)
        Every step of every walker (burn-in included).
    log_prob : ndarray, shape (n_steps, n_walkers)
        Log-density of each position.
    burn : int
        Steps discarded as burn-in.
    thin : int
        Thinning of the stored posterior draws (≈ τ/2).
    tau : ndarray (d,)
        Integrated autocorrelation times after burn-in [steps].
    rhat, ess : ndarray (d,)
        Rank-normalised split R-hat and bulk effective sample size (ArviZ,
        walkers as chains) of the post-burn-in chain.
    acceptance : ndarray (n_walkers,)
        Acceptance fraction of each walker.
    converged : bool
        The stopping rule was met.
    stopped : str
        Why the run ended: ``"converged"``, ``"max_steps"``, ``"max_evaluations"`` (its work budget spent),
        ``"projected"`` (the rule projected past the work budget; see ``projection``), ``"q_tails"``
        (a chain of the independence move alone met the rule but its proposals' ``pareto_k`` did not) or
        ``"max_seconds"`` (the wall-time cap: a machine limit, not a result).
    wall_s : float
        Wall time of this call, its pilot included (a resumed run counts only its own part) [s].
    evaluations : int
        Log-density evaluations of the run: walker-steps of the chain and of its pilot and adaptation rounds
        (stored steps of a resumed run included: the work the result stands on).
    max_evaluations : int or None
        The run's work budget [evaluations] (``MCMCSettings.max_evaluations`` as the call was given it).
    max_seconds : float or None
        The run's wall-time cap [s] (``MCMCSettings.max_seconds`` as the call was given it).
    seed_entropy : str
        Entropy of the run's SeedSequence.
    names : tuple of str
        Coordinate names.
    history : list of dict
        Each convergence check: step, burn, tau_max, rhat_max.
    pilot_steps : int
        Steps run before this chain to fit the independence proposal: the
        pilot and the adaptation rounds (0: none); they are not in ``chain``.
    adapt_acceptance : tuple of float
        Mean acceptance of each adaptation round (:mod:`bayes_mr.inference.mcmc.adapt`).
    projection : dict or None
        With ``stopped == "projected"``: ``tau_max``, ``steps_needed``, ``steps_allowed``,
        ``evaluations_needed`` and ``evaluations_allowed`` of the chain proper
        (:func:`bayes_mr.inference.mcmc.convergence.projection`).
    pareto_k : float
        Pareto k̂ of the importance weights p/q of the independence move's proposals where a chain of that
        move alone met the rule (:func:`bayes_mr.inference.mcmc.convergence.tail_index`); NaN otherwise.
    """

    chain: np.ndarray
    log_prob: np.ndarray
    burn: int
    thin: int
    tau: np.ndarray
    rhat: np.ndarray
    ess: np.ndarray
    acceptance: np.ndarray
    converged: bool
    wall_s: float
    seed_entropy: str
    stopped: str = "converged"
    names: tuple[str, ...] = ()
    history: list = field(default_factory=list)
    pilot_steps: int = 0
    adapt_acceptance: tuple[float, ...] = ()
    projection: dict | None = None
    pareto_k: float = float("nan")
    evaluations: int = 0
    max_evaluations: int | None = None
    max_seconds: float | None = None

    @property
    def n_steps(self) -> int:
        return int(self.chain.shape[0])

    @property
    def n_walkers(self) -> int:
        return int(self.chain.shape[1])

    def samples(self, *, thin: int | None = None, flat: bool = True) -> np.ndarray:
        """Post-burn-in draws, thinned: (n, d) if ``flat`` else (n_draw, n_walkers, d)."""
        s = self.chain[self.burn:: self.thin if thin is None else thin]
        return s.reshape(-1, s.shape[-1]) if flat else s

    def mean(self) -> np.ndarray:
        """Posterior mean of each coordinate from every post-burn-in step (d,)."""
        return self.chain[self.burn:].reshape(-1, self.chain.shape[-1]).mean(axis=0)

    def cov(self) -> np.ndarray:
        """Posterior covariance from every post-burn-in step (d, d)."""
        return np.cov(self.chain[self.burn:].reshape(-1, self.chain.shape[-1]), rowvar=False)

    def mcse(self) -> np.ndarray:
        """Monte Carlo standard error of the posterior mean, SD/√ESS (d,)."""
        sd = self.chain[self.burn:].reshape(-1, self.chain.shape[-1]).std(axis=0, ddof=1)
        return sd / np.sqrt(self.ess)


def open_backend(settings, group: str, shape: tuple[int, int], entropy: str) -> tuple[object | None, bool]:
    """The run's HDF5 backend, and whether it resumes a stored chain.

    Parameters
    ----------
    settings : MCMCSettings
        Its ``backend`` (file, or None for memory only) and ``resume``.
    group : str
        HDF5 group of the chain inside the file.
    shape : (int, int)
        (walkers, dimension) of this run.
    entropy : str
        Seed entropy of this run (:func:`.start.run_seeds`).

    Returns
    -------
    backend : emcee.backends.HDFBackend or None
    resuming : bool
        True when ``settings.resume`` and the group holds a chain; else the
        group is reset and stamped with the seed entropy and settings.

    Raises
    ------
    ValueError
        If the stored chain was made with another seed or another shape.
    """
    if settings.backend is None:
        return None, False
    backend = emcee.backends.HDFBackend(str(settings.backend), name=group)
    if settings.resume and backend.initialized and backend.iteration > 0:
        with backend.open() as f:
            stored = f[group].attrs.get("bayes_mr_seed_entropy")
        if stored is not None and str(stored) != entropy:
            raise ValueError(f"{settings.backend}[{group}]: checkpoint was made with seed entropy {stored}, "
                             f"not {entropy}; resume with the same seed or start afresh (resume=False)")
        if backend.shape != shape:
            raise ValueError(f"{settings.backend}[{group}]: checkpoint holds {backend.shape} (walkers, dim), "
                             f"this run needs {shape}")
        return backend, True
    Path(settings.backend).parent.mkdir(parents=True, exist_ok=True)
    backend.reset(*shape)
    with backend.open("a") as f:
        f[group].attrs["bayes_mr_seed_entropy"] = entropy
        f[group].attrs["bayes_mr_settings"] = json.dumps({**asdict(settings), "seed": entropy}, default=str)
    return backend, False


def run_chain(
    log_prob: LogDensity,
    x0_center: np.ndarray,
    x0_cov: np.ndarray,
    settings: MCMCSettings,
    names: Sequence[str],
    *,
    initial: np.ndarray | None = None,
    group: str = "mcmc",
    proposal: tuple | None = None,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
) -> MCMCResult:
    """One chain of ``settings.moves`` (no pilot: a move that needs a proposal is given ``proposal``) until the
    stopping rule, ``max_steps``, ``max_evaluations`` or ``max_seconds``; arguments as :func:`~bayes_mr.inference.mcmc.sampler.sample`'s.

    With ``settings.resume`` and a checkpoint the chain continues from its last stored step and random state.
    """
    t0 = _time.perf_counter()
    d = x0_center.size
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
        wall_s=_time.perf_counter() - t0, seed_entropy=entropy, names=tuple(names), history=history,
        projection=diag.get("projection"), pareto_k=float(diag.get("pareto_k", np.nan)),
        evaluations=int(sampler.iteration) * n_walkers, max_evaluations=settings.max_evaluations,
        max_seconds=settings.max_seconds,
    )
