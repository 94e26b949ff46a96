"""How effects are added to a model: forward selection, one ranking, and the restart of each named extension.

:func:`forward_select` re-screens every remaining effect after each addition
(diagnose's default); :func:`ranked_select` ranks them once and adds the
passing ones best first (a stiff model on a long record). Either way an effect
that passes is searched again over every parameter before it is kept
(:func:`restarted`): the local refits of the screen start at
the base optimum, which may already have absorbed part of the effect. A
ranking's refinements stop on a crawl (:data:`.screen.STALL`); the effect that is
kept is refined on from there (:func:`settled`) before the next round builds on it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import xarray as xr

from bayes_mr.execution.executor import local_threads
from bayes_mr.models import EFFECTS
from bayes_mr.diagnosis.fits import Fit, global_refit, refit
from bayes_mr.diagnosis.input_noise import checked
from bayes_mr.diagnosis.ranking import rank as by_explanation
from bayes_mr.diagnosis.screen import THRESHOLD, Candidate, applicable, passes, screen, screen_one, scored


@dataclass(frozen=True)
class Search:
    """How :func:`~bayes_mr.diagnosis.diagnose.diagnose` adds effects to the baseline.

    Attributes
    ----------
    route : {"forward", "ranked"}
        ``forward``: re-screen every remaining effect after each addition
        (:func:`forward_select`). ``ranked``: rank them once against the
        baseline and add the passing ones best first, each refitted and kept
        only if it still passes (:func:`ranked_select`; one fit per effect, for
        a stiff model on a long record).
    candidates : tuple of str or None
        Effects tried (None: every applicable one).
    max_effects : int
        Most effects added.
    threshold : float
        Score an effect must exceed to be named (:data:`~.screen.THRESHOLD`).
    """

    route: str = "forward"
    candidates: tuple[str, ...] | None = None
    max_effects: int = 3
    threshold: float = THRESHOLD

    def __post_init__(self):
        if self.route not in ("forward", "ranked"):
            raise ValueError(f"search must be 'forward' or 'ranked', got {self.route!r}")

    def run(self, record: xr.Dataset, base: Fit, *, seed: int = 0, progress=None,
            executor=None) -> tuple[list[Candidate], list[list[Candidate]]]:
        """Effects added to ``base`` (in order) and the rounds of scores (the first against ``base``); the candidates
        of a round are fitted on ``executor``, by default side by side on this process's threads
        (:func:`~bayes_mr.execution.executor.local_threads`: the same result)."""
        with local_threads(executor) as ex:
            if self.route == "forward":
                return forward_select(record, base, threshold=self.threshold, max_effects=self.max_effects,
                                      seed=seed, progress=progress, executor=ex, candidates=self.candidates)
            selected, ranking, _ = ranked_select(record, base, candidates=self.candidates, threshold=self.threshold,
                                                 max_effects=self.max_effects, seed=seed, progress=progress,
                                                 executor=ex)
        return selected, [ranking]


#: Relative spread of the screen's refined starts' final costs above which a named extension is searched again.
#: Measured on 16 records (dahl, structure tests): the four of the small-amplitude family whose local refits
#: miss the optimum ended their two refined starts at costs 2.6e-3 to 0.17 apart (relative); the twelve others
#: (six effects × two magnitudes, each refit at its optimum already) agreed to within 1e-5.
RESTART_SPREAD = 1e-4
#: Slack [nats] added to that spread when a refined start stopped on the screen's stall rule (:data:`.screen.STALL`):
#: two stalled refinements in one basin end up to what their crawls would still gain apart (≤ 0.3 nats measured),
#: far below two basins' spread (2.6e-3 relative is ≥ 8 nats at the ~3000 residuals of the smallest records above).
STALL_SLACK = 1.0


def restarted(base: Fit, cand: Candidate, *, seed: int = 0) -> Candidate:
    """``cand`` (an effect that passed against ``base``) after a global search of its extension, rescored.

    When the screen's refined starts did not end at one cost (more than
    :data:`RESTART_SPREAD` apart: the landscape near the base optimum has more
    than one basin), the extension is searched again by differential evolution
    (:func:`.fits.global_refit`) and kept if it fits better; the score, MSE
    ratio and evidence gain are recomputed against ``base``. ``restart``
    records what was done (or why it was not). ``sensor_delay`` keeps its
    exhaustive grid over lags.
    """
    if cand.fit is None or cand.name == "sensor_delay":
        return cand
    ends = [r["cost"] for r in cand.runs]
    slack = STALL_SLACK if any(r.get("stalled") for r in cand.runs) else 0.0
    if len(ends) > 1 and max(ends) - min(ends) <= RESTART_SPREAD * abs(min(ends)) + slack:
        within = f"{RESTART_SPREAD:g} relative" + (f" + {slack:g} for a stalled one" if slack else "")
        return replace(cand, restart={"skipped": f"its {len(ends)} refined starts ended at one cost (within "
                                                 f"{within}): one basin"})
    fit, info = global_refit(cand.fit, [p.name for p in cand.effect.params], seed=seed)
    if fit is cand.fit:
        return replace(cand, restart=info)
    return scored(base, fit, cand.effect, runs=cand.runs, restart=info)


def settled(base: Fit, cand: Candidate) -> Candidate:
    """``cand`` (an effect that is kept) refined on from where the screen's stall rule stopped it, rescored.

    The screen stops a refinement that crawls (:data:`~.screen.STALL`), a
    little short of the optimum; a kept extension is reported and becomes the
    base of the next round, whose extensions would otherwise gain what it left
    (an alarm from nothing). When the refined start the fit came from stopped
    on the rule, it is refined once more from its point, without the rule;
    otherwise (it ended on scipy's tolerances or its evaluations, or a global
    restart replaced it) it is kept as it is.
    """
    if cand.fit is None or not cand.runs or (cand.restart or {}).get("improved"):
        return cand
    if not min(cand.runs, key=lambda r: r["cost"]).get("stalled"):
        return cand
    fit, _ = refit(cand.fit.lik, np.atleast_2d(cand.fit.phi), cand.fit.result.sigma, n_refine=1)
    if not fit.result.log_likelihood > cand.fit.result.log_likelihood:
        return cand
    return scored(base, fit, cand.effect, runs=cand.runs, restart=cand.restart)


def kept(base: Fit, cand: Candidate, *, seed: int = 0) -> Candidate:
    """An effect that passed, as it is added: searched again globally where needed (:func:`restarted`), then
    refined to its end (:func:`settled`)."""
    return settled(base, restarted(base, cand, seed=seed))


def _beyond_input_noise(record: xr.Dataset, base: Fit, ranked: list[Candidate], threshold: float,
                        seed: int) -> Candidate | None:
    """The first of a round's ``ranked`` candidates that passes, its input-noise null included
    (:func:`.input_noise.checked`; device tests); those checked are replaced in ``ranked`` by their checked
    selves, so the round reports their null score. None when none passes."""
    for i, cand in enumerate(ranked):
        if not passes(cand, threshold):
            break  # ranked: those that pass come first
        ranked[i] = cand = checked(record, base, cand, seed=seed)
        if passes(cand, threshold):
            return cand
    return None


def forward_select(record: xr.Dataset, base: Fit, *, threshold: float = THRESHOLD, max_effects: int = 3,
                   seed: int = 0, progress=None, executor=None,
                   candidates=None) -> tuple[list[Candidate], list[list[Candidate]]]:
    """Greedy forward selection of effects.

    Screen every applicable effect (of ``candidates``, names, when given) against the current model; add the
    one that explains the most of those that pass (:func:`.ranking.rank`); re-screen the rest against the extended model; stop when nothing passes (or after
    ``max_effects``). ``executor`` fits each round's candidates as parallel jobs (:func:`~.screen.screen`). Each
    effect added is searched again globally first (:func:`restarted`) and refined on where the screen's stall
    rule stopped it (:func:`settled`).

    Returns
    -------
    selected : list of Candidate
        Effects added, in order (each scored against the model before it).
    rounds : list of list of Candidate
        The ranked screen of each round (the first, at index 0, is against the baseline).
    """
    selected: list[Candidate] = []
    rounds: list[list[Candidate]] = []
    current = base
    for _ in range(max_effects):
        have = {c.name for c in selected}
        effects = [e for e in applicable(current.model, record)
                   if e.name not in have and (candidates is None or e.name in candidates)]
        if not effects:
            break
        ranked = by_explanation(screen(record, current, effects, seed=seed, progress=progress, executor=executor),
                                threshold)
        rounds.append(ranked)
        best = _beyond_input_noise(record, current, ranked, threshold, seed)
        if best is None:
            break
        best = kept(current, best, seed=seed)
        selected.append(best)
        current = best.fit
    return selected, rounds


def ranked_select(record: xr.Dataset, base: Fit, *, candidates: tuple[str, ...] | None = None,
                  threshold: float = THRESHOLD, max_effects: int = 5, rank: bool = True, seed: int = 0,
                  progress=None, executor=None) -> tuple[list[Candidate], list[Candidate], list[Candidate]]:
    """Rank the candidate effects once against ``base``; add the passing ones best first (:func:`.ranking.rank`).

    The first passing effect is kept as ranked; each later one is refitted as
    an extension of the model so far (warm-started there,
    :func:`~.screen.screen_one`) and kept only if it still passes
    (:func:`~.screen.passes`). Unlike :func:`forward_select`, the
    other effects are not re-screened after each addition: one ranking and one
    refit per passing effect, which keeps a stiff device model at a high rate
    within minutes.

    Parameters
    ----------
    record : xarray.Dataset
    base : Fit
        The base model's fit on ``record``.
    candidates : tuple of str, optional
        Effects tried, in this order without ``rank`` (None: every applicable
        one, :func:`~.screen.applicable`; names that do not apply are skipped).
    threshold : float
        Score an effect must pass.
    max_effects : int
        Most effects added.
    rank : bool
        False: no ranking; every candidate is tried once, in the order given,
        against the model so far.
    seed : int
    progress : callable, optional
    executor : object, optional
        Fits the ranking's candidates as parallel jobs (same result, :func:`~.screen.screen`).

    Returns
    -------
    selected : list of Candidate
        Effects added, in order (each scored against the model before it).
    ranking : list of Candidate
        Every candidate against ``base``, best first (empty without ``rank``).
    tried : list of Candidate
        Each addition tried, kept or not, in order.
    """
    say = progress or (lambda msg: None)
    offered = [e.name for e in applicable(base.model, record)]
    names = offered if candidates is None else [n for n in candidates if n in offered]
    ranking: list[Candidate] = []
    if rank:
        ranking = by_explanation(screen(record, base, [EFFECTS[n] for n in names], seed=seed, progress=say,
                                        executor=executor),
                                 threshold)
        names = [c.name for c in ranking if passes(c, threshold)]
    selected: list[Candidate] = []
    tried: list[Candidate] = []
    fit = base
    for name in names:
        if len(selected) >= max_effects:
            break
        first = ranking and not selected
        now = next(c for c in ranking if c.name == name) if first else screen_one(record, fit, EFFECTS[name], seed=seed)
        ok = passes(now, threshold)
        if ok:
            now = kept(fit, now, seed=seed)
            fit = now.fit
            selected.append(now)
        tried.append(now)
        say(f"  + {name}: score {now.score:.4g}, {'kept' if ok else 'dropped'}")
    return selected, ranking, tried
