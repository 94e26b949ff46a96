"""Model evidence ln p(y | model) by three routes besides the UKF's innovation likelihood.

* ``laplace`` — the Laplace approximation at the least-squares optimum
  (:func:`bayes_mr.inference.lsq.least_squares.laplace`, wrapped here, not repeated). Exact
  for a likelihood Gaussian in φ inside the prior box; no error estimate of its
  own (its error is the posterior's non-Gaussianity, which only a sampling
  route can measure).
* ``ti`` — thermodynamic integration over a temperature ladder
  0 = β_0 < … < β_K = 1, every temperature sampled with the package's emcee
  machinery (:func:`bayes_mr.inference.mcmc.sampler.sample`), the walkers of β_k
  starting where the chain of β_{k+1} ended:

      ln Z = ∫₀¹ E_β[g] dβ,   d E_β[g] / dβ = Var_β[g],

  by the trapezoid rule with the Friel–Hurn–Wyse (2014) curvature correction
  −Σ_k Δβ_k²/12 · (Var_{β_{k+1}}[g] − Var_{β_k}[g]). Two paths:

  - ``path="prior"`` (power posteriors, Friel & Pettitt 2008):
    p_β ∝ L^β p, g = ln L, β_k = (k/K)⁵. Textbook, but for a long record the
    likelihood is so much narrower than the prior box that E_β[ln L] falls by
    many orders of magnitude as β → 0 (random parameters in the box fit the
    record terribly) and the ladder error is large; it is kept as a reference
    and for small problems.
  - ``path="reference"`` (the default; Lartillot & Philippe 2006, Fan et al.
    2011): p_β ∝ (L p)^β q^{1−β} with q the Gaussian fitted to the posterior
    draws (truncated to the prior box, its mass there estimated by Monte
    Carlo), g = ln L + ln p − ln q. The answer does not depend on q — only
    its precision does — and when the posterior is nearly Gaussian g is
    nearly constant, so a short ladder (K = 8) suffices and every
    temperature stays where the model is cheap to simulate. The ladder is
    β_k = (k/8)³ (:func:`bayes_mr.inference.evidence.ladder.default_ladder`; the ladder's
    samples are drawn by :func:`bayes_mr.inference.evidence.ladder.run_ladder`).

  ``ladder_error`` is the magnitude of the curvature correction (the
  discretisation error of the plain trapezoid; the corrected rule is of
  higher order, so this bounds what remains). ``mc_error`` is
  √(Σ_k w_k² Var_k τ_k / n_k) with trapezoid weights w_k and τ_k the
  integrated autocorrelation time of g in the chain of β_k (β_0 is drawn
  exactly, iid), plus the Monte Carlo error of the reference's box mass.
* ``ss`` — stepping-stone sampling (Xie et al. 2011; generalised with the
  reference by Fan et al. 2011) on the same samples:
  ln Z = Σ_k ln E_{β_k}[exp(Δβ_k g)]. No discretisation error; ``mc_error``
  from the autocorrelation-corrected variance of each stone's weights.

Which route selects (``compare``): **ti** when an MCMC posterior is run,
else **laplace**; ``ss`` is shown beside TI as a cross-check on the same
samples and ``laplace`` as the cheap baseline. :func:`select_route` encodes this;
:data:`PREFERENCE` is the order. Measured on the §3.8 study (truth dahl, 1 %
measurement noise, 2–10 s at 1 kHz): for dahl, whose posterior is Gaussian,
Laplace, TI and SS agree to 0.005 nats; for normalized Bouc–Wen to
0.005–0.5 (its n, σ are curved at 2 s); for LuGre,
whose ε piles up at the lower end of its prior (LuGre contains dahl as
ε → 0), Laplace is off by 0.3–2.4 nats — at 3 s it puts LuGre level with
dahl, where TI and SS (agreeing to 0.01) put dahl 2.4 nats ahead. Only a
sampling route sees a posterior that is not Gaussian, and only it reports
an error bar; TI's error splits into Monte Carlo and ladder parts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.special import logsumexp

from bayes_mr.inference.evidence.ladder import LADDER_SETTINGS, Ladder, mean_variance, run_ladder
from bayes_mr.inference.mcmc.chain import MCMCResult
from bayes_mr.inference.mcmc.settings import MCMCSettings
from bayes_mr.inference.evidence.tmcmc import TMCMCResult, TMCMCSettings, run_tmcmc

#: Routes in order of preference for model selection (``tmcmc`` only where asked for, without TI).
PREFERENCE = ("ti", "tmcmc", "laplace")


@dataclass(frozen=True)
class Evidence:
    """An estimate of ln p(y | model).

    Attributes
    ----------
    route : str
        ``laplace``, ``ti`` or ``ss``.
    log_z : float
        ln Z [nats].
    mc_error : float
        Monte Carlo standard error of ``log_z`` [nats] (0 for Laplace).
    ladder_error : float
        Discretisation error of the temperature ladder [nats] (TI; 0 for
        stepping-stone, NaN — unknown — for Laplace).
    total_error : float
        √(mc_error² + ladder_error²) (NaN for Laplace: no error estimate).
    wall_s : float
        Wall time of the route [s] (for TI/SS: the ladder, excluding the β = 1 posterior run).
    details : dict
        Route-specific numbers (ladder, per-temperature means, …).
    unconverged : list of float
        β of the ladder rungs whose chains did not converge (TI, SS); empty
        when every rung did (and for Laplace).
    """

    route: str
    log_z: float
    mc_error: float
    ladder_error: float
    total_error: float
    wall_s: float = 0.0
    details: dict = field(default_factory=dict)
    unconverged: list = field(default_factory=list)

    @property
    def converged(self) -> bool:
        """Every chain behind the estimate converged."""
        return not self.unconverged

    def to_dict(self) -> dict:
        """Plain-Python summary (no per-temperature arrays)."""
        return {"route": self.route, "log_z": float(self.log_z), "mc_error": float(self.mc_error),
                "ladder_error": float(self.ladder_error), "total_error": float(self.total_error),
                "wall_s": float(self.wall_s), "converged": self.converged,
                "unconverged_betas": [float(b) for b in self.unconverged]}


def select_route(routes: dict[str, Evidence]) -> Evidence:
    """The route that decides a model comparison (first of :data:`PREFERENCE` present)."""
    for name in PREFERENCE:
        if name in routes:
            return routes[name]
    raise ValueError(f"no evidence route to select from (have {', '.join(routes) or 'none'})")


# --- Laplace ------------------------------------------------------------------------

def laplace_evidence(lsq) -> Evidence:
    """The Laplace evidence of a least-squares fit (:func:`bayes_mr.inference.lsq.least_squares.laplace`).

    Parameters
    ----------
    lsq : LSQResult
    """
    return Evidence("laplace", float(lsq.log_evidence), 0.0, float("nan"), float("nan"), float(lsq.wall_s),
                    details={"log_likelihood": float(lsq.log_likelihood)})


def thermodynamic_integration(ladder: Ladder) -> Evidence:
    """ln Z by the curvature-corrected trapezoid over the ladder (module docstring)."""
    b = ladder.betas
    mean, var, mcvar = ladder.moments()
    db = np.diff(b)
    trap = float(np.sum(db * 0.5 * (mean[1:] + mean[:-1])))
    correction = -float(np.sum(db**2 / 12.0 * (var[1:] - var[:-1])))
    w = np.zeros_like(b)
    w[:-1] += 0.5 * db
    w[1:] += 0.5 * db
    mc = math.sqrt(float(np.sum(w**2 * mcvar)) + ladder.extra_var)
    ladder_err = abs(correction)
    log_z = trap + correction + ladder.extra_log_z
    return Evidence("ti", log_z, mc, ladder_err, math.hypot(mc, ladder_err), ladder.wall_s, details={
        "path": ladder.path, "betas": b.tolist(), "mean_g": mean.tolist(), "var_g": var.tolist(),
        "tau_g": ladder.tau.tolist(), "trapezoid": trap + ladder.extra_log_z, "correction": correction,
        "n_temps": int(b.size - 1)}, unconverged=ladder.unconverged())


def stepping_stone(ladder: Ladder) -> Evidence:
    """ln Z = Σ_k ln E_{β_k}[exp(Δβ_k g)] on the ladder's samples."""
    b = ladder.betas
    total, var_total = ladder.extra_log_z, ladder.extra_var
    stones = []
    for k in range(b.size - 1):
        g = np.asarray(ladder.g[k], float)
        a = (b[k + 1] - b[k]) * g
        ln_r = float(logsumexp(a) - math.log(a.size))
        w = np.exp(a - a.max())
        # relative variance of the mean weight, with the weights' own autocorrelation time
        rel = mean_variance(w) / float(np.mean(w)) ** 2  # β_0 is drawn exactly: (n, 1), iid
        total += ln_r
        var_total += rel
        stones.append(ln_r)
    mc = math.sqrt(var_total)
    return Evidence("ss", total, mc, 0.0, mc, ladder.wall_s, details={
        "path": ladder.path, "betas": b.tolist(), "ln_ratio": stones}, unconverged=ladder.unconverged())


def tmcmc_evidence(res: TMCMCResult) -> Evidence:
    """Transitional MCMC's ln Z (:mod:`bayes_mr.inference.evidence.tmcmc`); its unhealthy stages count as unconverged."""
    return Evidence("tmcmc", res.log_z, res.log_z_error, 0.0, res.log_z_error, res.wall_s, details=res.details(),
                    unconverged=list(res.unhealthy))


# --- the package's routes ----------------------------------------------------------------

def evidence_routes(
    lik,
    *,
    lsq=None,
    posterior: MCMCResult | None = None,
    mcmc_settings: MCMCSettings | None = None,
    ladder_settings: MCMCSettings = LADDER_SETTINGS,
    path: str = "reference",
    betas: np.ndarray | None = None,
    seed: int = 0,
    executor=None,
    tmcmc: TMCMCSettings | None = None,
) -> dict[str, Evidence]:
    """Laplace, TI and stepping-stone evidence of an OutputError posterior.

    Parameters
    ----------
    lik : OutputError
    lsq : LSQResult, optional
        Least-squares fit (run here if not given).
    posterior : MCMCResult, optional
        emcee posterior of ``lik`` (run here, from ``lsq``, if not given).
    mcmc_settings, ladder_settings : MCMCSettings
    path : {"reference", "prior"}
    betas : ndarray, optional
    seed : int
    executor : object, optional
        Runs the ladder's rungs as jobs (:func:`bayes_mr.inference.evidence.ladder.run_ladder`).
    tmcmc : TMCMCSettings, optional
        Also transitional MCMC (opt-in route ``tmcmc``, seeded by ``seed``;
        with ``start="reference"`` from q of ``posterior``).

    Returns
    -------
    dict
        ``{"laplace": Evidence, "ti": Evidence, "ss": Evidence}`` (and ``"tmcmc"``); the one to
        select with is :func:`select_route` of it.
    """
    from bayes_mr.inference.lsq.joint import fit_any
    from bayes_mr.inference.lsq.least_squares import LSQSettings
    from bayes_mr.inference.mcmc.sampler import fit_mcmc

    if lsq is None:
        lsq = fit_any(lik, LSQSettings(seed=seed))
    if posterior is None:
        posterior = fit_mcmc(lik, lsq=lsq, settings=mcmc_settings or MCMCSettings(seed=seed))
    ladder = run_ladder(lik, posterior, path=path, betas=betas, settings=ladder_settings, seed=seed,
                        executor=executor)
    out = {"laplace": laplace_evidence(lsq), "ti": thermodynamic_integration(ladder), "ss": stepping_stone(ladder)}
    if tmcmc is not None:
        out["tmcmc"] = tmcmc_evidence(run_tmcmc(lik, replace(tmcmc, seed=seed), posterior=posterior))
    return out
