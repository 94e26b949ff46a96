"""The three engines, each ``fit(likelihood, *, seed, progress) -> Posterior``.

* :class:`LeastSquares` — output-error least squares with a Laplace
  posterior (:mod:`.lsq`);
* :class:`Emcee` — an emcee posterior started at the least-squares optimum,
  with evidence by thermodynamic integration or Laplace (:mod:`.mcmc`,
  :mod:`.evidence`);
* :class:`UKF` — the thesis's augmented-state UKF trained from LHS × τ
  priors, the run with the lowest validation MSE kept (:mod:`.ukf_training`,
  :mod:`.ukf_validation`).

All three read the same :class:`~bayes_mr.likelihood.output_error.OutputError` and return
a :class:`~bayes_mr.inference.base.Posterior`; :func:`bayes_mr.inference.results.build`
turns any of them into the one InferenceData schema. A fourth engine is a
class here with a ``name`` and a ``fit``, and an entry in :data:`ENGINES`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import xarray as xr

from bayes_mr.execution.executor import job_executor
from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.inference.base import Posterior, laplace_draws
from bayes_mr.inference.lsq.joint import fit_any, laplace_any, peak_any
from bayes_mr.inference.lsq.least_squares import LSQResult, LSQSettings
from bayes_mr.likelihood.joint import JointLikelihood
from bayes_mr.inference import calibrate
from bayes_mr.inference.ukf import filter as ukf
from bayes_mr.inference.lsq.evidence_scale import calibration_info
from bayes_mr.inference.ukf.filter import TAUS, UKFSettings


@dataclass(frozen=True)
class LeastSquares:
    """Output-error least squares with Laplace uncertainty (:mod:`bayes_mr.inference.lsq.least_squares`).

    Attributes
    ----------
    settings : LSQSettings
        Starts, tolerances and the seed of the candidates.
    n_draws : int
        Draws of the Laplace posterior stored as the ``posterior`` group.
    """

    settings: LSQSettings = field(default_factory=LSQSettings)
    n_draws: int = 1000
    name: str = "lsq"

    def fit(self, likelihood: OutputError, *, seed: int = 0, progress: bool = True) -> Posterior:
        """Optimum, Laplace draws (seeded by ``seed``) and Laplace evidence."""
        return self.posterior(likelihood, fit_any(likelihood, self.settings), seed=seed)

    def posterior(self, lik: OutputError, res: LSQResult, *, seed: int = 0) -> Posterior:
        """The Laplace posterior of a least-squares optimum ``res`` of ``lik`` (draws seeded by ``seed``);
        also how a fit made elsewhere (diagnose's refits) becomes a result."""
        coords = lik.par.coords
        draws_phi, n_clipped = laplace_draws(res.phi, res.cov_phi, lik.phi_lo, lik.phi_hi, self.n_draws,
                                             np.random.default_rng(seed))
        x = draws_phi
        if lik.noise == "sampled":
            x = np.hstack([draws_phi, np.tile(np.log(res.sigma), (draws_phi.shape[0], 1))])
        point = coords.to_theta(res.phi)
        starts = None if not res.starts else xr.Dataset(
            {"start_phi": (("start", "param"), np.array([s["phi0"] for s in res.starts])),
             "final_phi": (("start", "param"), np.array([s["phi"] for s in res.starts])),
             "cost": ("start", np.array([s["cost"] for s in res.starts])),
             "nfev": ("start", np.array([s["nfev"] for s in res.starts]))},
            coords={"param": list(coords.names)})
        info = {"evidence_route": "laplace", "sigma": dict(zip(lik.noise_labels, res.sigma)),
                "optimum": dict(zip(coords.names, point)), "hac_lag": res.hac_lag, "n_starts": len(res.starts),
                "draws_clipped": n_clipped, "uncertainty": calibrate.describe(res, lik.noise_labels),
                **calibration_info(res.evidence_terms)}
        return Posterior(engine=self.name, draws=coords.to_theta(draws_phi)[None], point=point, x_draws=x,
                         log_evidence=res.log_evidence, info=info,
                         groups={"lsq_starts": starts} if starts is not None else {},
                         wall_s=res.wall_s)


@dataclass(frozen=True)
class Emcee:
    """emcee posterior started at the least-squares optimum (:mod:`bayes_mr.inference.mcmc.sampler`).

    Attributes
    ----------
    settings : MCMCSettings, optional
        Sampler settings (default: ``MCMCSettings(seed=seed, progress=progress)``). With a work budget
        (``max_evaluations``, in log-density evaluations) a posterior that cannot hold its pilot and the shortest
        chain the rule has held in is not started: :class:`~bayes_mr.inference.mcmc.budget.OverBudget` says why
        (:func:`~bayes_mr.inference.mcmc.budget.check_budget`).
    evidence : {"ti", "laplace", "tmcmc"}
        ``"ti"``: thermodynamic integration over a temperature ladder, with
        stepping-stone and Laplace beside it; ``"laplace"``: no ladder, the
        cheap route; ``"tmcmc"`` (opt-in): transitional MCMC from the
        posterior's reference q (:mod:`bayes_mr.inference.evidence.tmcmc`), Laplace beside it.
    executor : object, optional
        Runs the evidence ladder's rungs (``concurrent.futures`` or a dask
        Client; same numbers). A fit that itself runs on a Dask worker sends
        them to its cluster without it (:func:`bayes_mr.execution.executor.job_executor`).
    """

    settings: object | None = None
    evidence: str = "ti"
    name: str = "mcmc"
    executor: object | None = None

    def __post_init__(self):
        if self.evidence not in ("ti", "laplace", "tmcmc"):
            raise ValueError(f"evidence must be 'ti', 'laplace' or 'tmcmc', got {self.evidence!r}")

    def fit(self, likelihood: OutputError, *, seed: int = 0, progress: bool = True) -> Posterior:
        """Least squares (:meth:`lsq_settings`), then the chain from its optimum, then the evidence routes."""
        return self.fit_from(likelihood, fit_any(likelihood, self.lsq_settings(seed)), seed=seed, progress=progress)

    @staticmethod
    def lsq_settings(seed: int) -> LSQSettings:
        """The least-squares fit the chain starts from: the package's defaults, candidates seeded by ``seed``."""
        return LSQSettings(seed=seed)

    def fit_from(self, likelihood: OutputError, res: LSQResult, *, seed: int = 0,
                 progress: bool = True) -> Posterior:
        """The chain and its evidence routes from a least-squares fit ``res`` of ``likelihood`` already made
        (``compare`` reuses its ``lsq`` row's: :func:`bayes_mr.selection.fit_jobs.lsq_mcmc_job`)."""
        from bayes_mr.inference.evidence.routes import evidence_routes, laplace_evidence, tmcmc_evidence
        from bayes_mr.inference.mcmc.settings import MCMCSettings
        from bayes_mr.inference.mcmc.sampler import fit_mcmc
        from bayes_mr.inference.mcmc_posterior import mcmc_posterior
        from bayes_mr.inference.evidence.tmcmc import TMCMCSettings, run_tmcmc

        settings = self.settings or MCMCSettings(seed=seed, progress=progress)
        chain = fit_mcmc(likelihood, lsq=res, settings=settings)  # OverBudget before any work, if it cannot fit
        if self.evidence == "ti":
            with job_executor(self.executor) as ex:  # the ladder's rungs: on the cluster the fit runs on, if any
                routes = evidence_routes(likelihood, lsq=res, posterior=chain, seed=seed, executor=ex)
        else:
            routes = {"laplace": laplace_evidence(res)}
        if self.evidence == "tmcmc":
            beside = TMCMCSettings(start="reference", final_moves=False, seed=seed)  # the chain is the posterior
            routes["tmcmc"] = tmcmc_evidence(run_tmcmc(likelihood, beside, posterior=chain))
        return mcmc_posterior(likelihood, chain, res, evidence=routes)


@dataclass(frozen=True)
class UKF:
    """The thesis's augmented-state UKF trained from LHS × τ priors (:mod:`bayes_mr.inference.ukf.training`).

    Attributes
    ----------
    settings : UKFSettings
        Sigma points, random walks, sub-step control.
    n_lhs : int
        Latin-hypercube prior means (× ``taus`` = runs; the thesis's 10 × 10).
    taus : tuple of float
        Indices of dispersion (fractions).
    executor : object, optional
        Runs training chunks (``concurrent.futures`` or a dask Client).
    validate_on : xarray.Dataset, optional
        Choose the run by its MSE on this record (thesis method 2); default
        the fitted record itself (method 1).
    n_draws : int
        Draws from the selected run's final Gaussian, truncated to the prior box (as least squares').
    chunk_size : int, optional
        Runs per training chunk.
    peak_nfev : int
        Most model evaluations of a local least-squares search from the
        filter's estimate to the output-error likelihood's peak (0: none, the
        filter's covariance alone). The filter's estimate stays the point; its
        offset δ from the peak is added to the filter's covariance (δδᵀ, a
        mean-squared-error matrix), so the interval holds both where the
        filter ended and where the record's likelihood peaks. Measured on the
        coverage study's 18 records (3 LHS × 2 τ priors): on two LuGre records
        the chosen run sat in another basin (ε ≈ 0.3 where the peak has
        ε ≈ 18; c 7 SD off with 100 priors); with the offset every one of the
        90 true values lay within 2.4 SD, 85 of 90 inside the 90 % interval.
        A floor at least squares' calibrated sandwich was rejected: it
        over-covered: the filter treats input noise as process noise and its
        estimates lay 3× closer to the truth than that sandwich said (median
        |z| 0.23 on Dahl records, against 0.67 for a calibrated interval).

        Device tests are the exception, and keep that floor (the Loewner
        maximum with least squares' calibrated covariance at the peak, input-
        noise replicas included). Their measured displacement and velocity are
        the model's inputs and reach the force directly (c·ẋ, k·x, the
        hysteretic rate), not through a state the filter tracks, so the filter
        cannot carry their noise as process noise. Measured on 12 simulated
        dahl device tests (truths ±20 % about c = 300 N·s/m, k = 300 N/m,
        F_d = 40 N, σ = 3000 /m; BLWN and sweeps, 250 Hz, 6 s, 1–5 % noise on
        every channel; 3 × 2 priors): without the floor 31 of 48 true values
        inside the 90 % interval (σ at z up to 5.6, the filter's SDs 2–3×
        below least squares' while its estimate sat at the likelihood's peak),
        43 of 48 with the floor, least squares 44 of 48 (a second family of
        12: 45 and 43 of 48; ``tests/inference/test_coverage.py`` checks the
        coverage study's device family).
    """

    settings: UKFSettings = field(default_factory=UKFSettings)
    n_lhs: int = 10
    taus: tuple[float, ...] = TAUS
    executor: object | None = None
    validate_on: xr.Dataset | None = None
    n_draws: int = 1000
    chunk_size: int | None = None
    peak_nfev: int = 40
    name: str = "ukf"

    def fit(self, likelihood: OutputError, *, seed: int = 0, progress: bool = True) -> Posterior:
        """Train from every prior, keep the run with the lowest validation MSE, draw from its Gaussian.

        Seeds the Latin hypercube (``seed`` itself) and the posterior draws
        (its first spawned child), so both are reproducible and independent.

        Raises
        ------
        ValueError
            No run could be trained and validated (every prior diverged).
        """
        from bayes_mr.inference.ukf.joint import filtered, validate_on_records
        from bayes_mr.inference.ukf.training import train
        from bayes_mr.inference.ukf.validation import best_run, validate_runs

        # several records: filtered in turn, the parameters carried and the states reset (bayes_mr.inference.ukf.joint)
        one, reset, records = filtered(likelihood)
        if len(records) == 1:
            likelihood = one  # a set of one record is that record
        training = train(one, n_lhs=self.n_lhs, taus=self.taus, settings=self.settings, seed=seed,
                         executor=self.executor, chunk_size=self.chunk_size, progress=progress, reset=reset)
        method = 1 if self.validate_on is None else 2
        validation = validate_on_records(training, records) if method == 1 else validate_runs(training,
                                                                                               self.validate_on)
        sel = best_run(training, validation)
        run = training.sel(run=sel)
        # further passes from the chosen run without its prior's transient (UKFSettings.refine_passes)
        ref = ukf.refine(ukf.make_problem(one, self.settings), run["final_phi"].values,
                         run["final_cov_phi"].values, self.settings, reset=reset)
        phi, cov, uncertainty = self._widened(likelihood, ref["phi"], ref["cov"])
        rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])
        # the same prior box as every engine's: a direction the record hardly sees is bounded by the prior,
        # not carried to exp(φ) = inf (lugre's ε in the coverage study)
        draws_phi, n_clipped = laplace_draws(phi, 0.5 * (cov + cov.T), likelihood.phi_lo, likelihood.phi_hi,
                                             self.n_draws, rng)
        x = draws_phi
        if likelihood.noise == "sampled":
            x = np.hstack([draws_phi, np.tile(np.log(likelihood.noise_sd), (self.n_draws, 1))])
        log_evidence = float(run["log_evidence"])
        point = likelihood.par.coords.to_theta(phi)
        info = {
            "evidence_route": "ukf_innovations", "method": method, "selected_run": int(sel),
            "selected_lhs": int(run["lhs"]), "selected_tau": float(run["tau"]),
            "validation_mse": float(validation["mse"].sel(run=sel)),
            "validated_on": str(validation.attrs.get("source", "")),
            "interrupted": int(training.attrs["interrupted"]), "training_wall_s": float(training.attrs["wall_s"]),
            "refine_passes": ref["passes"], "refined_log_lik": ref["log_lik"], "uncertainty": uncertainty,
            "draws_clipped": n_clipped,
        }
        return Posterior(
            engine=self.name, draws=likelihood.par.coords.to_theta(draws_phi)[None], point=point, x_draws=x,
            log_evidence=log_evidence, lp=np.full((1, self.n_draws), log_evidence),
            simulation={"c_acc": self.settings.c_acc, "n_max": self.settings.n_max, "ros2": self.settings.ros2},
            info=info,
            groups={"ukf_training": training, "ukf_validation": validation},
            attrs={"selected_run": int(sel), "method": method},
            trained=int(training.attrs["trained"]), diverged=int(training.attrs["diverged"]),
            wall_s=float(training.attrs["wall_s"]) + ref["wall_s"],
        )


    def _widened(self, likelihood, phi: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict]:
        """The filter's Gaussian (φ, Cov φ) widened by its offset from the likelihood's peak (:attr:`peak_nfev`),
        floored on a device test with input noise at least squares' calibrated covariance there; with the
        fit JSON's ``uncertainty``. A joint likelihood's peak and covariance are those of its summed records."""
        uncertainty = {"covariance": "filter"}
        if self.peak_nfev <= 0:
            return phi, cov, uncertainty
        peak = peak_any(likelihood, phi, self.peak_nfev)
        delta = peak["delta"]
        uncertainty.update(covariance="filter + offset to the likelihood's peak", peak_nfev=peak["nfev"],
                           peak_offset_sd=float(np.sqrt(max(delta @ np.linalg.pinv(cov) @ delta, 0.0))))
        cov = cov + np.outer(delta, delta)
        parts = likelihood.parts if isinstance(likelihood, JointLikelihood) else [likelihood]
        if likelihood.kind == "device" and any(calibrate.input_noise_sd(p) for p in parts):
            # a device test feeds its measured (noisy) motion straight into the force: the filter tracks no
            # state that could absorb that noise, so its covariance misses it (class docstring, peak_nfev)
            cov = calibrate.loewner_max(cov, laplace_any(likelihood, peak["phi"]).cov_phi)
            uncertainty["covariance"] += ", floored at least squares' calibrated covariance there"
        return phi, cov, uncertainty


#: Engine name → estimator class (the ``--engine`` choices).
ENGINES = {"lsq": LeastSquares, "ukf": UKF, "mcmc": Emcee}


def engine(name: str, **options):
    """The estimator for an engine name (``lsq``, ``ukf``, ``mcmc``), built with ``options``."""
    if name not in ENGINES:
        raise ValueError(f"unknown engine '{name}'; valid: {', '.join(ENGINES)}")
    return ENGINES[name](**options)
