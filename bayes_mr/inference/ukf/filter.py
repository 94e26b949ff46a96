"""Augmented-state UKF: one filter run, and the thesis's 100-prior training.

The compiled filter is :mod:`bayes_mr.inference.ukf.kernel`; this module
sets it up from a model and a record (coordinates, noise, priors), runs it
for many priors at once, and returns labelled results.

Training (thesis §3.6.1): priors are 10 Latin-hypercube samples of the
parameter means in their plausible ranges × 10 indices of dispersion
τ ∈ {0.1, 1, 10, 25, 50, 75, 100, 200, 300, 600} %, with σ_j = τ·μ_j on the
log-scaled coordinate μ_j = ln(s_j θ_j) (3-42). A run that fails numerically
is recorded with its reason and step and left out; it never stops the study.
"""

from __future__ import annotations

import dataclasses
import math
import time as _time
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import qmc

from bayes_mr._compile.specialise import kernel
from bayes_mr.likelihood.output_error import OutputError, channel_noise
from bayes_mr.models import Model, Scales
from bayes_mr.models.params import Coordinates
from bayes_mr.simulation.simulate import Inputs
from bayes_mr.inference.ukf import kernel as K
from bayes_mr.inference.ukf.sigma_points import MerweScaled

#: Indices of dispersion of thesis eq. 3-43 (as fractions).
TAUS = (0.001, 0.01, 0.1, 0.25, 0.5, 0.75, 1.0, 2.0, 3.0, 6.0)


@dataclass(frozen=True)
class UKFSettings:
    """Filter settings.

    Attributes
    ----------
    points : MerweScaled
        Sigma-point scheme (``MerweScaled.thesis()`` for the thesis's).
    param_walk : float
        Random-walk intensity of φ [log-units/√s]: Q_φ = param_walk²·h.
        Default 0: the parameters are constants, so the final Gaussian is the
        filter's posterior given the whole record. A walk (1e-3, as in
        :meth:`UKFSettings.thesis`) makes the final estimate a
        fading-memory one, weighted to the record's quiet tail: on an
        independent simulation of thesis Table 3.2 it put γ 7–8 % low at
        z ≈ −3.5 and n 2 % low at z ≈ −3 (MSE 234–244 against 219–221
        without it), while the sigma-point α_h (0.1 or the thesis's 1e-4)
        and 4× finer sub-steps changed nothing (``tests/inference/test_ukf_table_3_2.py``).
    state_walk : float
        Process noise on hysteretic states, as a fraction of each state's
        scale per √s.
    box_decades : float
        The mean of φ is kept within the plausible range widened by this many
        decades on each side (log parameters; signed ones by this factor).
    refine_passes : int
        Passes of the filter over the record after the best run is chosen,
        each started from the previous final mean with its SDs widened by
        ``refine_inflation`` (a prior holding 1/inflation² of the data's
        precision), without parameter walk. The chosen run's estimate
        carries the transient of its wide prior (on the normalized Bouc–Wen
        test record its n was 5.7 % off at z = 47); two passes bring every
        parameter within 1.4 SD. 0 keeps the chosen run as is (the thesis).
    refine_inflation : float
        SD factor of the refinement passes' priors.
    c_acc, n_max, ros2 : float, int, bool
        Sub-step control and integrator of the model (see ``simulate``).
    history_points : int
        Parameter histories are kept at about this many time points.
    """

    points: MerweScaled = field(default_factory=MerweScaled)
    param_walk: float = 0.0
    state_walk: float = 1e-3
    box_decades: float = 1.0
    refine_passes: int = 2
    refine_inflation: float = 10.0
    c_acc: float = 1.0
    n_max: int = 400
    ros2: bool = True
    history_points: int = 2000

    @classmethod
    def thesis(cls) -> "UKFSettings":
        """The thesis's filter as this package reads it: its sigma points
        (α_h = 1e-4, :meth:`MerweScaled.thesis`), a parameter walk of 1e-3 and the best run as is."""
        return cls(points=MerweScaled.thesis(), param_walk=1e-3, refine_passes=0)


@dataclass(frozen=True)
class Prior:
    """A Gaussian prior on φ (the log-scaled free parameters).

    Attributes
    ----------
    mean, sd : ndarray, shape (p,)
        Mean and standard deviation of φ.
    lhs, tau : int, float
        Latin-hypercube sample index and index of dispersion (labels).
    """

    mean: np.ndarray
    sd: np.ndarray
    lhs: int = -1
    tau: float = float("nan")


@dataclass(frozen=True)
class Problem:
    """Everything the compiled filter needs about (model, record)."""

    model: Model
    kind: str
    inputs: Inputs
    channels: tuple[str, ...]  # the measured channels, the columns of yobs and R
    yobs: np.ndarray
    valid: np.ndarray
    coords: Coordinates
    template: np.ndarray
    free_idx: np.ndarray
    R: np.ndarray
    q_states: np.ndarray  # per-step process variance of each state
    p0_states: np.ndarray  # initial variance of each state
    scales: Scales


def make_problem(lik: OutputError, settings: UKFSettings = UKFSettings()) -> Problem:
    """Prepare the binding of (model, record, noise) for filtering.

    Parameters
    ----------
    lik : OutputError
        The likelihood every engine shares: its measured channels, valid
        mask, record scales, parameterisation (plausible ranges, fixed
        parameters) and measurement-noise SDs (``lik.noise_sd``, the
        filter's R) are the filter's.
    settings : UKFSettings
        Process-noise intensities of the hysteretic states.
    """
    model, kind = lik.model, lik.kind
    if model.effect("sensor_delay"):
        raise ValueError(
            "sensor_delay delays a measured channel after the dynamics; the UKF engine filters states "
            "sample by sample and cannot estimate it — use --engine lsq or mcmc"
        )
    if model.effect("inertia"):
        raise ValueError(
            "inertia adds m_e·ẍ to the simulated force after the dynamics (ẍ derived from the whole imposed "
            "motion); the UKF engine filters sample by sample and cannot estimate it — use --engine lsq or mcmc"
        )
    par = lik.par
    coords, template, free = par.coords, par.template, par.free_idx
    R = np.diag(np.asarray(lik.noise_sd, float) ** 2)
    h = lik.inputs.dt
    mid = coords.to_theta(0.5 * (coords.phi_lower + coords.phi_upper))
    theta_mid = template.copy()
    theta_mid[free] = mid
    sscale = model.state_scales(kind, theta_mid, lik.scales)
    q = (settings.state_walk * sscale) ** 2 * h
    p0 = (1e-3 * sscale) ** 2
    if kind != "device":
        # the input is measured with noise: it drives x, ẋ as process noise (a forced test's force
        # through the mass, taken at the middle of its range when it is estimated)
        drive = "ground_acceleration" if kind == "structure" else "applied_force"
        sd_in = float(channel_noise(lik.record, (drive,))[0])
        if kind == "forced":
            sd_in /= theta_mid[model.param_names(kind).index("m")]
        q[0] = (sd_in * h * h / 2) ** 2
        q[1] = (sd_in * h) ** 2
    return Problem(model, kind, lik.inputs, tuple(lik.channels), lik.y, lik.valid, coords, template, free, R, q,
                   p0, lik.scales)


def lhs_priors(coords: Coordinates, n_lhs: int = 10, taus=TAUS, *, seed: int | np.random.Generator = 0) -> list[Prior]:
    """The thesis's priors: ``n_lhs`` Latin-hypercube means × the indices of dispersion.

    Means are Latin-hypercube samples of φ uniform over the plausible range
    (log-uniform in θ for positive parameters); σ_j = τ·|μ_j| (3-42).
    """
    rng = np.random.default_rng(seed)
    sampler = qmc.LatinHypercube(d=len(coords.names), seed=rng)
    u = sampler.random(n_lhs)
    lo, hi = coords.phi_lower, coords.phi_upper
    means = lo + u * (hi - lo)
    priors = []
    for i, mu in enumerate(means):
        for tau in taus:
            sd = np.maximum(tau * np.abs(mu), 1e-6)
            priors.append(Prior(mu, sd, lhs=i, tau=float(tau)))
    return priors


def _kernel_args(problem: Problem, settings: UKFSettings):
    model, kind = problem.model, problem.kind
    coords = problem.coords
    pts = settings.points
    L = len(problem.p0_states) + len(coords.names)
    w0m, w0c, wi = pts.weights(L)
    margin = settings.box_decades * math.log(10.0)
    lo, hi = coords.phi_lower, coords.phi_upper
    width = hi - lo
    phi_lo = np.where(coords.log_like, lo - margin, lo - settings.box_decades * width)
    phi_hi = np.where(coords.log_like, hi + margin, hi + settings.box_decades * width)
    # the filter predicts the channels the likelihood measures; its layout carries L and ny (ukf_kernel.ukf_layout)
    lay = K.ukf_layout(model.layout(kind, problem.channels), L, len(problem.channels))
    cst = model.constants(problem.inputs.mass, c_acc=settings.c_acc, n_max=settings.n_max, ros2=settings.ros2)
    return dict(
        lay=lay, cst=cst, tmpl=problem.template, free_idx=problem.free_idx, is_log=coords.code,
        scale=coords.scale, phi_lo=phi_lo, phi_hi=phi_hi, h=problem.inputs.dt,
        inputs=problem.inputs.rows, yobs=np.ascontiguousarray(problem.yobs), valid=problem.valid,
        hold=problem.inputs.hold,
        w0m=w0m, w0c=w0c, wi=wi, spread=pts.spread(L), ab=pts.beta - pts.alpha**2, central=pts.central,
    )


def _initial(problem: Problem, prior: Prior, settings: UKFSettings):
    ns = len(problem.p0_states)
    m0 = np.concatenate([np.zeros(ns), prior.mean])
    P0 = np.diag(np.concatenate([problem.p0_states, prior.sd**2]))
    Q = np.diag(np.concatenate([problem.q_states, np.full(len(prior.mean), settings.param_walk**2 * problem.inputs.dt)]))
    return m0, P0, Q


def _reset_mask(problem: Problem, reset) -> np.ndarray:
    n = problem.inputs.n
    if reset is None:
        return np.zeros(n, bool)
    reset = np.ascontiguousarray(reset, dtype=bool)
    if reset.shape != (n,):
        raise ValueError(f"reset must have one entry per sample, shape ({n},), got {reset.shape}")
    return reset


def run_priors(
    problem: Problem,
    priors: list[Prior],
    settings: UKFSettings = UKFSettings(),
    *,
    reset: np.ndarray | None = None,
    parallel: bool = True,
) -> dict:
    """Filter the record once per prior (in parallel); raw arrays.

    Parameters
    ----------
    reset : bool array, shape (N,), optional
        True where a sample starts another record filtered in the same run:
        the model states restart from rest there while φ carries over
        (thesis method 3, sequential rather than a stacked state vector —
        see :func:`bayes_mr.inference.ukf.kernel.ukf_run`). Default: none.
    parallel : bool
        Spread the runs over numba's threads (True), or filter them one after
        another in this thread, releasing the GIL (for callers that
        parallelise themselves, e.g. an executor running chunks).

    Returns
    -------
    dict with ``mean`` (R, L), ``cov`` (R, L, L), ``info`` (R, INFO_SIZE),
    ``hist_mean``/``hist_sd`` (R, H, L), ``hist_index`` (H,), ``wall_s``.
    """
    args = _kernel_args(problem, settings)
    reset = _reset_mask(problem, reset)
    ns = len(problem.p0_states)
    L = ns + len(problem.coords.names)
    N = problem.inputs.n
    stride = max(1, int(math.ceil(N / settings.history_points)))
    H = (N - 1) // stride + 1
    R_ = len(priors)
    M = np.zeros((R_, L))
    PP = np.zeros((R_, L, L))
    Q = None
    for r, prior in enumerate(priors):
        M[r], PP[r], Q = _initial(problem, prior, settings)
    HM = np.full((R_, H, L), np.nan)
    HS = np.full((R_, H, L), np.nan)
    INFO = np.zeros((R_, K.INFO_SIZE))
    t0 = _time.perf_counter()
    common = (
        args["lay"], args["cst"], args["tmpl"], args["free_idx"], args["is_log"], args["scale"],
        args["phi_lo"], args["phi_hi"], args["h"], args["inputs"], args["yobs"], args["valid"], reset,
        args["hold"],
    )
    weights = (args["w0m"], args["w0c"], args["wi"], args["spread"], args["ab"], args["central"], stride)
    work = R_ * problem.inputs.n * (2 * L + 1)  # sigma points propagated per sample
    if parallel:
        kernel(K.ukf_batch, args["lay"], work)(*common, M, PP, Q, problem.R, *weights, HM, HS, INFO)
    else:
        dummy = np.zeros((1, L))
        run = kernel(K.ukf_run, args["lay"], work)
        for r in range(R_):
            run(*common, M[r], PP[r], Q, problem.R, *weights, HM[r], HS[r], dummy, False, INFO[r])
    wall = _time.perf_counter() - t0
    return dict(mean=M, cov=PP, info=INFO, hist_mean=HM, hist_sd=HS,
                hist_index=np.arange(H) * stride, wall_s=wall)


def filter_states(
    problem: Problem,
    prior: Prior,
    settings: UKFSettings = UKFSettings(),
    *,
    reset: np.ndarray | None = None,
) -> dict:
    """One filter run keeping the full state-mean history (for figures).

    ``reset`` (N,) bool marks samples that start another record (see
    :func:`run_priors`).

    Returns ``states`` (N, L) filtered means, ``mean``/``cov`` final, ``info``.
    """
    args = _kernel_args(problem, settings)
    reset = _reset_mask(problem, reset)
    m, P, Q = _initial(problem, prior, settings)
    L = m.size
    N = problem.inputs.n
    states = np.zeros((N, L))
    info = np.zeros(K.INFO_SIZE)
    hm = np.zeros((1, L))
    hs = np.zeros((1, L))
    kernel(K.ukf_run, args["lay"])(
        args["lay"], args["cst"], args["tmpl"], args["free_idx"], args["is_log"], args["scale"],
        args["phi_lo"], args["phi_hi"], args["h"], args["inputs"], args["yobs"], args["valid"], reset,
        args["hold"], m, P, Q, problem.R, args["w0m"], args["w0c"], args["wi"], args["spread"], args["ab"],
        args["central"], N + 1, hm, hs, states, True, info,
    )
    return dict(states=states, mean=m, cov=P, info=info)


def refine(problem: Problem, phi: np.ndarray, cov: np.ndarray, settings: UKFSettings, *,
           reset: np.ndarray | None = None) -> dict:
    """The chosen run refined by ``settings.refine_passes`` further passes (see :class:`UKFSettings`).

    Parameters
    ----------
    phi : ndarray, shape (p,)
        Final mean of the chosen run [φ].
    cov : ndarray, shape (p, p)
        Its final covariance [φ²].
    reset : ndarray of bool, shape (N,), optional
        Samples that start another record (several records filtered in turn, :func:`run_priors`).

    Returns
    -------
    dict
        ``phi`` and ``cov`` of the last pass that completed, ``passes`` (how
        many completed), ``log_lik`` (innovation log-likelihood of that pass;
        None when none completed) and ``wall_s``.
    """
    ns = len(problem.p0_states)
    walk = dataclasses.replace(settings, param_walk=0.0)
    out = {"phi": np.asarray(phi, float), "cov": np.asarray(cov, float), "passes": 0, "log_lik": None, "wall_s": 0.0}
    for _ in range(settings.refine_passes):
        sd = settings.refine_inflation * np.sqrt(np.clip(np.diag(out["cov"]), 0.0, None))
        res = run_priors(problem, [Prior(out["phi"], np.maximum(sd, 1e-6))], walk, reset=reset, parallel=False)
        out["wall_s"] += res["wall_s"]
        if res["info"][0, K.I_STATUS] != K.OK or not np.all(np.isfinite(res["mean"][0, ns:])):
            break  # keep the last pass that completed
        out.update(phi=res["mean"][0, ns:], cov=res["cov"][0, ns:, ns:], passes=out["passes"] + 1,
                   log_lik=float(res["info"][0, K.I_LOGLIK]))
    return out
