"""The result of an emcee run (:func:`bayes_mr.inference.mcmc.sampler.sample`): the chain and its diagnostics."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


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
        Why the run ended: ``"converged"``, ``"max_steps"``, ``"max_seconds"``,
        ``"projected"`` (the rule projected past ``max_seconds``; see ``projection``) or ``"q_tails"``
        (a chain of the independence move alone met the rule but its proposals' ``pareto_k`` did not).
    wall_s : float
        Wall time of this call, its pilot included (a resumed run counts only its own part) [s].
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
        Mean acceptance of each adaptation round (:func:`bayes_mr.inference.mcmc.sampler.sample`).
    projection : dict or None
        With ``stopped == "projected"``: ``tau_max``, ``steps_needed``,
        ``seconds_needed`` and ``budget_s``
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
