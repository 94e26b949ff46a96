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

The JSON summary (SPEC keys) is kept as a string attribute ``summary`` of the
``posterior`` group so that ``validate RESULT.nc`` can read the model, kind
and engine back.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import xarray as xr

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
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
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
        out.update(_jsonable(self.extra))
        return out

    @classmethod
    def from_dict(cls, d: dict) -> "FitSummary":
        known = {k: d[k] for k in (
            "model", "engine", "kind", "params", "params_sd", "log_evidence", "mse", "force_errors",
            "force_nrmse", "masked", "trained", "diverged", "wall_s") if k in d}
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


def make_inference_data(
    *,
    summary: FitSummary,
    draws: np.ndarray,
    names: tuple[str, ...],
    units: tuple[str, ...],
    point: np.ndarray,
    record: xr.Dataset,
    lp: np.ndarray | None = None,
    log_likelihood: dict[str, np.ndarray] | None = None,
    ll_index: np.ndarray | None = None,
    predictive: dict[str, np.ndarray] | None = None,
    sample_stats: dict[str, np.ndarray] | None = None,
    extra_groups: dict[str, xr.Dataset] | None = None,
    attrs: dict | None = None,
) -> az.InferenceData:
    """Assemble a fit into InferenceData.

    Parameters
    ----------
    draws : ndarray, shape (chain, draw, p)
        Posterior draws of θ [SI].
    names, units : tuple of str
        Parameter names and units, length p.
    point : ndarray, shape (p,)
        The engine's point estimate [SI].
    record : xarray.Dataset
        The fitted record (observed and constant data come from it).
    lp : ndarray, shape (chain, draw), optional
        Log posterior of each draw.
    log_likelihood : dict, optional
        Channel → pointwise log-density, shape (chain, draw_ll, n_obs), on the
        samples ``ll_index`` (n_obs,) of the record.
    predictive : dict, optional
        Channel → simulated values, shape (chain, draw_pp, time).
    sample_stats, extra_groups, attrs : optional
        Engine-specific additions.
    """
    draws = np.asarray(draws, float)
    posterior = xr.Dataset(
        {n: (("chain", "draw"), draws[:, :, j], {"units": u}) for j, (n, u) in enumerate(zip(names, units))},
        coords={"chain": np.arange(draws.shape[0]), "draw": np.arange(draws.shape[1])},
    )
    posterior.attrs.update(
        summary=json.dumps(summary.to_dict()),
        model=summary.model,
        engine=summary.engine,
        kind=summary.kind,
        source=str(record.attrs.get("source", "")),
        **{k: v for k, v in (attrs or {}).items() if isinstance(v, (str, int, float))},
    )
    groups = {"posterior": posterior}
    stats = dict(sample_stats or {})
    if lp is not None:
        stats["lp"] = np.asarray(lp, float)
    if stats:
        groups["sample_stats"] = xr.Dataset(
            {k: (("chain", "draw") + tuple(f"{k}_dim_{i}" for i in range(np.ndim(v) - 2)), np.asarray(v))
             for k, v in stats.items()},
            coords={"chain": np.arange(draws.shape[0]), "draw": np.arange(np.asarray(next(iter(stats.values()))).shape[1])},
        )
    time = record["time"].values
    from .data.schema import OUTPUTS

    channels = [c for c in OUTPUTS[record.attrs["kind"]] + ("force",) if c in record]
    channels = list(dict.fromkeys(channels))
    groups["observed_data"] = xr.Dataset(
        {c: ("time", record[c].values, {"units": record[c].attrs.get("units", "")}) for c in channels},
        coords={"time": time},
    )
    inputs = [c for c in ("ground_acceleration", "displacement", "velocity", "voltage") if c in record]
    const = {c: ("time", record[c].values, {"units": record[c].attrs.get("units", "")}) for c in inputs}
    const["valid"] = ("time", record["valid"].values.astype(np.int8) if "valid" in record
                      else np.ones(time.size, np.int8))
    groups["constant_data"] = xr.Dataset(const, coords={"time": time})
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
        {"theta": ("param", np.asarray(point, float)), "units": ("param", list(units))},
        coords={"param": list(names)},
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # non-standard group names are intended
        idata = az.InferenceData(**groups)
        for name, ds in (extra_groups or {}).items():
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


def load(path: str | Path) -> az.InferenceData:
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
