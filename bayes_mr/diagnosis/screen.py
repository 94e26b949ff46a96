"""Name the cause: score every effect of the SPEC as an extension of a fitted model.

Each candidate effect is fitted as ``BASE+EFFECT`` by least squares,
warm-started at the base optimum (base parameters at their values, the effect
from its "off" value and a small grid over its plausible range; the best two
starts by cost are refined), and scored by an approximate log Bayes factor of
the extension against the base, corrected for autocorrelated residuals.

The score
---------
The Laplace evidence of :mod:`bayes_mr.inference.lsq.least_squares` treats residuals as
independent. Residuals of a dynamic model are not: the response to input
(process) noise, and any model error, are smooth in time, so the
log-likelihood gain Δℓ of an extra parameter is inflated — under the null
"the effect is absent", 2Δℓ is distributed as Σ λ_i χ²_1 rather than χ²_d,
with λ_i the eigenvalues of the design effect
Σ_iid,EE⁻¹ Σ_HAC,EE (Rao & Scott 1981; White 1982): the ratio of the
autocorrelation-consistent (Newey–West sandwich) to the iid covariance of the
effect's d parameters E, both marginal over the base parameters. With
κ = max(1, mean λ_i) the score is the Laplace log evidence ratio of the
*tempered* likelihood p(y|θ)^{1/κ} (a coarsened posterior, Miller & Dunson
2019), whose curvature is that of κ-fold fewer independent samples:

    score = Δℓ / κ + Σ_i min(0, ½ ln(2π κ μ_i)),

where μ_i are the eigenvalues of D⁻¹ Σ_iid,EE D⁻¹, D = diag of the effect
parameters' prior widths in the estimation coordinates φ (uniform prior on
φ, :class:`~bayes_mr.likelihood.output_error.OutputError`). The second term is the
Occam factor of the effect's parameters (posterior over prior volume of
each principal direction, at most 1: a direction the data do not
determine costs nothing and gains nothing, instead of the unbounded
½ ln|Σ| an unidentified parameter gives a Laplace approximation). The base
parameters' Occam factors are taken as unchanged by the extension. κ = 1
gives back the ordinary Laplace log Bayes factor.

An effect passes when its score exceeds :data:`THRESHOLD` (calibrated on
families of simulated records, see that constant).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import xarray as xr
from scipy.stats import qmc

from bayes_mr.execution.executor import Outcome, run_jobs, share
from bayes_mr.inference.lsq.refine import Stall
from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.models import EFFECTS, Effect, Model
from bayes_mr.models.effects import DEVICE_ONLY, ON_COMMAND
from bayes_mr.diagnosis.fits import Fit, refit
from bayes_mr.diagnosis.inflation import design_effect
from bayes_mr.diagnosis.residuals import envelope, varying_voltage

#: Decision threshold on the score (an approximate log Bayes factor).
#:
#: Calibrated on families of simulated records with thesis-style 1 % input and
#: output noise (``synthesize(..., noise=0.01)``): clean records of every form
#: (dahl, normalized-bouc-wen, lugre, and spencer for device tests), several
#: signals (BLWN, frequency and amplitude sweeps, El Centro), seeds, lengths
#: and sampling rates, structure and device tests — and records with each
#: effect hidden at two magnitudes (``tests/diagnosis/test_diagnose.py``:
#: ``test_clean_record_gives_none*`` and ``test_hidden_effect_is_named_and_fixed*``).
#: The value lies above every clean record's best score with a margin, and is "very strong"
#: evidence on the Kass–Raftery scale (ln B > 5). With the command-path, fluid and friction
#: effects among the candidates the margin is small: a clean structure record's best score
#: (stribeck_friction) reaches about 7.
THRESHOLD = 8.0

#: When the screen's refinements stop: after three accepted steps that together gained less than 0.05 nats.
#: Some refinements crawl along a ridge (shear_thinning's c0/c_p on dahl + a hidden offset: a fraction of a
#: nat over many evaluations) and end with negative scores either way. A stalled refit is short of its optimum
#: by about what the crawl would still gain there (a few tenths of a nat): scores only go down by it, so a
#: clean record raises no new alarm; a kept effect whose fit the rule stopped is refined on from there before
#: it is reported or built on (:func:`.search.settled`). Used by a round's ranking (:func:`screen`) only: the
#: ranked route's later additions (:func:`.search.ranked_select`), whose fits become the model, refine to the
#: end — with the rule there too, a 20-parameter spencer addition that ends at ``max_nfev`` stops elsewhere
#: and the term search after it takes another path. ``tests/diagnosis/test_stall.py`` checks the rule.
STALL = Stall(steps=3, nats=0.05)

#: Grid points of a one-parameter effect; Latin-hypercube points of a larger one.
N_GRID = 9
N_LHS = 14


@dataclass
class Candidate:
    """One effect fitted as an extension of a base model, and its score.

    Attributes
    ----------
    name : str
        Effect name (SPEC vocabulary).
    effect : Effect
        The effect with its options (``sensor_delay``'s channel).
    fit : Fit or None
        The extended fit (None if it failed).
    score : float
        κ-corrected log Bayes factor (module docstring); −inf on failure.
    kappa : float
        Variance-inflation factor used (≥ 1).
    delta_loglik : float
        ℓ(extended) − ℓ(base), both at their ML noise SDs.
    occam : float
        Occam term of the effect's parameters (≤ 0).
    delta_log_evidence : float
        Plain Laplace ln Z(extended) − ln Z(base) (iid likelihood).
    mse_ratio : float
        MSE(extended) / MSE(base).
    error : str or None
        Why the fit failed.
    restart : dict or None
        The global search of a named extension (:func:`.search.restarted`); None when it did not run.
    input_noise : dict or None
        The score the effect reaches on a device test's input-noise null (:mod:`.input_noise`: ``score`` and
        the motion noise used); None when it was not run.
    """

    name: str
    effect: Effect
    fit: Fit | None
    score: float
    kappa: float = 1.0
    delta_loglik: float = 0.0
    occam: float = 0.0
    delta_log_evidence: float = 0.0
    mse_ratio: float = 1.0
    error: str | None = None
    runs: list = field(default_factory=list)
    restart: dict | None = None
    input_noise: dict | None = None

    @property
    def channel(self) -> str | None:
        return self.effect.options.get("channel") if self.name == "sensor_delay" else None

    def params(self) -> dict[str, float]:
        if self.fit is None:
            return {}
        th = self.fit.params()
        return {p.name: th[p.name] for p in self.effect.params if p.name in th}

    def to_dict(self) -> dict:
        out = {"name": self.name, "score": _num(self.score), "kappa": _num(self.kappa),
               "delta_loglik": _num(self.delta_loglik), "occam": _num(self.occam),
               "delta_log_evidence": _num(self.delta_log_evidence), "mse_ratio": _num(self.mse_ratio),
               "params": {k: _num(v) for k, v in self.params().items()}}
        if self.channel:
            out["channel"] = self.channel
        if self.error:
            out["error"] = self.error
        for key in ("restart", "input_noise"):
            if getattr(self, key) is not None:
                out[key] = {k: (_num(v) if isinstance(v, float) else v) for k, v in getattr(self, key).items()}
        return out


def _num(v) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None


#: Current laws the screen leaves to ``compare``: on one record ``command_saturation`` stands for the family. The
#: laws' g(u) differ in their curvature above the knee only, which one record's command range rarely tells apart
#: (a tie, :mod:`.ranking`, at the cost of a command-path fit each); across a matrix of constant currents they are
#: models to compare (``spencer+command_polynomial`` against ``spencer+exponential_saturation``).
COMPARED_LAWS = ("command_polynomial", "exponential_saturation")


def applicable(model: Model, record: xr.Dataset, command_varies: bool | None = None) -> list[Effect]:
    """Effects that can extend ``model`` on ``record``.

    Leaves out effects the model has or its form contains (``spencer``:
    voltage dependence, low-velocity roll-off), ``voltage_dependence`` without
    a varying voltage, ``small_amplitude_regime`` when the amplitude hardly
    varies (:func:`regime_range`), the command-path effects (``command_saturation``,
    ``field_dynamics``) on a model without a command path (they come in after
    ``voltage_dependence`` is named), device-only effects (``inertia``) on other
    tests, the current laws of :data:`COMPARED_LAWS`, and gives ``sensor_delay`` once per measured channel (structure test:
    displacement and acceleration can each lag). ``command_varies`` says whether the command varies where the record
    alone cannot (a constant current that differs between the tests of a matrix); None: the record's voltage varies.
    """
    kind = record.attrs["kind"]
    have = {e.name for e in model.effects} | set(model.form.built_in)
    out = []
    for name, effect in EFFECTS.items():
        if name in have or name in COMPARED_LAWS:
            continue
        if effect.needs_voltage and not (varying_voltage(record) if command_varies is None else command_varies):
            continue
        if (name in ON_COMMAND and not model.commanded) or (name in DEVICE_ONLY and kind != "device"):
            continue
        if name == "small_amplitude_regime" and regime_range(record, effect.options["t_env"]) is None:
            continue
        if name == "sensor_delay":
            channels = ("acceleration", "displacement") if kind == "structure" else ("force",)
            out.extend(effect.with_options(channel=c) for c in channels)
        else:
            out.append(effect)
    return out


#: Effect parameters whose "off" value is an end of their plausible range, and the
#: factor that end is moved by so that the extension can switch itself off to
#: far below the noise (the library's ranges start at effects of ~0.1 % of the
#: force, which thousands of samples at 1 % noise already resolve — an
#: extension that cannot be switched off would not nest its base model).
#: The prior is log-uniform over the widened range; its Occam cost is in the score.
OFF_END = {"k3": ("lower", 1e-3), "c_s": ("upper", 1e3), "delay": ("lower", 1e-3),
           "a_v": ("lower", 1e-3), "c_v": ("lower", 1e-3),
           "u_s": ("upper", 1e3), "tau_c": ("lower", 1e-3), "c_p": ("lower", 1e-3),
           "F_st": ("lower", 1e-3), "m_e": ("lower", 1e-3)}


#: Share of the record each regime of ``small_amplitude_regime`` must hold at least.
REGIME_SHARE = 0.1


def regime_range(record: xr.Dataset, t_env: float) -> tuple[float, float] | None:
    """Range of the ``small_amplitude_regime`` threshold x_s [m] this record can inform.

    Quantiles REGIME_SHARE and 1 − REGIME_SHARE of the amplitude envelope
    (valid samples): a threshold below which only the first instants of the
    record fall (the motion building up from rest) describes a start-up
    transient, not a regime — and at 1 % input noise that transient does
    differ (noise dithers the hysteresis while the motion is small). None
    when the amplitude hardly varies (no two regimes to compare).
    """
    valid = record["valid"].values.astype(bool)
    env = envelope(record["displacement"].values, float(record.attrs["dt"]), t_env)[valid]
    lo, hi = np.quantile(env, [REGIME_SHARE, 1 - REGIME_SHARE])
    if not (lo > 0 and hi > 1.2 * lo):
        return None
    return float(lo), float(hi)


def effect_ranges(model: Model, record: xr.Dataset, scales=None) -> dict[str, tuple[float, float]]:
    """Prior ranges of ``model``'s effect parameters as diagnose uses them.

    The library's plausible ranges, with the "off" end widened
    (:data:`OFF_END`) and the small-amplitude threshold kept where both
    regimes hold a share of the record (:func:`regime_range`).
    """
    from bayes_mr.likelihood.output_error import record_scales

    scales = scales or record_scales(record)
    kind = record.attrs["kind"]
    free = set(model.free_names(kind))
    out = {}
    for e in model.effects:
        for p in e.params:
            if p.name not in free:
                continue
            lo, hi = p.plausible(scales)
            if p.name in OFF_END:
                end, factor = OFF_END[p.name]
                out[p.name] = (lo * factor, hi) if end == "lower" else (lo, hi * factor)
            elif p.name == "x_s":
                reg = regime_range(record, e.options["t_env"])
                if reg is not None:
                    out[p.name] = (max(lo, reg[0]), min(hi, reg[1])) if max(lo, reg[0]) < min(hi, reg[1]) else reg
    return out


def _null(name: str, lo: float, hi: float, default: float) -> float:
    """The value that switches an effect's parameter off (or nearest inside its box)."""
    off = {"f0": 0.0, "drift": 0.0, "asym": 0.0, "r_s": 1.0, "c_s": hi, "delay": lo, "k3": lo,
           "a_v": lo, "c_v": lo, "u_s": hi, "tau_c": lo, "c_p": lo, "F_st": lo, "m_e": lo,
           "r_d": 1.0}
    if name in off:
        return float(np.clip(off[name], lo, hi))
    if name == "x_s":
        return math.sqrt(lo * hi)
    return float(np.clip(default, lo, hi))


def effect_starts(lik: OutputError, base_theta: dict[str, float], effect: Effect, seed: int = 0) -> np.ndarray:
    """Starting φ (B, p) of ``BASE+EFFECT``: base parameters at their optimum; the
    effect switched off, at its default, and on a grid (one parameter) or a
    Latin hypercube (more) over its plausible range in φ."""
    coords = lik.par.coords
    names = lik.par.names
    e_idx = [names.index(p.name) for p in effect.params if p.name in names]
    specs = {p.name: p for p in effect.params}
    base = _phi_of(coords, np.arange(len(names)), np.array([base_theta.get(n, np.nan) for n in names]))
    lo, hi = coords.lower[e_idx], coords.upper[e_idx]
    null = np.array([_null(names[j], lo[k], hi[k], specs[names[j]].default) for k, j in enumerate(e_idx)])
    default = np.clip([specs[names[j]].default for j in e_idx], lo, hi)
    plo, phi_hi = lik.phi_lo[e_idx], lik.phi_hi[e_idx]
    if len(e_idx) == 1:
        u = ((np.arange(N_GRID) + 0.5) / N_GRID)[:, None]
    else:
        u = qmc.LatinHypercube(d=len(e_idx), seed=np.random.default_rng(seed)).random(N_LHS)
    grid = plo + u * (phi_hi - plo)
    sub = np.vstack([_phi_of(coords, e_idx, null), _phi_of(coords, e_idx, default), grid])
    starts = np.repeat(base[None], sub.shape[0], axis=0)
    starts[:, e_idx] = sub
    if np.isnan(starts).any():
        raise ValueError(f"{lik.model.name}: base parameters missing from the start")
    return np.clip(starts, lik.phi_lo, lik.phi_hi)


def _phi_of(coords, idx, theta) -> np.ndarray:
    """φ of the parameters at positions ``idx`` with values θ [SI] (the maps of Coordinates.to_phi)."""
    s, log = coords.scale[idx], coords.log[idx]
    theta = np.asarray(theta, float)
    return np.where(log, np.log(s * np.maximum(theta, 1e-300)), s * theta)


def score(base: Fit, ext: Fit, effect: Effect) -> tuple[float, float, float, float]:
    """(score, κ, Δℓ, Occam) of ``ext`` = base + effect (module docstring)."""
    names = ext.lik.par.names
    e = [names.index(p.name) for p in effect.params if p.name in names]
    res = ext.result
    kappa, _ = design_effect(ext.lik, res.phi, res.sigma, e)
    kappa = max(kappa, 1.0) if math.isfinite(kappa) else 1.0
    s_iid = res.cov_phi_iid[np.ix_(e, e)]
    width = (ext.lik.phi_hi - ext.lik.phi_lo)[e]
    mu = np.linalg.eigvalsh(s_iid / np.outer(width, width))
    occam = float(np.sum(np.minimum(0.0, 0.5 * np.log(2 * math.pi * kappa * np.clip(mu, 1e-300, None)))))
    dll = res.log_likelihood - base.result.log_likelihood
    return dll / kappa + occam, kappa, float(dll), occam


def screen_one(record: xr.Dataset, base: Fit, effect: Effect, *, seed: int = 0,
               stall: Stall | None = None) -> Candidate:
    """Fit ``base.model + effect`` warm-started at ``base`` and score it; ``stall`` stops its refinements on a
    crawl (:func:`screen` passes :data:`STALL`: a ranking's fits give scores; a fit that is built on does not)."""
    model = base.model + effect
    ranges = effect_ranges(model, record, base.lik.scales)
    try:
        if effect.name == "sensor_delay":
            return _screen_delay(record, base, effect, ranges)
        # the base's likelihood class (a measurement chain, :mod:`.chain`, stays on for its extensions)
        lik = type(base.lik)(model, record, ranges=ranges, scales=base.lik.scales, residual=base.lik.residual)
        starts = effect_starts(lik, base.params(), effect, seed)
        ext, runs = refit(lik, starts, base.result.sigma, stall=stall)
    except (RuntimeError, ValueError, np.linalg.LinAlgError) as exc:
        return Candidate(effect.name, effect, None, -math.inf, error=str(exc))
    return scored(base, ext, effect, runs=runs)


def scored(base: Fit, ext: Fit, effect: Effect, **extra) -> Candidate:
    """``ext`` = base + effect as a :class:`Candidate`: its score (:func:`score`), evidence gain and MSE ratio
    against ``base``; ``extra`` sets the other fields (``runs``, ``restart``)."""
    s, kappa, dll, occam = score(base, ext, effect)
    return Candidate(effect.name, effect, ext, s, kappa, dll, occam,
                     ext.result.log_evidence - base.result.log_evidence, ext.mse / base.mse, **extra)


#: Most whole-sample lags the delay screen tries.
MAX_DELAY_SAMPLES = 200


def _shift(y: np.ndarray, k: int) -> np.ndarray:
    """``y`` delayed by k whole samples, the first value held (as :func:`bayes_mr.simulation.simulate.delay`)."""
    if k <= 0:
        return y
    return np.concatenate([np.full(k, y[0]), y[:-k]])


def _screen_delay(record: xr.Dataset, base: Fit, effect: Effect, ranges: dict) -> Candidate:
    """``sensor_delay`` scored over whole-sample lags.

    A *fractional* delay is applied by linear interpolation, which also
    low-passes the simulated channel: with noise on a device test's measured
    input (which drives the simulation) that smoothing alone lowers the
    residual, and a continuous delay would be "found" in every clean record.
    The SPEC's effect is a lag of a few samples, so the evidence is computed on
    whole-sample lags k = 1..K (K samples span the delay's plausible range),
    with a uniform prior over them — Occam term −ln K — and the base
    parameters refitted at the best lag. The extended model reported is then
    refined with a continuous delay from there; κ is that fit's design effect
    of the delay.
    """
    kind = record.attrs["kind"]
    model = base.model + effect
    channel = model.delay_channel(kind)
    dt = float(record.attrs["dt"])
    hi = ranges.get("delay", effect.params[0].plausible(base.lik.scales))[1]
    n_lags = int(max(1, min(MAX_DELAY_SAMPLES, math.floor(hi / dt))))
    lik0 = base.lik
    j = lik0.channels.index(channel)
    y = lik0.y[lik0.valid, j]
    sim = base.predicted[channel]
    sd = base.result.sigma[j]
    sse = [float(np.sum(((y - _shift(sim, k)[lik0.valid]) / sd) ** 2)) for k in range(1, n_lags + 1)]
    k_best = 1 + int(np.argmin(sse))
    fixed_ranges = {k: v for k, v in ranges.items() if k != "delay"}
    lik_k = type(base.lik)(model, record, ranges=fixed_ranges, fixed={"delay": k_best * dt}, scales=base.lik.scales,
                        residual=base.lik.residual)
    start = _phi_of(lik_k.par.coords, np.arange(lik_k.n_params), np.array([base.params()[n] for n in lik_k.par.names]))
    fit_k, _ = refit(lik_k, start[None], base.result.sigma, n_refine=1)
    lik = type(base.lik)(model, record, ranges=ranges, scales=base.lik.scales, residual=base.lik.residual)
    theta = {**fit_k.params(), "delay": k_best * dt}
    start = _phi_of(lik.par.coords, np.arange(lik.n_params), np.array([theta[n] for n in lik.par.names]))
    ext, runs = refit(lik, np.clip(start, lik.phi_lo, lik.phi_hi)[None], fit_k.result.sigma, n_refine=1)
    _, kappa, _, _ = score(base, ext, effect)
    dll = fit_k.result.log_likelihood - base.result.log_likelihood
    occam = -math.log(n_lags)
    runs = [{"lag_samples": k_best, "n_lags": n_lags, **r} for r in runs]
    return Candidate(effect.name, effect, ext, dll / kappa + occam, kappa, dll, occam,
                     ext.result.log_evidence - base.result.log_evidence, ext.mse / base.mse, runs=runs)


def screen_job(record: xr.Dataset, base: Fit, effect: Effect, seed: int, stall: Stall | None) -> Candidate:
    """:func:`screen_one` as a job for an executor (module level, positional, picklable)."""
    return screen_one(record, base, effect, seed=seed, stall=stall)


def _candidate(effect: Effect, o: Outcome) -> Candidate:
    """The candidate a screening job gave, or a failed one carrying the job's error."""
    return o.value if o.ok else Candidate(effect.name, effect, None, -math.inf, error=o.error)


def screen(record: xr.Dataset, base: Fit, effects: list[Effect], *, seed: int = 0, progress=None,
           executor=None) -> list[Candidate]:
    """Every effect of ``effects`` as an extension of ``base``, ranked by score (best first).

    With ``executor`` (:mod:`bayes_mr.execution.executor`) the candidates are fitted as
    parallel jobs; each candidate's fit depends only on (record, base,
    effect, seed), and the ranking is of the candidates in the order of
    ``effects``, so the result is the one of the loop in process.
    """
    say = progress or (lambda msg: None)
    rec, fitted = share(executor, record), share(executor, base)
    n_done = [0]

    def finished(o: Outcome) -> None:
        n_done[0] += 1
        effect = effects[o.index]
        c = _candidate(effect, o)
        say(f"{base.name} + {effect.name}{'(' + c.channel + ')' if c.channel else ''}: score {c.score:.3g} "
            f"({n_done[0]}/{len(effects)})")

    # the costliest first on an executor (an effect's fit costs about as its parameters: shear_thinning's three
    # are a quarter of the bench's diagnose, and submitted last they would end the round alone)
    jobs = [(rec, fitted, e, seed, STALL) for e in effects]  # a ranking: its refinements stop on a crawl
    outcomes = run_jobs(screen_job, jobs, executor=executor, on_done=finished, cost=[len(e.params) for e in effects])
    out = [_candidate(e, o) for e, o in zip(effects, outcomes)]
    return sorted(out, key=lambda c: -c.score if math.isfinite(c.score) else math.inf)


def passes(c: Candidate, threshold: float = THRESHOLD) -> bool:
    """The decision: enough evidence, and the extension lowers the record's error; where the input-noise null
    ran (:mod:`.input_noise`), evidence beyond what the motion's noise alone gives the effect there."""
    beyond = max(0.0, c.input_noise["score"]) if c.input_noise else 0.0
    return c.fit is not None and c.score > threshold + beyond and c.mse_ratio < 1.0
