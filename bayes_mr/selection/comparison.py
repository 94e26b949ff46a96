"""Compare models × engines on one record: parameters, errors, evidence, Bayes factors.

>>> from bayes_mr.selection.comparison import compare
>>> out = compare(record, ["dahl", "lugre"], engines=("lsq", "mcmc"))   # doctest: +SKIP
>>> out.selected, out.bayes_factors, out.table()                       # doctest: +SKIP

Every (model, engine) pair is fitted with :class:`bayes_mr.inference.identify.Identify`
and stored as InferenceData; one row per pair carries the ``fit`` JSON keys. The
result is a :class:`~bayes_mr.selection.result.Comparison` (JSON keys, table, figure, fits).
A fit that fails (a model that diverges everywhere, a filter that loses every
run) is a row with ``error`` set, never the end of the comparison.

Selection is by model evidence, one route for every model so the numbers are
comparable: thermodynamic integration (``mcmc`` engine) when every model has
an MCMC row, else the Laplace evidence of least squares (``lsq``), else the
UKF's innovation likelihood of its best run (``ukf``; the thesis ranked by
MSE, which is shown beside). ``bayes_factors`` are ln Z(selected) − ln Z(model)
on that route. Beside them the calibrated evidence (:func:`calibrated_evidence`,
:mod:`bayes_mr.inference.lsq.evidence_scale`): the Laplace evidence of the
likelihood raised to one k for all models, whose Bayes factors do not grow with
the sampling rate under model error; ``selected`` is its choice by default
(:data:`SELECT_ON`, ``selected_on``). With ``validate`` every fit also predicts another record
(thesis method 2) and the row carries its scores. With both ``ukf`` and
``mcmc`` run, ``crosscheck`` holds the z-scores of the UKF estimates against
the MCMC posterior (:mod:`bayes_mr.inference.ukf.crosscheck`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import xarray as xr

from bayes_mr.inference import results
from bayes_mr.execution.executor import Outcome, run_jobs, share
from bayes_mr.inference.estimators import engine
from bayes_mr.selection.fit_jobs import free_parameters, row_message, unit_job, unit_results
from bayes_mr.selection.fit_jobs import units as fit_units
from bayes_mr.inference.lsq.evidence_scale import LaplaceTerms, at_common_scale
from bayes_mr.models import get_model
from bayes_mr.execution.progress import say as progress_say
from bayes_mr.selection.result import Comparison, table
from bayes_mr.simulation.simulate import Inputs

__all__ = ["ROUTES", "SELECT_ON", "Comparison", "calibrated_evidence", "choose", "compare", "crosscheck", "row_of",
           "selection_route", "simulating_point", "table"]

#: Route of each engine's ``log_evidence``, in order of preference for selection.
#: Evidence routes a comparison selects by, in order of preference. The UKF's innovation likelihood is
#: not among them: it is the best of 100 runs chosen after seeing the data, with a parameter random walk,
#: not a marginal likelihood; UKF-only comparisons fall back to the thesis's lowest MSE (3.6.3).
ROUTES = (("mcmc", "ti"), ("lsq", "laplace"))
#: What ``selected`` is chosen on when an evidence route exists: ``raw`` (the route's ln Z of the working
#: likelihood) or ``calibrated`` (the magnitude-adjusted Laplace evidence at the common scale,
#: :mod:`bayes_mr.inference.lsq.evidence_scale`). Both sets of Bayes factors are always reported. Calibrated by
#: default: studies/bayes_factor_rate.py (structure tests, 2 % input and output noise) — between two wrong forms
#: the raw iid ln BF grew ×17 from 250 Hz to 4 kHz, the calibrated one ×1.04 (median of 8 records); with a
#: true candidate the calibrated evidence picked it at least as often (iid 10/12 vs 9/12 at 250 Hz, 11/12 vs
#: 10/12 at 1 kHz; ar 10/12 vs 10/12, 11/12 vs 10/12).
SELECT_ON = "calibrated"


def row_of(rows: list[dict], model: str | None, engine: str) -> dict | None:
    """The row of ``model`` × ``engine`` that did not fail (None if none)."""
    return next((r for r in rows if r["model"] == model and r["engine"] == engine and "error" not in r), None)


def simulating_point(row: dict) -> dict[str, float]:
    """A row's parameters [SI] that simulate: its ``point`` (optimum or best draw) when it has one, else its
    ``params`` (a sloppy model's posterior mean need not simulate)."""
    return row.get("point") or row["params"]


def selection_route(rows: list[dict], models: Sequence[str]) -> tuple[str | None, str | None]:
    """The engine whose evidence every model has (first of :data:`ROUTES`), and its route name.

    A row counts for its engine's route only if its ``log_evidence`` came by
    that route: an ``mcmc`` row whose evidence is the Laplace approximation
    (``Emcee(evidence="laplace")``) does not stand in for thermodynamic
    integration.
    """
    for eng, route in ROUTES:
        have = {r["model"] for r in rows if r["engine"] == eng and _finite(r.get("log_evidence"))
                and r.get("evidence_route", route) == route}
        if have and all(m in have for m in models):
            return eng, route
    return None, None


def _finite(v) -> bool:
    return v is not None and math.isfinite(float(v))


def crosscheck(ukf_idata, mcmc_idata) -> dict[str, dict[str, float]]:
    """UKF estimates against the MCMC posterior of the same model, per parameter [SI].

    ``z`` = (mean_ukf − mean_mcmc)/√(sd_ukf² + sd_mcmc²) and ``sd_ratio`` =
    sd_ukf/sd_mcmc (|z| ≤ 3: agreement; sd_ratio ≪ 1: an overconfident filter).
    """
    u, m = results.summary_of(ukf_idata), results.summary_of(mcmc_idata)
    out = {}
    for name, mean_m in m.params.items():
        if name not in u.params:
            continue
        sd_u, sd_m = float(u.params_sd[name]), float(m.params_sd[name])
        scale = math.hypot(sd_u, sd_m)
        out[name] = {"ukf": float(u.params[name]), "ukf_sd": sd_u, "mcmc": float(mean_m), "mcmc_sd": sd_m,
                     "z": (float(u.params[name]) - float(mean_m)) / scale if scale > 0 else math.nan,
                     "sd_ratio": sd_u / sd_m if sd_m > 0 else math.nan}
    return out


def compare(
    record: xr.Dataset,
    models: Sequence[str],
    *,
    engines: Sequence[str] = ("lsq", "mcmc", "ukf"),
    validate: xr.Dataset | None = None,
    seed: int = 0,
    progress=True,
    out_dir: str | Path | None = None,
    estimators: dict | None = None,
    executor=None,
    noise: str = "iid",
    force: bool = False,
) -> Comparison:
    """Fit every model with every engine and compare.

    Parameters
    ----------
    record : xarray.Dataset, RecordSet or list of records
        The record (package schema; masked samples are left out everywhere), or several records of one
        device fitted by one likelihood summed over them (:class:`~bayes_mr.likelihood.joint.JointLikelihood`;
        the UKF rows then fail: the filter runs on one record).
    models : sequence of str
        Model names, e.g. ``["dahl", "lugre+force_offset"]``.
    engines : sequence of str
        ``lsq``, ``mcmc``, ``ukf``.
    validate : xarray.Dataset or RecordSet, optional
        Another record of the same kind (thesis method 2), or several (scores pooled over them, and each one's).
    seed : int
    progress : bool or callable
    out_dir : path, optional
        Write each fit as ``MODEL__ENGINE.nc`` and the table as ``compare.csv``.
    estimators : dict, optional
        Engine name → configured estimator (e.g. ``{"ukf": UKF(n_lhs=4)}``)
        overriding the defaults of :func:`bayes_mr.inference.estimators.engine`.
    executor : object, optional
        Runs the model × engine fits as jobs (a ``concurrent.futures``
        executor or a ``dask.distributed.Client``, :mod:`bayes_mr.execution.executor`);
        the result is the same as in process.
    noise : {"iid", "ar"}
        Residual model of every fit (``Identify.noise``).
    force : bool
        Select even when the evidence route's chains did not all converge
        (the JSON then says ``forced``); by default such a comparison is
        ``refused`` and names the model and rungs that failed.

    Returns
    -------
    Comparison
        Its JSON keys (:meth:`~Comparison.to_dict`): ``rows`` (one per model × engine: the ``fit`` keys,
        ``error`` if it failed, ``validation`` with ``validate``), ``selected``, ``bayes_factors``
        (model → ln Z(selected) − ln Z(model)), ``selected_on`` (:data:`SELECT_ON`),
        :func:`calibrated_evidence`'s keys, ``evidence_route``, ``evidence_engine``, ``crosscheck``;
        and ``idata``: (model, engine) → InferenceData of every fit that did not fail.
    """
    say, models = progress_say(progress), [get_model(m).name for m in models]
    if not models:
        raise ValueError("give at least one model to compare")
    engines = list(dict.fromkeys(engines))
    for e in engines:
        engine(e)  # validates the name
    estimators = dict(estimators or {})
    if out_dir is not None:
        Path(out_dir).mkdir(parents=True, exist_ok=True)
    pairs = [(m, e) for m in models for e in engines]
    rows, fits = _run_grid(pairs, record, validate, seed, estimators, executor=executor, say=say,
                           progress=bool(progress) and executor is None, out_dir=out_dir, noise=noise)

    cross = {m: crosscheck(fits[(m, "ukf")], fits[(m, "mcmc")])
             for m in models if (m, "ukf") in fits and (m, "mcmc") in fits}
    out = {"rows": rows, **choose(rows, models, force), "crosscheck": cross, **_about(record)}
    if out_dir is not None:
        table(out).to_csv(Path(out_dir) / "compare.csv", index=False)
    return Comparison(out, fits)


def _about(record) -> dict:
    """The comparison's ``record``, ``masked``, ``input_interp`` and ``command_interp``; for several records
    the files joined by "; ", the masked samples summed, the first record's interpolation, and ``records``
    (per record: ``file``, ``role``, ``conditions``, ``masked``)."""
    several = [record] if isinstance(record, xr.Dataset) else list(record)
    inputs = Inputs.from_record(several[0])
    masked = [int((~r["valid"].values.astype(bool)).sum()) if "valid" in r else 0 for r in several]
    out = {"record": "; ".join(str(r.attrs.get("source", "")) for r in several), "masked": sum(masked),
           "input_interp": inputs.interp, "command_interp": inputs.command_interp}
    if not isinstance(record, xr.Dataset):
        about = record.describe() if hasattr(record, "describe") else [
            {"file": str(r.attrs.get("source", "")), "role": "train", "conditions": {}} for r in several]
        out["records"] = [{**a, "masked": m} for a, m in zip(about, masked)]
    return out


def choose(rows: list[dict], models: Sequence[str], force: bool = False) -> dict:
    """The model a set of fitted rows selects, as :func:`compare` selects it.

    The route every model has (:func:`selection_route`), its Bayes factors,
    the calibrated evidence (:func:`calibrated_evidence`) and :data:`SELECT_ON`
    applied; an unconverged evidence selects nothing unless ``force``.

    Returns
    -------
    dict
        ``selected``, ``bayes_factors``, ``evidence_route``, ``evidence_engine``,
        ``selected_by``, ``selected_on`` and the calibrated keys.
    """
    eng, route = selection_route(rows, models)
    selected, factors, verdict = _select(rows, eng, route, force)
    selected, factors, verdict = _select_on(selected, factors, verdict, calibrated_evidence(rows, eng, models))
    return {"selected": selected, "bayes_factors": factors, "evidence_route": route, "evidence_engine": eng,
            **verdict}


def calibrated_evidence(rows: list[dict], eng: str | None, models: Sequence[str]) -> dict:
    """The magnitude-adjusted Laplace evidence of every model at the comparison's common scale k̄.

    From the ``evidence_calibration`` terms of the selecting engine's rows (an
    ``mcmc`` row carries those of the least-squares fit it started from):
    k̄ = Σ p_m / Σ tr(H_m C_m) (:func:`bayes_mr.inference.lsq.evidence_scale.common_scale`),
    ln Z_k̄ of each model and ln BF = ln Z_k̄(best) − ln Z_k̄(model). Empty when
    some model lacks the terms (a UKF-only comparison, a failed fit).

    Returns
    -------
    dict
        ``evidence_scale`` (k̄), ``log_evidence_calibrated`` and
        ``bayes_factors_calibrated`` (model → nats), ``evidence_route_calibrated``
        (``laplace``) and ``selected_calibrated`` (the model with the largest ln Z_k̄).
    """
    terms = {r["model"]: LaplaceTerms.from_dict(r["evidence_calibration"]) for r in rows
             if r.get("engine") == eng and r.get("evidence_calibration")}
    if eng is None or not all(m in terms for m in models):
        return {}
    pooled = at_common_scale(terms)
    if pooled is None:
        return {}
    k, ln_z = pooled
    best = max(ln_z, key=ln_z.get)
    return {"evidence_scale": k, "log_evidence_calibrated": ln_z, "evidence_route_calibrated": "laplace",
            "bayes_factors_calibrated": {m: ln_z[best] - z for m, z in ln_z.items()}, "selected_calibrated": best}


def _select_on(selected: str | None, factors: dict, verdict: dict, calibrated: dict) -> tuple[str | None, dict, dict]:
    """(selected, raw ``bayes_factors`` against it, verdict with ``selected_on`` and the calibrated keys).

    :data:`SELECT_ON` applied: on the calibrated evidence the raw factors stay
    ln Z(selected) − ln Z(model), negative where the raw evidence prefers another model.
    """
    verdict = {**verdict, "selected_on": "mse" if verdict.get("selected_by") == "mse" else "raw", **calibrated}
    if SELECT_ON == "calibrated" and calibrated and verdict.get("selected_by") and selected is not None:
        new = calibrated["selected_calibrated"]
        factors = {m: f - factors[new] for m, f in factors.items()}
        selected = new
        verdict.update(selected_by="calibrated laplace evidence", selected_on="calibrated")
    return selected, factors, verdict


def _select(rows: list[dict], eng: str | None, route: str | None, force: bool) -> tuple[str | None, dict, dict]:
    """(selected model, ln Bayes factors, verdict keys) by the route's evidence, or by MSE without one.

    An evidence whose chains did not all converge (a TI/SS ladder rung, or the
    posterior itself) is not selected on: the comparison says which model and
    which rungs failed and selects nothing, unless ``force`` (then it selects
    and says ``forced``).
    """
    if eng is None:  # no evidence every model has: the thesis's criterion, the lowest MSE of any engine
        mse = {r["model"]: float(r["mse"]) for r in rows if _finite(r.get("mse"))}
        best = min(mse, key=mse.get) if mse else None
        return best, {}, {"selected_by": "mse" if best else None}
    ours = [r for r in rows if r["engine"] == eng]
    failed = {r["model"]: (r.get("evidence_routes") or {}).get(route, {}).get("unconverged_betas")
              for r in ours if not (r.get("evidence_routes") or {}).get(route, {}).get("converged", True)}
    ln_z = {r["model"]: float(r["log_evidence"]) for r in ours}
    best = max(ln_z, key=ln_z.get)
    factors = {m: ln_z[best] - z for m, z in ln_z.items()}
    verdict = {"selected_by": f"{route} evidence"}
    if failed:
        detail = "; ".join(f"{m}: rungs β = {', '.join(f'{b:.3g}' for b in bs)}" for m, bs in failed.items())
        verdict["unconverged"] = {m: bs for m, bs in failed.items()}
        if not force:
            return None, factors, {**verdict, "selected_by": None,
                                   "refused": f"{route} evidence did not converge ({detail}); rerun with longer "
                                              "chains or pass --force to select anyway"}
        verdict["forced"] = True
    return best, factors, verdict


def _run_grid(pairs: list[tuple[str, str]], record: xr.Dataset, validate, seed: int, estimators: dict, *,
              executor, say, progress: bool, out_dir, noise: str = "iid") -> tuple[list[dict], dict]:
    """Fit every (model, engine) of ``pairs``; rows in the order of ``pairs``, fits by pair."""
    rec, val = share(executor, record), (share(executor, validate) if validate is not None else None)
    units = fit_units(pairs, estimators, seed)
    jobs = [(m, tuple(est for _, est in ests), rec, val, seed, progress, noise) for m, ests in units]
    n_done = [0]

    def started(i: int) -> None:
        if executor is None:
            say(f"{units[i][0]} × {' + '.join(e for e, _ in units[i][1])} …")

    def finished(o: Outcome) -> None:  # as each job finishes: report its rows, write its fits
        m, ests = units[o.index]
        for e, row, idata in unit_results(o, m, [e for e, _ in ests]):
            n_done[0] += 1
            if idata is not None and out_dir is not None:
                results.save(idata, Path(out_dir) / f"{m.replace('+', '_')}__{e}.nc")
            say(f"{row_message(m, e, row)} [{n_done[0]}/{len(pairs)}]")

    if executor is not None:
        say(f"{len(pairs)} fits on {type(executor).__name__} …")
    # on an executor the models with the most parameters first (their fits are the long ones)
    outcomes = run_jobs(unit_job, jobs, executor=executor, on_start=started, on_done=finished,
                        cost=[free_parameters(m, record) for m, _ in units])
    done = {(m, e): (row, idata) for (m, ests), o in zip(units, outcomes)
            for e, row, idata in unit_results(o, m, [e for e, _ in ests])}
    rows = [done[p][0] for p in pairs]
    fits = {p: done[p][1] for p in pairs if done[p][1] is not None}
    return rows, fits

