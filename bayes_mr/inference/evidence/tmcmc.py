"""Transitional MCMC (Ching & Chen 2007; Betz, Papaioannou & Straub 2016): an opt-in evidence route.

A population of N particles moves from β = 0 to β = 1 along the tempered path
p_β ∝ exp(β g + h) of :mod:`bayes_mr.inference.evidence.ladder` — from the prior box
(``start="prior"``, g = ln L, h = ln p: the field's way) or from the
reference q fitted to a posterior chain (``start="reference"``, g = ln L + ln p
− ln q, h = ln q: TI's reference path). Each stage j:

1. the next β_{j+1} is the one at which the plausibility weights
   w_i = exp((β_{j+1} − β_j) g_i) have coefficient of variation
   ``target_cov`` (= 1, Betz et al.), found by bisection;
2. ln Ŝ_j = ln mean(w_i), and ln Ẑ = Σ_j ln Ŝ_j (+ ln of q's box mass on the
   reference start);
3. N particles are resampled multinomially by w;
4. each is moved by random-walk Metropolis on p_{β_{j+1}} with the proposal
   c² Σ_j, Σ_j the weighted covariance of the stage's population (Betz et al.:
   the current stage's, not the previous one's); the scale c is adapted after
   every step towards ``target_acceptance``, and the chains run until a
   particle has on average made ``min_moves`` accepted moves (Betz et al.'s
   burn-in: a resampled particle must forget its duplicate), at least
   ``min_steps`` and at most ``max_steps`` steps. All N chains step together:
   one batched likelihood call of N parameter sets per step.

Error: the Lee & Whiteley (2018) / Chan & Lai (2013) single-run estimator of
the relative variance of Ẑ from the particles' *Eve* indices (the stage-0
ancestor each descends from; multinomial resampling, which is why it is used):
Var(Ẑ)/Ẑ² ≈ 1 − (N/(N−1))^{n+1} Σ_{E_i ≠ E_k} W_i W_k with W the last stage's
normalised weights and n the resampling steps; ``mc_error`` = its square root
(delta method). It grows when the genealogy collapses to few Eves, so it is
conservative where the population has lost diversity. ``details`` also carries
the naive stage-wise estimate √(Σ_j CoV_j²/N) (independent particles assumed),
measured to be optimistic (see the verdict).

Health (``unconverged``: the β of every stage that fails, like a failed rung,
so ``compare`` refuses it): a stage fails if the effective sample size of its
weights (Σw)²/Σw² is below ``min_ess`` (default max(50, 10·d)), or if fewer than
``min_moved`` of its particles moved in its MCMC (the population is then
duplicates); and β = 1 is flagged when the last stage descends from fewer than
``min_eves`` stage-0 particles (the error bar is then meaningless). A run that
needs more than ``max_stages`` stages raises.

Verdict — measured by ``scripts/measure_tmcmc.py`` (single process, under load from
other jobs; N = 1000 particles (500 on dahl); TI/SS = the reference-path ladder of
:mod:`~bayes_mr.inference.evidence.routes` whose evaluations include the emcee
posterior it needs; "evals" of TMCMC are those ln Ẑ needed). Bias and SD of
ln Ẑ − ln Z over 5 seeds:

==========================  ================  ================  ==================  ================
case                        TI                SS                TMCMC from prior    TMCMC from q
==========================  ================  ================  ==================  ================
4-D Gaussian, box 30 SD     −0.002 ± 0.004    −0.002 ± 0.003    −0.03 ± 0.15        −0.001 ± 0.006
  evals / wall              41 k / 4.4 s      (same samples)    60 k / 0.1 s        1 k (+9 k post.)
linear LuGre device (3-D)   −0.004 ± 0.002    −0.002 ± 0.009    −0.07 ± 0.15        −0.001 ± 0.009
  evals / wall              25 k / 51 s       (same samples)    98 k / 23 s         1 k / 2 s
bimodal 0.3/0.7, 12 SD      **−1.204** ± 0.005 **−1.204** ± 0.005 −0.06 ± 0.04       **−1.206** ± 0.003
==========================  ================  ================  ==================  ================

Reported errors were honest (|z| ≤ 2 on every unimodal run; mean reported
error 0.145–0.17 against SD 0.15 from the prior, where the stage-wise
"naive" error, 0.09–0.12, is optimistic — the Eve estimator is the one used).
Simulated dahl structure test, 4 s at 250 Hz (1 % output noise, 6-D with the
two ln σ; ln Z unknown, so against TI), 3 seeds, generic kernels: TI
13377.982, SD 0.004 (error 0.004), 87 k evals, 255 s; SS agrees (SD 0.005);
**TMCMC from the prior (N = 500) lands 40–109 nats low** (SD 37), 93 k evals,
213 s: the population settles in a secondary mode and the genealogy collapses
to 1–2 Eves — all three runs are flagged (fewer than 80 % of particles moved
at β ≈ 1e-3–5e-3, and the Eve floor), so ``compare`` would refuse them, but
its error bar (0.7–1.0) is no guide; TMCMC from q (N = 500, one stage) −0.003
± 0.012 from TI with error 0.008, 500 evals (+ the posterior chain), 10 s.

So: **from the prior (the field's way) TMCMC does not earn the selecting
place** — on the model record it is wrong by tens of nats (flagged), and on
the analytic cases, at 1.5–4× TI's likelihood evaluations, its error is 15–40×
larger (work-normalised variance ~10³× worse), because it pays the whole
prior-to-posterior information gain in stages of CoV 1 with a few hundred
surviving lineages. Its batched likelihood makes it fast per evaluation
(0.24 ms against emcee's 2 ms on the device record), not enough to close
that gap. It has one **robustness advantage** the ladder has not: a mode the
β = 1 emcee chain never visited is invisible to TI and SS (and to TMCMC from
q, which inherits the chain's reference), which then report ln Z off by
ln 0.3 with an error bar of 0.005 and every rung converged; TMCMC from the
prior finds both modes and their shares — on a toy; on the dahl record the
same search ended in the wrong mode. **From the reference q** it is
importance sampling from q in one stage whenever q's weights have CoV ≤ 1
(every unimodal case here, dahl included) — as accurate as TI/SS for
1/20–1/140 of the ladder's evaluations, and it adds stages by itself where q
fits badly (not measured here: a posterior piled on a bound, LuGre's ε). It
stays an opt-in route (``Emcee(evidence="tmcmc")``, from q; or beside TI via
:func:`~bayes_mr.inference.evidence.routes.evidence_routes`): making it the default
would change default results, and the non-Gaussian case is unmeasured; on
these measurements it is the cheaper route wherever the posterior chain has
found every mode.
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import dataclass, field

import numpy as np
from scipy.special import logsumexp

from bayes_mr.inference.evidence.ladder import BoxTarget, Reference, _Path


@dataclass(frozen=True)
class TMCMCSettings:
    """Settings of a TMCMC run.

    Attributes
    ----------
    n_particles : int
        Population size N.
    target_cov : float
        Coefficient of variation of the plausibility weights that sets each Δβ.
    target_acceptance : float
        Acceptance rate the proposal scale is adapted towards.
    min_moves : float
        Mean accepted Metropolis moves per particle per stage before the stage ends.
    min_steps, max_steps : int
        Bounds on the Metropolis steps of one stage.
    max_stages : int
        Stages allowed before the run is abandoned (ValueError).
    min_ess : float or None
        Weight ESS a healthy stage needs (default max(50, 10·d)).
    min_moved : float
        Fraction of particles a healthy stage's MCMC must have moved.
    min_eves : int
        Distinct stage-0 ancestors the last stage needs; with fewer the Eve
        error bar has nothing to stand on and the run is flagged (at β = 1).
    start : {"prior", "reference"}
        β = 0 is the prior box or the reference Gaussian q of a posterior chain.
    final_moves : bool
        Move the particles after the last stage too (they are then the
        posterior's; ln Ẑ does not need it, and a run beside an emcee posterior
        skips it).
    seed : int
    """

    n_particles: int = 1000
    target_cov: float = 1.0
    target_acceptance: float = 0.25
    min_moves: float = 2.0
    min_steps: int = 3
    max_steps: int = 40
    max_stages: int = 400
    min_ess: float | None = None
    min_moved: float = 0.8
    min_eves: int = 20
    start: str = "prior"
    final_moves: bool = True
    seed: int = 0

    def __post_init__(self):
        if self.start not in ("prior", "reference"):
            raise ValueError(f"start must be 'prior' or 'reference', got {self.start!r}")
        if self.n_particles < 4:
            raise ValueError("TMCMC needs at least 4 particles")


class Counted:
    """A target whose likelihood calls are counted (rows evaluated), for budgets.

    Parameters
    ----------
    target : OutputError or BoxTarget
    """

    def __init__(self, target):
        self.target, self.n_evals = target, 0
        self.lower, self.upper = np.asarray(target.lower, float), np.asarray(target.upper, float)

    def log_likelihood(self, x: np.ndarray) -> np.ndarray:
        x = np.atleast_2d(x)
        self.n_evals += x.shape[0]
        return self.target.log_likelihood(x)

    def log_prior(self, x: np.ndarray) -> np.ndarray:
        return self.target.log_prior(x)

    #: ln posterior of each row, a log-density for :func:`~bayes_mr.inference.mcmc.sampler.sample` (BoxTarget's on these methods)
    __call__ = BoxTarget.__call__


@dataclass
class TMCMCResult:
    """A finished TMCMC run (its :class:`~bayes_mr.inference.evidence.routes.Evidence` is
    :func:`bayes_mr.inference.evidence.routes.tmcmc_evidence` of it).

    Attributes
    ----------
    log_z : float
        ln Ẑ [nats].
    log_z_error : float
        Eve-based standard error of ln Ẑ [nats].
    naive_error : float
        Stage-wise error assuming independent particles [nats].
    particles : ndarray (N, d)
        Posterior particles (β = 1, after the last stage's moves).
    betas : ndarray (J+1,)
        0 = β_0 < … < β_J = 1.
    stages : list of dict
        Per stage: ``beta`` (the stage's new β), ``log_s``, ``ess``, ``acceptance``, ``moved``, ``steps``, ``scale``.
    n_evals : int
        Likelihood evaluations (parameter sets).
    n_evals_evidence : int
        Of them, those ln Ẑ needed (all but the last stage's moves, which only
        make the posterior particles).
    n_eves : int
        Distinct stage-0 ancestors among the last stage's particles.
    unhealthy : list of float
        β of the stages that failed the health checks.
    wall_s : float
    """

    log_z: float
    log_z_error: float
    naive_error: float
    particles: np.ndarray
    betas: np.ndarray
    stages: list
    n_evals: int
    n_eves: int
    n_evals_evidence: int = 0
    unhealthy: list = field(default_factory=list)
    wall_s: float = 0.0

    def details(self) -> dict:
        """Plain-Python per-run numbers for :class:`~bayes_mr.inference.evidence.routes.Evidence` ``details``."""
        return {"n_stages": len(self.stages), "betas": self.betas.tolist(), "n_evals": int(self.n_evals),
                "n_evals_evidence": int(self.n_evals_evidence), "n_eves": int(self.n_eves),
                "naive_error": float(self.naive_error), "ess": [s["ess"] for s in self.stages],
                "acceptance": [s["acceptance"] for s in self.stages], "moved": [s["moved"] for s in self.stages]}


# --- the pieces of one stage -------------------------------------------------------------

def next_beta(g: np.ndarray, beta: float, target_cov: float) -> float:
    """The β after ``beta`` at which exp(Δβ g) has coefficient of variation ``target_cov``.

    Particles with g = −∞ (a failed simulation) weigh 0 at any Δβ > 0; if they
    alone already push the CoV past the target, the target is relaxed to just
    above that floor (the stage then drops them).
    """
    finite = np.isfinite(g)
    frac_dead = 1.0 - float(finite.mean())
    floor = math.sqrt(frac_dead / (1.0 - frac_dead)) if frac_dead < 1 else math.inf
    if not math.isfinite(floor):
        raise ValueError("every particle has a zero likelihood; TMCMC cannot start")
    target = max(target_cov, 1.05 * floor)
    gf = g[finite] - np.max(g[finite])

    def cov(db: float) -> float:
        w = np.zeros(g.size)
        w[finite] = np.exp(db * gf)
        return float(np.std(w) / np.mean(w))

    hi = 1.0 - beta
    if cov(hi) <= target:
        return 1.0
    lo = 0.0
    for _ in range(100):  # bisection on Δβ; CoV rises with Δβ
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if cov(mid) < target else (lo, mid)
        if hi - lo < 1e-12 * max(hi, 1e-300):
            break
    return beta + 0.5 * (lo + hi)


def weighted_cov(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Covariance of the rows of x (N, d) under normalised weights w (N,), regularised to be positive definite."""
    mean = w @ x
    r = x - mean
    c = (r * w[:, None]).T @ r / max(1e-12, 1.0 - float(np.sum(w * w)))
    d = x.shape[1]
    return 0.5 * (c + c.T) + 1e-10 * (np.trace(c) / d + 1e-300) * np.eye(d)


def mutate(tp: _Path, x: np.ndarray, g: np.ndarray, beta: float, cov: np.ndarray, scale: float,
           s: TMCMCSettings, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, dict]:
    """Random-walk Metropolis of every particle on p_β (all chains step together).

    Returns
    -------
    x, g : ndarray
        The moved particles and their g.
    info : dict
        ``acceptance``, ``moved`` (fraction of particles moved), ``steps``, ``scale`` (adapted c).
    """
    n, d = x.shape
    chol = np.linalg.cholesky(cov)
    h = tp.h(x)
    accepted = np.zeros(n)
    steps = 0
    log_c = math.log(scale)
    while steps < s.max_steps and (steps < s.min_steps or accepted.mean() < s.min_moves):
        y = x + math.exp(log_c) * rng.standard_normal((n, d)) @ chol.T
        hy = tp.h(y)
        gy = np.full(n, -np.inf)
        ok = np.isfinite(hy)
        if ok.any():
            gy[ok] = tp.g(y[ok])
        with np.errstate(invalid="ignore"):
            log_a = beta * (gy - g) + (hy - h)
        acc = np.log(rng.random(n)) < np.where(np.isfinite(log_a), log_a, -np.inf)
        x, g, h = np.where(acc[:, None], y, x), np.where(acc, gy, g), np.where(acc, hy, h)
        accepted += acc
        steps += 1
        # Robbins–Monro on ln c towards the target acceptance (one population-wide scale)
        log_c += (float(acc.mean()) - s.target_acceptance) / math.sqrt(steps)
    return x, g, {"acceptance": float(accepted.sum() / (n * steps)), "moved": float(np.mean(accepted > 0)),
                  "steps": steps, "scale": math.exp(log_c)}


def eve_relative_variance(eves: np.ndarray, log_w: np.ndarray, n_resamplings: int) -> float:
    """Lee–Whiteley estimate of Var(Ẑ)/Ẑ² from the last stage's Eve indices and log-weights.

    1 − (N/(N−1))^{n+1} (1 − Σ_k S_k²), S_k the normalised weight of Eve k's
    descendants; for one stage (plain importance sampling) it is the usual
    Var(w)/(N w̄²) up to N/(N−1).
    """
    n = eves.size
    wn = np.exp(log_w - logsumexp(log_w))
    share = np.bincount(eves, weights=wn, minlength=n)
    distinct = 1.0 - float(np.sum(share**2))
    return max(0.0, 1.0 - (n / (n - 1.0)) ** (n_resamplings + 1) * distinct)


def _stage(tp: _Path, x, g, eves, beta: float, scale: float, s: TMCMCSettings, rng) -> tuple:
    """One stage: next β, weights, ln Ŝ, multinomial resampling, Metropolis moves.

    Returns the moved particles, their g and Eve indices, the stage's record
    and (log-weights, Eve indices) of the population the weights were computed on.
    """
    n = x.shape[0]
    new = next_beta(g, beta, s.target_cov)
    log_w = np.where(np.isfinite(g), (new - beta) * g, -np.inf)
    log_s = float(logsumexp(log_w) - math.log(n))
    wn = np.exp(log_w - logsumexp(log_w))
    w = np.exp(log_w - log_s)
    cov = weighted_cov(x, wn)  # Betz et al.: the proposal from the weighted population of the new β
    idx = rng.choice(n, size=n, p=wn)
    if new < 1.0 or s.final_moves:
        moved_x, moved_g, info = mutate(tp, x[idx], g[idx], new, cov, scale, s, rng)
    else:  # the evidence is complete; the resampled particles stand (not checked for movement)
        moved_x, moved_g, info = x[idx], g[idx], {"acceptance": math.nan, "moved": math.nan, "steps": 0, "scale": scale}
    stage = {"beta": new, "log_s": log_s, "ess": 1.0 / float(np.sum(wn**2)), "cov": float(np.std(w)), **info}
    return moved_x, moved_g, eves[idx], stage, (log_w, eves.copy())


# --- the run ---------------------------------------------------------------------------------

def _start(target, s: TMCMCSettings, posterior, rng: np.random.Generator) -> tuple[_Path, np.ndarray, float, float]:
    """(path, N particles at β = 0, ln Z offset, its variance): the prior box or q of ``posterior``."""
    lower, upper = np.asarray(target.lower, float), np.asarray(target.upper, float)
    n = s.n_particles
    if s.start == "prior":
        return _Path(target, "prior", None), lower + rng.random((n, lower.size)) * (upper - lower), 0.0, 0.0
    if posterior is None:
        raise ValueError("start='reference' needs a posterior chain to fit q to")
    post = posterior.chain[posterior.burn:]
    fit = post.reshape(-1, post.shape[-1])
    q = Reference(fit.mean(axis=0), np.cov(fit, rowvar=False), lower, upper, rng)
    return _Path(target, "reference", q), q.draw(n, rng), 0.0, q.log_mass_error**2


def run_tmcmc(target, settings: TMCMCSettings = TMCMCSettings(), *, posterior=None) -> TMCMCResult:
    """Run TMCMC from β = 0 to 1 on ``target`` (module docstring).

    Parameters
    ----------
    target : OutputError or BoxTarget
        ``log_likelihood`` (batched), ``log_prior``, ``lower``, ``upper``.
    settings : TMCMCSettings
    posterior : MCMCResult, optional
        A posterior chain (only for ``start="reference"``: q is fitted to it).

    Returns
    -------
    TMCMCResult
    """
    t0 = _time.perf_counter()
    s = settings
    counted = Counted(target)
    rng = np.random.default_rng(s.seed)
    tp, x, log_z, var_extra = _start(counted, s, posterior, rng)
    n, d = x.shape
    min_ess = s.min_ess if s.min_ess is not None else max(50.0, 10.0 * d)
    g = tp.g(x)
    eves = np.arange(n)
    beta, betas, stages, naive_var, unhealthy = 0.0, [0.0], [], 0.0, []
    scale = 2.38 / math.sqrt(d)
    while beta < 1.0:
        if len(stages) >= s.max_stages:
            raise ValueError(f"TMCMC did not reach β = 1 in {s.max_stages} stages (β = {beta:.3g})")
        evals_before = counted.n_evals  # the last stage's value is what the evidence needed
        x, g, eves, stage, last = _stage(tp, x, g, eves, beta, scale, s, rng)
        scale, beta = stage["scale"], stage["beta"]
        log_z += stage["log_s"]
        naive_var += stage["cov"] ** 2 / n
        betas.append(beta)
        stages.append(stage)
        if stage["ess"] < min_ess or stage["moved"] < s.min_moved:
            unhealthy.append(beta)
    rel = eve_relative_variance(last[1], last[0], len(stages) - 1)
    n_eves = int(np.unique(last[1]).size)
    if n_eves < s.min_eves and 1.0 not in unhealthy:
        unhealthy.append(1.0)
    return TMCMCResult(log_z=log_z, log_z_error=math.sqrt(rel + var_extra), naive_error=math.sqrt(naive_var + var_extra),
                       particles=x, betas=np.array(betas), stages=stages, n_evals=counted.n_evals,
                       n_evals_evidence=evals_before,
                       n_eves=n_eves, unhealthy=unhealthy, wall_s=_time.perf_counter() - t0)
