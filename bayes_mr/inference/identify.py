"""Identify a model from a record: one likelihood, any estimator, one result schema.

>>> import bayes_mr as bm
>>> job = bm.Identify(bm.get_model("dahl+force_offset"), bm.LeastSquares())   # doctest: +SKIP
>>> idata = job.fit(record)                                                     # doctest: +SKIP

:class:`Identify` binds (model, record) into the one
:class:`~bayes_mr.likelihood.output_error.OutputError`, hands it to the estimator
(``fit(likelihood, *, seed, progress) -> Posterior``, see
:mod:`bayes_mr.inference.base`) and turns the posterior into InferenceData with
:func:`bayes_mr.inference.results.build`, so comparison, validation and plotting do not
care which engine ran.
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass, field

import numpy as np
import xarray as xr

from bayes_mr.data.records import RecordSet
from bayes_mr.inference import results
from bayes_mr.inference.base import Estimator
from bayes_mr.inference.estimators import UKF, Emcee, LeastSquares, engine
from bayes_mr.inference.joint_results import build_any
from bayes_mr.likelihood.joint import JointLikelihood
from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.scores.pooled import pooled
from bayes_mr.models import FORCE_OFFSET, Model, get_model
from bayes_mr.scores import score
from bayes_mr.scores.conditions import condition_row
from bayes_mr.simulation.simulate import Inputs, simulate

__all__ = ["UKF", "Emcee", "Identify", "LeastSquares", "engine", "predict", "validate", "validate_records"]


def predict(model: Model | str, record: xr.Dataset, theta: dict[str, float],
            input_interp: str = "auto", command_interp: str = "auto") -> dict[str, np.ndarray]:
    """Simulated channels of ``model`` at parameters ``theta`` [SI] under ``record``'s inputs.

    Missing parameters (the form's fixed ones) take their defaults; the
    input between samples is read as ``input_interp`` says, the command as
    ``command_interp`` says (:class:`Inputs`; "auto": the record's attributes).

    Raises
    ------
    ValueError
        The simulation diverged (names the sample).
    """
    model = get_model(model)
    inputs = Inputs.from_record(record, input_interp, command_interp)
    sim = simulate(model, inputs, model.theta(record.attrs["kind"], theta))
    if not sim.ok.all():
        raise ValueError(f"{model.name} diverged at sample {int(sim.failed[0])} of {record.attrs.get('source')}")
    return dict(sim.outputs)


@dataclass(frozen=True)
class Identify:
    """A model, an estimator and optional prior settings: ``Identify(model, estimator).fit(record)``.

    Attributes
    ----------
    model : Model or str
    estimator : Estimator
        ``LeastSquares()``, ``Emcee()``, ``UKF()`` or any object with ``name``
        and ``fit(likelihood, *, seed, progress) -> Posterior``.
    ranges : dict, optional
        Plausible-range overrides name → (lo, hi) [SI].
    fixed : dict, optional
        Parameters held fixed, name → value [SI].
    noise : {"iid", "ar"}
        Residual model of the likelihood (:mod:`bayes_mr.likelihood.noise_model`):
        independent Gaussian errors per channel, or an AR(p) process per
        channel with p chosen by BIC on a first iid fit's residual. Least
        squares, emcee, thermodynamic integration and stepping-stone all use
        it. The UKF keeps its own iid measurement model: its evidence is the
        innovation likelihood of its selected run, not comparable with the
        other engines' (the fit JSON's ``evidence_note`` says so); only its
        scores and pointwise log-likelihood use ``noise``.
    input_interp : {"auto", "linear", "bandlimited"}
        The input between samples (:mod:`bayes_mr.simulation.input_grid`): "auto" reads
        the record's ``input_interp`` attribute, else its drive's bandwidth.
    command_interp : {"auto", "linear", "hold"}
        The command between samples: "auto" reads the record's
        ``command_interp`` attribute, else linear; "hold" for a command a DAC
        held from sample to sample.
    """

    model: Model | str
    estimator: Estimator = field(default_factory=LeastSquares)
    ranges: dict | None = None
    fixed: dict | None = None
    noise: str = "iid"
    input_interp: str = "auto"
    command_interp: str = "auto"

    def likelihood(self, record: xr.Dataset | RecordSet | list) -> OutputError | JointLikelihood:
        """The binding of (model, record, noise model) every estimator consumes.

        A record gives an :class:`OutputError`; several (a :class:`~bayes_mr.data.records.RecordSet`
        or a list of records) one :class:`~bayes_mr.likelihood.joint.JointLikelihood` summed over them.
        """
        options = dict(ranges=self.ranges, fixed=self.fixed, residual=self.noise, input_interp=self.input_interp,
                       command_interp=self.command_interp)
        if isinstance(record, xr.Dataset):
            return OutputError(get_model(self.model), record, **options)
        return JointLikelihood(get_model(self.model), record, **options)  # a RecordSet keeps its conditions

    def fit(self, record: xr.Dataset | RecordSet | list, *, seed: int = 0, progress: bool = True):
        """Fit and return InferenceData (see :mod:`bayes_mr.inference.results`); ``wall_s`` is the whole fit's.

        Several records (a RecordSet or a list) are fitted by one likelihood summed over them; the result
        is :func:`~bayes_mr.inference.joint_results.build_joint`'s (one record's: exactly that record's fit).
        """
        t0 = _time.perf_counter()
        lik = self.likelihood(record)
        post = self.estimator.fit(lik, seed=seed, progress=progress)
        idata = build_any(lik, post)
        results.set_wall(idata, _time.perf_counter() - t0)
        return idata


def validate(idata, record: xr.Dataset, *, warmup: float = 0.0) -> dict:
    """Thesis method 2: a fitted model predicts another record.

    Parameters
    ----------
    idata : arviz.InferenceData
        A fit (:meth:`Identify.fit` or ``bayes-mr fit -o``).
    record : xarray.Dataset
        The other record, of the same kind.
    warmup : float
        Seconds at the start that are simulated (from rest, as always) but
        not scored: the transient of a steady-state multisine, or one the
        model does not describe.

    Returns
    -------
    dict
        The ``fit`` JSON keys for the new record: the fitted parameters, the
        scores of the point estimate's prediction over the scored samples
        (``mse`` over ``mse_channels``, ``rmse`` per measured channel [SI]),
        ``warmup_s`` and the new record's ``input_interp`` (its attribute,
        else from its drive's bandwidth) and ``command_interp`` (its attribute, else linear).
    """
    return validated(idata, record, warmup)[0]


def profiled(model: str, record: xr.Dataset, theta: dict[str, float], scored: xr.Dataset,
             inputs: Inputs) -> tuple[dict[str, np.ndarray], float]:
    """``model`` at ``theta`` on ``record`` with the record's own force offset: (prediction, f0 [N]).

    A test's force offset (a load cell zeroed before it) is a nuisance of that test, which no other test
    predicts: it is profiled on the record, f0 the mean force residual over ``scored``'s valid samples —
    the least-squares value of an additive constant. ``theta``'s per-record offsets ``f0[r]`` of the fit's own
    records are not used.
    """
    shared = {k: v for k, v in theta.items() if not k.startswith("f0[")}
    model = get_model(model)
    if model.effect("force_offset") is None:
        model = model + FORCE_OFFSET
    shared["f0"] = 0.0
    pred = predict(model, record, shared, inputs.interp, inputs.command_interp)
    valid = scored["valid"].values.astype(bool) if "valid" in scored else np.ones(scored.sizes["time"], bool)
    shared["f0"] = float(np.mean((record["force"].values - pred["force"])[valid]))
    return predict(model, record, shared, inputs.interp, inputs.command_interp), shared["f0"]


def validated(idata, record: xr.Dataset, warmup: float,
              record_offsets: bool | None = None) -> tuple[dict, dict[str, np.ndarray]]:
    """:func:`validate`'s dict, and the prediction it scored (channel → array, on the record's samples).

    ``record_offsets`` (default: whether the fit had them): the record's own force offset is profiled on it
    (:func:`profiled`, its value in ``record_offset`` [N]) instead of taken from the fit."""
    summary = results.summary_of(idata)
    if record.attrs["kind"] != summary.kind:
        raise ValueError(f"the result is a {summary.kind} test, the record a {record.attrs['kind']} test")
    if not (np.isfinite(warmup) and warmup >= 0):
        raise ValueError(f"warmup must be a non-negative number of seconds, got {warmup}")
    t0 = _time.perf_counter()
    # parameters held fixed in the fit are not in the point estimate; without them the defaults would be used
    inputs = Inputs.from_record(record)
    theta = {**summary.extra.get("fixed", {}), **results.point_of(idata)}
    offsets = bool(summary.extra.get("record_offsets")) if record_offsets is None else record_offsets
    if offsets:
        pred, offset = profiled(summary.model, record, theta, after_warmup(record, warmup), inputs)
    else:  # a fit's per-record offsets belong to its own records (f0[r]), not to this one
        pred = predict(summary.model, record, {k: v for k, v in theta.items() if not k.startswith("f0[")},
                       inputs.interp, inputs.command_interp)
    scores = score(after_warmup(record, warmup), pred)
    out = summary.to_dict()
    if offsets:
        out["record_offset"] = offset
    out.update(
        mse=scores["mse"], mse_channels=scores["mse_channels"], force_errors=scores["force_errors"],
        force_nrmse=scores["force_nrmse"], rmse=scores["rmse"], masked=int(record.attrs.get("masked", 0)),
        warmup_s=float(warmup), wall_s=_time.perf_counter() - t0, input_interp=inputs.interp,
        command_interp=inputs.command_interp,
        log_evidence=None, validated_on=str(record.attrs.get("source", "")),
        trained_on=str(idata.posterior.attrs.get("source", "")),
    )
    return out, pred


def validate_records(idata, records: RecordSet | list, *, warmup: float = 0.0,
                     record_offsets: bool | None = None) -> dict:
    """:func:`validate` on each of several records, and the scores pooled over them.

    Each record's own force offset is profiled on it (:func:`profiled`) where ``record_offsets`` says so,
    by default where the fit had per-record offsets or the set says its tests carry their own
    (:attr:`~bayes_mr.data.records.RecordSet.record_offsets`).

    Returns
    -------
    dict
        One record: :func:`validate`'s dict (from a RecordSet with ``records``: its file, role and
        conditions). Several: the same keys with ``mse``, ``rmse``,
        ``force_nrmse`` and the force errors pooled over every record's scored samples
        (:func:`bayes_mr.scores.pooled.pooled`), ``masked`` and ``wall_s`` summed,
        ``validated_on`` every file, and ``records`` (per record: ``file``, ``role``,
        ``conditions`` and its own scores) and, where every record measures displacement and force,
        ``by_condition`` (per record: ``record``, ``file``, ``role`` and the condition and scores of
        :func:`bayes_mr.scores.conditions.condition_row`: amplitude, frequency, command, force NRMSE,
        peak-force and energy-per-cycle errors).
    """
    recs = list(records)
    if record_offsets is None and getattr(records, "record_offsets", False):
        record_offsets = True
    done = [validated(idata, r, warmup, record_offsets) for r in recs]
    each = [e for e, _ in done]
    if len(each) == 1:  # a manifest's one record: its keys, and what the manifest says of it
        return {**each[0], "records": records.describe()} if isinstance(records, RecordSet) else each[0]
    scored = [after_warmup(r, warmup) for r in recs]
    keys = ("mse", "mse_channels", "force_errors", "force_nrmse", "rmse")
    for e, r in zip(each, scored):
        e["n"] = int(r["valid"].values.sum()) if "valid" in r else r.sizes["time"]
    if any(e["mse"] is None for e in each):
        total = dict.fromkeys(keys)
    else:
        total = pooled(scored, [{k: e[k] for k in keys + ("n",)} for e in each])
    about = records.describe() if isinstance(records, RecordSet) else [
        {"file": str(r.attrs.get("source", "")), "role": "test", "conditions": {}} for r in recs]
    out = dict(each[0])
    out.pop("record_offset", None)  # each record's own, in records
    out.update({k: total[k] for k in keys if k in total}, masked=sum(e["masked"] for e in each),
               wall_s=sum(e["wall_s"] for e in each), validated_on=[e["validated_on"] for e in each],
               n_records=len(each), records=[{**a, **{k: e[k] for k in keys + ("masked", "n", "input_interp",
                                                                                "command_interp", "record_offset")
                                                      if k in e}}
                                             for a, e in zip(about, each)])
    if all("force" in r and "displacement" in r for r in recs):
        out["by_condition"] = [{"record": i, "file": a["file"], "role": a["role"],
                                **by_condition(r, pred["force"], records, i)}
                               for i, (a, r, (_, pred)) in enumerate(zip(about, scored, done))]
    return out


def by_condition(record: xr.Dataset, force_hat: np.ndarray, records: RecordSet | list, i: int) -> dict:
    """The table row of record ``i`` of a set (:func:`bayes_mr.scores.conditions.condition_row`): the manifest's
    conditions and units where the set has them, the record's motion otherwise."""
    if isinstance(records, RecordSet):
        return condition_row(record, force_hat, conditions=records.conditions[i], units=records.units,
                             source=records.source)
    return condition_row(record, force_hat)


def after_warmup(record: xr.Dataset, warmup: float) -> xr.Dataset:
    """The record with samples in its first ``warmup`` seconds [s] left out of every score (``valid`` False)."""
    if warmup == 0:
        return record
    time = record["time"].values
    keep = time - time[0] >= warmup
    if not keep.any():
        raise ValueError(f"warmup {warmup} s is longer than the record ({time[-1] - time[0]:.6g} s)")
    valid = record["valid"].values.astype(bool) if "valid" in record else np.ones(time.size, bool)
    out = record.copy()
    out["valid"] = ("time", valid & keep, record["valid"].attrs if "valid" in record else {})
    return out
