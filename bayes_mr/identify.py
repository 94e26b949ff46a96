"""Identify a model from a record with one of the three estimators.

>>> from bayes_mr.identify import Identify, LeastSquares
>>> from bayes_mr.models import DAHL, FORCE_OFFSET
>>> job = Identify(DAHL + FORCE_OFFSET, LeastSquares())          # doctest: +SKIP
>>> idata = job.fit(record)                                        # doctest: +SKIP

Every estimator returns the same :mod:`bayes_mr.results` InferenceData, so
comparison, validation and plotting do not care which one ran.
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass, field

import numpy as np
import xarray as xr

from . import results
from .inference.lsq import LSQResult, LSQSettings, fit_lsq
from .inference.ukf import TAUS, UKFSettings
from .likelihood import OutputError
from .models import Model, get_model
from .results import FitSummary
from .scores import score
from .simulate import Inputs, simulate


@dataclass(frozen=True)
class LeastSquares:
    """Output-error least squares with Laplace uncertainty (:mod:`bayes_mr.inference.lsq`)."""

    settings: LSQSettings = field(default_factory=LSQSettings)
    name: str = "lsq"


@dataclass(frozen=True)
class UKF:
    """The thesis's augmented-state UKF trained from LHS × τ priors (:mod:`bayes_mr.selection.training`)."""

    settings: UKFSettings = field(default_factory=UKFSettings)
    n_lhs: int = 10
    taus: tuple[float, ...] = TAUS
    executor: object | None = None
    name: str = "ukf"


@dataclass(frozen=True)
class Emcee:
    """emcee posterior started at the least-squares optimum (:mod:`bayes_mr.inference.mcmc`).

    ``evidence``: ``"ti"`` (thermodynamic integration over a temperature
    ladder, with stepping-stone and Laplace beside it) or ``"laplace"`` (no
    ladder: the cheap route).
    """

    def __post_init__(self):
        if self.evidence not in ("ti", "laplace"):
            raise ValueError(f"evidence must be 'ti' or 'laplace', got {self.evidence!r}")

    settings: object | None = None
    evidence: str = "ti"
    name: str = "mcmc"


ENGINES = {"lsq": LeastSquares, "ukf": UKF, "mcmc": Emcee}


def engine(name: str):
    """The estimator for an engine name (``lsq``, ``ukf``, ``mcmc``)."""
    if name not in ENGINES:
        raise ValueError(f"unknown engine '{name}'; valid: {', '.join(ENGINES)}")
    return ENGINES[name]()


def predict(model: Model | str, record: xr.Dataset, theta: dict[str, float]) -> dict[str, np.ndarray]:
    """Simulated channels of ``model`` at parameters ``theta`` under ``record``'s inputs.

    Missing parameters (the form's fixed ones) take their defaults.
    """
    model = get_model(model)
    kind = record.attrs["kind"]
    sim = simulate(model, Inputs.from_record(record), model.theta(kind, theta))
    if not sim.ok.all():
        raise ValueError(f"{model.name} diverged at sample {int(sim.failed[0])} of {record.attrs.get('source')}")
    return dict(sim.outputs)


def _thin_index(valid: np.ndarray, n: int) -> np.ndarray:
    idx = np.flatnonzero(valid)
    return idx[np.linspace(0, idx.size - 1, min(n, idx.size)).astype(int)]


def lsq_inference_data(lik: OutputError, res: LSQResult, record: xr.Dataset, *, seed: int = 0,
                       n_draws: int = 1000) -> "results.az.InferenceData":
    """InferenceData of a least-squares fit: Laplace draws of φ mapped to θ."""
    rng = np.random.default_rng(seed)
    coords = lik.par.coords
    # the prior is uniform on the φ box: the Laplace posterior is the Gaussian truncated to it
    # (an optimum on a bound with a huge SD would otherwise map to θ = inf)
    draws_phi = rng.multivariate_normal(res.phi, res.cov_phi, size=n_draws, method="eigh")
    draws_phi = np.clip(draws_phi, lik.phi_lo, lik.phi_hi)
    draws = coords.to_theta(draws_phi)[None]
    point = coords.to_theta(res.phi)
    theta = dict(zip(coords.names, point))
    pred = predict(lik.model, record, theta)
    scores = score(record, pred)
    # pointwise log-likelihood and predictive on a few draws (full simulations are the cost)
    sub = draws_phi[: min(100, n_draws)]
    x = np.hstack([sub, np.tile(np.log(res.sigma), (sub.shape[0], 1))]) if lik.noise == "sampled" else sub
    _, terms = lik.log_likelihood(x, pointwise=True)
    idx = _thin_index(lik.valid, 2000)
    ll = {c: terms[None, :, idx, j] for j, c in enumerate(lik.channels)}
    yhat, sim = lik.predict(sub[:20])
    pp = {c: yhat[None, :, :, j] for j, c in enumerate(lik.channels)}
    if lik.kind == "structure":
        pp["force"] = sim["force"][None]
    summary = FitSummary(
        model=lik.model.name, engine="lsq", kind=lik.kind,
        params=dict(zip(coords.names, draws[0].mean(axis=0))),
        params_sd=dict(zip(coords.names, draws[0].std(axis=0))),
        log_evidence=res.log_evidence, mse=scores["mse"], force_errors=scores["force_errors"],
        force_nrmse=scores["force_nrmse"], masked=int(record.attrs.get("masked", 0)), wall_s=res.wall_s,
        extra={"evidence_route": "laplace", "sigma": dict(zip(lik.channels, res.sigma)),
               "optimum": theta, "hac_lag": res.hac_lag, "n_starts": len(res.starts)},
    )
    return results.make_inference_data(
        summary=summary, draws=draws, names=coords.names, units=coords.units, point=point, record=record,
        log_likelihood=ll, ll_index=idx, predictive=pp,
        extra_groups={"lsq_starts": xr.Dataset(
            {"start_phi": (("start", "param"), np.array([s["phi0"] for s in res.starts])),
             "final_phi": (("start", "param"), np.array([s["phi"] for s in res.starts])),
             "cost": ("start", np.array([s["cost"] for s in res.starts])),
             "nfev": ("start", np.array([s["nfev"] for s in res.starts]))},
            coords={"param": list(coords.names)})},
    )


@dataclass(frozen=True)
class Identify:
    """A model, an estimator and optional prior settings: ``Identify(model, estimator).fit(record)``.

    Attributes
    ----------
    model : Model or str
    estimator : LeastSquares, UKF or Emcee
    ranges : dict, optional
        Plausible-range overrides name → (lo, hi) [SI].
    fixed : dict, optional
        Parameters held fixed, name → value [SI].
    """

    model: Model | str
    estimator: LeastSquares | UKF | Emcee = field(default_factory=LeastSquares)
    ranges: dict | None = None
    fixed: dict | None = None

    def fit(self, record: xr.Dataset, *, seed: int = 0, progress: bool = True,
            validate_on: xr.Dataset | None = None):
        """Fit and return InferenceData (see :mod:`bayes_mr.results`)."""
        model = get_model(self.model)
        est = self.estimator
        t0 = _time.perf_counter()
        if isinstance(est, UKF):
            from .selection.ukf_fit import ukf_fit

            return ukf_fit(model, record, validate_on=validate_on, n_lhs=est.n_lhs, taus=est.taus,
                           settings=est.settings, seed=seed, executor=est.executor, progress=progress,
                           ranges=self.ranges, fixed=self.fixed)
        lik = OutputError(model, record, ranges=self.ranges, fixed=self.fixed)
        lsq_settings = est.settings if isinstance(est, LeastSquares) else LSQSettings(seed=seed)
        res = fit_lsq(lik, lsq_settings)
        if isinstance(est, LeastSquares):
            idata = lsq_inference_data(lik, res, record, seed=seed)
        else:
            from .inference.evidence import evidence_routes, laplace_evidence
            from .inference.mcmc import MCMCSettings, fit_mcmc, to_inference_data

            settings = est.settings or MCMCSettings(seed=seed, progress=progress)
            chain = fit_mcmc(lik, lsq=res, settings=settings)
            if est.evidence == "ti":
                routes = evidence_routes(lik, lsq=res, posterior=chain, seed=seed)
            else:
                routes = {"laplace": laplace_evidence(res)}
            idata = to_inference_data(lik, chain, res, evidence=routes, record=record)
        summary = results.summary_of(idata)
        summary.wall_s = _time.perf_counter() - t0
        results.set_summary(idata, summary)
        return idata


def validate(idata, record: xr.Dataset) -> dict:
    """Thesis method 2: a fitted model predicts another record.

    Returns the ``fit`` JSON keys for the new record: the fitted parameters,
    and the scores of the point estimate's prediction.
    """
    summary = results.summary_of(idata)
    if record.attrs["kind"] != summary.kind:
        raise ValueError(f"the result is a {summary.kind} test, the record a {record.attrs['kind']} test")
    t0 = _time.perf_counter()
    pred = predict(summary.model, record, results.point_of(idata))
    scores = score(record, pred)
    out = summary.to_dict()
    out.update(
        mse=scores["mse"], force_errors=scores["force_errors"], force_nrmse=scores["force_nrmse"],
        masked=int(record.attrs.get("masked", 0)), wall_s=_time.perf_counter() - t0,
        log_evidence=None, validated_on=str(record.attrs.get("source", "")),
        trained_on=str(idata.posterior.attrs.get("source", "")),
    )
    return out
