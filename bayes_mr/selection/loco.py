"""Leave-one-condition-out cross-validation over a test matrix: does the model predict a test it never saw?

A model fitted on a damper's tests is worth what it predicts of the conditions
not tested. A condition is an amplitude, a frequency and a current
(:func:`bayes_mr.scores.conditions.condition_of`); records at one condition —
repeats of a test — form one fold (:func:`condition_folds`). For each fold in
turn the model is fitted by least squares on the records of every other
condition (one likelihood summed over them,
:class:`bayes_mr.likelihood.joint.JointLikelihood`) and predicts the fold's
records: a repeat of the held-out test in the training set would let the fit
see the condition it is asked to predict. The table of the held-out scores by condition
(:func:`bayes_mr.scores.conditions.condition_row`) says where the model fails
to transfer: which amplitudes, which frequencies, which currents.
"""

from __future__ import annotations

import time as _time
from collections.abc import Callable

from bayes_mr.data.records import RecordSet
from bayes_mr.inference.estimators import Emcee, engine
from bayes_mr.inference.identify import Identify, after_warmup, by_condition, validated
from bayes_mr.inference.lsq.least_squares import LSQSettings
from bayes_mr.scores.conditions import condition_of
from bayes_mr.scores.pooled import pooled


#: Relative difference of amplitude and of frequency within which two tests are at one condition (a
#: peak-to-peak estimate from a noisy record scatters by a few per cent about the nominal amplitude).
TOLERANCE = 0.1


def condition_folds(records: RecordSet, tolerance: float = TOLERANCE) -> list[int]:
    """The fold of each record: records with one command (name and value) whose amplitudes and frequencies
    differ by at most ``tolerance`` (relative) from the fold's first record share it; folds numbered from 0
    in the order their first record appears."""
    firsts, folds = [], []
    for i, rec in enumerate(records):
        c = condition_of(rec, records.conditions[i], records.units, records.source)
        for k, ref in enumerate(firsts):
            if _same(c, ref, tolerance):
                folds.append(k)
                break
        else:
            firsts.append(c)
            folds.append(len(firsts) - 1)
    return folds


def _same(a: dict, b: dict, tolerance: float) -> bool:
    """Whether two tests' conditions (:func:`condition_of`) are one: same command, close motion."""
    if a["command"] != b["command"] or (a["command_value"] is None) != (b["command_value"] is None):
        return False
    if a["command_value"] is not None and abs(a["command_value"] - b["command_value"]) > 1e-9 * max(
            1.0, abs(b["command_value"])):
        return False
    return all(abs(a[k] - b[k]) <= tolerance * abs(b[k]) for k in ("amplitude", "frequency"))


def leave_one_out(records: RecordSet, model: str, *, seed: int = 0, noise: str = "iid", warmup: float = 0.0,
                  fixed: dict[str, float] | None = None, ranges: dict[str, tuple[float, float]] | None = None,
                  progress: Callable[[str], None] | None = None, settings: LSQSettings | None = None) -> dict:
    """Fit ``model`` on the records of all conditions but one and predict that one's, for each condition.

    Parameters
    ----------
    records : RecordSet
        At least two records of one device, each measuring displacement and force;
        roles are ignored (every record is held out once).
    model : str
        ``FORM[+EFFECT...]``.
    seed : int
        Seed of the least-squares starts (as ``bayes-mr fit --engine lsq --seed``).
    noise : {"iid", "ar"}
        The residual model of the fits.
    warmup : float
        Seconds at the start of each held-out record simulated but not scored [s].
    fixed, ranges : dict, optional
        Parameters held fixed [SI] and plausible ranges (LO, HI) [SI] of every fold's fit, as
        ``bayes-mr fit --fix`` and ``--prior`` give them.
    progress : callable, optional
        Called with one line per fold.
    settings : LSQSettings, optional
        Least-squares settings of every fold's fit, from scratch (default: the package's, candidates seeded by
        ``seed``, as ``bayes-mr fit --engine lsq``); a smaller search for a smoke test.

    Returns
    -------
    dict
        ``model``, ``engine`` (``lsq``), ``n_folds`` (conditions, :func:`condition_folds`), ``table`` (per
        record, in the set's order: ``record``, ``fold``, ``file``, ``conditions`` (the manifest's), the row of
        :func:`bayes_mr.scores.conditions.condition_row` — ``amplitude`` [m], ``frequency`` [Hz],
        ``command``, ``command_value`` [A or V], ``force_nrmse``, ``peak_force_error``,
        ``energy_error``, … — and the fold's ``mse``, ``params`` and ``trained_on``), ``pooled``
        (``mse``, ``rmse``, ``force_nrmse``, ``force_errors`` of every held-out prediction pooled as
        :func:`bayes_mr.scores.pooled.pooled` pools them), ``worst`` (``file`` and ``force_nrmse`` of
        the held-out record predicted worst) and ``wall_s``.

    Raises
    ------
    ValueError
        Fewer than two records, a record without displacement and force, or every record at one condition.
    """
    n = len(records)
    if n < 2:
        raise ValueError(f"{records.source or 'record set'}: leave-one-condition-out needs at least two records, "
                         f"got {n}")
    missing = [f for f, r in zip(records.files, records) if not ("force" in r and "displacement" in r)]
    if missing:
        raise ValueError(f"{missing[0]}: leave-one-condition-out scores the force of a test: the record needs "
                         "displacement and force channels")
    t0 = _time.perf_counter()
    folds = condition_folds(records)
    if max(folds) == 0:
        raise ValueError(f"{records.source or 'record set'}: every record is at one condition (command, amplitude "
                         "and frequency): nothing is left to fit when it is held out")
    rows: list[dict | None] = [None] * n
    for fold in range(max(folds) + 1):
        keep = [j for j in range(n) if folds[j] != fold]
        train = RecordSet(tuple(records[j] for j in keep), tuple(records.conditions[j] for j in keep),
                          ("train",) * len(keep), records.source, records.units, records.record_offsets)
        job = Identify(model, engine("lsq", settings=settings or Emcee.lsq_settings(seed)), ranges=ranges or {},
                       fixed=fixed or {}, noise=noise)
        idata = job.fit(train, seed=seed, progress=False)
        for i in (i for i in range(n) if folds[i] == fold):
            rows[i] = {"fold": fold, **_fold(idata, records, i, warmup, train)}
            if progress is not None:
                progress(f"held out {records.files[i]}: force NRMSE {rows[i]['force_nrmse']:.3g}")
    scored = [row.pop("_scores") for row in rows]
    total = pooled([s["record"] for s in scored], [s["scores"] for s in scored])
    worst = max(rows, key=lambda r: r["force_nrmse"])
    return {"model": model, "engine": "lsq", "n_folds": max(folds) + 1, "table": rows,
            "pooled": {k: total[k] for k in ("mse", "mse_channels", "rmse", "force_nrmse", "force_errors")},
            "worst": {"file": worst["file"], "force_nrmse": worst["force_nrmse"]},
            "wall_s": _time.perf_counter() - t0}


def _fold(idata, records: RecordSet, i: int, warmup: float, train: RecordSet) -> dict:
    """The table row of held-out record ``i``, with what :func:`leave_one_out` pools under ``_scores``."""
    out, pred = validated(idata, records[i], warmup, records.record_offsets or None)
    scored = after_warmup(records[i], warmup)
    n = int(scored["valid"].values.sum()) if "valid" in scored else scored.sizes["time"]
    keys = ("mse", "mse_channels", "force_errors", "force_nrmse", "rmse")
    return {"record": i, "file": records.files[i], "conditions": dict(records.conditions[i]),
            **by_condition(scored, pred["force"], records, i), "mse": out["mse"], "params": out["point"],
            "trained_on": list(train.files),
            "_scores": {"record": scored, "scores": {**{k: out[k] for k in keys}, "n": n}}}
