"""Diagnose a model on measured data: residual → cause → extension → gain.

>>> from bayes_mr.data import load_packaged
>>> from bayes_mr.diagnosis.diagnose import diagnose
>>> report = diagnose(load_packaged(), out_dir="results/diagnose")   # doctest: +SKIP
>>> report.cause, report.gain["mse_ratio"], report.table()             # doctest: +SKIP

1. **Show what is wrong.** Fit the baseline (given, or the form with the
   highest Laplace evidence) by output-error least squares, and view the
   residual of every measured channel against time, displacement, velocity,
   amplitude envelope and voltage, its whiteness and its lag
   (:mod:`.residuals`).
2. **Name the cause.** Fit every applicable effect of the SPEC as an
   extension of the baseline and score it by an autocorrelation-corrected
   log Bayes factor that decides whether it is there (:mod:`.screen`); of
   those that pass, add the one that explains the most (:mod:`.ranking`),
   and say which others the record cannot tell from it. No effect passing
   is the answer ``none``.
3. **Extend and measure.** Report the extended model's MSE ratio and
   evidence gain, and with ``validate`` its error ratio on another record
   (thesis method 2); write the SPEC's JSON and, with ``out_dir``, a Markdown
   report with before/after figures (:mod:`.report`).
"""

from __future__ import annotations

import json
import math
import os
import time as _time
from functools import partial
from pathlib import Path

import xarray as xr

from bayes_mr.inference.lsq.evidence_scale import at_common_scale
from bayes_mr.inference.lsq.least_squares import LSQSettings
from bayes_mr.models import NONE, Model, get_model
from bayes_mr.execution.progress import say as progress_say
from bayes_mr.scores import score
from bayes_mr.diagnosis.fits import Fit, fit_model, inference_data, predict
from bayes_mr.diagnosis.residuals import residual_views, varying_voltage
from bayes_mr.data.records import RecordSet
from bayes_mr.diagnosis.extend import fit_at
from bayes_mr.diagnosis.matrix import diagnose_matrix
from bayes_mr.diagnosis.ranking import ambiguous
from bayes_mr.diagnosis.result import Diagnosis
from bayes_mr.diagnosis.search import Search
from bayes_mr.diagnosis.screen import THRESHOLD, Candidate
from bayes_mr.diagnosis.term_search import search_terms
from bayes_mr.diagnosis.unexplained import BEYOND, FLOOR_RATIO, unexplained, verdict, worst_ratio

__all__ = ["FORMS", "THRESHOLD", "Diagnosis", "Search", "diagnose", "select_baseline"]

#: Forms compared when no baseline is given (spencer only for device tests with a varying voltage).
FORMS = ("normalized-bouc-wen", "dahl", "lugre", "bouc-wen")


def select_baseline(record: xr.Dataset, forms: tuple[str, ...] | None = None, *,
                    settings: LSQSettings = LSQSettings(), progress=None,
                    noise: str = "iid") -> tuple[Fit, list[dict]]:
    """Fit each form and keep the one with the highest Laplace evidence.

    Parameters
    ----------
    record : xarray.Dataset
    forms : tuple of str, optional
        Default :data:`FORMS`, plus ``spencer`` for a device test whose
        voltage varies.

    Returns
    -------
    Fit, list of dict
        The selected fit and one row per form (``model``, ``log_evidence``,
        ``mse``, or ``error``).
    """
    say = progress_say(progress)
    if forms is None:
        forms = FORMS + (("spencer",) if record.attrs["kind"] == "device" and varying_voltage(record) else ())
    fits, rows = [], []
    for name in forms:
        t0 = _time.perf_counter()
        try:
            f = fit_model(record, name, settings, noise=noise)
        except (RuntimeError, ValueError) as exc:
            rows.append({"model": name, "log_evidence": None, "mse": None, "error": str(exc)})
            say(f"baseline {name}: failed ({exc})")
            continue
        fits.append(f)
        rows.append({"model": name, "log_evidence": _num(f.result.log_evidence), "mse": _num(f.mse),
                     "wall_s": round(_time.perf_counter() - t0, 2)})
        say(f"baseline {name}: ln Z {f.result.log_evidence:.6g}, MSE {f.mse:.4g}")
    if not fits:
        raise RuntimeError(f"{record.attrs.get('source', 'record')}: no model form could be fitted")
    best = max(fits, key=lambda f: f.result.log_evidence if math.isfinite(f.result.log_evidence) else -math.inf)
    return best, rows


def diagnose(
    record: xr.Dataset,
    model: Model | str | None = None,
    *,
    validate: xr.Dataset | str | os.PathLike | None = None,
    out_dir: str | os.PathLike | None = None,
    seed: int = 0, progress=True,
    settings: LSQSettings | None = None, noise: str = "iid",
    executor=None, terms: bool | None = None,
    search: Search | str = "forward", start: dict[str, float] | None = None,
) -> Diagnosis:
    """Show where ``model`` departs from ``record``, name the cause, extend, measure the gain.

    Parameters
    ----------
    record : xarray.Dataset or RecordSet or sequence of xarray.Dataset
        A record in the package schema (structure or device test; masked
        samples are left out of every fit and score). Several device tests (a
        test matrix) are diagnosed by one likelihood, and an effect is kept only
        where it predicts the conditions it was not fitted on
        (:mod:`.matrix`: forward selection, ``search``'s candidates, threshold and
        most effects apply; a set with ``record_offsets`` fits a force offset per test,
        so an offset of one test is absorbed there, not named); a set of one is that record.
    model : Model or str, optional
        Baseline, e.g. ``"dahl"`` or ``"lugre+force_offset"``. Default: the
        form with the highest evidence (:func:`select_baseline`).
    validate : Dataset or path, optional
        Another record of the same kind: the baseline and the extended model,
        as fitted, predict it (thesis method 2).
    out_dir : path, optional
        Write ``diagnose.md``, ``diagnose.json``, figures, ``baseline.nc`` and
        ``extended.nc`` (InferenceData ``bayes-mr validate`` scores) here.
    seed : int
        Seed of the least-squares candidates and of the effects' starts.
    progress : bool or callable
        Report each stage on stderr (or to the callable).
    settings : LSQSettings, optional
        Settings of the baseline fits.
    noise : {"iid", "ar"}
        Residual model of the fits (extensions keep the baseline's AR orders).
    executor : object, optional
        Fits the candidate effects as parallel jobs (:mod:`bayes_mr.execution.executor`; default this process's threads).
    terms : bool, optional
        Search the term library: always, never, or (None) where the model stays above its floor (:func:`_asked`).
    search : Search or {"forward", "ranked"}
        How effects are added: route, candidates, most effects, threshold (:class:`.search.Search`).
    start : dict, optional
        Parameters [SI] of ``model`` to refit the baseline from (its optimum elsewhere,
        :func:`.extend.fit_at`) instead of a search from scratch; needs ``model``.

    Returns
    -------
    Diagnosis
        Its JSON keys (:meth:`~Diagnosis.to_dict`) are the SPEC's ``diagnose`` keys —
        ``baseline`` {model, mse, log_evidence},
        ``cause`` (an effect name or ``"none"``), ``causes`` (every candidate ranked, ``{name, score, ...}``: those
        that pass by the log-likelihood they add, :mod:`.ranking`), ``ambiguous`` and ``alternatives`` (the
        effects the record cannot tell from the cause, and their extended models, :func:`_ambiguity`),
        ``extended`` {model, mse, log_evidence}, ``gain`` {mse_ratio, delta_log_evidence, validation_mse_ratio; also
        ``delta_log_evidence_calibrated`` at the pooled ``evidence_scale``, :func:`_calibrated_gain`} — and
        ``effects`` (all effects named, in the order they were added), ``selection`` (each forward-selection round),
        ``masked``, ``threshold``, ``residuals`` (before/after summaries),
        ``baselines`` (form comparison), ``wall_s``, ``figures``, ``report``;
        ``unexplained``, ``unexplained_ratio``, ``at_noise_floor``, ``verdict``
        (:func:`_unexplained`); ``terms`` (:func:`_search`); with ``out_dir``, ``results`` (the ``.nc`` paths).
        Its ``idata`` holds the baseline, the extended model and (with a kept term) the term search's model
        as InferenceData, built when first read (with ``out_dir``: the ones written).
    """
    t0 = _time.perf_counter()
    say = progress_say(progress)
    settings = settings or LSQSettings(seed=seed)
    search = Search(route=search) if isinstance(search, str) else search
    if not isinstance(record, xr.Dataset):  # a RecordSet or a list: one record is that record's diagnosis
        records = _as_set(record)
        if len(records) > 1:
            return _matrix(records, model, validate, out_dir, seed, say, settings, noise, search)
        record = records[0]
    base, baselines = _baseline(record, model, settings, say, noise, start)
    say(f"baseline {base.name}: MSE {base.mse:.4g}, ln Z {base.result.log_evidence:.6g}")
    before = residual_views(record, base.predicted)
    selected, rounds = search.run(record, base, seed=seed, progress=say, executor=executor)
    ext, after = (selected[-1].fit, residual_views(record, selected[-1].fit.predicted)) if selected else (base, before)
    say(f"named: {', '.join(c.name for c in selected) or NONE}")
    validation, validate = _validate(base, ext, validate, record)
    out = _report(record, base, ext, selected, rounds, validation, baselines)
    out.update(_unexplained(record, before, after, [c.name for c in selected]), seed=seed, threshold=search.threshold,
               residuals={"before": before.summary(), "after": after.summary()}, input_interp=base.lik.inputs.interp,
               command_interp=base.lik.inputs.command_interp)
    out["terms"], term_fit = _search(record, ext, _asked(out) if terms is None else terms, validate, seed,
                                     search.threshold, say)
    out["wall_s"] = round(_time.perf_counter() - t0, 2)
    fits = {label: partial(inference_data, f, seed=seed)
            for label, f in (("baseline", base), ("extended", ext), ("terms", term_fit)) if f is not None}
    if out_dir is not None:  # the report states the time to here; the JSON the time with the report
        written, built = _write(out, record, (base, ext, term_fit), before, after, rounds, Path(out_dir), seed)
        out.update(written)
        fits.update(built)
        out["wall_s"] = round(_time.perf_counter() - t0, 2)
        (Path(out_dir) / "diagnose.json").write_text(json.dumps(out, indent=2))
    return Diagnosis(out, fits)


def _as_set(records) -> RecordSet:
    """A RecordSet of ``records`` (a RecordSet, or a sequence of records without conditions)."""
    if isinstance(records, RecordSet):
        return records
    records = tuple(records)
    return RecordSet(records, ({},) * len(records), ("train",) * len(records), "", {})


def _matrix(records: RecordSet, model, validate, out_dir, seed: int, say, settings: LSQSettings, noise: str,
            search: Search) -> Diagnosis:
    """The diagnosis of several records by one likelihood (:func:`.matrix.diagnose_matrix`); its held-out
    conditions are its validation, so ``validate`` is refused; with ``out_dir``, ``diagnose.json``,
    ``diagnose.md`` and its figures."""
    if validate is not None:
        raise ValueError("diagnose of several records validates on each held-out condition: give the validation "
                         "record as one more record of the set instead of validate=")
    if any(r.attrs["kind"] != "device" for r in records):
        raise ValueError("diagnose of several records runs on device tests (force and displacement): the held-out "
                         "gain is scored on the force of each test")
    out = diagnose_matrix(records, model, settings=settings, seed=seed, noise=noise, say=say,
                          names=search.candidates, threshold=search.threshold,
                          max_effects=search.max_effects, forms=FORMS, out_dir=out_dir)
    out["seed"] = seed
    if out_dir is not None:
        (Path(out_dir) / "diagnose.json").write_text(json.dumps(out, indent=2))
    return Diagnosis(out, {})


def _baseline(record: xr.Dataset, model, settings: LSQSettings, say, noise: str = "iid",
              start: dict[str, float] | None = None) -> tuple[Fit, list[dict] | None]:
    """The baseline fit (``model``, from ``start`` or a search; or the form of highest evidence) and the form
    comparison (None if given)."""
    if record.attrs["kind"] == "structure" and "mass" not in record.attrs:
        raise ValueError(f"{record.attrs.get('source', 'record')}: a structure test needs the storey mass")
    if model is None:
        if start is not None:
            raise ValueError("diagnose: a start needs the model it belongs to (model=...)")
        return select_baseline(record, settings=settings, progress=say, noise=noise)
    if start is not None:
        return fit_at(record, model, start, noise=noise), None
    return fit_model(record, get_model(model), settings, noise=noise), None


def _unexplained(record: xr.Dataset, before, after, effects: list[str]) -> dict:
    """``unexplained`` (channel → what the final model leaves, :mod:`.unexplained`), ``verdict`` and the
    worst fitted channel's ratio against :data:`~.unexplained.FLOOR_RATIO`."""
    unexp = unexplained(record, after, before)
    worst = _num(worst_ratio(unexp))
    return {"unexplained": unexp, "verdict": verdict(effects, unexp), "unexplained_ratio": worst,  # worst channel
            "at_noise_floor": worst is not None and worst <= FLOOR_RATIO, "floor_ratio_threshold": FLOOR_RATIO}


def _asked(out: dict) -> str | None:
    """Why the term search runs by default, or None: the verdict is "unexplained by the vocabulary", or effects
    were named and the extended model is still above the noise floor (what they leave is what the library is for)."""
    if out["verdict"] == BEYOND:
        return f"verdict '{BEYOND}'"
    if out["effects"] and not out["at_noise_floor"]:
        return f"the extended model at {out['unexplained_ratio']:.3g} × the noise floor"
    return None


def _search(record: xr.Dataset, ext: Fit, ask: bool | str | None, validate: xr.Dataset | None, seed: int,
            threshold: float, say) -> tuple[dict | None, Fit | None]:
    """The term search (:mod:`.terms`) on the final model: ``ask`` True/False, or why it runs by default
    (:func:`_asked`; None: it does not); with ``validate``, the kept terms' model predicts it (``validation``).

    Returns
    -------
    terms : dict or None
        The ``terms`` JSON field (None when the search does not run).
    fit : Fit or None
        The whole-record fit of the model with the kept terms (None when none is kept).
    """
    if ask is False or ask is None:
        return None, None
    found, fit = search_terms(record, ext, seed=seed, threshold=threshold, progress=say)
    found["asked"] = "explicitly" if ask is True else ask
    say(f"terms kept: {', '.join(found['kept']) or 'none'}")
    if not found["kept"]:
        return found, None
    if validate is not None:
        found["validation"] = {k: _num(v) for k, v in _scores_on(fit, validate).items()}
    return found, fit


def _write(out: dict, record: xr.Dataset, models: tuple[Fit, Fit, Fit | None], before, after, rounds,
           out_dir: Path, seed: int) -> tuple[dict, dict]:
    """Report, figures, and ``baseline.nc`` / ``extended.nc`` / (with kept terms) ``terms.nc``: InferenceData
    ``bayes-mr validate`` reads. ``models`` is (baseline, extended, the term search's model or None).

    Returns the JSON keys of what was written and label → the InferenceData written."""
    from bayes_mr.inference import results
    from bayes_mr.diagnosis.report import write_report

    base, ext, term_fit = models
    paths = write_report(out, record, base, ext, before, after, rounds, out_dir)
    fits, built = {}, {}
    for label, f in (("baseline", base), ("extended", ext), ("terms", term_fit)):
        if f is not None:
            built[label] = inference_data(f, seed=seed)
            fits[label] = str(results.save(built[label], out_dir / f"{label}.nc"))
    return {"figures": {k: str(v) for k, v in paths.items() if k != "report"}, "report": str(paths["report"]),
            "results": fits}, built


def _report(record: xr.Dataset, base: Fit, ext: Fit, selected: list[Candidate], rounds, validation,
            baselines) -> dict:
    """The ``diagnose`` JSON keys of a finished diagnosis (without timing and figures)."""
    names = [c.name for c in selected]
    return {
        "record": {"source": str(record.attrs.get("source", "")), "kind": record.attrs["kind"],
                   "samples": int(record.sizes["time"]), "fs": float(record.attrs["fs"]),
                   "duration_s": float(record.sizes["time"] / record.attrs["fs"])},
        "masked": int((~record["valid"].values.astype(bool)).sum()),
        "baseline": _fit_dict(base),
        "baselines": baselines,
        "cause": names[0] if names else NONE,
        **_ambiguity(selected, rounds),
        "effects": names,
        "causes": _causes(rounds, selected),
        "selection": [dict(round=i + 1, **c.to_dict()) for i, c in enumerate(selected)],
        "extended": _fit_dict(ext),
        "gain": {
            "mse_ratio": _num(ext.mse / base.mse),
            "delta_log_evidence": _num(ext.result.log_evidence - base.result.log_evidence),
            **_calibrated_gain(base, ext),
            "delta_score": _num(sum(c.score for c in selected)) if selected else 0.0,
            "validation_mse_ratio": validation["mse_ratio"] if validation else None,
        },
        "validation": validation,
    }


def _ambiguity(selected: list[Candidate], rounds: list[list[Candidate]]) -> dict:
    """``ambiguous`` (the cause and the first round's passing effects the record cannot tell from it, cause
    first; empty when it stands alone, :func:`.ranking.ambiguous`) and ``alternatives`` (each such effect's
    extended model and the test against the cause)."""
    if not selected or not rounds:
        return {"ambiguous": [], "alternatives": []}
    cause = selected[0]
    ties = ambiguous(cause, rounds[0])
    alternatives = [{"name": t["name"], "extended": _fit_dict(t["candidate"].fit),
                     "mse_ratio": _num(t["candidate"].mse_ratio), "delta_loglik": _num(t["candidate"].delta_loglik),
                     "difference": _num(t["difference"]), "sd": _num(t["sd"]), "z": _num(t["z"])} for t in ties]
    return {"ambiguous": [cause.name] + [t["name"] for t in ties] if ties else [], "alternatives": alternatives}


def _calibrated_gain(base: Fit, ext: Fit) -> dict:
    """``evidence_scale`` k̄ and ``delta_log_evidence_calibrated``: ln Z_k̄(extended) − ln Z_k̄(baseline).

    The Laplace evidences of the two fits' likelihood raised to their pooled k̄ (as ``compare``'s calibrated
    Bayes factors, :func:`~bayes_mr.inference.lsq.evidence_scale.at_common_scale`): the raw difference counts every
    sample as independent and grows with the sampling rate, this one counts what the record holds. Its
    covariance is diagnose's HAC/GLS one (no input-noise replicas, :mod:`.fits`). None where a fit has no terms.
    """
    terms = {"base": base.result.evidence_terms, "ext": ext.result.evidence_terms}
    pooled = at_common_scale(terms) if None not in terms.values() else None
    if pooled is None:
        return {"evidence_scale": None, "delta_log_evidence_calibrated": None}
    k, ln_z = pooled
    return {"evidence_scale": k, "delta_log_evidence_calibrated": _num(ln_z["ext"] - ln_z["base"])}


def _num(v) -> float | None:
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None


def _fit_dict(f: Fit) -> dict:
    out = {"model": f.name, "mse": _num(f.mse), "log_evidence": _num(f.result.log_evidence),
           "log_likelihood": _num(f.result.log_likelihood),
           "params": {k: _num(v) for k, v in f.params().items()},
           "params_sd": {k: _num(v) for k, v in f.result.sd_theta.items()},
           "sigma": dict(zip(f.lik.channels, map(_num, f.result.sigma)))}
    delay = f.model.effect("sensor_delay")
    if delay is not None:
        out["options"] = {"sensor_delay": {"channel": f.model.delay_channel(f.lik.kind)}}
    return out


def _causes(rounds: list[list[Candidate]], selected: list[Candidate]) -> list[dict]:
    """Round-one candidates ranked by score; an effect named in a later round
    carries that round's score too."""
    if not rounds:
        return []
    chosen = {id(c): i for i, c in enumerate(selected)}
    later = {c.name: (i, c) for i, c in enumerate(selected)}
    rows = []
    for c in rounds[0]:
        row = c.to_dict()
        row["selected"] = c.name in later
        if c.name in later and id(c) not in chosen:
            i, s = later[c.name]
            if s.channel == c.channel:
                row["score_when_selected"] = _num(s.score)
                row["selected_round"] = i + 1
            else:
                row["selected"] = False
        elif id(c) in chosen:
            row["selected_round"] = chosen[id(c)] + 1
        rows.append(row)
    return rows


def _validation_record(validate, record: xr.Dataset) -> xr.Dataset:
    """The validation record (read when a path), checked to be of ``record``'s kind."""
    if not isinstance(validate, xr.Dataset):
        from bayes_mr.data import load

        validate = load(validate, mass=record.attrs.get("mass"))
    if validate.attrs["kind"] != record.attrs["kind"]:
        raise ValueError(f"validation record is a {validate.attrs['kind']} test, the record a "
                         f"{record.attrs['kind']} test")
    return validate


def _scores_on(fit: Fit, validate: xr.Dataset) -> dict:
    """``mse`` and ``force_nrmse`` of ``fit``'s model, as fitted, predicting ``validate`` (inf/None if it
    diverges; the force NRMSE is null when the record measures no force)."""
    pred = predict(fit.model, validate, fit.theta_full)
    scores = score(validate, pred) if pred is not None else {"mse": math.inf, "force_nrmse": None}
    return {"mse": scores["mse"], "force_nrmse": _num(scores["force_nrmse"])}


def _validate(base: Fit, ext: Fit, validate, record: xr.Dataset) -> tuple[dict | None, xr.Dataset | None]:
    """Errors of the baseline and the extended model, as fitted, on another record (a Dataset or a path, read
    and checked by :func:`_validation_record`), and that record; (None, None) without one."""
    if validate is None:
        return None, None
    validate = _validation_record(validate, record)
    out = {"source": str(validate.attrs.get("source", "")),
           "masked": int((~validate["valid"].values.astype(bool)).sum())}
    mses = {}
    for label, f in (("baseline", base), ("extended", ext)):
        scores = _scores_on(f, validate)
        mses[label] = scores["mse"]
        out[f"{label}_mse"] = _num(mses[label])
        out[f"{label}_force_nrmse"] = scores["force_nrmse"]
    out["mse_ratio"] = _num(mses["extended"] / mses["baseline"]) if mses["baseline"] > 0 else None
    return out, validate
