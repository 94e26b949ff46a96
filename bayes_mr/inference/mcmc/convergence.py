"""Convergence of an ensemble chain: burn-in, integrated times, R-hat, ESS and the verdict.

The rule: a pilot τ₀, the longest integrated time of the chain's second half (the start-up
transient lives in the first half once the chain is a few τ long); burn-in
⌈``burn_tau_multiple`` · τ₀⌉ (at most half); and converged when the chain after burn-in is ``min_tau_multiple`` times its
longest integrated time *and* every coordinate's rank-normalised split R-hat
(walkers as chains) is below ``rhat_max``. :func:`run_until_converged` drives
a sampler by that rule, within ``max_steps``, an optional work budget in
log-density evaluations and an optional wall-time cap; with a work budget, a
chain whose own integrated time projects the rule past it stops at that check
(:func:`projection`) instead of running into the limit.

A chain of the independence move alone adds one condition (:func:`tail_index`): its
proposals are draws of q, and the Pareto k̂ of their importance weights p/q (Vehtari et
al. 2024, ArviZ's ``psislw``) must be below the sample-size bound :func:`tail_bound`
when the rule is met. Above it p/q has a heavy tail: a region q underweights is visited
rarely and held long, so the chain's τ and R-hat do not show how far its means can be off.
"""

from __future__ import annotations

import math
import time
import warnings

import numpy as np

from bayes_mr.execution.progress import bar as progress_bar
from bayes_mr.numerics.stats import integrated_times


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


def convergence_check(chain: np.ndarray, settings) -> dict:
    """Burn-in, τ, R-hat, ESS and the convergence verdict (module docstring rule).

    Parameters
    ----------
    chain : ndarray, shape (n_steps, n_walkers, d)
    settings : MCMCSettings
        Uses ``burn_tau_multiple``, ``min_tau_multiple`` and ``rhat_max``.

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


#: Steps of the chain (stored ones included) a projection needs before it is trusted (two checks at the default 50).
MIN_PROJECTION_STEPS = 100


def projection(tau_max: float, step: int, steps_allowed: int | None, settings) -> dict | None:
    """Whether the rule can still be met within the work budget, from the chain's integrated time so far.

    The rule needs a chain of about (``burn_tau_multiple`` + ``min_tau_multiple``) · τ steps (burn-in and
    the ≥ 50 τ after it), against the steps the budget allows the chain. τ estimated from a short chain is low,
    so the projection is optimistic: it stops a chain that cannot converge (spencer on the packaged damper:
    τ 23 after 315 steps, ~5000 needed at τ ≈ 99), never one that could. R-hat is not projected. Counted in
    steps, never timed: the same chain stops at the same step on any machine.

    Parameters
    ----------
    tau_max : float
        Longest integrated time at this check [steps].
    step : int
        Steps of the chain so far (stored ones included: a resumed run decides as an uninterrupted one).
    steps_allowed : int or None
        Steps of the chain its work budget allows in all (None: no budget).
    settings : MCMCSettings

    Returns
    -------
    dict or None
        None while the rule may still be met (or too few steps to tell); else ``tau_max``,
        ``steps_needed`` and ``steps_allowed``.
    """
    if steps_allowed is None or not math.isfinite(tau_max) or step < MIN_PROJECTION_STEPS:
        return None
    need = int(math.ceil((settings.burn_tau_multiple + settings.min_tau_multiple) * tau_max))
    if need <= steps_allowed:
        return None
    return {"tau_max": tau_max, "steps_needed": need, "steps_allowed": int(steps_allowed)}


#: Proposals a tail index needs before it can stop a chain (fewer: the condition is not applied). A run
#: resumed from a checkpoint counts its own proposals only (they are not stored).
TAIL_MIN_DRAWS = 200


def tail_bound(n: int) -> float:
    """Largest Pareto k̂ of n importance weights at which their estimates are reliable: min(1 − 1/log₁₀ n, 0.7)
    (Vehtari et al. 2024, §3.2.3): 0.62 at 400 draws, 0.7 from ~2150."""
    return min(1.0 - 1.0 / math.log10(max(n, 11)), 0.7)


def tail_index(log_weights: list[np.ndarray]) -> tuple[float, int]:
    """Pareto k̂ of importance weights (ArviZ's ``psislw``) and their number.

    Parameters
    ----------
    log_weights : list of ndarray
        ln p(x′) − ln q(x′) of draws x′ of q, in any chunks (an independence move's ``log_weights``).

    Returns
    -------
    k : float
        NaN with fewer than :data:`TAIL_MIN_DRAWS` draws.
    n : int
    """
    lw = np.concatenate(log_weights) if log_weights else np.empty(0)
    if lw.size < TAIL_MIN_DRAWS:
        return math.nan, int(lw.size)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # ArviZ warns above 0.7: the caller decides
        k = _quiet_arviz().psislw(lw - lw.max())[1]
    return float(k), int(lw.size)


def last_step(settings, n_walkers: int) -> tuple[int, int | None]:
    """The chain's last step (``max_steps``, or fewer where the work budget ends first) and the steps the work
    budget allows (None: no budget), counted from the chain's start on ``n_walkers`` walkers."""
    allowed = None if settings.max_evaluations is None else int(settings.max_evaluations) // n_walkers
    last = settings.max_steps if allowed is None else min(settings.max_steps, allowed)
    if last < 1:
        raise ValueError(f"a work budget of {settings.max_evaluations} log-density evaluations allows no step of "
                         f"{n_walkers} walkers")
    return last, allowed


def _stopped(diag: dict, tails: bool, it: int, settings, last: int, out_of_time: bool) -> str:
    """Why the chain ends at this check (:func:`run_until_converged`): a rule or a budget before the wall-time cap."""
    return ("converged" if diag["converged"] else "q_tails" if tails
            else "max_steps" if it >= settings.max_steps else "max_evaluations" if it >= last
            else "max_seconds" if out_of_time else "projected")


def run_until_converged(sampler, state, settings, resuming: bool, tail=None) -> tuple[dict, list[dict]]:
    """Advance an emcee sampler in blocks of ``check_every`` steps until the rule, ``max_steps``, the work budget
    or the wall-time cap.

    Checks fall at multiples of ``check_every`` counted from the chain's start (stored steps included), and the
    work budget counts the chain's steps from its start too, so a resumed run takes the decisions of an
    uninterrupted one. A run past the cap ``settings.max_seconds`` stops after the current step and is checked
    there (flagged not converged: a machine limit).

    Parameters
    ----------
    sampler : emcee.EnsembleSampler
    state : emcee.State
        Where the chain continues.
    settings : MCMCSettings
        ``max_evaluations`` is the chain's own work budget (its walkers × steps).
    resuming : bool
        The state comes from a checkpoint (emcee skips its initial-state check).
    tail : callable, optional
        ``tail() -> (k̂, n)``: the tail index of the proposals so far (:func:`tail_index`), for a chain of
        the independence move alone; when the rule is met, k̂ above :func:`tail_bound` stops the chain
        unconverged (``"q_tails"``).

    Returns
    -------
    diag : dict
        The last :func:`convergence_check`, with ``stopped`` (``"converged"``, ``"max_steps"``,
        ``"max_evaluations"`` (the work budget spent), ``"projected"`` (the rule projected past the work budget,
        :func:`projection`, whose dict, with ``evaluations_needed`` and ``evaluations_allowed``, is then
        ``diag["projection"]``), ``"max_seconds"`` (the wall-time cap) or ``"q_tails"``) and ``pareto_k``
        (NaN without ``tail``).
    history : list of dict
        Each check: step, burn, tau_max, rhat_max (and pareto_k where it was taken).
    """
    t0 = time.perf_counter()
    cap = math.inf if settings.max_seconds is None else float(settings.max_seconds)
    walkers = int(sampler.nwalkers)
    last, allowed = last_step(settings, walkers)
    it = int(sampler.iteration)
    history: list[dict] = []
    bar = progress_bar(last, "emcee", unit="step", enabled=settings.progress, initial=it)
    try:
        while True:
            out_of_time = time.perf_counter() - t0 > cap
            if it > 0 and (it % settings.check_every == 0 or it >= last or out_of_time):
                diag = convergence_check(sampler.get_chain(), settings)
                history.append({"step": it, "burn": diag["burn"], "tau_max": float(diag["tau"].max()),
                                "rhat_max": float(diag["rhat"].max())})
                diag["pareto_k"], tails = math.nan, False
                if diag["converged"] and tail is not None:
                    diag["pareto_k"], n = tail()
                    history[-1]["pareto_k"] = diag["pareto_k"]
                    tails = n >= TAIL_MIN_DRAWS and diag["pareto_k"] > tail_bound(n)
                    diag["converged"] = not tails
                bar.set_postfix(tau=f"{diag['tau'].max():.1f}",
                                N_over_tau=f"{(it - diag['burn']) / diag['tau'].max():.0f}",
                                rhat=f"{diag['rhat'].max():.3f}")
                ahead = None if diag["converged"] else projection(float(diag["tau"].max()), it, allowed, settings)
                if diag["converged"] or tails or it >= last or out_of_time or ahead:
                    diag["stopped"] = _stopped(diag, tails, it, settings, last, out_of_time)
                    diag["projection"] = None if diag["stopped"] != "projected" else {
                        **ahead, "evaluations_needed": ahead["steps_needed"] * walkers,
                        "evaluations_allowed": ahead["steps_allowed"] * walkers}
                    break
            target = min(last, (it // settings.check_every + 1) * settings.check_every)
            # one step at a time through the generator so the bar moves; the backend saves every step
            # emcee's check that the walkers span the space serves its ensemble moves; independent walkers
            # (the independence move alone) may be fewer than the dimensions
            skip = resuming or not settings.ensemble
            for state in sampler.sample(state, iterations=target - it, skip_initial_state_check=skip):
                bar.update(1)
                it += 1
                resuming = False
                if time.perf_counter() - t0 > cap:
                    break
    finally:
        bar.close()
    return diag, history
