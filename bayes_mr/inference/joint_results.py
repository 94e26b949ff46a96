"""The InferenceData of a fit over several records: one result, the record a dimension of its log-likelihood.

:func:`build_joint` is :func:`bayes_mr.inference.results.build` for a
:class:`~bayes_mr.likelihood.joint.JointLikelihood`. The ``fit`` keys keep
their meaning over the whole set — ``mse``, ``rmse``, ``force_nrmse`` and the
force errors pooled over every record's valid samples
(:func:`bayes_mr.scores.pooled.pooled`), ``masked`` summed — and ``records``
lists each record with its file, role, conditions and its own scores of the
point estimate. The groups:

* ``log_likelihood`` — each channel's pointwise log-density on thinned samples
  of every record, dim ``obs`` with coordinates ``obs_record`` (the record's
  index) and ``obs_time``; and ``per_record`` (chain, draw, record), each
  record's whole log-likelihood ln p(y_r | x), so that
  ``az.loo(idata, var_name="per_record")`` leaves out one test at a time;
* ``observed_data``, ``constant_data``, ``posterior_predictive`` — the
  records one after another along ``time`` (its values restart with each record).

A set of one record gives exactly :func:`~bayes_mr.inference.results.build`'s result.
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import xarray as xr

from bayes_mr.inference import results
from bayes_mr.inference.base import Posterior, even_indices
from bayes_mr.likelihood.joint import JointLikelihood
from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.scores import score
from bayes_mr.scores.pooled import pooled
from bayes_mr.simulation.input_grid import describe as describe_interp
from bayes_mr.simulation.simulate import simulate

with warnings.catch_warnings():
    warnings.simplefilter("ignore", FutureWarning)
    import arviz as az


def _record_scores(lik: JointLikelihood, post: Posterior) -> tuple[list[dict | None], list[dict]]:
    """Each record's scores of the point estimate (None where it does not simulate) and its noise info."""
    scores, noise = [], []
    for r, part in enumerate(lik.parts):
        own = replace(post, point=np.asarray(post.point, float)[lik.index[r]]) if lik.record_offsets else post
        sim = simulate(part.model, part.inputs, part.par.full_theta(own.point)[None], **post.simulation)
        scores.append(score(part.record, {k: v[0] for k, v in sim.outputs.items()}) if sim.ok.all() else None)
        noise.append(results.noise_info(part, own, sim))
    return scores, noise


def _records_key(lik: JointLikelihood, scores, noise, about: list[dict] | None) -> list[dict]:
    """The ``records`` key: per record its file, role, conditions, scores, noise model and interpolation."""
    out = []
    for r, (part, sc, nz) in enumerate(zip(lik.parts, scores, noise)):
        entry = {"record": r, "file": str(part.record.attrs.get("source", "")), "role": "train", "conditions": {}}
        entry.update(about[r])
        entry.update({k: (sc or {}).get(k) for k in ("mse", "force_errors", "force_nrmse", "rmse")})
        entry.update(masked=int((~part.valid).sum()), n_valid=part.n_valid, input_interp=part.inputs.interp,
                     command_interp=part.inputs.command_interp, **{k: v for k, v in nz.items() if k != "evidence_note"})
        out.append(entry)
    return out


def build_any(lik: OutputError | JointLikelihood, post: Posterior) -> az.InferenceData:
    """:func:`build_joint` for a joint likelihood, :func:`~bayes_mr.inference.results.build` for one record's."""
    return build_joint(lik, post) if isinstance(lik, JointLikelihood) else results.build(lik, post)


def build_joint(lik: JointLikelihood, post: Posterior, *, about: list[dict] | None = None) -> az.InferenceData:
    """The InferenceData of an estimator's posterior over several records (module docstring).

    Parameters
    ----------
    lik : JointLikelihood
        The likelihood the engine fitted.
    post : Posterior
        The engine's draws (x over every record's σ), point, evidence and diagnostics.
    about : list of dict, optional
        Per record: ``file``, ``role``, ``conditions`` (default the likelihood's :attr:`~JointLikelihood.about`).
    """
    if len(lik.parts) == 1:
        return results.build(lik.parts[0], post)
    scores, noise = _record_scores(lik, post)
    ok = all(s is not None for s in scores)
    total = pooled(lik.records, scores) if ok else dict.fromkeys(("mse", "force_errors", "force_nrmse", "rmse"))
    labels = list(dict.fromkeys(n["noise_model"] for n in noise))
    names, units, draws = lik.model.reported(lik.kind, lik.par.coords.names, lik.par.coords.units, post.draws,
                                             lik.par.full_theta(post.draws))
    point = lik.model.reported(lik.kind, lik.par.names, (), post.point, lik.par.full_theta(post.point))[2]
    flat = draws.reshape(-1, draws.shape[-1])
    first = lik.parts[0].inputs
    summary = results.FitSummary(
        model=lik.model.name, engine=post.engine, kind=lik.kind,
        params=dict(zip(names, flat.mean(axis=0))),
        params_sd=dict(zip(names, flat.std(axis=0, ddof=post.params_sd_ddof))),
        log_evidence=post.log_evidence, mse=total["mse"], force_errors=total["force_errors"],
        force_nrmse=total["force_nrmse"], masked=int(sum((~p.valid).sum() for p in lik.parts)),
        trained=post.trained, diverged=post.diverged, wall_s=post.wall_s, point=dict(zip(names, point)),
        rmse=total["rmse"], noise_model=labels[0] if len(labels) == 1 else "; ".join(
            f"[{r}] {n['noise_model']}" for r, n in enumerate(noise)),
        extra={**post.info, **_noise_keys(lik, noise), "mse_channels": list(lik.channels), "fixed": dict(lik.fixed),
               **describe_interp(first.interp, post.engine, first.command_interp),
               "n_records": len(lik.parts), "records": _records_key(lik, scores, noise, about or lik.about),
               "record_offsets": lik.record_offsets},
    )
    joined, offsets = _joined(lik.records)
    ll = _log_likelihood_group(lik, post, joined, offsets)
    pp = _predictive(lik, post)
    idata = results.make_inference_data(summary, replace(post, draws=draws, point=point), names, units, joined,
                                        predictive=pp)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        idata.add_groups({"log_likelihood": ll})
    return idata


def _noise_keys(lik: JointLikelihood, noise: list[dict]) -> dict:
    """``n_eff`` of the set (channel → the records' effective samples summed: independent records add) and,
    under AR, ``ar_coef`` (``channel[r]`` → record r's coefficients, labelled as the noise SDs are)."""
    out = {"n_eff": {c: float(sum(n["n_eff"][c] for n in noise)) for c in lik.channels}}
    if all("ar_coef" in n for n in noise):
        out["ar_coef"] = {f"{c}[{r}]": n["ar_coef"][c] for r, n in enumerate(noise) for c in lik.channels}
    if any("evidence_note" in n for n in noise):
        out["evidence_note"] = noise[0].get("evidence_note")
    return out


def _joined(records: list[xr.Dataset]) -> tuple[xr.Dataset, np.ndarray]:
    """The records one after another along ``time`` (their common variables), and each one's first index."""
    common = [v for v in records[0].data_vars if all(v in r for r in records)]
    joined = xr.concat([r[common] for r in records], dim="time", coords="minimal", compat="override",
                       combine_attrs="override")
    sizes = np.array([r.sizes["time"] for r in records])
    joined = joined.assign_coords(record=("time", np.repeat(np.arange(len(records)), sizes)))
    joined.attrs["source"] = "; ".join(str(r.attrs.get("source", "")) for r in records)
    return joined, np.concatenate([[0], np.cumsum(sizes)[:-1]])


def _log_likelihood_group(lik: JointLikelihood, post: Posterior, joined: xr.Dataset,
                          offsets: np.ndarray) -> xr.Dataset:
    """Pointwise terms of every record on thinned samples (``obs``) and each record's total (``per_record``)."""
    x = post.x_draws if post.x_chain is not None else post.x_draws[:results.LL_DRAWS]
    shape = post.x_chain if post.x_chain is not None else (1, x.shape[0])
    terms, totals, where = [], [], []
    for r, part in enumerate(lik.parts):
        t, tot, index = _pointwise(part, lik.part_x(x, r), post.simulation)
        terms.append(t.reshape(*shape, index.size, len(lik.channels)))
        totals.append(tot.reshape(shape))
        where.append(np.stack([np.full(index.size, r), index + offsets[r]], axis=1))
    terms = np.concatenate(terms, axis=2)
    where = np.concatenate(where)
    time = joined["time"].values
    data = {c: (("chain", "draw", "obs"), terms[..., j]) for j, c in enumerate(lik.channels)}
    data["per_record"] = (("chain", "draw", "record"), np.stack(totals, axis=-1))
    return xr.Dataset(data, coords={"chain": np.arange(shape[0]), "draw": np.arange(shape[1]),
                                    "obs": np.arange(where.shape[0]), "obs_record": ("obs", where[:, 0]),
                                    "obs_time": ("obs", time[where[:, 1]]), "record": np.arange(len(lik.parts))})


def _pointwise(part: OutputError, x: np.ndarray, simulation: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One record's pointwise terms (n, obs, C) on evenly spaced valid samples, its totals (n,) and those samples."""
    valid = np.flatnonzero(part.valid)
    index = valid[even_indices(valid.size, results.LL_SAMPLES)]
    terms = np.empty((x.shape[0], index.size, len(part.channels)))
    totals = np.empty(x.shape[0])
    for start in range(0, x.shape[0], results.LL_BATCH):
        phi, sigma = part.split(x[start: start + results.LL_BATCH])
        yhat, sim = part.predict(phi, **simulation)
        tot, t = part.log_density(yhat, sigma, sim.ok, pointwise=True)
        stop = start + phi.shape[0]
        terms[start:stop] = np.where(sim.ok[:, None, None] & np.isfinite(t[:, index]), t[:, index], -np.inf)
        totals[start:stop] = np.where(sim.ok, tot, -np.inf)
    return terms, totals, index


def _predictive(lik: JointLikelihood, post: Posterior) -> dict[str, np.ndarray]:
    """Every record's predictive draws (:func:`~bayes_mr.inference.results.predictive_draws`), one after another."""
    each = [results.predictive_draws(part, replace(
        post, x_draws=lik.part_x(post.x_draws, r),
        pp_draws=None if post.pp_draws is None else lik.part_x(post.pp_draws, r)))
        for r, part in enumerate(lik.parts)]
    return {c: np.concatenate([e[c] for e in each], axis=2) for c in each[0]}
