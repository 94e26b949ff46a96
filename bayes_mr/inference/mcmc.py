"""emcee posterior: vectorised ensemble sampling until 50 autocorrelation times.

:func:`sample` draws from any vectorised log-density ``f(X (B, d)) -> (B,)``
with :class:`emcee.EnsembleSampler` (``vectorize=True``: every proposal of a
half-ensemble is one call, so one compiled batched simulation serves all
walkers); :func:`fit_mcmc` applies it to an
:class:`~bayes_mr.likelihood.OutputError` posterior, starting the walkers at
the least-squares optimum; :func:`to_inference_data` stores the result in the
package's InferenceData schema (:mod:`bayes_mr.results`).

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

Moves: differential evolution (80 %, emcee ``DEMove``, γ₀ = 2.38/√(2d)) and
the DE snooker update (20 %, :class:`Snooker`). Both are affine-invariant
like the stretch move, but DE's scale is the optimal one for Gaussian targets
in d dimensions while the stretch move's efficiency falls with d. Measured on
a correlated 6-d Gaussian (scales over three decades, 24 walkers): integrated
time ≈ 19 steps (DE alone), ≈ 23 (DE + snooker), ≈ 70 (stretch). The snooker
share is kept because it makes the Monte Carlo errors honest: over 24 seeds
on a 4-d Gaussian at 50 τ, (mean − truth)/MCSE has SD 1.3–1.4 with DE alone
(τ of a pure-DE ensemble is underestimated) and 1.0–1.2 with the mixture;
and it moves along lines through other walkers, which helps on curved ridges.
emcee 3.1.6's own ``DESnookerMove`` is wrong (see :class:`Snooker`) and is
not used.

Randomness: ``seed`` → :class:`numpy.random.SeedSequence`; one child seeds the
:class:`numpy.random.Generator` that draws the initial walkers, the other the
MT19937 ``RandomState`` emcee uses for its moves (emcee keeps a legacy
RandomState; we set its state, never the global one). The HDF5 backend
stores that state after every step, so resuming from a checkpoint continues
the same random stream: an interrupted and resumed run equals the
uninterrupted one bit for bit.
"""

from __future__ import annotations

import json
import math
import time as _time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import emcee
import numpy as np

from ..progress import bar as progress_bar
from ..scores import score
from ..stats import integrated_times


class Snooker(emcee.moves.DESnookerMove):
    """DE snooker update (ter Braak & Vrugt 2008) with emcee 3.1.6's two errors fixed.

    emcee 3.1.6 projects on ``(s − z)/√|s − z|`` instead of the unit vector
    and uses ½(d − 1) in the Hastings factor; its chain is not stationary at
    the target (on a 4-d Gaussian it under-disperses, E[χ²] 15 MCSE low —
    ``tests/test_mcmc.py``). Fixed upstream after 3.1.6 (dfm/emcee#531);
    this is the corrected proposal, so the pinned emcee can stay.
    """

    def get_proposal(self, s, c, random):
        ns, ndim = s.shape
        q = np.empty_like(s)
        log_factor = np.empty(ns)
        for i in range(ns):
            w = np.array([c[j][random.randint(len(c[j]))] for j in range(3)])
            random.shuffle(w)
            z, z1, z2 = w
            delta = s[i] - z
            norm = np.linalg.norm(delta)
            u = delta / norm
            q[i] = s[i] + u * self.gammas * (np.dot(u, z1) - np.dot(u, z2))
            log_factor[i] = (ndim - 1.0) * (np.log(np.linalg.norm(q[i] - z)) - np.log(norm))
        return q, log_factor


#: Move names accepted in :attr:`MCMCSettings.moves`. ``emcee_snooker`` is emcee 3.1.6's biased
#: DESnookerMove, kept only so the test can show the bias.
MOVES = {
    "de": emcee.moves.DEMove,
    "snooker": Snooker,
    "stretch": emcee.moves.StretchMove,
    "emcee_snooker": emcee.moves.DESnookerMove,
}

LogDensity = Callable[[np.ndarray], np.ndarray]


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
        Burn-in in pilot autocorrelation times (module docstring).
    rhat_max : float
        Every coordinate's rank-normalised split R-hat must be below this.
    max_steps : int
        Hard limit on steps (the result is then flagged not converged).
    check_every : int
        Steps between convergence checks (at multiples of it).
    moves : tuple of (str, float)
        Move names (:data:`MOVES`) and weights.
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
    check_every: int = 250
    moves: tuple[tuple[str, float], ...] = (("de", 0.8), ("snooker", 0.2))
    seed: int | np.random.SeedSequence = 0
    backend: str | Path | None = None
    resume: bool = False
    progress: bool | None = None

    def __post_init__(self):
        if self.max_steps < 1 or self.check_every < 1:
            raise ValueError(f"max_steps and check_every must be positive, got {self.max_steps}, {self.check_every}")

    def walkers(self, ndim: int) -> int:
        """Number of walkers for a ``ndim``-dimensional target."""
        if self.n_walkers is None:
            return max(4 * ndim, 2 * ndim + 2)
        n = int(self.n_walkers)
        if n % 2 or n < 2 * ndim + 2:
            raise ValueError(f"n_walkers must be even and at least 2·d + 2 = {2 * ndim + 2} "
                             f"(red–blue half-ensembles spanning the space), got {n}")
        return n

    def make_moves(self) -> list:
        """Fresh emcee move objects (moves keep per-run state; never share them)."""
        for name, _ in self.moves:
            if name not in MOVES:
                raise ValueError(f"unknown move '{name}'; valid: {', '.join(MOVES)}")
        return [(MOVES[name](), float(w)) for name, w in self.moves]


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
        The stopping rule was met (else ``max_steps`` stopped the run).
    wall_s : float
        Wall time of this call (a resumed run counts only its own part) [s].
    seed_entropy : str
        Entropy of the run's SeedSequence.
    names : tuple of str
        Coordinate names.
    history : list of dict
        Each convergence check: step, burn, tau_max, rhat_max.
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
    names: tuple[str, ...] = ()
    history: list = field(default_factory=list)

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


# --- diagnostics -----------------------------------------------------------------

def _quiet_arviz():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        import arviz as az
    return az


def rhat_ess(chain: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rank-normalised split R-hat and bulk ESS per coordinate (walkers as chains).

    Parameters
    ----------
    chain : ndarray, shape (n_steps, n_walkers, d)

    Returns
    -------
    rhat, ess : ndarray (d,)
    """
    az = _quiet_arviz()
    x = np.moveaxis(np.asarray(chain, float), 1, 0)  # (walker, step, d)
    rhat = np.array([float(az.rhat(x[:, :, j], method="rank")) for j in range(x.shape[2])])
    ess = np.array([float(az.ess(x[:, :, j], method="bulk")) for j in range(x.shape[2])])
    return rhat, ess


def diagnose(chain: np.ndarray, settings: MCMCSettings) -> dict:
    """Burn-in, τ, R-hat, ESS and the convergence verdict (module docstring rule).

    Parameters
    ----------
    chain : ndarray, shape (n_steps, n_walkers, d)
    settings : MCMCSettings

    Returns
    -------
    dict with ``burn``, ``tau`` (d,), ``rhat`` (d,), ``ess`` (d,), ``converged``.
    """
    n = chain.shape[0]
    tau0 = float(np.max(integrated_times(chain[n // 2:])))
    burn = n // 2 if not np.isfinite(tau0) else int(min(math.ceil(settings.burn_tau_multiple * tau0), n // 2))
    post = chain[burn:]
    tau = integrated_times(post)
    rhat, ess = rhat_ess(post)
    long_enough = bool(np.all(np.isfinite(tau))) and post.shape[0] >= settings.min_tau_multiple * float(np.max(tau))
    converged = bool(long_enough and np.all(rhat < settings.rhat_max))
    return {"burn": burn, "tau": tau, "rhat": rhat, "ess": ess, "converged": converged}


# --- sampling --------------------------------------------------------------------

def _seeds(seed) -> tuple[np.random.SeedSequence, np.random.Generator, dict]:
    """SeedSequence, the Generator of the initial walkers, and emcee's RandomState state."""
    seq = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    init_seq, move_seq = seq.spawn(2)
    rs = np.random.RandomState(np.random.MT19937(move_seq))
    return seq, np.random.default_rng(init_seq), rs.get_state()


#: Each redraw of the walkers that fell outside the support narrows their cloud by this factor.
SHRINK = 0.8


def initial_walkers(
    log_prob: LogDensity,
    center: np.ndarray,
    cov: np.ndarray,
    n_walkers: int,
    rng: np.random.Generator,
    *,
    max_rounds: int = 50,
) -> tuple[np.ndarray, np.ndarray]:
    """Walkers drawn from N(center, cov), redrawn until the log-density is finite.

    A walker whose draw has no finite log-density is drawn again from a cloud
    narrowed by :data:`SHRINK` per round, so a centre at the edge of the
    prior box (an optimum on a bound) still yields a full ensemble.

    Returns
    -------
    coords : ndarray (n_walkers, d)
    log_prob : ndarray (n_walkers,)

    Raises
    ------
    RuntimeError
        If after ``max_rounds`` fewer than all walkers have a finite
        log-density (the centre is outside the support, or the model fails
        near it).
    """
    center = np.asarray(center, float)
    d = center.size
    cov = np.atleast_2d(np.asarray(cov, float))
    # a tiny jitter keeps a singular covariance (an unidentified direction) drawable
    jitter = 1e-12 * max(float(np.trace(cov)) / d, 1e-300)
    L = np.linalg.cholesky(0.5 * (cov + cov.T) + jitter * np.eye(d))
    coords = np.empty((n_walkers, d))
    lp = np.full(n_walkers, -np.inf)
    todo = np.arange(n_walkers)
    for r in range(max_rounds):
        # a cloud that overhangs the prior box (an optimum at its edge) is drawn again, narrower
        x = center + SHRINK**r * rng.standard_normal((todo.size, d)) @ L.T
        val = np.asarray(log_prob(x), float)
        ok = np.isfinite(val)
        coords[todo[ok]] = x[ok]
        lp[todo[ok]] = val[ok]
        todo = todo[~ok]
        if todo.size == 0:
            return coords, lp
    raise RuntimeError(
        f"{todo.size} of {n_walkers} walkers have no finite log-density after {max_rounds} draws around "
        f"the starting point; check that it lies inside the prior box")


def sample(
    log_prob: LogDensity,
    x0_center: np.ndarray,
    x0_cov: np.ndarray,
    settings: MCMCSettings = MCMCSettings(),
    *,
    names: Sequence[str] | None = None,
    initial: np.ndarray | None = None,
    group: str = "mcmc",
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

    Returns
    -------
    MCMCResult

    Notes
    -----
    With ``settings.resume`` and an existing checkpoint the chain continues
    from its last stored step and random state; the seed and walker count
    must match the checkpoint's.
    """
    t0 = _time.perf_counter()
    x0_center = np.asarray(x0_center, float)
    d = x0_center.size
    names = tuple(names) if names is not None else tuple(f"x{j}" for j in range(d))
    n_walkers = settings.walkers(d) if initial is None else int(np.shape(initial)[0])
    seq, init_rng, move_state = _seeds(settings.seed)
    # a spawned child shares its parent's entropy: the spawn key tells them apart
    entropy = str(seq.entropy) + ("/" + "-".join(map(str, seq.spawn_key)) if seq.spawn_key else "")

    backend = None
    resuming = False
    if settings.backend is not None:
        backend = emcee.backends.HDFBackend(str(settings.backend), name=group)
        if settings.resume and backend.initialized and backend.iteration > 0:
            with backend.open() as f:
                stored = f[group].attrs.get("bayes_mr_seed_entropy")
            if stored is not None and str(stored) != entropy:
                raise ValueError(f"{settings.backend}[{group}]: checkpoint was made with seed entropy {stored}, "
                                 f"not {entropy}; resume with the same seed or start afresh (resume=False)")
            if backend.shape != (n_walkers, d):
                raise ValueError(f"{settings.backend}[{group}]: checkpoint holds {backend.shape} (walkers, dim), "
                                 f"this run needs {(n_walkers, d)}")
            resuming = True
        else:
            Path(settings.backend).parent.mkdir(parents=True, exist_ok=True)
            backend.reset(n_walkers, d)
            with backend.open("a") as f:
                f[group].attrs["bayes_mr_seed_entropy"] = entropy
                f[group].attrs["bayes_mr_settings"] = json.dumps({**asdict(settings), "seed": entropy}, default=str)

    sampler = emcee.EnsembleSampler(n_walkers, d, log_prob, moves=settings.make_moves(), backend=backend,
                                    vectorize=True)
    if resuming:
        state = sampler.backend.get_last_sample()  # carries the stored random state
    else:
        if initial is not None:
            coords = np.asarray(initial, float).copy()
            lp0 = np.asarray(log_prob(coords), float)
            if not np.all(np.isfinite(lp0)):
                raise ValueError(f"{int(np.sum(~np.isfinite(lp0)))} initial walkers have no finite log-density")
        else:
            coords, lp0 = initial_walkers(log_prob, x0_center, x0_cov, n_walkers, init_rng)
        state = emcee.State(coords, log_prob=lp0, random_state=move_state)

    it = int(sampler.iteration)
    history: list[dict] = []
    diag = None
    bar = progress_bar(settings.max_steps, "emcee", unit="step", enabled=settings.progress, initial=it)
    try:
        while True:
            if it > 0 and (it % settings.check_every == 0 or it >= settings.max_steps):
                diag = diagnose(sampler.get_chain(), settings)
                history.append({"step": it, "burn": diag["burn"], "tau_max": float(diag["tau"].max()),
                                    "rhat_max": float(diag["rhat"].max())})
                bar.set_postfix(tau=f"{diag['tau'].max():.1f}",
                                N_over_tau=f"{(it - diag['burn']) / diag['tau'].max():.0f}",
                                rhat=f"{diag['rhat'].max():.3f}")
                if diag["converged"] or it >= settings.max_steps:
                    break
            target = min(settings.max_steps, (it // settings.check_every + 1) * settings.check_every)
            # one step at a time through the generator so the bar moves; the backend saves every step
            steps = sampler.sample(state, iterations=target - it, skip_initial_state_check=resuming)
            for new_state in steps:
                bar.update(1)
            state = new_state
            it = target
            resuming = False
    finally:
        bar.close()

    chain = sampler.get_chain()
    lp = sampler.get_log_prob()
    tau = diag["tau"]
    return MCMCResult(
        chain=np.array(chain),
        log_prob=np.array(lp),
        burn=int(diag["burn"]),
        thin=max(1, int(0.5 * float(np.min(tau)))) if np.all(np.isfinite(tau)) else 1,
        tau=tau,
        rhat=diag["rhat"],
        ess=diag["ess"],
        acceptance=np.array(sampler.acceptance_fraction),
        converged=bool(diag["converged"]),
        wall_s=_time.perf_counter() - t0,
        seed_entropy=entropy,
        names=names,
        history=history,
    )


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
    """emcee posterior of an :class:`~bayes_mr.likelihood.OutputError`, started at least squares.

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
        from .lsq import LSQSettings, fit_lsq

        lsq = fit_lsq(lik, lsq_settings or LSQSettings(seed=settings.seed))
    center, cov = start_from_lsq(lik, lsq)
    return sample(lik, center, cov, settings, names=lik.names)


# --- results ----------------------------------------------------------------------------

def _even(n_have: int, n_want: int) -> np.ndarray:
    """``min(n_want, n_have)`` evenly spaced indices into ``range(n_have)``."""
    return np.unique(np.linspace(0, n_have - 1, min(n_want, n_have)).round().astype(int))


def to_inference_data(lik, result: MCMCResult, lsq=None, *, evidence=None, record=None,
                      n_ll_draws: int = 200, n_ll_samples: int = 2000, n_predictive: int = 20):
    """The package's InferenceData (:mod:`bayes_mr.results`) of an emcee posterior.

    Parameters
    ----------
    lik : OutputError
        The posterior that was sampled.
    result : MCMCResult
        Its chain (coordinates x = [φ, ln σ_c]).
    lsq : LSQResult, optional
        The least-squares fit the walkers started from (reported beside).
    evidence : Evidence or dict of str → Evidence, optional
        Evidence routes; with a dict the selecting one is
        :func:`bayes_mr.inference.evidence.select` of it and the others are
        reported beside it (``summary.extra["evidence_routes"]`` and the
        ``evidence`` group).
    record : xarray.Dataset, optional
        The fitted record (default ``lik.record``).
    n_ll_draws, n_ll_samples : int
        Pointwise log-likelihood on at most this many draws (all walkers ×
        evenly spaced draws) and evenly spaced valid samples.
    n_predictive : int
        Draws simulated for ``posterior_predictive``.

    Returns
    -------
    arviz.InferenceData
        ``posterior`` θ [SI] per free parameter, dims (chain = walker, draw)
        from the post-burn-in chain thinned by ``result.thin``;
        ``sample_stats`` ``lp`` with attributes ``rhat``, ``ess``, ``tau``
        (per coordinate, names in ``coordinates``); ``point_estimate`` the
        maximum-posterior step; the FitSummary scores are those of that point.
    """
    from .. import results
    from .evidence import Evidence, select

    record = lik.record if record is None else record
    coords = lik.par.coords
    p = lik.n_params
    kept = result.chain[result.burn:: result.thin]  # (n_draw, W, d)
    lp = result.log_prob[result.burn:: result.thin]
    x = np.moveaxis(kept, 1, 0)  # (W, n_draw, d)
    draws = coords.to_theta(x[:, :, :p])
    # the point the engine stands behind: the highest posterior density visited after burn-in
    post_lp = result.log_prob[result.burn:]
    i, w = np.unravel_index(int(np.argmax(post_lp)), post_lp.shape)
    x_map = result.chain[result.burn + i, w]
    point = coords.to_theta(x_map[:p])

    # pointwise log-likelihood: every walker at a few evenly spaced draws, on evenly spaced valid samples
    W, n_draw = x.shape[0], x.shape[1]
    d_idx = _even(n_draw, max(1, n_ll_draws // W))
    valid_idx = np.flatnonzero(lik.valid)
    t_idx = valid_idx[_even(valid_idx.size, n_ll_samples)]
    xs = x[:, d_idx].reshape(-1, x.shape[-1])
    terms_t = np.empty((xs.shape[0], t_idx.size, len(lik.channels)))
    for s in range(0, xs.shape[0], 24):
        _, terms = lik.log_likelihood(xs[s: s + 24], pointwise=True)
        terms_t[s: s + 24] = terms[:, t_idx, :]
    terms_t = terms_t.reshape(W, d_idx.size, t_idx.size, -1)
    ll = {c: terms_t[..., j] for j, c in enumerate(lik.channels)}

    flat = x.reshape(-1, x.shape[-1])
    pp_idx = _even(flat.shape[0], n_predictive)
    yhat, sim = lik.predict(flat[pp_idx, :p])
    pp = {c: yhat[None, :, :, j] for j, c in enumerate(lik.channels)}
    if lik.kind == "structure":
        pp["force"] = sim["force"][None]

    _, sim_map = lik.predict(x_map[:p])
    predicted = {k: v[0] for k, v in sim_map.outputs.items()}
    scores = score(record, predicted)

    routes: dict = {}
    if isinstance(evidence, Evidence):
        routes = {evidence.route: evidence}
        chosen = evidence
    elif evidence:
        routes = dict(evidence)
        chosen = select(routes)
    else:
        chosen = None
    sigma = np.exp(flat[:, p:]).mean(axis=0) if lik.noise == "sampled" else np.asarray(lik.noise_sd, float)
    flat_theta = draws.reshape(-1, p)
    wall = result.wall_s + (lsq.wall_s if lsq is not None else 0.0) + max(
        [e.wall_s for e in routes.values() if e.route != "laplace"] or [0.0])
    extra = {
        "evidence_route": chosen.route if chosen is not None else None,
        "evidence_routes": {k: e.to_dict() for k, e in routes.items()},
        "sigma": dict(zip(lik.channels, sigma)),
        "map": dict(zip(coords.names, point)),
        "n_steps": result.n_steps, "n_walkers": result.n_walkers, "burn": result.burn, "thin": result.thin,
        "tau_max": float(np.max(result.tau)), "rhat_max": float(np.max(result.rhat)),
        "ess_min": float(np.min(result.ess)), "acceptance": float(np.mean(result.acceptance)),
        "converged": bool(result.converged), "seed_entropy": result.seed_entropy,
    }
    if lsq is not None:
        extra["lsq_optimum"] = dict(lsq.theta)
    summary = results.FitSummary(
        model=lik.model.name, engine="mcmc", kind=lik.kind,
        params=dict(zip(coords.names, flat_theta.mean(axis=0))),
        params_sd=dict(zip(coords.names, flat_theta.std(axis=0, ddof=1))),
        log_evidence=None if chosen is None else float(chosen.log_z),
        mse=scores.get("mse"), force_errors=scores.get("force_errors"), force_nrmse=scores.get("force_nrmse"),
        masked=int((~lik.valid).sum()), wall_s=wall, extra=extra,
    )
    import xarray as xr

    names = list(lik.names)
    extra_groups = {"mcmc_diagnostics": xr.Dataset(
        {"rhat": ("coordinate", result.rhat), "ess": ("coordinate", result.ess),
         "tau": ("coordinate", result.tau), "acceptance": ("walker", result.acceptance)},
        coords={"coordinate": names}, attrs={"burn": result.burn, "thin": result.thin,
                                             "n_steps": result.n_steps, "converged": int(result.converged)})}
    if routes:
        order = list(routes)
        extra_groups["evidence"] = xr.Dataset(
            {k: ("route", np.array([getattr(routes[r], k) for r in order], float))
             for k in ("log_z", "mc_error", "ladder_error", "total_error", "wall_s")},
            coords={"route": order}, attrs={"selected": chosen.route})
    idata = results.make_inference_data(
        summary=summary, draws=draws, names=coords.names, units=coords.units, point=point, record=record,
        lp=np.moveaxis(lp, 1, 0), log_likelihood=ll, ll_index=t_idx, predictive=pp,
        extra_groups=extra_groups, attrs={"seed_entropy": result.seed_entropy},
    )
    idata.sample_stats.attrs.update(
        coordinates=",".join(names), rhat=np.asarray(result.rhat, float), ess=np.asarray(result.ess, float),
        tau=np.asarray(result.tau, float), burn=int(result.burn), thin=int(result.thin))
    return idata
