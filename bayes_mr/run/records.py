"""The main job's records: the measured record prepared and split, and a second record of the same damper.

:func:`prepare` turns a device test into the parts the main job fits and
checks (quality-controlled by the loader, trimmed to its excited part,
decimated to the job's rate, part A to train and part B never fitted).
:func:`prepare_other` makes a second record of the same damper (another test
of the same device: other motion, other command) comparable with them —
same trim, same rate, same inputs between samples, all of it held out — and
:func:`predict_other` scores every fit of the comparison on it (thesis
method 2 across records); :func:`diagnosis_on_other` scores
the diagnosis's baseline and extended model, and :func:`second_record` does
both for the main job.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import xarray as xr

from bayes_mr.inference import results
from bayes_mr.selection.fit_jobs import validation_scores
from bayes_mr.data import load_packaged, trim_excited
from bayes_mr.data.derive import decimate_record
from bayes_mr.data.noise_floor import noise_floor, with_noise_floor

if TYPE_CHECKING:
    from bayes_mr.run.plan import Budget


def _condition(budget: Budget, rec: xr.Dataset) -> tuple[xr.Dataset, dict, int]:
    """The record trimmed, decimated to ``budget.fs``, with its noise floor, inputs and length set.

    Returns
    -------
    record : xarray.Dataset
    trim : dict
        :func:`bayes_mr.data.trim_excited`'s window.
    factor : int
        Decimation factor.
    """
    trimmed, trim = trim_excited(rec)
    factor = max(1, int(round(float(trimmed.attrs["fs"]) / budget.fs)))
    decimated = decimate_record(trimmed, factor) if factor > 1 else trimmed
    if not any(k.startswith("noise_sd_") for k in rec.attrs):
        # the noise floor of the whole record at the fitted rate, before trimming removes its quiet
        # start and end: a differencing estimate on the trimmed record sees the signal's curvature
        # (the packaged damper at 250 Hz: force 130 N, against 1.0 N in its quiet tail)
        decimated = with_noise_floor(decimated, noise_floor(decimate_record(rec, factor) if factor > 1 else rec))
    out = decimated
    if budget.input_interp is not None:
        out.attrs["input_interp"] = budget.input_interp  # every fit and prediction reads the record's attribute
    if budget.duration_s is not None:
        out = out.isel(time=slice(0, int(budget.duration_s * float(out.attrs["fs"]))))
    return out, trim, factor


def _info(rec: xr.Dataset, trim: dict, factor: int, budget: Budget) -> dict:
    """What was done to a record: source, masked samples, trim window, decimation, rate, length, noise floor."""
    n = rec.sizes["time"]
    return {
        "source": str(rec.attrs.get("source", "")),
        "masked": int((~rec["valid"].values.astype(bool)).sum()),
        "trim": {k: (float(v) if isinstance(v, (int, float, np.floating)) else v) for k, v in trim.items()},
        "decimation": factor, "fs": float(rec.attrs["fs"]), "samples": int(n), "input_interp": budget.input_interp,
        "command_interp": str(rec.attrs.get("command_interp", "linear")),
        "duration_s": float(n / rec.attrs["fs"]),
        "noise_sd": {k[len("noise_sd_"):]: float(v) for k, v in rec.attrs.items() if k.startswith("noise_sd_")},
        "noise_floor": json.loads(rec.attrs.get("noise_floor", "{}")),
    }


def prepare(budget: Budget, record: xr.Dataset | None = None) -> tuple[xr.Dataset, xr.Dataset, xr.Dataset, dict]:
    """Quality-controlled, trimmed, decimated record and its parts A and B.

    Parameters
    ----------
    budget : bayes_mr.run.plan.Budget
        ``fs`` [Hz], ``duration_s`` [s], ``train_fraction`` and ``input_interp`` are used.
    record : xarray.Dataset, optional
        A device test (default: the packaged NEES record).

    Returns
    -------
    whole, part_a, part_b : xarray.Dataset
        Part B's clock restarts at 0 (every simulation starts from rest at its first sample).
    info : dict
        What was done: masked samples, trim window, decimation factor, sizes, noise floor.

    Raises
    ------
    ValueError
        When ``record`` is not a device test with a measured force (the main job fits one).
    """
    if record is not None and (record.attrs.get("kind") != "device" or "force" not in record):
        raise ValueError(f"{record.attrs.get('source', 'the record')}: the main job fits a device test (imposed "
                         f"displacement, measured force), this is a {record.attrs.get('kind')} test"
                         f"{'' if 'force' in record else ' without a force channel'}; `bayes-mr compare` "
                         "fits any record")
    rec, trim, factor = _condition(budget, load_packaged() if record is None else record)
    n = rec.sizes["time"]
    cut = int(budget.train_fraction * n)
    part_a = rec.isel(time=slice(0, cut))
    part_b = rec.isel(time=slice(cut, None))
    part_b = part_b.assign_coords(time=part_b["time"].values - float(part_b["time"].values[0]))
    part_a.attrs = {**rec.attrs, "source": f"{rec.attrs.get('source', 'record')} part A"}
    part_b.attrs = {**rec.attrs, "source": f"{rec.attrs.get('source', 'record')} part B"}
    info = {**_info(rec, trim, factor, budget),
            "part_a_s": float(cut / rec.attrs["fs"]), "part_b_s": float((n - cut) / rec.attrs["fs"])}
    return rec, part_a, part_b, info


def prepare_other(budget: Budget, record: xr.Dataset, like: xr.Dataset) -> tuple[xr.Dataset, dict]:
    """A second record of the same damper prepared as part B was: trimmed, at the same rate, all held out.

    Parameters
    ----------
    budget : bayes_mr.run.plan.Budget
        As for :func:`prepare` (its ``fs`` is the rate the record is decimated to, by an integer factor).
    record : xarray.Dataset
        The other test, as :func:`bayes_mr.data.load` read it.
    like : xarray.Dataset
        Part A of the main record: the second one must be the same kind of test with the same channels.

    Returns
    -------
    record : xarray.Dataset
    info : dict
        As :func:`prepare`'s, without the split.

    Raises
    ------
    ValueError
        When the second record is another kind of test or lacks a channel the fits read. A record at
        another rate is decimated by the integer factor nearest ``budget.fs`` (the models are in
        continuous time; ``info["fs"]`` says the rate it is scored at).
    """
    source = record.attrs.get("source", "the second record")
    if record.attrs.get("kind") != like.attrs.get("kind"):
        raise ValueError(f"{source}: a {record.attrs.get('kind')} test, the main record a "
                         f"{like.attrs.get('kind')} test; give a second test of the same damper")
    missing = [c for c in ("displacement", "force", *(c for c in ("voltage", "current") if c in like))
               if c not in record]
    if missing:
        raise ValueError(f"{source}: no {', '.join(missing)} column, which the fits of the main record read; "
                         "name it with --columns CHANNEL=NAME")
    rec, trim, factor = _condition(budget, record)
    rec.attrs["source"] = str(source)
    return rec, _info(rec, trim, factor, budget)


def predict_other(fits: dict, other: xr.Dataset) -> list[dict]:
    """Every fit of the comparison predicts the second record (thesis method 2).

    Parameters
    ----------
    fits : dict
        ``(model, engine)`` → InferenceData, as :func:`bayes_mr.selection.comparison.compare` returns them.
    other : xarray.Dataset
        :func:`prepare_other`'s record.

    Returns
    -------
    list of dict
        One row per fit: ``model``, ``engine`` and :func:`~bayes_mr.selection.fit_jobs.validation_scores` (``force_nrmse``,
        ``mse``, ``rmse`` [SI], …, or ``error`` when the prediction failed: a row, not a crash).
    """
    return [{"model": model, "engine": engine, **validation_scores(idata, other)}
            for (model, engine), idata in fits.items()]


def diagnosis_on_other(d: dict, folder: Path, budget: Budget, record: xr.Dataset,
                       like: xr.Dataset) -> tuple[dict, xr.Dataset]:
    """The diagnosis's baseline and extended model, as fitted on part A, predict the second record.

    Parameters
    ----------
    d : dict
        The diagnosis JSON (``baseline``, ``extended``).
    folder : Path
        Where the diagnosis wrote ``baseline.nc``, ``extended.nc`` and (when the term search kept a term)
        ``terms.nc``: they are scored as ``bayes-mr validate FOLDER/extended.nc DATA2`` scores them.
    budget : bayes_mr.run.plan.Budget
        The job's budget; the record is prepared at the diagnosis's rate (``diagnose_fs``).
    record : xarray.Dataset
        The second record, as read.
    like : xarray.Dataset
        The record the diagnosis ran on (part A at its rate).

    Returns
    -------
    scores : dict
        ``fs`` [Hz], ``duration_s`` [s], and per model (``baseline``, ``extended`` and, with kept terms,
        ``terms``) ``…_model``, ``…_force_nrmse``, ``…_mse`` (or ``…_error`` when that prediction failed).
    record : xarray.Dataset
        The second record at the diagnosis's rate (for the figures).
    """
    rec, info = prepare_other(replace(budget, fs=budget.diagnose_fs or budget.fs), record, like)
    out = {"fs": info["fs"], "duration_s": info["duration_s"]}
    kept = bool((d.get("terms") or {}).get("kept"))
    for label in ("baseline", "extended", "terms")[:3 if kept else 2]:
        out[f"{label}_model"] = d[label]["model"]
        path = folder / f"{label}.nc"
        v = validation_scores(results.load_result(path), rec) if path.exists() else {"error": f"no {path}"}
        out.update({f"{label}_{k}": v[k] for k in ("force_nrmse", "mse", "error") if k in v})
    return out, rec


def diagnosis_dir(out_dir: Path, model: str) -> Path:
    """The folder of the main job's diagnosis of ``model`` (its report, figures, ``baseline.nc``, ``extended.nc``)."""
    return Path(out_dir) / f"diagnose_{model.replace('+', '_')}"


def second_record(raw: xr.Dataset, prepared: tuple[xr.Dataset, dict], comp: dict, diag: dict, budget: Budget, *,
                  like: xr.Dataset, out_dir: Path, say) -> dict:
    """Every fit of the comparison, and the diagnosis's baseline and extended model, predict the second record.

    Parameters
    ----------
    raw : xarray.Dataset
        The second record as read (prepared again at the diagnosis's rate).
    prepared : (xarray.Dataset, dict)
        :func:`prepare_other` at the comparison's rate.
    comp, diag : dict
        :func:`bayes_mr.run.job.with_posteriors` and :func:`bayes_mr.run.stages.diagnose_selected`.
    budget : bayes_mr.run.plan.Budget
    like : xarray.Dataset
        Part A of the main record.
    out_dir : Path
    say : callable

    Returns
    -------
    dict
        ``record`` (what was done to it, at the comparison's rate), ``rows`` (:func:`predict_other`)
        and, when the diagnosis ran, ``diagnosis`` (:func:`diagnosis_on_other`); the
        record at the diagnosis's rate is left in ``diag["_other"]`` for the figures.
    """
    other, info = prepared
    say(f"predicting the second record ({info['source']}, {info['duration_s']:.1f} s) with every fit")
    out = {"record": info, "rows": predict_other(comp["idata"], other)}
    d = next(((m, v) for m, v in diag.items() if not m.startswith("_") and "error" not in v), None)
    if d is not None:
        model, dj = d
        out["diagnosis"], diag["_other"] = diagnosis_on_other(dj, diagnosis_dir(out_dir, model), budget,
                                                              raw, like)
    return out
