"""The temperature ladder of the sampling evidence routes (:mod:`bayes_mr.inference.evidence.routes`).

:func:`run_ladder` samples the integrand g at every temperature
0 = β_0 < … < β_K = 1 of a tempered path, p_β ∝ exp(β g + h):

* ``path="prior"`` (power posteriors): g = ln L, h = ln p;
* ``path="reference"``: g = ln L + ln p − ln q, h = ln q, with q the Gaussian
  fitted to the first half of the posterior chain, truncated to the prior
  box (:class:`Reference`).

β = 1 is the posterior chain itself, β = 0 is drawn exactly (iid from the
prior or from q), and every temperature between is an emcee chain
(:func:`bayes_mr.inference.mcmc.sampler.sample` with :data:`LADDER_SETTINGS`).
Where its walkers start depends on the path:

* reference path: every rung starts from the posterior's last walkers. Each
  p_β = q^(1−β) (p L)^β lies between q — a Gaussian fitted to the posterior —
  and the posterior, so those walkers are already typical there, and the
  rungs are independent jobs: they run one after another in process or side
  by side on an executor (:mod:`bayes_mr.execution.executor`), with the same numbers
  either way (each rung's seed is its own child of the ladder's seed);
* prior path: the walkers of each rung start where the chain of the rung
  above ended, the first rung's at the posterior's last walkers (or, when
  it has fewer than the rungs' ensemble needs, at draws spread over its
  chain: :func:`_ensemble_start`; the power posteriors spread from the posterior to the prior
  box over 20 rungs; a rung near β = 0 started at the posterior would need a
  long burn-in), so these rungs run in order, in process.
:func:`mean_variance` is the Monte Carlo variance of a rung's mean of g that
both thermodynamic integration and stepping-stone use.
"""

from __future__ import annotations

import math
import time as _time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from bayes_mr.execution.executor import run_jobs, share
from bayes_mr.numerics.stats import integrated_times
from bayes_mr.numerics.synthetic_noise import as_seed_sequence
from bayes_mr.inference.mcmc.chain import MCMCResult
from bayes_mr.inference.mcmc.settings import MCMCSettings
from bayes_mr.inference.mcmc.sampler import sample
from bayes_mr.inference.mcmc.moves import local_moves


@dataclass(frozen=True)
class BoxTarget:
    """A likelihood with a uniform prior on a box (anything :func:`run_ladder` can use).

    :class:`~bayes_mr.likelihood.output_error.OutputError` has the same interface
    (``log_likelihood``, ``log_prior``, ``lower``, ``upper``).

    Attributes
    ----------
    loglike : callable
        ln L(X) for X of shape (B, d) → (B,).
    lower, upper : ndarray (d,)
        The prior box.
    """

    loglike: Callable[[np.ndarray], np.ndarray]
    lower: np.ndarray
    upper: np.ndarray

    def log_likelihood(self, x: np.ndarray) -> np.ndarray:
        return np.asarray(self.loglike(np.atleast_2d(x)), float)

    def log_prior(self, x: np.ndarray) -> np.ndarray:
        x = np.atleast_2d(np.asarray(x, float))
        inside = np.all((x >= self.lower) & (x <= self.upper), axis=1)
        return np.where(inside, -float(np.sum(np.log(np.asarray(self.upper) - self.lower))), -np.inf)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        lp = self.log_prior(x)
        out = lp.copy()
        inside = np.isfinite(lp)
        if inside.any():
            out[inside] += self.log_likelihood(np.atleast_2d(x)[inside])
        return out


class Reference:
    """Gaussian reference density q truncated to the prior box.

    Parameters
    ----------
    mean : ndarray (d,)
    cov : ndarray (d, d)
    lower, upper : ndarray (d,)
        Prior box.
    rng : numpy.random.Generator
        Draws for the box mass (and nothing else).
    n_mass : int
        Draws used to estimate P_q(box).
    """

    def __init__(self, mean, cov, lower, upper, rng: np.random.Generator, n_mass: int = 200_000):
        self.mean = np.asarray(mean, float)
        d = self.mean.size
        cov = np.asarray(cov, float).reshape(d, d)
        self.chol = np.linalg.cholesky(0.5 * (cov + cov.T) + 1e-12 * np.trace(cov) / d * np.eye(d))
        self.cov = self.chol @ self.chol.T
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)
        self._log_norm = -0.5 * d * math.log(2 * math.pi) - float(np.sum(np.log(np.diag(self.chol))))
        z = rng.standard_normal((n_mass, d))
        inside = self._inside(self.mean + z @ self.chol.T)
        p = float(inside.mean())
        if p <= 0:
            raise ValueError("the reference Gaussian has no mass inside the prior box")
        self.log_mass = math.log(p)
        # binomial error of ln p̂
        self.log_mass_error = math.sqrt((1 - p) / (p * n_mass)) if p < 1 else 1.0 / n_mass

    def _inside(self, x):
        return np.all((x >= self.lower) & (x <= self.upper), axis=1)

    def logpdf(self, x: np.ndarray) -> np.ndarray:
        """ln q_trunc(x) (−inf outside the box)."""
        x = np.atleast_2d(x)
        u = np.linalg.solve(self.chol, (x - self.mean).T).T
        out = self._log_norm - 0.5 * np.sum(u * u, axis=1) - self.log_mass
        return np.where(self._inside(x), out, -np.inf)

    def draw(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """n exact draws of q_trunc (rejection from the Gaussian)."""
        out = []
        have = 0
        while have < n:
            x = self.mean + rng.standard_normal((2 * (n - have) + 16, self.mean.size)) @ self.chol.T
            x = x[self._inside(x)]
            out.append(x)
            have += x.shape[0]
        return np.vstack(out)[:n]


class _Path:
    """Tempered density ln p_β = β g + h and the integrand g (both vectorised)."""

    def __init__(self, target, kind: str, reference: Reference | None):
        self.target, self.kind, self.reference = target, kind, reference

    def h(self, x):
        """The β-independent part: ln p (prior path) or ln q (reference path)."""
        return self.target.log_prior(x) if self.kind == "prior" else self.reference.logpdf(x)

    def g(self, x):
        """The integrand: ln L (prior path) or ln L + ln p − ln q (reference path)."""
        x = np.atleast_2d(x)
        h = self.h(x)
        out = np.full(x.shape[0], -np.inf)
        ok = np.isfinite(h)
        if ok.any():
            ll = self.target.log_likelihood(x[ok])
            out[ok] = ll if self.kind == "prior" else ll + self.target.log_prior(x[ok]) - h[ok]
        return out

    def density(self, beta: float):
        def f(x):
            x = np.atleast_2d(x)
            h = self.h(x)
            out = np.full(x.shape[0], -np.inf)
            ok = np.isfinite(h)
            if self.kind == "reference":
                ok &= np.isfinite(self.target.log_prior(x))
            if ok.any():
                g = self.g(x[ok])
                val = beta * g + h[ok]
                out[ok] = np.where(np.isfinite(g), val, -np.inf)
            return out
        return f

    def g_from_lp(self, x, lp, beta):
        """g at chain positions x (..., d) from their stored log-density lp (...) (no likelihood call)."""
        x = np.asarray(x, float)
        h = self.h(x.reshape(-1, x.shape[-1])).reshape(x.shape[:-1])
        return (np.asarray(lp, float) - h) / beta


# --- the ladder ---------------------------------------------------------------------------

@dataclass
class Ladder:
    """Samples of g at every temperature.

    Attributes
    ----------
    betas : ndarray (K+1,)
        0 = β_0 < … < β_K = 1.
    g : list of ndarray
        g at β_k: (n_k, 1) exact draws at β_0, (n_steps, n_walkers) post-burn chain otherwise.
    tau : ndarray (K+1,)
        Integrated autocorrelation time of g at each β (1 for the exact draws).
    path : str
    extra_log_z : float, extra_var : float
        Constant added to ln Z and its variance (reference box mass).
    chains : list of MCMCResult or None
    wall_s : float
    """

    betas: np.ndarray
    g: list
    tau: np.ndarray
    path: str
    extra_log_z: float = 0.0
    extra_var: float = 0.0
    chains: list = field(default_factory=list)
    wall_s: float = 0.0

    def unconverged(self) -> list[float]:
        """The β of every rung whose chain did not converge (β = 1 is the posterior's own chain).

        A rung that stopped at ``max_steps`` before its ≥ N τ and R-hat rule
        held gives a biased mean of g there, so an evidence from this ladder
        is not to be selected on (see :func:`bayes_mr.selection.comparison.selection_route`).
        """
        return [float(b) for b, c in zip(self.betas, self.chains)
                if c is not None and not bool(getattr(c, "converged", True))]

    def moments(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Mean, variance and Monte Carlo variance of the mean of g at each β."""
        mean = np.array([float(np.mean(g)) for g in self.g])
        var = np.array([float(np.var(g, ddof=1)) for g in self.g])
        return mean, var, np.array([mean_variance(g) for g in self.g])


def default_ladder(path: str, n_temps: int | None = None) -> np.ndarray:
    """β_k = (k/K)⁵ with K = 20 for the prior path; β_k = (k/K)³ with K = 8 for the reference path.

    The reference path's integrand is flat for a Gaussian posterior whatever
    the spacing, but where the posterior is not Gaussian (LuGre's ε pinned
    at its lower bound) q puts mass where the likelihood is tiny and Var_β[g]
    falls from ~4000 at β = 0 to ~1 by β ≈ 0.3; cubic spacing resolves that
    (measured: uniform K = 8 gives a ladder error of 5 nats there, cubic
    K = 8 0.02, cubic K = 12 0.006, and the three agree within errors).
    """
    if path == "prior":
        K = n_temps or 20
        return (np.arange(K + 1) / K) ** 5
    K = n_temps or 8
    return (np.arange(K + 1) / K) ** 3


#: Settings of each temperature's chain: the mean of g with an error bar is all that is needed,
#: so 10 τ (not 50) and R-hat < 1.1; the MC error is :func:`mean_variance`. On the analytic
#: evidence of ``tests/inference/test_evidence.py`` (linear LuGre device test), with the reference
#: path's rungs proposing from q alone on the posterior's 8 independent walkers
#: (``MCMCSettings.moves``), the z-scores (ln Ẑ − ln Z)/error over six seeds have mean 0.15 and SD
#: 0.44 (TI), 0.27 and 0.60 (stepping-stone): the error bars are conservative. Rejected: the differential-evolution mixture on 2·d + 2 walkers,
#: whose error bars were optimistic by a factor ≈ 1.6 (τ of a short chain is underestimated). The
#: errors are a hundredth of a nat, far below the differences that decide a selection.
LADDER_SETTINGS = MCMCSettings(min_tau_multiple=10.0, rhat_max=1.1, check_every=50, max_steps=4000)


def run_ladder(
    target,
    posterior: MCMCResult,
    *,
    path: str = "reference",
    betas: np.ndarray | None = None,
    settings: MCMCSettings = LADDER_SETTINGS,
    n_exact: int = 4000,
    seed: int | np.random.SeedSequence = 0,
    executor=None,
) -> Ladder:
    """Sample g at every temperature of the ladder.

    Parameters
    ----------
    target : OutputError or BoxTarget
        ``log_likelihood``, ``log_prior``, ``lower``, ``upper``.
    posterior : MCMCResult
        A converged chain of the posterior (β = 1) in the target's coordinates;
        it is reused as the top rung and, for the reference path, fits q.
    path : {"reference", "prior"}
    betas : ndarray, optional
        The ladder (default :func:`default_ladder`).
    settings : MCMCSettings
        Settings of each temperature's chain; ``seed`` is replaced by a child
        of ``seed`` per temperature, and a ``backend`` file holds every
        temperature as its own group (``ti_<k>``) so a ladder resumes too.
    n_exact : int
        Exact draws at β = 0 (from the prior or from q).
    seed : int or SeedSequence
    executor : object, optional
        Runs the reference path's rungs as jobs (a ``concurrent.futures``
        executor or a ``dask.distributed.Client``); the ladder is the same as
        in process. Not with a ``backend`` (one HDF5 file cannot take writes
        from several processes); the prior path's chained rungs ignore it.

    Returns
    -------
    Ladder
    """
    if path not in ("reference", "prior"):
        raise ValueError(f"path must be 'reference' or 'prior', got {path!r}")
    t0 = _time.perf_counter()
    betas = default_ladder(path) if betas is None else np.asarray(betas, float)
    if not (betas[0] == 0 and betas[-1] == 1 and np.all(np.diff(betas) > 0)):
        raise ValueError("the ladder must rise strictly from 0 to 1")
    seq = as_seed_sequence(seed)
    ref_seq, exact_seq, *temp_seqs = seq.spawn(2 + betas.size)
    reference, post, lp_post = _top_rung(target, posterior, path, ref_seq)
    extra, extra_var = 0.0, (reference.log_mass_error**2 if reference is not None else 0.0)
    tp = _Path(target, path, reference)

    K = betas.size - 1
    g = [None] * (K + 1)
    tau = np.ones(K + 1)
    chains: list = [None] * (K + 1)
    # β = 1: the posterior itself
    g_top = tp.g_from_lp(post, lp_post, 1.0)
    g[K], tau[K], chains[K] = g_top, _tau(g_top), posterior
    g[0] = _exact_rung(tp, target, path, n_exact, np.random.default_rng(exact_seq))[:, None]
    rungs = list(range(K - 1, 0, -1))
    settings_k = {k: replace(settings, seed=temp_seqs[k]) for k in rungs}
    top = post[-1] if path == "reference" else _ensemble_start(post, settings.walkers(post.shape[-1]))
    for k, res in zip(rungs, _run_rungs(tp, betas, rungs, top, settings_k, executor)):
        gk = tp.g_from_lp(res.chain[res.burn:], res.log_prob[res.burn:], float(betas[k]))
        g[k], tau[k], chains[k] = gk, _tau(gk), res
    return Ladder(betas, g, tau, path, extra, extra_var, chains, _time.perf_counter() - t0)


def _run_rungs(tp: _Path, betas: np.ndarray, rungs: list[int], top: np.ndarray, settings_k: dict, executor) -> list:
    """The chains of ``rungs`` (indices into ``betas``, top down), from the posterior's last walkers ``top``.

    Reference path: independent jobs (:func:`bayes_mr.execution.executor.run_jobs`, on ``executor`` if given);
    prior path: in order, each rung from where the one above ended.
    """
    if tp.kind == "reference":
        if executor is not None and any(s.backend is not None for s in settings_k.values()):
            raise ValueError("a ladder on an executor cannot share one HDF5 backend between its rungs")
        ref = share(executor, tp)
        jobs = [(ref, float(betas[k]), top, settings_k[k], f"ti_{k:02d}") for k in rungs]
        outcomes = run_jobs(rung_chain, jobs, executor=executor)
        failed = [o.error for o in outcomes if not o.ok]
        if failed:
            raise RuntimeError(f"ladder rung failed: {failed[0]}")
        return [o.value for o in outcomes]
    done, start = [], top
    for k in rungs:
        done.append(rung_chain(tp, float(betas[k]), start, settings_k[k], f"ti_{k:02d}"))
        start = done[-1].chain[-1]
    return done


def rung_chain(tp: _Path, beta: float, start: np.ndarray, settings: MCMCSettings, group: str) -> MCMCResult:
    """The emcee chain of one temperature β, its walkers starting at ``start`` (n_walkers, d).

    Module level with picklable arguments: a job for :func:`bayes_mr.execution.executor.run_jobs`.
    """
    if tp.kind == "reference":
        # p_β lies between q and the posterior: q itself is the independence move's proposal
        proposal = (tp.reference.mean, tp.reference.cov)
    else:
        # the power posteriors widen towards the prior box, which no Gaussian of the rung above fits
        proposal = None
        settings = replace(settings, moves=local_moves(settings.adapt_moves))
    return sample(tp.density(beta), start.mean(axis=0), np.eye(start.shape[1]), settings, initial=start,
                  group=group, proposal=proposal)


def _ensemble_start(post: np.ndarray, n: int) -> np.ndarray:
    """``n`` walkers for the prior path's first rung from a posterior chain (n_steps, n_walkers, d): its last
    walkers, and where the chain has fewer (a chain of independent walkers, ``MCMCSettings.moves``), draws
    of theirs spread evenly over the chain, so that the ensemble's moves start from walkers spanning the
    posterior."""
    if post.shape[1] >= n:
        return post[-1, :n]
    flat = post.reshape(-1, post.shape[-1])
    return flat[np.linspace(0, flat.shape[0] - 1, n).round().astype(int)[::-1]]


def _top_rung(target, posterior: MCMCResult, path: str, ref_seq) -> tuple[Reference | None, np.ndarray, np.ndarray]:
    """The reference q (None on the prior path) and the posterior chain and log-densities that serve as β = 1.

    On the reference path q is fitted to the first half of the post-burn-in
    chain and E_1[g] taken over the second: on the samples q was fitted to,
    ln q is too high by ~(#q parameters)/ESS (in-sample optimism).
    """
    post = posterior.chain[posterior.burn:]
    lp_post = posterior.log_prob[posterior.burn:]
    if path != "reference":
        return None, post, lp_post
    lower, upper = np.asarray(target.lower, float), np.asarray(target.upper, float)
    half = post.shape[0] // 2
    fit = post[:half].reshape(-1, post.shape[-1])
    reference = Reference(fit.mean(axis=0), np.cov(fit, rowvar=False), lower, upper,
                          np.random.default_rng(ref_seq))
    return reference, post[half:], lp_post[half:]


def _exact_rung(tp: _Path, target, path: str, n_exact: int, rng: np.random.Generator) -> np.ndarray:
    """g at ``n_exact`` exact draws of β = 0 (uniform on the prior box, or from q) (n_exact,)."""
    lower, upper = np.asarray(target.lower, float), np.asarray(target.upper, float)
    x0 = (lower + rng.random((n_exact, lower.size)) * (upper - lower)) if path == "prior" \
        else tp.reference.draw(n_exact, rng)
    g0 = tp.g(x0)
    if not np.all(np.isfinite(g0)):
        # a model that fails to simulate has zero likelihood there: E_0[ln L] is −∞ and TI undefined
        raise ValueError(f"{int(np.sum(~np.isfinite(g0)))} of {n_exact} draws at β = 0 have no finite "
                         f"log-likelihood; the {path} path cannot integrate from there")
    return g0


def _tau(g: np.ndarray) -> float:
    """Integrated autocorrelation time of g (n_steps, n_walkers), at least 1."""
    g = np.asarray(g, float)
    if g.ndim == 1 or g.shape[0] < 4 or np.all(g == g.flat[0]):
        return 1.0
    return max(1.0, float(integrated_times(g[:, :, None])[0]))


def mean_variance(g: np.ndarray) -> float:
    """Monte Carlo variance of the mean of g, (n_steps, n_walkers) from an ensemble or (n, 1) iid.

    Ensemble moves couple the walkers, so per-walker autocorrelation times
    miss the correlation *between* walkers. The variance is the larger of
    Var(g)·τ/N (per-walker τ) and Var(ḡ_t)·τ_ḡ/n_steps, with ḡ_t the
    ensemble mean at step t (which carries the between-walker part).
    On the analytic evidence of ``tests/inference/test_evidence.py``, per-walker
    τ alone gives z-scores of SD ≈ 2.
    """
    g = np.asarray(g, float)
    if g.ndim == 1:
        g = g[:, None]
    per_walker = float(np.var(g, ddof=1)) * _tau(g) / g.size
    if g.shape[1] == 1 or g.shape[0] < 4:
        return per_walker
    gbar = g.mean(axis=1)
    if np.all(gbar == gbar[0]):
        return per_walker
    tau_bar = max(1.0, float(integrated_times(gbar[:, None, None])[0]))
    return max(per_walker, float(np.var(gbar, ddof=1)) * tau_bar / gbar.size)
