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
   regression's estimate, and a grid over the term's range). It is kept only
   if *both* the evidence improves — the κ-corrected log Bayes factor of
   :func:`.screen.score` above the threshold named effects face, and the plain
   Laplace Δ ln Z above 0 — *and* the error on the held-out part falls (MSE
   ratio below 1). A kept term is part of the model the next one extends.
4. **Report.** The model with the kept terms is refitted on the whole record
   (warm-started at the training fit) and each kept term is said in words.
"""

from __future__ import annotations

import math

import numpy as np
import xarray as xr

from ..likelihood import OutputError
from ..models import terms as lib
from ..models.kernel import N_TERMS
from .fits import Fit, record_mse, refit
from .library import Proposal, library, propose
from .screen import THRESHOLD, effect_starts, score

#: Share of the record (its end) held out of the term search.
HOLDOUT = 0.3
#: Blocks the held-out part is cut into, and how many must see the error fall (:func:`heldout_blocks`).
N_BLOCKS, MIN_BLOCKS = 10, 8


def _masked(record: xr.Dataset, cut: int) -> xr.Dataset:
    """``record`` with samples from ``cut`` on marked invalid (they still drive the simulation)."""
    valid = record["valid"].values.astype(bool).copy()
    valid[cut:] = False
    return record.assign(valid=(record["valid"].dims, valid))


def _heldout_mse(record: xr.Dataset, fit: Fit, cut: int) -> float:
    """The record score of ``fit``'s prediction on samples ``cut:`` (the held-out part)."""
    part = record.isel(time=slice(cut, None))
    return record_mse(part, {k: v[cut:] for k, v in fit.predicted.items()})


def heldout_blocks(record: xr.Dataset, base: Fit, ext: Fit, cut: int) -> int:
    """In how many of :data:`N_BLOCKS` consecutive blocks of the held-out part ``ext``'s error is below ``base``'s.

    Squared errors of the channels over their noise SDs. Blocks, not samples:
    residuals are autocorrelated, so an error drop must hold across the
    held-out part, not in a stretch of it (a sign test over blocks; ≥ 8 of 10
    is one-sided p ≈ 0.055 when the term does nothing).
    """
    valid = record["valid"].values.astype(bool)[cut:]
    d = np.zeros(int(valid.sum()))
    for c, sd in zip(base.lik.channels, base.result.sigma):
        y = record[c].values[cut:][valid]
        d += ((y - base.predicted[c][cut:][valid]) ** 2 - (y - ext.predicted[c][cut:][valid]) ** 2) / sd**2
    return int(sum(np.sum(b) > 0 for b in np.array_split(d, N_BLOCKS) if b.size))


def _refit_on(record: xr.Dataset, fit: Fit, start: np.ndarray | None = None) -> Fit:
    """``fit``'s model refitted on ``record`` from its optimum (same ranges, scales and residual model)."""
    lik = OutputError(fit.model, record, ranges=fit.lik.ranges, scales=fit.lik.scales, residual=fit.lik.residual)
    phi = fit.phi if start is None else start
    out, _ = refit(lik, np.atleast_2d(phi), fit.result.sigma, n_refine=1)
    return out


def _try(record_train: xr.Dataset, record: xr.Dataset, current: Fit, prop: Proposal, cut: int, seed: int,
         threshold: float) -> dict:
    """Refit ``current`` + the proposed term on the training part; score it against ``current``."""
    effect = lib.make(prop.name, current.model.form.name)
    model = current.model + effect
    row = prop.to_dict()
    try:
        lik = OutputError(model, record_train, ranges=current.lik.ranges, scales=current.lik.scales,
                          residual=current.lik.residual)
        starts = effect_starts(lik, current.params(), effect, seed)
        j = lik.par.names.index(effect.params[0].name)
        guess = starts[:1].copy()
        guess[0, j] = np.clip(lik.par.coords.to_phi(np.full(len(lik.par.names), prop.theta))[j],
                              lik.phi_lo[j], lik.phi_hi[j])
        ext, _ = refit(lik, np.vstack([starts[:1], guess, starts[1:]]), current.result.sigma, n_refine=3)
    except (RuntimeError, ValueError, np.linalg.LinAlgError) as exc:
        row.update(kept=False, error=str(exc))
        return row
    s, kappa, dll, _ = score(current, ext, effect)
    dlz = ext.result.log_evidence - current.result.log_evidence
    ratio = _heldout_mse(record, ext, cut) / _heldout_mse(record, current, cut)
    blocks = heldout_blocks(record, current, ext, cut)
    theta = ext.params()[effect.params[0].name]
    row.update(score=_num(s), kappa=_num(kappa), delta_loglik=_num(dll), delta_log_evidence=_num(dlz),
               heldout_mse_ratio=_num(ratio), heldout_blocks_better=blocks, theta_refit=_num(theta),
               kept=bool(s > threshold and dlz > 0 and ratio < 1.0 and blocks >= MIN_BLOCKS), fit=ext)
    return row


def _num(v) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None


def _step(train: xr.Dataset, record: xr.Dataset, current: Fit, proposals: list[Proposal], cut: int, seed: int,
          threshold: float, say) -> tuple[list[dict], Fit | None]:
    """Try ``proposals`` in order against ``current``; stop at the first kept (rows tried, its fit or None)."""
    rows = []
    for prop in proposals:
        row = _try(train, record, current, prop, cut, seed, threshold)
        ext = row.pop("fit", None)
        say(f"term {prop.name}: score {row.get('score')}, held-out MSE ratio {row.get('heldout_mse_ratio')}, "
            f"{'kept' if row['kept'] else 'dropped'}")
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
        Share of the record, at its end, held out of the search and used to check each term.

    Returns
    -------
    dict, Fit
        The ``terms`` JSON field — ``proposed`` (each with its regression
        estimate, refit, score, Δ ln Z, held-out MSE ratio, ``kept``), ``kept``
        (names), ``sentences``, ``model``, ``params``, ``mse_ratio`` and
        ``delta_log_evidence`` of the whole-record refit against ``fit``,
        ``holdout`` — and the whole-record fit of the model with the kept
        terms (``fit`` itself when none is kept).
    """
    say = progress or (lambda msg: None)
    n = int(record.sizes["time"])
    cut = int(round((1.0 - holdout) * n))
    train = _masked(record, cut)
    current = _refit_on(train, fit)
    tried, seen, dropped = [], [], set()
    # forward: propose on the current model's residual, keep the first proposal that passes, propose again
    while len(lib.term_effects(current.model.effects)) < N_TERMS:
        names = [t for t in library(current.model, record) if t not in dropped]
        proposals, info = propose(current.lik, current.phi, current.result.sigma, current.lik.valid, names)
        seen.append({"model": current.name, **info, "proposed": [p.to_dict() for p in proposals]})
        say(f"term search on {current.name}: {len(names)} candidates, proposed "
            f"{', '.join(p.name for p in proposals) or 'none'}")
        step = _step(train, record, current, proposals, cut, seed, threshold, say)
        tried.extend(step[0])
        dropped.update(r["term"] for r in step[0] if not r["kept"])
        if step[1] is None:
            break
        current = step[1]
    kept = [r["term"] for r in tried if r["kept"]]
    out = {"proposed": tried, "kept": kept, "holdout": holdout, "heldout_from_s": float(cut / record.attrs["fs"]),
           "rounds": seen, "model": fit.name, "sentences": [], "params": {}}
    if not kept:
        out.update(mse_ratio=1.0, delta_log_evidence=0.0)
        return out, fit
    whole = _refit_on(record, current)
    p = whole.params()
    out["model"] = whole.name
    for name in kept:
        pname = lib.make(name, whole.model.form.name).params[0].name
        out["params"][pname] = _num(p[pname])
        out["sentences"].append(sentence(name, p[pname], whole.model.form.name))
    out.update(mse_ratio=_num(whole.mse / fit.mse),
               delta_log_evidence=_num(whole.result.log_evidence - fit.result.log_evidence))
    return out, whole
