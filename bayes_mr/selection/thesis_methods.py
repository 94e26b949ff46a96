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

Each returns a :class:`Trial`; :func:`best_trial` picks the trial (model × method)
with the lowest MSE, as in Fig. 3.16.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
import xarray as xr

from bayes_mr.inference.ukf.training import concat_records, train
from bayes_mr.inference.ukf.validation import combine, validate_runs
from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.models import Model


@dataclass(frozen=True)
class Trial:
    """One model trained and validated by one method.

    Attributes
    ----------
    method : int
        1, 2 or 3 (thesis §3.6.3).
    model : str
    training : xarray.Dataset
        Every run (:func:`bayes_mr.inference.ukf.training.train`).
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
_LIKELIHOOD_KW = ("ranges", "fixed")


def _split(kw: dict) -> tuple[dict, dict, dict]:
    """(likelihood, training, validation) keyword arguments."""
    return ({k: v for k, v in kw.items() if k in _LIKELIHOOD_KW},
            {k: v for k, v in kw.items() if k not in _VALIDATION_KW + _LIKELIHOOD_KW},
            {k: v for k, v in kw.items() if k in _VALIDATION_KW})


def _train(model: Model | str, record: xr.Dataset, lik_kw: dict, train_kw: dict, **extra) -> xr.Dataset:
    """Train on ``record`` through the likelihood every engine shares."""
    return train(OutputError(model, record, noise="fixed", **lik_kw), **train_kw, **extra)


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

    Keyword arguments: ``ranges`` and ``fixed`` go to the likelihood
    (:class:`~bayes_mr.likelihood.output_error.OutputError`), ``noise_sd`` to
    :func:`~bayes_mr.inference.ukf.validation.validate_runs`, the others to
    :func:`~bayes_mr.inference.ukf.training.train` (``n_lhs``, ``taus``,
    ``settings``, ``seed``, ``executor``, ``chunk_size``, ``progress``).
    """
    lik_kw, train_kw, val_kw = _split(kw)
    training = _train(model, record, lik_kw, train_kw)
    return _trial(1, training, [validate_runs(training, record, **val_kw)])


def method2(model: Model | str, train_record: xr.Dataset, validation_record: xr.Dataset, **kw) -> Trial:
    """Thesis method 2 (cross-validation): train on one record, validate on another.

    Keyword arguments as :func:`method1`.
    """
    lik_kw, train_kw, val_kw = _split(kw)
    training = _train(model, train_record, lik_kw, train_kw)
    return _trial(2, training, [validate_runs(training, validation_record, **val_kw)])


def method3(model: Model | str, record_a: xr.Dataset, record_b: xr.Dataset, **kw) -> Trial:
    """Thesis method 3: train on both records at once, validate on both.

    Training filters ``record_a`` then ``record_b`` in one UKF run per prior,
    the model states restarting from rest at the start of ``record_b`` and
    the parameters carried over (``train(..., reset=...)``):
    sequential, where the thesis stacks both signals' states into one state
    vector; given θ the two signals are independent, so the parameters are
    conditioned on the same two likelihoods either way (see
    :func:`bayes_mr.inference.ukf.kernel.ukf_run`). The filter uses one
    measurement-noise covariance for both, the records' pooled noise
    variances (:func:`~bayes_mr.inference.ukf.training.concat_records`). Runs are
    ranked by the MSE over both records, weighted by their valid samples
    (:func:`combine`); each record's MSE uses its own noise SDs.

    Keyword arguments as :func:`method1`.
    """
    lik_kw, train_kw, val_kw = _split(kw)
    both, reset = concat_records([record_a, record_b])
    training = _train(model, both, lik_kw, train_kw, reset=reset)
    training.attrs["records"] = json.dumps([str(r.attrs.get("source", "")) for r in (record_a, record_b)])
    validations = [validate_runs(training, record_a, **val_kw), validate_runs(training, record_b, **val_kw)]
    return _trial(3, training, validations)


def best_trial(trials: dict[str, Trial]) -> tuple[str, Trial]:
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
