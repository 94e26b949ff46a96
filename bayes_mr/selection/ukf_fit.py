"""``bayes-mr fit --engine ukf``: train, validate, select, and store as InferenceData.

The thesis's procedure (Fig. 3.15) for one model: train the UKF from every
LHS × τ prior (:func:`~bayes_mr.selection.training.train`), validate every
trained run — on the fitted record (method 1) or on another record
(method 2, ``validate_on``) — and keep the run with the lowest MSE. Its final
Gaussian on the log-scaled parameters φ is the UKF's posterior; the result
uses the same schema as the other engines (:mod:`bayes_mr.results`).
"""

from __future__ import annotations

import time as _time

import numpy as np
import xarray as xr

from .. import results
from ..data.schema import OUTPUTS
from ..inference.ukf import TAUS, UKFSettings
from ..likelihood import LOG_2PI, channel_noise
from ..models import Model, get_model
from ..scores import score
from ..simulate import OUTPUT_NAMES, Inputs, simulate
from .training import settings_from_json, to_theta
from .validation import _BATCH_BYTES, full_theta, method1, method2

#: Draws whose pointwise log-likelihood / predictive simulation is stored.
LL_DRAWS = 100
LL_SAMPLES = 2000
PP_DRAWS = 20


def _thin(valid: np.ndarray, n: int) -> np.ndarray:
    """At most ``n`` evenly spaced indices of valid samples."""
    idx = np.flatnonzero(valid)
    return idx[np.linspace(0, idx.size - 1, min(n, idx.size)).astype(int)]


def ukf_fit(
    model: Model | str,
    record: xr.Dataset,
    *,
    validate_on: xr.Dataset | None = None,
    n_lhs: int = 10,
    taus: tuple[float, ...] = TAUS,
    settings: UKFSettings = UKFSettings(),
    seed: int = 0,
    executor=None,
    progress: bool = True,
    n_draws: int = 1000,
    **kw,
) -> results.az.InferenceData:
    """Fit ``model`` to ``record`` with the thesis's UKF training and validation.

    Parameters
    ----------
    model : Model or str
    record : xarray.Dataset
        The record to fit (training record).
    validate_on : xarray.Dataset, optional
        Choose the run by its MSE on this record (method 2); default the
        fitted record itself (method 1).
    n_lhs, taus, settings, executor, progress
        As :func:`~bayes_mr.selection.training.train`.
    seed : int
        Seeds the Latin hypercube (the seed itself) and the posterior draws
        (its first spawned child), so both are reproducible and independent.
    n_draws : int
        Posterior draws from the selected run's final Gaussian.
    **kw
        ``ranges``, ``fixed``, ``chunk_size`` (training) and ``noise_sd``
        (validation scores).

    Returns
    -------
    arviz.InferenceData
        ``posterior`` (1 chain × ``n_draws`` of θ [SI]), ``sample_stats.lp``
        (the selected run's UKF log evidence, the same for every draw — the
        filter gives a Gaussian, not a density per draw), ``log_likelihood``
        (pointwise Gaussian with the measurement-noise SDs, ≤ 100 draws ×
        ≤ 2000 valid samples), ``posterior_predictive`` (measured channels,
        plus damper force for a structure test, ≤ 20 draws),
        ``point_estimate`` (the selected run's final mean), ``ukf_training``
        (every run) and ``ukf_validation`` (every run's scores). The summary
        holds the SPEC ``fit`` keys; ``mse`` and the force errors are those of
        the point estimate on the fitted record.

    Raises
    ------
    ValueError
        No run could be trained and validated (every prior diverged).
    """
    t0 = _time.perf_counter()
    model = get_model(model)
    common = dict(n_lhs=n_lhs, taus=taus, settings=settings, seed=seed, executor=executor, progress=progress, **kw)
    if validate_on is None:
        trial = method1(model, record, **common)
    else:
        trial = method2(model, record, validate_on, **common)
    training, validation = trial.training, trial.validation[0]
    if trial.best < 0:
        reasons = sorted(set(training["reason"].values.tolist()) | set(validation["reason"].values.tolist()) - {""})
        raise ValueError(f"UKF: none of {training.sizes['run']} runs of {model.name} could be trained and "
                         f"validated ({'; '.join(reasons)[:200]}) — widen the prior ranges (--prior) or "
                         "check the record")
    sel = trial.best
    kind = record.attrs["kind"]
    names = tuple(str(n) for n in training["param"].values)
    units = tuple(str(u) for u in training["unit"].values)
    run = training.sel(run=sel)
    phi, cov = run["final_phi"].values, run["final_cov_phi"].values
    rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])
    draws_phi = rng.multivariate_normal(phi, 0.5 * (cov + cov.T), size=n_draws, method="eigh")
    draws = to_theta(training, draws_phi)
    point = run["final_mean"].values
    log_evidence = float(run["log_evidence"])
    train_settings = settings_from_json(training.attrs["settings"])
    inputs = Inputs.from_record(record)
    sim_kw = dict(c_acc=train_settings.c_acc, n_max=train_settings.n_max)

    # scores of the point estimate on the fitted record
    point_sim = simulate(model, inputs, full_theta(training, point)[0], **sim_kw)
    noise_sd = kw.get("noise_sd")
    if point_sim.ok.all():
        scores = score(record, point_sim.outputs, noise_sd=noise_sd)
    else:  # validated elsewhere (method 2) but unstable on the fitted record: report, don't fail
        scores = {"mse": None, "force_errors": None, "force_nrmse": None, "n": 0}

    # pointwise log-likelihood and predictive draws, simulated in memory-bounded batches
    channels = OUTPUTS[kind]
    sd = channel_noise(record, channels)
    if noise_sd:
        sd = np.array([noise_sd.get(c, s) for c, s in zip(channels, sd)])
    valid = record["valid"].values.astype(bool) if "valid" in record else np.ones(inputs.n, bool)
    idx = _thin(valid, LL_SAMPLES)
    y = np.column_stack([record[c].values[idx] for c in channels])
    n_ll = min(LL_DRAWS, n_draws)
    ll = np.full((n_ll, idx.size, len(channels)), -np.inf)
    pp_names = channels + (("force",) if kind == "structure" else ())
    n_pp = min(PP_DRAWS, n_draws)
    pp = {c: np.full((n_pp, inputs.n), np.nan) for c in pp_names}
    batch = max(1, _BATCH_BYTES // (inputs.n * (len(OUTPUT_NAMES[kind]) + 1) * 8))
    for start in range(0, n_ll, batch):
        stop = min(n_ll, start + batch)
        sim = simulate(model, inputs, full_theta(training, draws[start:stop]), **sim_kw)
        yhat = np.stack([sim[c][:, idx] for c in channels], axis=-1)
        r = (y[None] - yhat) / sd
        terms = -0.5 * r * r - np.log(sd) - 0.5 * LOG_2PI
        ll[start:stop] = np.where(sim.ok[:, None, None] & np.isfinite(terms), terms, -np.inf)
        for b in range(start, min(stop, n_pp)):
            for c in pp_names:
                pp[c][b] = sim[c][b - start]
    log_lik = {c: ll[None, :, :, j] for j, c in enumerate(channels)}
    predictive = {c: v[None] for c, v in pp.items()}

    wall = _time.perf_counter() - t0
    summary = results.FitSummary(
        model=model.name, engine="ukf", kind=kind,
        params=dict(zip(names, draws.mean(axis=0))),
        params_sd=dict(zip(names, draws.std(axis=0))),
        log_evidence=log_evidence,
        mse=scores["mse"], force_errors=scores["force_errors"], force_nrmse=scores["force_nrmse"],
        masked=int(record.attrs.get("masked", 0)),
        trained=int(training.attrs["trained"]), diverged=int(training.attrs["diverged"]),
        wall_s=wall,
        extra={
            "evidence_route": "ukf_innovations",
            "method": trial.method,
            "selected_run": int(sel),
            "selected_lhs": int(run["lhs"]),
            "selected_tau": float(run["tau"]),
            "point": dict(zip(names, point)),
            "validation_mse": trial.scores["mse"],
            "validated_on": str(validation.attrs.get("source", "")),
            "interrupted": int(training.attrs["interrupted"]),
            "training_wall_s": float(training.attrs["wall_s"]),
        },
    )
    return results.make_inference_data(
        summary=summary, draws=draws[None], names=names, units=units, point=point, record=record,
        lp=np.full((1, n_draws), log_evidence), log_likelihood=log_lik, ll_index=idx, predictive=predictive,
        extra_groups={"ukf_training": training, "ukf_validation": validation},
        attrs={"selected_run": int(sel), "method": int(trial.method)},
    )
