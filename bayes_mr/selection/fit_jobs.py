"""The jobs of a comparison's grid: one model × engine, or a model's lsq and mcmc rows sharing one fit.

Module level with picklable arguments and results, so that any executor can
run them (:mod:`bayes_mr.execution.executor`); :func:`bayes_mr.selection.comparison.compare` builds
the grid (:func:`units`) and collects the rows in its own order.
"""

from __future__ import annotations

import time as _time

import numpy as np
import xarray as xr

from bayes_mr.inference import results
from bayes_mr.execution.executor import Outcome
from bayes_mr.inference.identify import Identify
from bayes_mr.inference.identify import validate as validate_fit
from bayes_mr.inference.identify import validate_records
from bayes_mr.inference.mcmc.budget import over_budget
from bayes_mr.inference.estimators import Emcee, LeastSquares, engine
from bayes_mr.inference.joint_results import build_any
from bayes_mr.inference.lsq.joint import fit_joint
from bayes_mr.inference.lsq.least_squares import LSQResult, fit_lsq
from bayes_mr.likelihood.joint import JointLikelihood
from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.models import get_model


#: What a fit may raise that makes it a row with ``error`` rather than the end of the comparison.
FIT_ERRORS = (RuntimeError, ValueError, FloatingPointError, np.linalg.LinAlgError)


def _failed(model: str, engine_name: str, error: str, wall_s: float) -> tuple[dict, None]:
    """The row of a fit that failed (``error``: ``"ExceptionType: message"``), and no result."""
    return {"model": get_model(model).name, "engine": engine_name, "error": error, "wall_s": wall_s}, None


def _why(exc: Exception) -> str:
    return f"{type(exc).__name__}: {exc}"


def error_row(model: str, engine_name: str, exc: Exception, wall_s: float) -> dict:
    """The row of a fit that raised ``exc`` after ``wall_s`` seconds (as every job of the grid makes it)."""
    return _failed(model, engine_name, _why(exc), wall_s)[0]


def row_message(model: str, engine_name: str, row: dict) -> str:
    """What a finished row says in the progress: its evidence, MSE and seconds; why a budget did not run it
    (:func:`~bayes_mr.inference.mcmc.budget.over_budget`); or why it failed."""
    head = f"{model} × {engine_name}: "
    if "error" in row:
        why = over_budget(row["error"])
        return head + (why if why else f"failed ({row['error']})")  # why ends "not run"
    return head + f"ln Z {row['log_evidence']}, MSE {row['mse']}, {row['wall_s']:.1f} s"


def _row(idata, validate: xr.Dataset | None) -> tuple[dict, object]:
    row = results.summary_of(idata).to_dict()
    if validate is not None:
        row["validation"] = validation_scores(idata, validate)
    return row, idata


def fit_job(model: str, estimator, record: xr.Dataset, validate: xr.Dataset | None, seed: int,
            progress: bool, noise: str = "iid") -> tuple[dict, object]:
    """(row, InferenceData) of one model × engine; a failed fit is a row with ``error`` and no result.

    Module level with picklable arguments and result, so that any executor
    can run it (:mod:`bayes_mr.execution.executor`); the seed is the comparison's own,
    never the order jobs finish in.
    """
    t0 = _time.perf_counter()
    try:
        idata = Identify(model, estimator, noise=noise).fit(record, seed=seed, progress=progress)
    except FIT_ERRORS as exc:
        return _failed(model, estimator.name, _why(exc), _time.perf_counter() - t0)
    return _row(idata, validate)


def shares_lsq(lsq, mcmc, seed: int) -> bool:
    """Whether an ``lsq`` row's fit is the one ``mcmc``'s chain would start from (:func:`lsq_mcmc_job`)."""
    return (isinstance(lsq, LeastSquares) and isinstance(mcmc, Emcee)
            and lsq.settings == mcmc.lsq_settings(seed))


def free_parameters(model: str, record: xr.Dataset) -> int:
    """Parameters of ``model`` on ``record``'s kind of test: a fit's cost grows with them (the ``cost`` by which a
    grid on an executor starts its longest jobs first, :func:`bayes_mr.execution.executor.run_jobs`)."""
    kind = record.attrs["kind"] if isinstance(record, xr.Dataset) else record[0].attrs["kind"]  # or several records
    return len(get_model(model).param_names(kind))


def least_squares(model: str, lsq, record: xr.Dataset, noise: str = "iid") -> tuple[OutputError, LSQResult]:
    """The likelihood of ``model`` on ``record`` and its least-squares fit: what a model's ``lsq`` row and its
    chain share (:func:`lsq_mcmc_job`). Raises what the fit raises (:data:`FIT_ERRORS`)."""
    lik = Identify(model, lsq, noise=noise).likelihood(record)
    return lik, (fit_joint if isinstance(lik, JointLikelihood) else fit_lsq)(lik, lsq.settings)


def lsq_mcmc_job(model: str, lsq, mcmc, record: xr.Dataset, validate: xr.Dataset | None, seed: int,
                 progress: bool, noise: str = "iid",
                 fitted: tuple[OutputError, LSQResult] | None = None) -> list[tuple[dict, object]]:
    """The ``lsq`` and ``mcmc`` rows of one model from one least-squares fit: [(row, InferenceData)] × 2.

    The chain starts from least squares' optimum (:meth:`~bayes_mr.inference.estimators.Emcee.fit_from`);
    when the ``lsq`` row's settings are those the chain would use (:func:`shares_lsq`) the fit is made once,
    not once per row — the same numbers as :func:`fit_job` twice. Each row's ``wall_s`` counts the shared fit,
    as it did when each made its own. A failure is a row with ``error``, as in :func:`fit_job`.

    ``fitted``: that fit already made on ``record`` (:func:`least_squares`; the main job's first pass), not made
    again — its seconds (``LSQResult.wall_s``) count as above. An estimator given as None makes no row: ``mcmc``
    None gives the ``lsq`` row alone, ``lsq`` None (with ``fitted``) the ``mcmc`` row alone.
    """
    t0 = _time.perf_counter()
    if fitted is None:
        try:
            fitted = least_squares(model, lsq, record, noise)
        except FIT_ERRORS as exc:
            wall = _time.perf_counter() - t0
            return [_failed(model, est.name, _why(exc), wall) for est in (lsq, mcmc) if est is not None]
        t_lsq = _time.perf_counter() - t0
    else:
        t_lsq = fitted[1].wall_s
    lik, res = fitted
    out = []
    for est, fit in ((lsq, lambda: lsq.posterior(lik, res, seed=seed)),
                     (mcmc, lambda: mcmc.fit_from(lik, res, seed=seed, progress=progress))):
        if est is None:
            continue
        t1 = _time.perf_counter()
        try:
            idata = build_any(lik, fit())
        except FIT_ERRORS as exc:
            out.append(_failed(model, est.name, _why(exc), t_lsq + _time.perf_counter() - t1))
            continue
        results.set_wall(idata, t_lsq + _time.perf_counter() - t1)  # each row counts the shared fit
        out.append(_row(idata, validate))
    return out


#: What a fit's prediction of another record reports (:func:`validation_scores`).
VALIDATION_KEYS = ("mse", "force_errors", "force_nrmse", "rmse", "masked")


def validation_scores(idata, record) -> dict:
    """A fit's prediction of another record (thesis method 2, :func:`bayes_mr.inference.identify.validate`):
    :data:`VALIDATION_KEYS`, or ``error`` when it cannot predict it (another kind of test, a divergence).

    Several records (a manifest's test rows): the scores pooled over them and ``records``, each one's
    (:func:`bayes_mr.inference.identify.validate_records`)."""
    try:
        if isinstance(record, xr.Dataset):
            v = validate_fit(idata, record)
        else:
            v = validate_records(idata, record)
    except (RuntimeError, ValueError) as exc:
        return {"error": str(exc)}
    return {k: v[k] for k in VALIDATION_KEYS + ("records",) if k in v}


def units(pairs: list[tuple[str, str]], estimators: dict, seed: int) -> list[tuple[str, list[tuple[str, object]]]]:
    """The jobs of a grid: (model, [(engine, estimator)]) — one per pair, except a model's ``lsq`` and ``mcmc``,
    which are one job when they share the least-squares fit (:func:`shares_lsq`). An ``lsq`` not given searches
    from the grid's ``seed`` (:meth:`~bayes_mr.inference.estimators.Emcee.lsq_settings`), as the chains do."""
    est = {e: estimators.get(e) or (LeastSquares(settings=Emcee.lsq_settings(seed)) if e == "lsq" else engine(e))
           for _, e in pairs}
    shared = ({m for m, e in pairs if e == "lsq" and (m, "mcmc") in pairs}
              if "lsq" in est and "mcmc" in est and shares_lsq(est["lsq"], est["mcmc"], seed) else set())
    units: list[tuple[str, list]] = []
    for m, e in pairs:
        if e == "mcmc" and m in shared:
            continue  # with its lsq row
        units.append((m, [(e, est[e])] + ([("mcmc", est["mcmc"])] if e == "lsq" and m in shared else [])))
    return units


def unit_job(model: str, estimators: tuple, *args):
    """One job of :func:`units`: :func:`fit_job` (one estimator) or :func:`lsq_mcmc_job` (lsq, mcmc)."""
    return lsq_mcmc_job(model, *estimators, *args) if len(estimators) == 2 else fit_job(model, estimators[0], *args)


def unit_results(o: Outcome, model: str, engines: list[str]) -> list[tuple[str, dict, object]]:
    """(engine, row, InferenceData) of each estimator of a finished job (a job that raised: an error row each)."""
    if not o.ok:
        return [(e, *_failed(model, e, o.error, o.wall_s)) for e in engines]
    return [(e, *rv) for e, rv in zip(engines, o.value if len(engines) > 1 else [o.value])]
