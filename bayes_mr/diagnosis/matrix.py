"""Diagnose over a test matrix: what the model misses by condition, and which extension transfers.

On several tests of one device (a :class:`~bayes_mr.data.records.RecordSet`) the baseline is fitted by one
likelihood summed over the records (:class:`~bayes_mr.likelihood.joint.JointLikelihood`), its residual is
located by condition (amplitude, frequency, current: :func:`by_condition`), and every applicable effect is
fitted as an extension on the same joint likelihood and scored as on one record (:func:`.screen.scored`,
with the design effect summed over the records, :func:`.inflation.design_effect`; ranked by
:func:`.ranking.rank`).

A gain measured on the tests an extension was fitted on is not a finding about the device: an offset in one
test, or a regime of one condition, raises the joint likelihood as much as a property of the damper does.
So an effect that passes is kept only if it also improves the prediction of conditions it was not fitted on
(:func:`held_out`): for each condition in turn (records at one condition together,
:func:`bayes_mr.selection.loco.condition_folds`) the baseline and the extension are refitted on the other
conditions' records — warm, from their full-data optimum, by least squares — and predict the held-out
records. The held-out gain is the share of the baseline's held-out error the extension removes; an effect
whose held-out gain is not positive, or is a small part of its training gain (:data:`TRANSFER_SHARE`), "fits only
its training conditions" and is not kept. Effects are added by forward selection, as on one record.
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import replace

import numpy as np

from bayes_mr.data.records import RecordSet
from bayes_mr.diagnosis.fits import MAX_NFEV, Fit, costs, predict, record_mse, residual_rms
from bayes_mr.diagnosis.residuals import residual_views
from bayes_mr.diagnosis.ranking import Z_AMBIGUOUS, long_run_variance, rank
from bayes_mr.diagnosis.unexplained import FLOOR_RATIO
from bayes_mr.inference.lsq.evidence_scale import at_common_scale
from bayes_mr.diagnosis.screen import (COMPARED_LAWS, STALL, THRESHOLD, Candidate, applicable, effect_ranges,
                                       effect_starts, passes, scored)
from bayes_mr.inference.identify import by_condition as condition_scores
from bayes_mr.inference.lsq.joint import JointResiduals, fit_joint, laplace_joint
from bayes_mr.inference.lsq.least_squares import LSQSettings
from bayes_mr.inference.lsq.refine import refine
from bayes_mr.likelihood.joint import OFFSET, JointLikelihood
from bayes_mr.models import EFFECTS, NONE, Model, get_model
from bayes_mr.selection.loco import condition_folds

#: Most residual evaluations of each fold's warm refit (:func:`held_out`): it starts at the full-data optimum,
#: which leaving one condition out moves only a little.
FOLD_NFEV = 20

#: Share of its training gain an extension must keep on held-out conditions to be said to transfer. A property
#: of the device predicts the conditions left out about as well as those fitted (a force offset planted on every
#: test of a 4-test matrix: training gain 0.984, held-out gain 0.984), while an effect of one test gains nothing
#: on the others, or loses (an offset in one long test: training gain 0.57, held-out gain −0.18); a gain kept by
#: chance is a small fraction of the training one (0.0007 of 0.024 for a 40 N offset in one long test, whose joint
#: fit ends near f0 = 0). Half is the midpoint between
#: "carries over" and "does not".
TRANSFER_SHARE = 0.5

#: What the report says of an extension whose training gain does not carry over to held-out conditions.
NOT_TRANSFERRED = "fits only its training conditions"


def _split(sigma: np.ndarray, lik: JointLikelihood) -> list[np.ndarray]:
    """Every record's channel SDs from the joint σ (R·C,) [channel units]."""
    c = len(lik.channels)
    return [np.asarray(sigma, float)[r * c:(r + 1) * c] for r in range(len(lik.parts))]


def finish(lik: JointLikelihood, res) -> Fit:
    """A joint fit as a :class:`~.fits.Fit`: ``predicted`` is one dict of channels per record, ``mse`` the
    records' scores (:func:`~.fits.record_mse`) averaged with their valid samples as weights."""
    predicted = [predict(lik.record_model(r), rec, lik.record_theta(res.phi, r)) for r, rec in enumerate(lik.records)]
    if any(p is None for p in predicted):
        raise RuntimeError(f"{lik.model.name}: the fitted model diverges on one of its records")
    n = np.array([p.n_valid for p in lik.parts], float)
    mse = float(np.sum(n * [record_mse(rec, p) for rec, p in zip(lik.records, predicted)]) / n.sum())
    return Fit(lik.model, lik, res, predicted, mse)


def fit_baseline(records: RecordSet, model: Model | str, settings: LSQSettings, noise: str = "iid",
                 record_offsets: bool = False) -> Fit:
    """The baseline fitted from scratch on every record by one likelihood (:func:`~.lsq.joint.fit_joint`);
    ``record_offsets``: with a force offset per record (:class:`~bayes_mr.likelihood.joint.JointLikelihood`)."""
    lik = JointLikelihood(get_model(model), list(records), residual=noise, record_offsets=record_offsets)
    return finish(lik, fit_joint(lik, replace(settings, input_noise_replicas=0)))


def select_baseline(records: RecordSet, forms: tuple[str, ...], settings: LSQSettings, noise: str,
                    say, record_offsets: bool = False) -> tuple[Fit, list[dict]]:
    """Each of ``forms`` fitted jointly; the one of highest Laplace evidence, and one row per form."""
    fits, rows = [], []
    for name in forms:
        try:
            f = fit_baseline(records, name, settings, noise, record_offsets)
        except (RuntimeError, ValueError) as exc:
            rows.append({"model": name, "log_evidence": None, "mse": None, "error": str(exc)})
            continue
        fits.append(f)
        rows.append({"model": name, "log_evidence": _num(f.result.log_evidence), "mse": _num(f.mse)})
        say(f"baseline {name}: ln Z {f.result.log_evidence:.6g}, MSE {f.mse:.4g}")
    if not fits:
        raise RuntimeError(f"{records.source or 'record set'}: no model form could be fitted")
    return max(fits, key=lambda f: _finite(f.result.log_evidence)), rows


def candidates(model: Model, records: RecordSet, names: tuple[str, ...] | None = None) -> list:
    """Effects that can extend ``model`` on the matrix.

    Those applicable to any of its records (:func:`.screen.applicable`; the command-dependent ones when the
    tests' commands differ, :func:`_commands_differ`); the current laws one record leaves to ``compare``
    (:data:`.screen.COMPARED_LAWS`) when the tests' constant commands tell their shapes apart (:func:`_laws`);
    ``small_amplitude_regime`` where the records' amplitudes differ by more than a fifth (a regime across
    tests); not ``sensor_delay``, whose screen scans one record's lags.
    """
    seen: dict[str, object] = {}
    varies = _commands_differ(records) or None  # None: each record's own command says
    for rec in records:
        for e in applicable(model, rec, varies):
            seen.setdefault(e.name, e)
    for name in _laws(model, records):
        seen.setdefault(name, EFFECTS[name])
    if any(e.name in CURRENT_LAWS for e in model.effects):
        # the field has its current law already: a second one would shape the command twice
        seen = {n: e for n, e in seen.items() if n not in CURRENT_LAWS}
    amps = _amplitudes(records)
    have = {e.name for e in model.effects}
    if "small_amplitude_regime" not in have and max(amps) > 1.2 * min(amps):
        seen.setdefault("small_amplitude_regime", EFFECTS["small_amplitude_regime"])
    return [e for n, e in seen.items() if n != "sensor_delay" and (names is None or n in names)]


#: The current laws beside the linear one: each maps the filtered command u to the g(u) every field-dependent
#: coefficient sees (:func:`bayes_mr.models.kernel._saturate`); a model carries at most one.
CURRENT_LAWS = ("command_saturation",) + COMPARED_LAWS

#: Distinct non-zero constant commands each law of :data:`.screen.COMPARED_LAWS` needs: a law's g(u) is seen
#: only through the gain at each command: a one-parameter saturation needs two non-zero levels (the gain and
#: the shape), the cubic three (the gain and its two coefficients).
LAW_LEVELS = {"exponential_saturation": 2, "command_polynomial": 3}


def _laws(model: Model, records: RecordSet) -> list[str]:
    """The current laws of :data:`.screen.COMPARED_LAWS` a constant-command matrix can tell apart: on a
    model with a command path, the tests' commands differing, and enough distinct non-zero commands
    (:data:`LAW_LEVELS`). A record whose own command varies is screened by :func:`.screen.applicable`."""
    if not model.commanded:
        return []
    levels = _command_levels(records)
    if len(levels) < 2:
        return []
    nonzero = sum(1 for _, v in levels if abs(v) > 1e-9)
    have = {e.name for e in model.effects}
    return [n for n in COMPARED_LAWS if n not in have and nonzero >= LAW_LEVELS[n]]


def _command_levels(records: RecordSet) -> set[tuple[str, float]]:
    """The distinct (command name, median value) of the records' command channels [A or V]."""
    values = set()
    for rec in records:
        for name in ("current", "voltage"):
            if name in rec:
                values.add((name, round(float(np.median(rec[name].values)), 9)))
    return values


def _commands_differ(records: RecordSet) -> bool:
    """Whether the tests' constant commands (``current`` or ``voltage``) differ between records: a matrix of
    constant currents informs the current dependence (``voltage_dependence``) no single test of it does."""
    return len(_command_levels(records)) > 1


def _amplitudes(records: RecordSet) -> list[float]:
    """Each record's largest displacement over its valid samples [m]."""
    return [float(np.max(np.abs(r["displacement"].values[r["valid"].values.astype(bool)]))) for r in records]


def _ranges(model: Model, records: RecordSet, lik: JointLikelihood) -> dict:
    """Effect ranges as on one record (:func:`.screen.effect_ranges`, on the longest record); the small-
    amplitude threshold x_s between the smallest and largest test amplitude [m]."""
    lead = max(range(len(records)), key=lambda r: lik.parts[r].n_valid)
    out = effect_ranges(model, records[lead], lik.scales)
    if "x_s" in model.free_names(lik.kind):
        amps = _amplitudes(records)
        out["x_s"] = (min(amps), max(amps))
    return out


def extend(records: RecordSet, base: Fit, effect, *, seed: int = 0, noise: str = "iid") -> Candidate:
    """``base.model + effect`` fitted on the joint likelihood, warm-started at ``base`` as on one record
    (:func:`.screen.effect_starts`; the nested start and the cheapest other refined), scored against ``base``."""
    model = base.model + effect
    try:
        lik = JointLikelihood(model, list(records), ranges=_ranges(model, records, base.lik), residual=noise,
                              record_offsets=base.lik.record_offsets)
        starts = effect_starts(lik, base.params(), effect, seed)
        sds = _split(base.result.sigma, base.lik)
        c = sum(costs(p, lik.part_phi(starts, r), sd) for r, (p, sd) in enumerate(zip(lik.parts, sds)))
        runs = []
        for j in ([0] + [int(k) for k in np.argsort(c) if k != 0])[:2]:
            if np.isfinite(c[j]):
                res = refine(lik, starts[j], None, MAX_NFEV, stall=STALL,
                             residuals=JointResiduals(lik.parts, sds, lik))
                runs.append({"start": j, "cost0": float(0.5 * c[j]), "cost": float(res.cost), "phi": res.x})
        if not runs:
            raise RuntimeError(f"{model.name}: every start diverged")
        phi = min(runs, key=lambda r: r["cost"])["phi"]
        # re-weighted by each record's own residual RMS, as every fit diagnose compares is (:func:`.fits.converge`)
        ml = [residual_rms(p, lik.part_phi(phi, r)) for r, p in enumerate(lik.parts)]
        phi = refine(lik, phi, None, MAX_NFEV, residuals=JointResiduals(lik.parts, ml, lik)).x
        ext = finish(lik, laplace_joint(lik, phi, replicas=0))
    except (RuntimeError, ValueError, np.linalg.LinAlgError) as exc:
        return Candidate(effect.name, effect, None, -math.inf, error=str(exc))
    return scored(base, ext, effect, runs=[{k: v for k, v in r.items() if k != "phi"} for r in runs])


def _fold_predictions(f: Fit, records: RecordSet, folds: list[int]) -> list[dict]:
    """Each record's prediction by ``f``'s model refitted without the record's condition (warm, :data:`FOLD_NFEV`).

    With record offsets, a held-out record's offset is a nuisance of that test the other tests cannot predict:
    it is profiled on the record itself (:func:`_profiled`), for the baseline and the extension alike.
    """
    sds = _split(f.result.sigma, f.lik)
    offsets = f.lik.record_offsets
    out: list[dict | None] = [None] * len(records)
    for fold in range(max(folds) + 1):
        keep = [j for j in range(len(records)) if folds[j] != fold]
        sub = JointLikelihood(f.model, [records[j] for j in keep], ranges=f.lik.ranges, fixed=f.lik.fixed,
                              residual=f.lik.parts[0].residual.kind, record_offsets=offsets)
        theta = f.params()
        # the kept records' offsets are f0[j] of the full fit, relabelled by their place in the fold
        if offsets:
            theta.update(zip(sub.offset_names, [theta[f.lik.offset_names[j]] for j in keep]))
        phi0 = np.clip(sub.par.coords.to_phi(np.array([theta[n] for n in sub.par.names])), sub.phi_lo, sub.phi_hi)
        phi = refine(sub, phi0, None, FOLD_NFEV,
                     residuals=JointResiduals(sub.parts, [sds[j] for j in keep], sub)).x
        full = sub.par.full(phi)
        for i in (i for i in range(len(records)) if folds[i] == fold):
            out[i] = _profiled(f.lik.record_model(i), records[i], sub.par, phi) if offsets else predict(
                f.model, records[i], full)
    return out


def _profiled(model: Model, record, par, phi: np.ndarray) -> dict | None:
    """``model`` (``BASE+force_offset``) on ``record`` at the shared φ of ``par``, its offset f0 [N] at the mean
    force residual over the valid samples: the least-squares offset of an additive constant."""
    names = model.param_names(par.kind)
    shared = dict(zip(model.param_names(par.kind), np.zeros(len(names))))
    shared.update(zip(par.model.param_names(par.kind), par.full(phi)))
    theta = np.array([shared[n] for n in names])
    pred = predict(model, record, theta)
    if pred is None:
        return None
    valid = record["valid"].values.astype(bool)
    theta[names.index(OFFSET)] = float(np.mean((record["force"].values - pred["force"])[valid]))
    return predict(model, record, theta)


def held_out(records: RecordSet, base_pred: list, pred: list, training_gain: float) -> dict:
    """Leave-one-condition-out gain of an extension's held-out predictions ``pred`` over the base's ``base_pred``
    (:func:`_fold_predictions`: each record predicted by the fit without its condition).

    Returns ``held_out_mse_ratio`` (Σ_r n_r MSE_r of the extension over the base's), ``held_out_gain``
    (1 − that ratio), ``transfer_share`` (held-out over ``training_gain``, 1 − the training MSE ratio),
    ``transfers`` (a positive held-out gain of at least :data:`TRANSFER_SHARE` of the training gain) and
    ``held_out`` (per record: the two held-out MSEs).
    """
    rows, num, den = [], 0.0, 0.0
    for i, rec in enumerate(records):
        n = float(rec["valid"].values.sum())
        mb = record_mse(rec, base_pred[i]) if base_pred[i] is not None else math.inf
        me = record_mse(rec, pred[i]) if pred[i] is not None else math.inf
        rows.append({"record": i, "baseline_mse": _num(mb), "extended_mse": _num(me)})
        num, den = num + n * me, den + n * mb
    ratio = num / den if den > 0 and math.isfinite(den) else math.inf
    gain = 1.0 - ratio
    share = gain / training_gain if training_gain > 0 else -math.inf
    return {"held_out_mse_ratio": _num(ratio), "held_out_gain": _num(gain), "transfer_share": _num(share),
            "transfers": bool(gain > 0 and share >= TRANSFER_SHARE), "held_out": rows}


def by_condition(records: RecordSet, fits: dict[str, Fit]) -> list[dict]:
    """Per record: file, conditions and, for each fit (label → Fit), its scores by condition
    (:func:`bayes_mr.scores.conditions.condition_row`: force NRMSE, peak-force and energy-per-cycle errors)."""
    rows = []
    for i, rec in enumerate(records):
        row = {"record": i, "file": records.files[i], "conditions": dict(records.conditions[i])}
        for label, f in fits.items():
            scores = condition_scores(rec, f.predicted[i]["force"], records, i)
            for k in ("amplitude", "frequency", "command", "command_value"):
                row.setdefault(k, scores.pop(k, None))
            row[label] = {k: (_num(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else v)
                          for k, v in scores.items()}
        rows.append(row)
    return rows


def diagnose_matrix(records: RecordSet, model: Model | str | None, *, settings: LSQSettings, seed: int = 0,
                    noise: str = "iid", say=lambda msg: None, names: tuple[str, ...] | None = None,
                    threshold: float = THRESHOLD, max_effects: int = 3, forms: tuple[str, ...] = (),
                    record_offsets: bool | None = None, out_dir=None) -> dict:
    """The diagnosis of a matrix (module docstring): the JSON keys of :func:`.diagnose.diagnose` on a set.

    Parameters
    ----------
    records : RecordSet
        Device tests of one damper (at least two).
    model : Model or str or None
        The baseline; None: the one of ``forms`` of highest joint Laplace evidence.
    settings : LSQSettings
        Settings of the baseline's least-squares fit.
    seed : int
        Seed of the effects' starts.
    noise : {"iid", "ar"}
        Residual model of every fit.
    say : callable
        Progress, one line per stage.
    names : tuple of str, optional
        Effects tried (None: every one :func:`candidates` offers).
    threshold : float
        Score an effect must pass (:data:`~.screen.THRESHOLD`).
    max_effects : int
        Most effects added (forward selection: each round re-screens the rest on the model so far).
    forms : tuple of str
        Forms compared when ``model`` is None.
    record_offsets : bool, optional
        A force offset per record in every fit (:class:`~bayes_mr.likelihood.joint.JointLikelihood`), a
        nuisance of each test: an offset in one test is absorbed there, and ``force_offset`` is not screened
        (the per-record offsets nest it). Default: the set's own
        (:attr:`~bayes_mr.data.records.RecordSet.record_offsets`).
    out_dir : path, optional
        Write ``diagnose.md`` and its figures here (:func:`.matrix_report.write_matrix_report`), and the
        baseline and extended fits as ``baseline.nc`` and ``extended.nc``; the JSON then carries ``figures``,
        ``report`` and ``results``.
    """
    t0 = _time.perf_counter()
    offsets = bool(getattr(records, "record_offsets", False)) if record_offsets is None else bool(record_offsets)
    if model is None:
        base, baselines = select_baseline(records, forms, settings, noise, say, offsets)
    else:
        base, baselines = fit_baseline(records, model, settings, noise, offsets), None
    say(f"baseline {base.name} on {len(records)} records: MSE {base.mse:.4g}")
    folds = condition_folds(records)
    first = held = _fold_predictions(base, records, folds) if max(folds) > 0 else None
    current, selected, rounds, screened = base, [], [], []
    for _ in range(max_effects):
        have = {c.name for c, _ in selected}
        offered = [e for e in candidates(current.model, records, names)
                   if e.name not in have and not (offsets and e.name == "force_offset")]
        if not offered:
            break
        rows, chosen, pred, pairs = _round(records, current, offered, folds, held, seed=seed, noise=noise,
                                           threshold=threshold, say=say)
        rounds.append(rows)
        screened.append(pairs)
        if chosen is None:
            break
        selected.append((chosen, next(r for r in rows if r["selected"])))
        current, held = chosen.fit, pred
    total = held_out(records, first, held, 1.0 - current.mse / base.mse) if selected else None
    out = _report(records, base, baselines, selected, rounds, total, folds, threshold, t0,
                  screened=screened[0] if screened else [])
    if out_dir is not None:
        from bayes_mr.diagnosis.matrix_report import write_matrix_report

        ext = selected[-1][0].fit if selected else base
        paths = write_matrix_report(out, records, base, ext, out_dir)
        out.update(figures={k: str(v) for k, v in paths.items() if k != "report"}, report=str(paths["report"]),
                   results=_write_results({"baseline": base, "extended": ext}, out_dir, seed))
        out["wall_s"] = round(_time.perf_counter() - t0, 2)
    return out


def _round(records: RecordSet, current: Fit, offered: list, folds: list[int], held: list | None, *, seed: int,
           noise: str, threshold: float, say) -> tuple[list[dict], Candidate | None, list | None, list[tuple]]:
    """One round of forward selection on the matrix: every offered effect fitted on ``current`` and ranked
    (:func:`.ranking.rank`); each passing one's held-out gain over ``held`` (``current``'s held-out predictions;
    None when every record is at one condition); the best-ranked that transfers is chosen.

    Returns the round's rows (the ``causes`` entries), the chosen candidate (or None), its held-out predictions,
    and (candidate, row) per ranked effect (what :func:`ambiguity` tests the cause against).
    """
    ranked = rank([extend(records, current, e, seed=seed, noise=noise) for e in offered], threshold)
    rows, chosen, chosen_pred = [], None, None
    for c in ranked:
        row = {**c.to_dict(), "training_gain": _num(1.0 - c.mse_ratio), "selected": False}
        if passes(c, threshold) and held is None:
            row["note"] = "every record at one condition: no held-out condition to measure a transfer on"
        elif passes(c, threshold):
            pred = _fold_predictions(c.fit, records, folds)
            row.update(held_out(records, held, pred, 1.0 - c.mse_ratio))
            if not row["transfers"]:
                row["note"] = NOT_TRANSFERRED
            elif chosen is None:
                chosen, chosen_pred, row["selected"] = c, pred, True
            say(f"  {c.name}: training gain {row['training_gain']:.3g}, held-out gain {row['held_out_gain']:.3g}")
        rows.append(row)
    return rows, chosen, chosen_pred, list(zip(ranked, rows))


def pointwise(f: Fit) -> list[np.ndarray]:
    """Per record of a joint fit: ln p(y_t | θ̂) of each valid sample, summed over channels (n_valid_r,)
    (:func:`.ranking.pointwise` of each record, with its own σ_r and residual model)."""
    out = []
    for part, pred, sigma in zip(f.lik.parts, f.predicted, _split(f.result.sigma, f.lik)):
        yhat = np.stack([pred[c] for c in part.channels], axis=-1)[None]
        _, terms = part.log_density(yhat, np.asarray(sigma, float)[None], np.array([True]), pointwise=True)
        out.append(terms[0].sum(axis=1)[part.valid])
    return out


def compare_joint(a: Fit, b: Fit) -> dict:
    """Vuong's test of two joint fits (:func:`.ranking.compare_fits` over a matrix): D = ln L(a) − ln L(b)
    summed over every record's samples, its SD from the Bartlett long-run variances of each record's pointwise
    differences summed (records are independent blocks; their residuals are autocorrelated within a record only)."""
    total, var = 0.0, 0.0
    for da, db in zip(pointwise(a), pointwise(b)):
        d = da - db
        if d.size == 0 or not np.all(np.isfinite(d)):
            return {"difference": None, "sd": None, "z": None}
        total += float(np.sum(d))
        var += d.size * long_run_variance(d)
    sd = math.sqrt(var)
    z = total / sd if sd > 0 else (math.inf if total > 0 else 0.0)
    return {"difference": total, "sd": sd, "z": z}


def ambiguity(selected: list, screened: list[tuple]) -> dict:
    """``ambiguous`` and ``alternatives`` of a matrix, by one record's rule (:func:`.ranking.ambiguous`) on the
    joint likelihood (:func:`compare_joint`): the effects of the first round that pass and transfer (those the
    held-out conditions did not already tell from the cause) whose joint log-likelihood is within
    :data:`~.ranking.Z_AMBIGUOUS` SDs of the cause's. Empty when no effect is kept or the cause stands alone."""
    if not selected:
        return {"ambiguous": [], "alternatives": []}
    cause = selected[0][0]
    ties = []
    for c, row in screened:
        if c.name == cause.name or not row.get("transfers") or c.fit is None:
            continue
        test = compare_joint(cause.fit, c.fit)
        if test["z"] is not None and test["z"] < Z_AMBIGUOUS:
            ties.append({"name": c.name, "extended": _fit_dict(c.fit), "mse_ratio": _num(c.mse_ratio),
                         "delta_loglik": _num(c.delta_loglik), "held_out_gain": row.get("held_out_gain"),
                         "difference": _num(test["difference"]), "sd": _num(test["sd"]), "z": _num(test["z"])})
    return {"ambiguous": [cause.name] + [t["name"] for t in ties] if ties else [], "alternatives": ties}


def _calibrated_gain(base: Fit, ext: Fit) -> dict:
    """``evidence_scale`` and ``delta_log_evidence_calibrated`` of the two joint fits, as one record's diagnosis
    gives them (their Laplace evidences at the pooled k̄, :func:`~bayes_mr.inference.lsq.evidence_scale.
    at_common_scale`); None where a fit has no evidence terms."""
    terms = {"base": base.result.evidence_terms, "ext": ext.result.evidence_terms}
    pooled = at_common_scale(terms) if None not in terms.values() else None
    if pooled is None:
        return {"evidence_scale": None, "delta_log_evidence_calibrated": None}
    k, ln_z = pooled
    return {"evidence_scale": _num(k), "delta_log_evidence_calibrated": _num(ln_z["ext"] - ln_z["base"])}


def _report(records: RecordSet, base: Fit, baselines, selected: list, rounds: list[list[dict]], total: dict | None,
            folds: list[int], threshold: float, t0: float, screened: list[tuple] = ()) -> dict:
    """The ``diagnose`` JSON keys of a matrix: one record's keys (``ambiguous`` and ``alternatives`` by
    :func:`ambiguity`) and the matrix's. ``selected`` holds (candidate, its round's row) per effect added,
    ``total`` the held-out gain of the final model over the baseline (None when nothing was added), ``screened``
    the first round's (candidate, row) pairs."""
    names = [c.name for c, _ in selected]
    ext = selected[-1][0].fit if selected else base
    notes = [f"{r['name']}: {r['note']}" for rows in rounds for r in rows if "note" in r]
    if selected:
        verdict = "; ".join([f"explained by {'+'.join(names)}, which transfers to held-out conditions"] + notes)
    else:
        verdict = "; ".join(notes) or "no effect passes on the joint likelihood"
    fits = {"baseline": base} if not selected else {"baseline": base, "extended": ext}
    gain = total["held_out_gain"] if total else None
    table = by_condition(records, fits)
    unexplained = _unexplained(ext)
    worst = max((u["ratio"] for u in unexplained.values() if u["ratio"] is not None), default=None)
    first = base.lik.parts[0].inputs
    return {
        "record": {"source": records.source or "; ".join(records.files), "kind": records.kind,
                   "samples": int(sum(r.sizes["time"] for r in records)),
                   "fs": float(records[0].attrs["fs"]),
                   "duration_s": float(sum(r.sizes["time"] / float(r.attrs["fs"]) for r in records))},
        "n_records": len(records), "records": records.describe(), "folds": folds, "n_folds": max(folds) + 1,
        "record_offsets": base.lik.record_offsets,
        "masked": int(sum((~r["valid"].values.astype(bool)).sum() for r in records)),
        "baseline": _fit_dict(base), "baselines": baselines,
        "cause": names[0] if names else NONE, **ambiguity(selected, list(screened)),
        "effects": names, "causes": rounds[0] if rounds else [],
        "selection": [dict(round=i + 1, **row) for i, (_, row) in enumerate(selected)],
        "extended": _fit_dict(ext),
        "gain": {"mse_ratio": _num(ext.mse / base.mse),
                 "delta_log_evidence": _num(ext.result.log_evidence - base.result.log_evidence),
                 **_calibrated_gain(base, ext),
                 "delta_score": _num(sum(c.score for c, _ in selected)) if selected else 0.0,
                 "training_gain": _num(1.0 - ext.mse / base.mse), "held_out_gain": gain,
                 "held_out_mse_ratio": total["held_out_mse_ratio"] if total else None,
                 "validation_mse_ratio": None},
        "held_out_gain": gain, "transfers": bool(selected),
        "by_condition": table, "worst_condition": _worst(table), "validation": None, "threshold": threshold,
        "verdict": verdict, "unexplained": unexplained, "unexplained_ratio": worst,
        "at_noise_floor": worst is not None and worst <= FLOOR_RATIO, "floor_ratio_threshold": FLOOR_RATIO,
        "input_interp": first.interp, "command_interp": first.command_interp,
        "terms": None,  # the term search scans one record's residual: it does not run on a matrix
        "residuals": {label: [residual_views(rec, f.predicted[i]).summary() for i, rec in enumerate(records)]
                      for label, f in (("before", base), ("after", ext))},
        "wall_s": round(_time.perf_counter() - t0, 2),
    }


def _write_results(fits: dict[str, Fit], out_dir, seed: int) -> dict[str, str]:
    """Each joint fit (label → Fit) as ``LABEL.nc``, the InferenceData ``fit --engine lsq`` writes for the set
    (its Laplace posterior, draws seeded by ``seed``), so ``bayes-mr validate`` predicts other tests with it."""
    from pathlib import Path

    from bayes_mr.inference import results
    from bayes_mr.inference.estimators import LeastSquares
    from bayes_mr.inference.joint_results import build_any

    return {label: str(results.save(build_any(f.lik, LeastSquares().posterior(f.lik, f.result, seed=seed)),
                                    Path(out_dir) / f"{label}.nc")) for label, f in fits.items()}


def _worst(table: list[dict]) -> dict:
    """The test the baseline misses most (highest force NRMSE): ``record``, ``file``, its condition and the
    baseline's ``force_nrmse`` (and the extension's, when one is kept)."""
    row = max(table, key=lambda r: _finite(r["baseline"]["force_nrmse"] or -math.inf))
    out = {k: row[k] for k in ("record", "file", "amplitude", "frequency", "command", "command_value")}
    out.update({f"{label}_force_nrmse": row[label]["force_nrmse"] for label in ("baseline", "extended") if label in row})
    return out


def _unexplained(f: Fit) -> dict:
    """Channel → the final model's residual RMS over each record's noise floor: ``ratio`` (the worst record)
    and ``by_record``."""
    each = [residual_rms(p, f.lik.part_phi(f.phi, r)) / np.asarray(p.noise_sd, float)
            for r, p in enumerate(f.lik.parts)]
    return {c: {"ratio": _num(max(e[j] for e in each)), "by_record": [_num(e[j]) for e in each]}
            for j, c in enumerate(f.lik.channels)}


def _fit_dict(f: Fit) -> dict:
    return {"model": f.name, "mse": _num(f.mse), "log_evidence": _num(f.result.log_evidence),
            "log_likelihood": _num(f.result.log_likelihood), "params": {k: _num(v) for k, v in f.params().items()},
            "params_sd": {k: _num(v) for k, v in f.result.sd_theta.items()},
            "sigma": [dict(zip(f.lik.channels, map(_num, s))) for s in _split(f.result.sigma, f.lik)]}


def _finite(v: float) -> float:
    return v if math.isfinite(v) else -math.inf


def _num(v) -> float | None:
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None
