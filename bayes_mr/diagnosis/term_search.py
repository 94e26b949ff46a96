"""Open-ended term discovery: what no named effect explains, searched in a library of terms.

1. **Hold out.** The last :data:`HOLDOUT` of the record is masked: nothing
   below sees it until the held-out check. The fitted model is refitted on
   the rest (warm-started at its optimum).
2. **Propose.** The residual on the training part is regressed on every
   library term's output sensitivity by the lasso, and the support of least
   BIC is proposed (:mod:`.library`).
3. **Refit and keep.** Each proposed term, best first, extends the current
   model and is refitted by output-error least squares inside it
   (:func:`.fits.refit`: the current optimum with the term off, the
   regression's estimate, and a grid over the term's range). It passes if
   *both* the evidence improves — the κ-corrected log Bayes factor of
   :func:`.screen.score` above the threshold named effects face, and the plain
   Laplace Δ ln Z above 0 — *and* the error on the held-out part falls (MSE
   ratio below 1, in at least :data:`MIN_BLOCKS` of its :data:`N_BLOCKS`
   blocks).
4. **Check on the other fold.** A term that passes is kept only if it passes
   again with the folds swapped: current model and extension refitted
   (warm-started) with the *first* :data:`HOLDOUT` of the record held out
   instead, and judged by the same rules there. A term whose gain is real
   lowers the error wherever the record is held out; one at the edge of the
   test (whose pass flips with a rounding-level change of the simulator: the
   ``make run`` of one round kept ẋ·|ẋ| at 8 of 10 blocks, the next dropped it
   at 7) rarely passes twice. A kept term is part of the model the next one
   extends.
5. **Report.** The model with the kept terms is refitted on the whole record
   (warm-started at the training fit) and each kept term is said in words.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import xarray as xr

from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.models import Effect
from bayes_mr.models import terms as lib
from bayes_mr.models.kernel import N_TERMS
from bayes_mr.diagnosis.fits import Fit, record_mse, refit
from bayes_mr.diagnosis.library import Proposal, library, propose
from bayes_mr.diagnosis.screen import THRESHOLD, effect_starts, score

#: Share of the record (its end) held out of the term search.
HOLDOUT = 0.3
#: Blocks the held-out part is cut into, and how many must see the error fall (:func:`heldout_blocks`).
N_BLOCKS, MIN_BLOCKS = 10, 8


@dataclass(frozen=True)
class Fold:
    """One split of the record: fits see ``train`` (the record with ``held`` masked); ``held`` judges them.

    Attributes
    ----------
    train : xarray.Dataset
        The record with the held-out samples marked invalid (they still drive the simulation).
    held : slice
        The held-out samples.
    """

    train: xr.Dataset
    held: slice
    _fits: dict = field(default_factory=dict, compare=False, repr=False)

    def refit(self, fit: Fit) -> Fit:
        """``fit``'s model refitted on :attr:`train` from its optimum (once per model: later calls reuse it)."""
        if fit.name not in self._fits:
            self._fits[fit.name] = _refit_on(self.train, fit)
        return self._fits[fit.name]


def folds(record: xr.Dataset, holdout: float) -> tuple[Fold, Fold]:
    """The search's fold (the last ``holdout`` of the record held out) and the check's (the first)."""
    n = int(record.sizes["time"])
    cut = int(round((1.0 - holdout) * n))
    end, start = slice(cut, None), slice(0, n - cut)
    return Fold(_masked(record, end), end), Fold(_masked(record, start), start)


def _masked(record: xr.Dataset, held: slice) -> xr.Dataset:
    """``record`` with the samples ``held`` marked invalid (they still drive the simulation)."""
    valid = record["valid"].values.astype(bool).copy()
    valid[held] = False
    return record.assign(valid=(record["valid"].dims, valid))


def _heldout_mse(record: xr.Dataset, fit: Fit, held: slice) -> float:
    """The record score of ``fit``'s prediction on the samples ``held``."""
    return record_mse(record.isel(time=held), {k: v[held] for k, v in fit.predicted.items()})


def heldout_blocks(record: xr.Dataset, base: Fit, ext: Fit, held: slice) -> int:
    """In how many of :data:`N_BLOCKS` consecutive blocks of the samples ``held`` ``ext``'s error is below ``base``'s.

    Squared errors of the channels over their noise SDs. Blocks, not samples:
    residuals are autocorrelated, so an error drop must hold across the
    held-out part, not in a stretch of it (a sign test over blocks; ≥ 8 of 10
    is one-sided p ≈ 0.055 when the term does nothing).
    """
    valid = record["valid"].values.astype(bool)[held]
    d = np.zeros(int(valid.sum()))
    for c, sd in zip(base.lik.channels, base.result.sigma):
        y = record[c].values[held][valid]
        d += ((y - base.predicted[c][held][valid]) ** 2 - (y - ext.predicted[c][held][valid]) ** 2) / sd**2
    return int(sum(np.sum(b) > 0 for b in np.array_split(d, N_BLOCKS) if b.size))


def _refit_on(record: xr.Dataset, fit: Fit) -> Fit:
    """``fit``'s model refitted on ``record`` from its optimum (same ranges, scales and residual model)."""
    lik = OutputError(fit.model, record, ranges=fit.lik.ranges, scales=fit.lik.scales, residual=fit.lik.residual)
    out, _ = refit(lik, np.atleast_2d(fit.phi), fit.result.sigma, n_refine=1)
    return out


def _judge(record: xr.Dataset, current: Fit, ext: Fit, effect: Effect, held: slice, threshold: float) -> dict:
    """``ext`` (= ``current`` + a term, fitted on the same fold) against ``current``: the keep rules' figures."""
    s, kappa, dll, _ = score(current, ext, effect)
    dlz = ext.result.log_evidence - current.result.log_evidence
    ratio = _heldout_mse(record, ext, held) / _heldout_mse(record, current, held)
    blocks = heldout_blocks(record, current, ext, held)
    return dict(score=_num(s), kappa=_num(kappa), delta_loglik=_num(dll), delta_log_evidence=_num(dlz),
                heldout_mse_ratio=_num(ratio), heldout_blocks_better=blocks,
                passed=bool(s > threshold and dlz > 0 and ratio < 1.0 and blocks >= MIN_BLOCKS))


def _try(record: xr.Dataset, fold: Fold, other: Fold, current: Fit, prop: Proposal, seed: int,
         threshold: float) -> dict:
    """Refit ``current`` + the proposed term on ``fold``'s training part; judge it there and, when it passes,
    on ``other`` (current model and extension refitted there from their optima)."""
    effect = lib.make(prop.name, current.model.form.name)
    model = current.model + effect
    row = prop.to_dict()
    try:
        lik = OutputError(model, fold.train, ranges=current.lik.ranges, scales=current.lik.scales,
                          residual=current.lik.residual)
        starts = effect_starts(lik, current.params(), effect, seed)
        j = lik.par.names.index(effect.params[0].name)
        guess = starts[:1].copy()
        guess[0, j] = np.clip(lik.par.coords.to_phi(np.full(len(lik.par.names), prop.theta))[j],
                              lik.phi_lo[j], lik.phi_hi[j])
        ext, _ = refit(lik, np.vstack([starts[:1], guess, starts[1:]]), current.result.sigma, n_refine=3)
        judged = _judge(record, current, ext, effect, fold.held, threshold)
    except (RuntimeError, ValueError, np.linalg.LinAlgError) as exc:
        row.update(kept=False, error=str(exc))
        return row
    checked = None
    if judged["passed"]:
        try:
            checked = _judge(record, other.refit(current), other.refit(ext), effect, other.held, threshold)
        except (RuntimeError, ValueError, np.linalg.LinAlgError) as exc:
            checked = {"passed": False, "error": str(exc)}
    passed = judged.pop("passed")
    row.update(judged, theta_refit=_num(ext.params()[effect.params[0].name]), other_fold=checked,
               kept=bool(passed and checked is not None and checked["passed"]), fit=ext)
    return row


def _num(v) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None


def _step(record: xr.Dataset, fold: Fold, other: Fold, current: Fit, proposals: list[Proposal], seed: int,
          threshold: float, say) -> tuple[list[dict], Fit | None]:
    """Try ``proposals`` in order against ``current``; stop at the first kept (rows tried, its fit or None)."""
    rows = []
    for prop in proposals:
        row = _try(record, fold, other, current, prop, seed, threshold)
        ext = row.pop("fit", None)
        checked = row.get("other_fold")
        say(f"term {prop.name}: score {row.get('score')}, held-out MSE ratio {row.get('heldout_mse_ratio')}"
            + (f" (other fold {checked.get('heldout_mse_ratio')}, {checked.get('heldout_blocks_better')} blocks)"
               if checked else "")
            + f", {'kept' if row['kept'] else 'dropped'}")
        rows.append(row)
        if row["kept"]:
            return rows, ext
    return rows, None


def sentence(name: str, theta: float, form: str) -> str:
    """A kept term in words a reader can check against the record."""
    target, factors = lib.parse(name)
    effect = lib.make(name, form)
    unit = effect.params[0].unit
    return (f"{lib.describe(target, factors, theta)} ({effect.params[0].name} = {theta:.4g} {unit}; "
            f"model term {name})")


def search_terms(record: xr.Dataset, fit: Fit, *, seed: int = 0, threshold: float = THRESHOLD,
                 holdout: float = HOLDOUT, progress=None) -> tuple[dict, Fit]:
    """Search the term library for what ``fit`` leaves unexplained in ``record``; refit what helps.

    Parameters
    ----------
    record : xarray.Dataset
        The record ``fit`` was fitted to.
    fit : Fit
        The model to extend (diagnose's final model).
    seed : int
        Seed of the refits' starts.
    threshold : float
        Score a term must exceed (:data:`~.screen.THRESHOLD`, the named effects' bar).
    holdout : float
        Share of the record held out: at its end in the search, at its start in each passing term's check.

    Returns
    -------
    dict, Fit
        The ``terms`` JSON field — ``proposed`` (each with its regression
        estimate, refit, score, Δ ln Z, held-out MSE ratio and blocks,
        ``other_fold``: the same figures and ``passed`` with the first part
        held out, for a term that passed on the last, else None; ``kept``), ``kept``
        (names), ``sentences``, ``model``, ``params``, ``mse_ratio`` and
        ``delta_log_evidence`` of the whole-record refit against ``fit``,
        ``holdout``, ``heldout_from_s``, ``other_fold_until_s`` — and the
        whole-record fit of the model with the kept terms (``fit`` itself when
        none is kept).
    """
    say = progress or (lambda msg: None)
    fold, other = folds(record, holdout)
    current = fold.refit(fit)
    tried, seen, dropped = [], [], set()
    # forward: propose on the current model's residual, keep the first proposal that passes, propose again
    while len(lib.term_effects(current.model.effects)) < N_TERMS:
        names = [t for t in library(current.model, record) if t not in dropped]
        proposals, info = propose(current.lik, current.phi, current.result.sigma, current.lik.valid, names)
        seen.append({"model": current.name, **info, "proposed": [p.to_dict() for p in proposals]})
        say(f"term search on {current.name}: {len(names)} candidates, proposed "
            f"{', '.join(p.name for p in proposals) or 'none'}")
        step = _step(record, fold, other, current, proposals, seed, threshold, say)
        tried.extend(step[0])
        dropped.update(r["term"] for r in step[0] if not r["kept"])
        if step[1] is None:
            break
        current = step[1]
    kept = [r["term"] for r in tried if r["kept"]]
    fs = float(record.attrs["fs"])
    out = {"proposed": tried, "kept": kept, "holdout": holdout, "heldout_from_s": fold.held.start / fs,
           "other_fold_until_s": other.held.stop / fs, "rounds": seen, "model": fit.name, "sentences": [], "params": {}}
    if not kept:
        out.update(mse_ratio=1.0, delta_log_evidence=0.0)
        return out, fit
    whole = _refit_on(record, current)
    p = whole.params()
    out["model"] = whole.name
    # every parameter of the model with the terms, as ``extended`` carries: what predicts another record (the
    # kept terms' coefficients alone, on the form's defaults, drew the main job's part-B figure far off)
    out["params"] = {k: _num(v) for k, v in p.items()}
    for name in kept:
        pname = lib.make(name, whole.model.form.name).params[0].name
        out["sentences"].append(sentence(name, p[pname], whole.model.form.name))
    out.update(mse_ratio=_num(whole.mse / fit.mse),
               delta_log_evidence=_num(whole.result.log_evidence - fit.result.log_evidence))
    return out, whole
