"""Model validation and selection (thesis §3.6.2, §3.6.3, Figs 3.15 and 3.16).

Every trained run's final estimate predicts a validation record (the model
simulated from rest under the record's inputs) and is scored by the thesis's
MSE (3-44) and force errors (3-45..3-49) (:mod:`bayes_mr.scores`);
the run with the lowest MSE is the trained model. The three identification
and validation methods of Lund et al. (2020) that the thesis describes:

* :func:`method1` — train and validate on the same signal;
* :func:`method2` — train on one signal, validate on another
  (cross-validation, the thesis's choice against over-fitting);
* :func:`method3` — train on both signals at once and validate on both
  (MSE averaged over the two, weighted by their valid samples).

Each returns a :class:`Trial`; :func:`select` picks the trial (model × method)
with the lowest MSE, as in Fig. 3.16.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
import xarray as xr

from ..inference import ukf_kernel as K
from ..models import Model, get_model
from ..scores import Scorer
from ..simulate import OUTPUT_NAMES, Inputs, simulate
from .training import settings_from_json, train

#: Score variables of a validation Dataset (per run).
SCORE_VARS = ("mse", "E_t", "E_x", "E_xdot", "force_nrmse")
#: Most bytes of simulated output held at once while validating.
_BATCH_BYTES = 1 << 26


def full_theta(training: xr.Dataset, theta_free: np.ndarray) -> np.ndarray:
    """Full parameter vectors (B, P) [SI] from free ones (B, p) of a training Dataset."""
    model = get_model(training.attrs["model"])
    kind = training.attrs["kind"]
    fixed = json.loads(training.attrs.get("fixed", "{}"))
    template = model.theta(kind, fixed)
    names = model.param_names(kind)
    free = [names.index(str(n)) for n in training["param"].values]
    theta_free = np.atleast_2d(np.asarray(theta_free, float))
    out = np.broadcast_to(template, (theta_free.shape[0], template.size)).copy()
    out[:, free] = theta_free
    return out


def validate_runs(
    training: xr.Dataset,
    record: xr.Dataset,
    *,
    noise_sd: dict[str, float] | None = None,
) -> xr.Dataset:
    """Score every trained run's final estimate on ``record``.

    Parameters
    ----------
    training : xarray.Dataset
        Output of :func:`bayes_mr.selection.training.train`.
    record : xarray.Dataset
        Validation record (same kind of test; for a structure test the same
        storey mass is not required — the record's own mass is used).
    noise_sd : dict, optional
        Noise SD per measured channel for the MSE, overriding the record's.

    Returns
    -------
    xarray.Dataset
        Dim ``run`` (the training's runs). ``mse``, ``E_t``, ``E_x``,
        ``E_xdot``, ``force_nrmse`` (NaN where not computed: the run diverged
        in training or in simulation, or the force is not measured), ``n``
        (valid samples scored), ``scored`` (1/0) and ``reason`` (why a run
        was not scored; empty when it was). Attributes: ``best`` (run index
        with the lowest MSE, −1 if none), ``best_mse``, ``source``,
        ``trained_on``, ``model``, ``kind``, ``masked``, ``has_force``,
        ``sigma`` (JSON: noise SDs used).
    """
    model = get_model(training.attrs["model"])
    kind = training.attrs["kind"]
    if record.attrs["kind"] != kind:
        raise ValueError(f"{record.attrs.get('source', 'record')}: a {record.attrs['kind']} test cannot "
                         f"validate a model trained on a {kind} test")
    settings = settings_from_json(training.attrs["settings"])
    scorer = Scorer(record, noise_sd=noise_sd)
    inputs = Inputs.from_record(record)
    runs = training["run"].values
    R = runs.size
    scores = {v: np.full(R, np.nan) for v in SCORE_VARS}
    n = np.zeros(R, np.int64)
    scored = np.zeros(R, np.int8)
    reason = np.array([""] * R, dtype=object)
    status = training["status"].values
    theta = training["final_mean"].values
    ok = (status == K.OK) & np.all(np.isfinite(theta), axis=1)
    for r in np.flatnonzero(~ok):
        reason[r] = f"not trained: {training['reason'].values[r]}" if status[r] != K.OK else "non-finite estimate"
    todo = np.flatnonzero(ok)
    per_member = inputs.n * (len(OUTPUT_NAMES[kind]) + 1) * 8
    batch = max(1, _BATCH_BYTES // per_member)
    for start in range(0, todo.size, batch):
        members = todo[start:start + batch]
        sim = simulate(model, inputs, full_theta(training, theta[members]),
                       c_acc=settings.c_acc, n_max=settings.n_max)
        for b, r in enumerate(members):
            if not sim.ok[b]:
                reason[r] = f"simulation diverged at sample {int(sim.failed[b])}"
                continue
            try:
                s = scorer({c: v[b] for c, v in sim.outputs.items()})
            except ValueError as exc:  # e.g. a finite state with a non-finite output
                reason[r] = f"not scored: {exc}"
                continue
            scores["mse"][r] = s["mse"]
            if s["force_errors"] is not None:
                for k, v in s["force_errors"].items():
                    scores[k][r] = v
            if s["force_nrmse"] is not None:
                scores["force_nrmse"][r] = s["force_nrmse"]
            n[r] = s["n"]
            scored[r] = 1
    ds = xr.Dataset(
        {**{v: ("run", a) for v, a in scores.items()},
         "n": ("run", n), "scored": ("run", scored), "reason": ("run", reason.astype(str))},
        coords={"run": runs},
    )
    _set_best(ds)
    ds.attrs.update(
        source=str(record.attrs.get("source", "")),
        trained_on=str(training.attrs.get("source", "")),
        model=model.name,
        kind=kind,
        masked=int(record.attrs.get("masked", 0)),
        has_force=int(scorer.has_force),
        sigma=json.dumps(scorer.sigma),
    )
    return ds


def _set_best(ds: xr.Dataset) -> None:
    mse = ds["mse"].values
    finite = np.isfinite(mse)
    if finite.any():
        i = int(np.argmin(np.where(finite, mse, np.inf)))
        ds.attrs.update(best=int(ds["run"].values[i]), best_mse=float(mse[i]))
    else:
        ds.attrs.update(best=-1, best_mse=float("nan"))


def combine(validations: tuple[xr.Dataset, ...] | list[xr.Dataset]) -> xr.Dataset:
    """Per-run scores over several validation records, weighted by their valid samples.

    ``mse`` is the sample-weighted mean, i.e. 3-44 over all samples of all
    records (each channel over its own record's noise variance); the force
    errors combine as the root of the sample-weighted mean of their squares
    (each record's errors over its own σ_f). A run counts only if every
    record scored it. One record: returned as it is.
    """
    validations = list(validations)
    if len(validations) == 1:
        return validations[0]
    w = np.array([v["n"].values for v in validations], float)  # (records, runs)
    all_scored = np.all([v["scored"].values == 1 for v in validations], axis=0)
    total = w.sum(axis=0)
    out = {}
    with np.errstate(invalid="ignore", divide="ignore"):
        for var in SCORE_VARS:
            vals = np.array([v[var].values for v in validations])
            if var == "mse":
                comb = np.sum(w * vals, axis=0) / total
            else:
                comb = np.sqrt(np.sum(w * vals**2, axis=0) / total)
            out[var] = ("run", np.where(all_scored, comb, np.nan))
    reasons = ["; ".join(r for r in rs if r) for rs in zip(*[v["reason"].values for v in validations])]
    ds = xr.Dataset(
        {**out, "n": ("run", total.astype(np.int64)), "scored": ("run", all_scored.astype(np.int8)),
         "reason": ("run", np.array(reasons, dtype=str))},
        coords={"run": validations[0]["run"].values},
    )
    _set_best(ds)
    ds.attrs.update(source=" + ".join(v.attrs.get("source", "") for v in validations),
                    trained_on=validations[0].attrs.get("trained_on", ""),
                    model=validations[0].attrs.get("model", ""), kind=validations[0].attrs.get("kind", ""),
                    masked=int(sum(v.attrs.get("masked", 0) for v in validations)),
                    has_force=int(all(v.attrs.get("has_force", 0) for v in validations)))
    return ds


@dataclass(frozen=True)
class Trial:
    """One model trained and validated by one method.

    Attributes
    ----------
    method : int
        1, 2 or 3 (thesis §3.6.3).
    model : str
    training : xarray.Dataset
        Every run (:func:`bayes_mr.selection.training.train`).
    validation : tuple of xarray.Dataset
        Per-run scores on each validation record (:func:`validate_runs`):
        one record for methods 1 and 2, two for method 3.
    best : int
        Run with the lowest (combined) validation MSE; −1 if no run could be scored.
    theta : dict
        That run's final estimate, name → value [SI] (free parameters).
    scores : dict
        Its scores as :func:`~bayes_mr.scores.score` returns them
        (``mse``, ``force_errors``, ``force_nrmse``, ``n``), combined over the
        validation records for method 3.
    """

    method: int
    model: str
    training: xr.Dataset
    validation: tuple[xr.Dataset, ...]
    best: int
    theta: dict[str, float]
    scores: dict

    @property
    def combined(self) -> xr.Dataset:
        """Per-run scores over all validation records (:func:`combine`)."""
        return combine(self.validation)


_VALIDATION_KW = ("noise_sd",)


def _split(kw: dict) -> tuple[dict, dict]:
    return ({k: v for k, v in kw.items() if k not in _VALIDATION_KW},
            {k: v for k, v in kw.items() if k in _VALIDATION_KW})


def _trial(method: int, training: xr.Dataset, validations: list[xr.Dataset]) -> Trial:
    comb = combine(validations)
    best = int(comb.attrs["best"])
    if best < 0:
        return Trial(method, training.attrs["model"], training, tuple(validations), -1, {},
                     {"mse": float("nan"), "force_errors": None, "force_nrmse": None, "n": 0})
    row = comb.sel(run=best)
    has_force = bool(comb.attrs.get("has_force", 0))
    scores = {
        "mse": float(row["mse"]),
        "force_errors": {k: float(row[k]) for k in ("E_t", "E_x", "E_xdot")} if has_force else None,
        "force_nrmse": float(row["force_nrmse"]) if has_force else None,
        "n": int(row["n"]),
    }
    theta = {str(n): float(v) for n, v in zip(training["param"].values, training["final_mean"].sel(run=best).values)}
    return Trial(method, training.attrs["model"], training, tuple(validations), best, theta, scores)


def method1(model: Model | str, record: xr.Dataset, **kw) -> Trial:
    """Thesis method 1: train on ``record`` and validate on the same record.

    Keyword arguments go to :func:`~bayes_mr.selection.training.train`
    (``n_lhs``, ``taus``, ``settings``, ``ranges``, ``fixed``, ``seed``,
    ``executor``, ``chunk_size``, ``progress``), except ``noise_sd``, which
    goes to :func:`validate_runs`.
    """
    train_kw, val_kw = _split(kw)
    training = train(model, record, **train_kw)
    return _trial(1, training, [validate_runs(training, record, **val_kw)])


def method2(model: Model | str, train_record: xr.Dataset, validation_record: xr.Dataset, **kw) -> Trial:
    """Thesis method 2 (cross-validation): train on one record, validate on another.

    Keyword arguments as :func:`method1`.
    """
    train_kw, val_kw = _split(kw)
    training = train(model, train_record, **train_kw)
    return _trial(2, training, [validate_runs(training, validation_record, **val_kw)])


def method3(model: Model | str, record_a: xr.Dataset, record_b: xr.Dataset, **kw) -> Trial:
    """Thesis method 3: train on both records at once, validate on both.

    Training filters ``record_a`` then ``record_b`` in one UKF run per prior,
    the model states restarting from rest at the start of ``record_b`` and
    the parameters carried over (``train(..., reset_records=[record_b])``):
    sequential, where the thesis stacks both signals' states into one state
    vector; given θ the two signals are independent, so the parameters are
    conditioned on the same two likelihoods either way (see
    :func:`bayes_mr.inference.ukf_kernel.ukf_run`). The filter uses one
    measurement-noise covariance for both, the records' pooled noise
    variances (:func:`~bayes_mr.selection.training.concat_records`). Runs are
    ranked by the MSE over both records, weighted by their valid samples
    (:func:`combine`); each record's MSE uses its own noise SDs.

    Keyword arguments as :func:`method1`.
    """
    train_kw, val_kw = _split(kw)
    training = train(model, record_a, reset_records=[record_b], **train_kw)
    validations = [validate_runs(training, record_a, **val_kw), validate_runs(training, record_b, **val_kw)]
    return _trial(3, training, validations)


def select(trials: dict[str, Trial]) -> tuple[str, Trial]:
    """The trial with the lowest validation MSE (thesis Figs 3.15, 3.16).

    Parameters
    ----------
    trials : dict
        Name (e.g. ``"dahl/method 2"``) → :class:`Trial`.

    Returns
    -------
    (name, Trial)

    Raises
    ------
    ValueError
        No trial has a finite MSE (every run diverged).
    """
    finite = {k: t for k, t in trials.items() if t.best >= 0 and np.isfinite(t.scores["mse"])}
    if not finite:
        raise ValueError(f"no trial has a validated run (every UKF run diverged): {', '.join(trials) or 'none given'}")
    name = min(finite, key=lambda k: finite[k].scores["mse"])
    return name, finite[name]
