"""Score every trained UKF run on a record, and pick the best (thesis §3.6.2, Fig. 3.15).

Every trained run's final estimate predicts a validation record (the model
simulated from rest under the record's inputs) and is scored by the thesis's
MSE (3-44) and force errors (3-45..3-49) (:mod:`bayes_mr.scores`); the run
with the lowest MSE is the trained model. :func:`combine` pools the scores of
several records (thesis method 3).
"""

from __future__ import annotations

import json

import numpy as np
import xarray as xr

from bayes_mr.models import get_model
from bayes_mr.scores import Scorer
from bayes_mr.simulation.simulate import OUTPUT_NAMES, Inputs, simulate
from bayes_mr.inference.ukf import kernel as K
from bayes_mr.inference.ukf.training import settings_from_json

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
        Output of :func:`bayes_mr.inference.ukf.training.train`.
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
    out = _Scores(R)
    reason = out.reason
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
                       c_acc=settings.c_acc, n_max=settings.n_max, ros2=settings.ros2)
        for b, r in enumerate(members):
            out.add(r, sim, b, scorer)
    ds = out.to_dataset(runs)
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


class _Scores:
    """Per-run score arrays filled one run at a time."""

    def __init__(self, n_runs: int):
        self.values = {v: np.full(n_runs, np.nan) for v in SCORE_VARS}
        self.n = np.zeros(n_runs, np.int64)
        self.scored = np.zeros(n_runs, np.int8)
        self.reason = np.array([""] * n_runs, dtype=object)

    def add(self, r: int, sim, b: int, scorer: Scorer) -> None:
        """Score member ``b`` of simulation ``sim`` as run ``r`` (or record why not)."""
        if not sim.ok[b]:
            self.reason[r] = f"simulation diverged at sample {int(sim.failed[b])}"
            return
        try:
            s = scorer({c: v[b] for c, v in sim.outputs.items()})
        except ValueError as exc:  # e.g. a finite state with a non-finite output
            self.reason[r] = f"not scored: {exc}"
            return
        self.values["mse"][r] = s["mse"]
        for k, v in (s["force_errors"] or {}).items():
            self.values[k][r] = v
        if s["force_nrmse"] is not None:
            self.values["force_nrmse"][r] = s["force_nrmse"]
        self.n[r] = s["n"]
        self.scored[r] = 1

    def to_dataset(self, runs: np.ndarray) -> xr.Dataset:
        return xr.Dataset(
            {**{v: ("run", a) for v, a in self.values.items()},
             "n": ("run", self.n), "scored": ("run", self.scored), "reason": ("run", self.reason.astype(str))},
            coords={"run": runs},
        )


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


def best_run(training: xr.Dataset, validation: xr.Dataset) -> int:
    """The run with the lowest validation MSE.

    Raises
    ------
    ValueError
        No run could be trained and validated (every prior diverged); the
        message lists the runs' reasons.
    """
    best = int(validation.attrs["best"])
    if best < 0:
        reasons = sorted(set(training["reason"].values.tolist()) | set(validation["reason"].values.tolist()) - {""})
        raise ValueError(f"UKF: none of {training.sizes['run']} runs of {training.attrs['model']} could be "
                         f"trained and validated ({'; '.join(reasons)[:200]}) — widen the prior ranges (--prior) "
                         "or check the record")
    return best
