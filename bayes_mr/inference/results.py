"""One result schema for all three estimators: ArviZ InferenceData.

Every fit — UKF, emcee, least squares — is stored as an
:class:`arviz.InferenceData` with the standard groups and dims:

* ``posterior`` — θ in SI, dims (chain, draw); one variable per free
  parameter. MCMC: the chain. Least squares: draws from the Laplace Gaussian
  in the estimation coordinates φ. UKF: draws from the selected run's final
  Gaussian on φ (the filter's posterior).
* ``sample_stats`` — ``lp`` (log posterior) and whatever the engine adds.
* ``log_likelihood`` — pointwise log-density of each measured channel on a
  thinned set of draws and samples (dims chain, draw, obs), so LOO/WAIC work.
* ``observed_data`` — the measured channels (dim ``time``).
* ``posterior_predictive`` — simulated measured channels and damper force
  for a few draws (dims chain, draw, time).
* ``constant_data`` — inputs and the ``valid`` mask.
* ``point_estimate`` — the parameter vector the engine stands behind (LSQ
  optimum, UKF selected run, MCMC maximum a posteriori), dim ``param``.
* engine-specific extra groups (``ukf_training``: every run's prior, final
  mean/covariance, evidence, status and parameter history).

Every summary says which residual model the likelihood used (``noise_model``:
``iid`` or ``ar(p=…)`` with one AR order per channel, :mod:`bayes_mr.likelihood.noise_model`)
and the effective number of independent samples of each channel (``n_eff``,
from the point estimate's residual). The UKF keeps its own iid measurement
model whatever the likelihood's: its ``log_evidence`` is the innovation
likelihood of the selected run (``evidence_route`` ``ukf_innovations``), not a
marginal likelihood under the likelihood's residual model, and is not
comparable with the least-squares or MCMC evidence (``evidence_note`` says so).

The JSON summary (the ``fit`` keys of ``docs/CONTRACT.md``) is kept as a
string attribute ``summary`` of the ``posterior`` group so that
``validate RESULT.nc`` can read the model, kind and engine back.

:func:`build` is the one place that turns an estimator's
:class:`~bayes_mr.inference.base.Posterior` into this schema: it scores the
engine's point estimate, thins the draws into the pointwise log-likelihood
and the predictive draws, and writes the summary — the same way for every
engine.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import xarray as xr

from bayes_mr.data.schema import OUTPUTS
from bayes_mr.inference.base import Posterior, even_indices
from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.simulation.input_grid import describe as describe_interp
from bayes_mr.likelihood.noise_model import ResidualModel
from bayes_mr.likelihood.noise_model import describe as describe_noise
from bayes_mr.scores import score
from bayes_mr.simulation.simulate import simulate

with warnings.catch_warnings():
    warnings.simplefilter("ignore", FutureWarning)
    import arviz as az


@dataclass
class FitSummary:
    """The ``fit`` JSON of the SPEC (more keys welcome, none renamed).

    Attributes
    ----------
    model, engine : str
    params, params_sd : dict
        Posterior mean and standard deviation of each parameter [SI].
    log_evidence : float or None
        ln p(data | model) from the engine's route (None if not computed).
    mse : float or None
        Thesis eq. 3-44 (structure tests).
    force_errors : dict or None
        E_t, E_x, E_xdot (3-45..3-49) where force is known.
    force_nrmse : float or None
        RMS(F − F̂)/SD(F) over unmasked samples (device tests; structure
        tests with a measured damper force).
    masked : int
        Samples left out by quality control.
    trained, diverged : int or None
        UKF runs that completed / failed.
    wall_s : float
        Wall time of the fit [s].
    point : dict
        A parameter set that simulates (the optimum, the maximum a
        posteriori draw or the selected UKF run) [SI]; ``mse`` and the force
        errors are its scores.
    rmse : dict or None
        Measured channel → RMS error of the point's prediction over the
        scored samples [channel units].
    noise_model : str
        The residual model of the likelihood: ``iid`` (independent Gaussian
        errors per channel) or ``ar(p=p_1,…)`` (an AR process per channel, its
        order in the order of the measured channels). ``n_eff`` (channel →
        effective independent samples) and, under AR, ``ar_coef`` are in ``extra``.
    """

    model: str
    engine: str
    kind: str
    params: dict[str, float]
    params_sd: dict[str, float]
    log_evidence: float | None = None
    mse: float | None = None
    force_errors: dict[str, float] | None = None
    force_nrmse: float | None = None
    masked: int = 0
    trained: int | None = None
    diverged: int | None = None
    wall_s: float = 0.0
    point: dict[str, float] = field(default_factory=dict)
    rmse: dict[str, float] | None = None
    noise_model: str = "iid"
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """The summary as plain JSON-ready Python."""
        out = {
            "model": self.model,
            "engine": self.engine,
            "kind": self.kind,
            "params": {k: float(v) for k, v in self.params.items()},
            "params_sd": {k: float(v) for k, v in self.params_sd.items()},
            "log_evidence": None if self.log_evidence is None else float(self.log_evidence),
            "mse": None if self.mse is None else float(self.mse),
            "force_errors": None if self.force_errors is None else {k: float(v) for k, v in self.force_errors.items()},
            "force_nrmse": None if self.force_nrmse is None else float(self.force_nrmse),
            "masked": int(self.masked),
            "trained": self.trained,
            "diverged": self.diverged,
            "wall_s": float(self.wall_s),
        }
        out.update(point={k: float(v) for k, v in self.point.items()}, rmse=_jsonable(self.rmse),
                   noise_model=self.noise_model)
        out.update(_jsonable(self.extra))
        return out

    @classmethod
    def from_dict(cls, d: dict) -> "FitSummary":
        known = {k: d[k] for k in (
            "model", "engine", "kind", "params", "params_sd", "log_evidence", "mse", "force_errors",
            "force_nrmse", "masked", "trained", "diverged", "wall_s", "point", "rmse", "noise_model") if k in d}
        extra = {k: v for k, v in d.items() if k not in known}
        return cls(**known, extra=extra)


def _jsonable(obj):
    """Plain-Python copy of ``obj`` (numpy scalars/arrays, NaN → None)."""
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if np.isfinite(v) else None
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    return obj


def write_json(data: dict, path: str | Path) -> Path:
    """Write ``data`` as pretty JSON atomically (nothing is left on error)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(_jsonable(data), indent=2, allow_nan=False) + "\n")
    tmp.replace(path)
    return path


#: Draws whose pointwise log-likelihood is stored, samples it is stored on, predictive draws.
LL_DRAWS = 100
LL_SAMPLES = 2000
PP_DRAWS = 20
#: Draws simulated at once for the pointwise log-likelihood (memory: batch × N × channels).
LL_BATCH = 24
#: What the UKF's evidence is (it keeps its own iid measurement model).
UKF_EVIDENCE_NOTE = ("innovation likelihood of the selected UKF run under the filter's own iid measurement "
                     "model: not a marginal likelihood of the fit's noise model, not comparable with lsq/mcmc")


def build(lik: OutputError, post: Posterior, *, noise_sd: dict[str, float] | None = None) -> az.InferenceData:
    """The InferenceData of an estimator's posterior (the one builder for every engine).

    Parameters
    ----------
    lik : OutputError
        The binding of (model, record, noise model) the engine fitted.
    post : Posterior
        The engine's draws, point estimate, evidence and diagnostics.
    noise_sd : dict, optional
        Noise SD per measured channel for the MSE, overriding the record's.

    Returns
    -------
    arviz.InferenceData
        See the module docstring; the summary's ``mse``, force errors and
        ``rmse`` are those of ``post.point`` on the fitted record (None when
        it does not simulate there).
    """
    record = lik.record
    names, units = lik.par.coords.names, lik.par.coords.units
    sim = simulate(lik.model, lik.inputs, lik.par.full_theta(post.point)[None], **post.simulation)
    if sim.ok.all():
        scores = score(record, {k: v[0] for k, v in sim.outputs.items()}, noise_sd=noise_sd)
    else:  # e.g. a UKF run chosen on another record that is unstable on this one: report, don't fail
        scores = {"mse": None, "force_errors": None, "force_nrmse": None, "rmse": None}
    info = dict(post.info, **noise_info(lik, post, sim))
    # the free parameters and the model's derived ones (spencer's x0 = F_pre/k1), draw by draw
    names, units, draws = lik.model.reported(lik.kind, names, units, post.draws, lik.par.full_theta(post.draws))
    point = lik.model.reported(lik.kind, lik.par.names, (), post.point, lik.par.full_theta(post.point))[2]
    flat = draws.reshape(-1, draws.shape[-1])
    summary = FitSummary(
        model=lik.model.name, engine=post.engine, kind=lik.kind,
        params=dict(zip(names, flat.mean(axis=0))),
        params_sd=dict(zip(names, flat.std(axis=0, ddof=post.params_sd_ddof))),
        log_evidence=post.log_evidence, mse=scores["mse"], force_errors=scores["force_errors"],
        force_nrmse=scores["force_nrmse"], masked=int((~lik.valid).sum()), trained=post.trained,
        diverged=post.diverged, wall_s=post.wall_s, point=dict(zip(names, point)), rmse=scores["rmse"],
        noise_model=info.pop("noise_model"),
        extra={**info, "mse_channels": list(lik.channels), "fixed": dict(lik.fixed),
               **describe_interp(lik.inputs.interp, post.engine, lik.inputs.command_interp)},
    )
    ll, ll_index = pointwise_log_likelihood(lik, post)
    return make_inference_data(summary, replace(post, draws=draws, point=point), names, units, record,
                               log_likelihood=ll, ll_index=ll_index, predictive=predictive_draws(lik, post))


def noise_info(lik: OutputError, post: Posterior, sim) -> dict:
    """``noise_model``, ``n_eff`` (and ``ar_coef``, ``evidence_note``) of a fit, at its point estimate.

    An engine that did not choose the AR orders (the UKF) has them chosen here
    on its point's residual, so its pointwise log-likelihood is of the same model.
    """
    if not sim.ok.all():
        if not lik.residual.resolved:
            lik.residual = ResidualModel("ar", (0,) * len(lik.channels))
        return {"noise_model": lik.residual.label()}
    if not lik.residual.resolved:
        lik.choose_residual_orders(lik.par.coords.to_phi(post.point))
    yhat = np.stack([sim[c][0] for c in lik.channels], axis=-1)
    out = describe_noise(lik.y - yhat, lik.valid, lik.residual, lik.channels)
    if post.engine == "ukf":
        out["evidence_note"] = UKF_EVIDENCE_NOTE
    return out


def pointwise_log_likelihood(lik: OutputError, post: Posterior) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Pointwise log-density of each measured channel at the first draws of ``post.x_draws``.

    Returns
    -------
    ll : dict
        Channel → array (chain, draw, obs): one chain of at most
        :data:`LL_DRAWS` draws, or the engine's (chain, draw) grid when
        ``post.x_chain`` gives one.
    index : ndarray of int
        The record samples (obs) the terms are stored on.
    """
    index = post.ll_time_index
    if index is None:
        valid = np.flatnonzero(lik.valid)
        index = valid[even_indices(valid.size, LL_SAMPLES)]
    x = post.x_draws if post.x_chain is not None else post.x_draws[:LL_DRAWS]
    terms = np.empty((x.shape[0], index.size, len(lik.channels)))
    for start in range(0, x.shape[0], LL_BATCH):
        phi, sigma = lik.split(x[start: start + LL_BATCH])
        yhat, sim = lik.predict(phi, **post.simulation)
        _, t = lik.log_density(yhat, sigma, sim.ok, pointwise=True)
        terms[start: start + LL_BATCH] = np.where(sim.ok[:, None, None] & np.isfinite(t[:, index]),
                                                  t[:, index], -np.inf)
    shape = post.x_chain if post.x_chain is not None else (1, x.shape[0])
    terms = terms.reshape(*shape, index.size, len(lik.channels))
    return {c: terms[..., j] for j, c in enumerate(lik.channels)}, index


def predictive_draws(lik: OutputError, post: Posterior) -> dict[str, np.ndarray]:
    """Simulated measured channels (and the damper force of a structure test) of a few draws.

    Returns channel → array (1, draw, time) for :data:`PP_DRAWS` evenly
    spaced rows of ``post.pp_draws`` when given, else the first rows of
    ``post.x_draws``.
    """
    if post.pp_draws is not None:
        x = post.pp_draws[even_indices(post.pp_draws.shape[0], PP_DRAWS)]
    else:
        x = post.x_draws[:PP_DRAWS]
    phi, _ = lik.split(x)
    yhat, sim = lik.predict(phi, **post.simulation)
    pp = {c: yhat[None, :, :, j] for j, c in enumerate(lik.channels)}
    if lik.kind == "structure":
        pp["force"] = sim["force"][None]
    return pp


def _posterior_group(summary: FitSummary, post: Posterior, names, units, record: xr.Dataset) -> xr.Dataset:
    draws = np.asarray(post.draws, float)
    posterior = xr.Dataset(
        {n: (("chain", "draw"), draws[:, :, j], {"units": u}) for j, (n, u) in enumerate(zip(names, units))},
        coords={"chain": np.arange(draws.shape[0]), "draw": np.arange(draws.shape[1])},
    )
    posterior.attrs.update(
        summary=json.dumps(summary.to_dict()), model=summary.model, engine=summary.engine, kind=summary.kind,
        source=str(record.attrs.get("source", "")),
        **{k: v for k, v in post.attrs.items() if isinstance(v, (str, int, float))},
    )
    return posterior


def _sample_stats_group(post: Posterior) -> xr.Dataset | None:
    stats = dict(post.sample_stats)
    if post.lp is not None:
        stats["lp"] = np.asarray(post.lp, float)
    if not stats:
        return None
    first = np.asarray(next(iter(stats.values())))
    ds = xr.Dataset(
        {k: (("chain", "draw") + tuple(f"{k}_dim_{i}" for i in range(np.ndim(v) - 2)), np.asarray(v))
         for k, v in stats.items()},
        coords={"chain": np.arange(first.shape[0]), "draw": np.arange(first.shape[1])},
    )
    ds.attrs.update(post.sample_stats_attrs)
    return ds


def _record_groups(record: xr.Dataset) -> dict[str, xr.Dataset]:
    """``observed_data`` (measured channels) and ``constant_data`` (inputs, ``valid``) of a record."""
    time = record["time"].values
    coords = {"time": time}
    if "record" in record.coords:  # several records one after another (bayes_mr.inference.joint_results)
        coords["record"] = ("time", record["record"].values)
    channels = list(dict.fromkeys(c for c in OUTPUTS[record.attrs["kind"]] + ("force",) if c in record))
    observed = xr.Dataset(
        {c: ("time", record[c].values, {"units": record[c].attrs.get("units", "")}) for c in channels},
        coords=coords,
    )
    inputs = [c for c in ("ground_acceleration", "displacement", "velocity", "voltage") if c in record]
    const = {c: ("time", record[c].values, {"units": record[c].attrs.get("units", "")}) for c in inputs}
    const["valid"] = ("time", record["valid"].values.astype(np.int8) if "valid" in record
                      else np.ones(time.size, np.int8))
    return {"observed_data": observed, "constant_data": xr.Dataset(const, coords=coords)}


def make_inference_data(summary: FitSummary, post: Posterior, names: tuple[str, ...], units: tuple[str, ...],
                        record: xr.Dataset, *, log_likelihood: dict[str, np.ndarray] | None = None,
                        ll_index: np.ndarray | None = None,
                        predictive: dict[str, np.ndarray] | None = None) -> az.InferenceData:
    """Assemble a fit into InferenceData.

    Parameters
    ----------
    summary : FitSummary
        The ``fit`` JSON keys (stored as the posterior's ``summary`` attribute).
    post : Posterior
        Draws (chain, draw, p) of θ [SI], point estimate, ``lp``, engine
        extras (``sample_stats``, ``groups``, ``attrs``).
    names, units : tuple of str
        Parameter names and units, length p.
    record : xarray.Dataset
        The fitted record (observed and constant data come from it).
    log_likelihood : dict, optional
        Channel → pointwise log-density, shape (chain, draw_ll, n_obs), on the
        samples ``ll_index`` (n_obs,) of the record.
    predictive : dict, optional
        Channel → simulated values, shape (chain, draw_pp, time).
    """
    groups = {"posterior": _posterior_group(summary, post, names, units, record)}
    stats = _sample_stats_group(post)
    if stats is not None:
        groups["sample_stats"] = stats
    groups.update(_record_groups(record))
    time = record["time"].values
    if log_likelihood:
        idx = np.asarray(ll_index)
        first = np.asarray(next(iter(log_likelihood.values())))
        groups["log_likelihood"] = xr.Dataset(
            {c: (("chain", "draw", "obs"), np.asarray(v)) for c, v in log_likelihood.items()},
            coords={"chain": np.arange(first.shape[0]), "draw": np.arange(first.shape[1]),
                    "obs": np.arange(idx.size), "obs_time": ("obs", time[idx])},
        )
    if predictive:
        first = np.asarray(next(iter(predictive.values())))
        groups["posterior_predictive"] = xr.Dataset(
            {c: (("chain", "draw", "time"), np.asarray(v)) for c, v in predictive.items()},
            coords={"chain": np.arange(first.shape[0]), "draw": np.arange(first.shape[1]), "time": time},
        )
    groups["point_estimate"] = xr.Dataset(
        {"theta": ("param", np.asarray(post.point, float)), "units": ("param", list(units))},
        coords={"param": list(names)},
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # non-standard group names are intended
        idata = az.InferenceData(**groups)
        for name, ds in post.groups.items():
            idata.add_groups({name: ds})
    return idata

def save(idata: az.InferenceData, path: str | Path) -> Path:
    """Write InferenceData to netCDF atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    idata.to_netcdf(str(tmp))
    tmp.replace(path)
    return path


def load_result(path: str | Path) -> az.InferenceData:
    """Read a result written by :func:`save` (fails clearly on anything else)."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such result file — write one with `bayes-mr fit DATA -o {path.name}`")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        idata = az.from_netcdf(str(path))
    if "posterior" not in idata.groups() or "summary" not in idata.posterior.attrs:
        raise ValueError(f"{path}: not a bayes_mr result (no posterior summary) — write one with `bayes-mr fit`")
    return idata


def summary_of(idata: az.InferenceData) -> FitSummary:
    """The FitSummary stored in a result."""
    return FitSummary.from_dict(json.loads(idata.posterior.attrs["summary"]))


def point_of(idata: az.InferenceData) -> dict[str, float]:
    """The point estimate of a result as name → value [SI]."""
    pe = idata["point_estimate"]
    return {str(n): float(v) for n, v in zip(pe["param"].values, pe["theta"].values)}


def set_summary(idata: az.InferenceData, summary: FitSummary) -> None:
    """Replace the summary stored in a result (e.g. after adding wall time)."""
    idata.posterior.attrs["summary"] = json.dumps(summary.to_dict())


def set_wall(idata: az.InferenceData, wall_s: float) -> None:
    """Set the summary's ``wall_s`` [s] (the whole fit's, measured by its caller)."""
    summary = summary_of(idata)
    summary.wall_s = wall_s
    set_summary(idata, summary)
