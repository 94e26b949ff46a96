"""``bayes-mr bench``: the performance benchmark, measured in one run.

* **UKF per step, ours vs filterpy** — the normalized Bouc–Wen structure
  model (9 augmented states, the size the thesis filtered) on thesis signal I
  with 1 % noise, from the same prior, same sigma points (α = 0.1, β = 2,
  κ = 0), same Q and R. filterpy's ``UnscentedKalmanFilter`` runs the model
  written in plain Python (the reference for ``speedup``) and, for
  comparison, with our compiled model step as ``fx``/``hx``.
  ``ukf_us_per_step`` is the engine as it is used — 100 priors filtered at
  once on all cores, wall time per run and sample filtered (a diverged run
  counts the samples before it stopped); ``ukf_us_per_step_single``
  is one run on one thread (``speedup_single``, like for like).
  ``max_state_diff`` is the largest |ours − filterpy| over the compared steps
  in units of filterpy's own standard deviation of that state.
* **100-prior training** — ``dahl`` on thesis signal I at the thesis's size
  (40 s at 4096 Hz, 163 840 samples), 10 LHS × 10 τ, both cores;
  ``trained_fraction`` is the share of runs that completed.
* **MCMC and least squares** — ``dahl`` (4 parameters + 2 noise SDs) on a
  25 s band-limited structure test at 1 kHz (emcee until 50 τ).
* **The Bouc–Wen benchmark** — ``bouc-wen`` (6 parameters with the mass,
  + 1 noise SD) on the packaged 40 960-sample training record of Noël &
  Schoukens (2016), least squares then emcee from it, with the largest
  distance of the estimate from the benchmark's true values in posterior SDs.

:func:`run_bench` returns every number; ``bayes-mr bench --json F`` writes
them to ``F`` and nothing else (``scripts/update_readme.py bench`` copies that file to
docs/data/bench.json and builds docs/performance.md from it, ``scripts/docs_sections.py``).
"""

from __future__ import annotations

import math
import time as _time

import numpy as np

from bayes_mr._compile.specialise import compiled_here
from bayes_mr.bench.kernels import kernel_bench
from bayes_mr.inference.ukf import filter as ukf
from bayes_mr.inference.ukf import kernel as K
from bayes_mr.inference.mcmc.geometry import chain_geometry
from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.models import get_model
from bayes_mr.signals import thesis_signal
from bayes_mr.simulation.simulate import synthesize


def _frame_record(model: str, sig, *, values: dict | None = None, noise: float = 0.01, seed: int = 0,
                  source: str):
    """A structure test of the thesis's numerical frame (m = 50 kg) driven by ``sig``, 1 % noise."""
    m = get_model(model)
    return synthesize(m, m.theta("structure", values or {}), sig.time, sig.as_input("structure"), mass=50.0,
                      noise=noise, seed=seed, source=source)


def _signal_I_record(model: str, seed: int = 0, noise: float = 0.01):
    return _frame_record(model, thesis_signal("I"), noise=noise, seed=seed, source="bench: thesis signal I")


def _python_rhs(form: str, mass: float):
    """The model's right-hand side written as a filterpy user would: plain Python.

    Returns ``rhs(s, theta, ag) -> (ṡ, f_r)`` for a structure test of the
    normalized Bouc–Wen or Dahl form (the equations of docs/CONTRACT.md).
    """
    def sgn(v):
        return math.copysign(1.0, v) if v != 0.0 else 0.0

    if form == "normalized-bouc-wen":
        def rhs(s, th, ag):
            x, xd, z = s
            c, k, kz, rho, n, sig = th
            zn = abs(z) ** n
            zd = rho * (xd - sig * abs(xd) * sgn(z) * zn + (sig - 1.0) * xd * zn)
            f = c * xd + k * x + kz * z
            return np.array([xd, -ag - f / mass, zd]), f
    elif form == "dahl":
        def rhs(s, th, ag):
            x, xd, z = s
            c, k, fd, sig = th
            f = c * xd + k * x + fd * z
            return np.array([xd, -ag - f / mass, sig * xd * (1.0 - z * sgn(xd))]), f
    else:
        raise ValueError(f"no Python reference for {form}")
    return rhs


def _time_ours_single(problem, prior, settings) -> tuple[dict, float]:
    """Our filter, one run on one thread: its output and its time per sample [µs] (compiled outside the timing)."""
    import numba

    with compiled_here():
        ukf.filter_states(problem, prior, settings)  # compile
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        t0 = _time.perf_counter()
        ours = ukf.filter_states(problem, prior, settings)
        ours_s = _time.perf_counter() - t0
    finally:
        numba.set_num_threads(threads)
    return ours, ours_s / (problem.inputs.n - 1) * 1e6


def _filterpy_models(model: str, rec, problem) -> dict[str, tuple]:
    """``fx``/``hx`` pairs for filterpy: the model in plain Python (RK4) and our compiled model step."""
    m = get_model(model)
    ns = len(problem.p0_states)
    lay, cst = m.layout("structure"), m.constants(rec.attrs["mass"])
    coords = problem.coords
    rhs = _python_rhs(model, float(rec.attrs["mass"]))

    def fx_python(x, dt, t, a0, a1):
        th = coords.to_theta(x[ns:])
        s, am = x[:ns], 0.5 * (a0[0] + a1[0])
        k1, _ = rhs(s, th, a0[0])
        k2, _ = rhs(s + 0.5 * dt * k1, th, am)
        k3, _ = rhs(s + 0.5 * dt * k2, th, am)
        k4, _ = rhs(s + dt * k3, th, a1[0])
        return np.concatenate([s + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4), x[ns:]])

    def hx_python(x, t, a):
        _, f = rhs(x[:ns], coords.to_theta(x[ns:]), a[0])
        return np.array([x[0], -f / rec.attrs["mass"]])

    def fx_compiled(x, dt, t, a0, a1):
        s = K.propagate(lay, cst, coords.to_theta(x[ns:]), t, dt, a0, a1, x[:ns].copy(), 1)
        return np.concatenate([s, x[ns:]])

    def hx_compiled(x, t, a):
        return K.measure(lay, cst, coords.to_theta(x[ns:]), t, a, x[:ns].copy(), 2)

    return {"python": (fx_python, hx_python), "compiled": (fx_compiled, hx_compiled)}


def _time_filterpy(problem, prior, settings, fx, hx, n: int, ours_states: np.ndarray | None) -> tuple[float, float]:
    """filterpy's UnscentedKalmanFilter over ``n`` steps: time per step [µs] and, given our states, the
    largest |ours − filterpy| in filterpy's standard deviations (0 without them)."""
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    L = len(problem.p0_states) + len(problem.coords.names)
    rows, y, h = problem.inputs.rows, problem.yobs, problem.inputs.dt
    pts = MerweScaledSigmaPoints(L, alpha=settings.points.alpha, beta=settings.points.beta,
                                 kappa=settings.points.kappa)
    f = UnscentedKalmanFilter(dim_x=L, dim_z=2, dt=h, hx=hx, fx=fx, points=pts)
    m0, P0, Q = ukf._initial(problem, prior, settings)
    f.x, f.P, f.Q, f.R = m0.copy(), P0.copy(), Q, problem.R
    fx(m0.copy(), h, 0.0, rows[0], rows[1])  # a compiled fx/hx compiles on its first call: not in the timing
    hx(m0.copy(), h, rows[1])
    diff = 0.0
    t0 = _time.perf_counter()
    for k in range(n):
        f.predict(t=k * h, a0=rows[k], a1=rows[k + 1])
        f.update(y[k + 1], t=(k + 1) * h, a=rows[k + 1])
        if ours_states is not None:  # outside the timed region would need a second pass; it is cheap
            d = np.abs(ours_states[k + 1] - f.x) / np.sqrt(np.diag(f.P))
            diff = float(np.maximum(diff, d.max()))  # a NaN stays NaN (Python's max(0.0, nan) is 0.0)
    return (_time.perf_counter() - t0) / n * 1e6, diff


def _batched_us(problem, settings, seed: int) -> float:
    """The engine as used: 100 priors filtered at once on all cores (first 10 s of signal I), µs per run and
    sample filtered. The priors span the LHS box, so some runs need many RK4 sub-steps per sample (stiff
    parameter draws) and some diverge: this is the cost of a training, not of the filter near the truth."""
    short = problem.__class__(**{**problem.__dict__, "inputs": problem.inputs.slice(0, 40960),
                                 "yobs": problem.yobs[:40960], "valid": problem.valid[:40960]})
    priors = ukf.lhs_priors(problem.coords, seed=seed)
    with compiled_here():  # the specialised batch kernel, compiled here (else the timed call starts a compile)
        ukf.run_priors(short, priors[:2], settings)
    batch = ukf.run_priors(short, priors, settings)
    info = batch["info"]
    # samples each run filtered: a run that diverged stopped at its I_STEP (counting the whole record for it
    # would flatter the figure: many LHS priors stop early)
    done = np.where(info[:, K.I_STATUS] == K.OK, short.inputs.n - 1, np.maximum(info[:, K.I_STEP], 1)).sum()
    return batch["wall_s"] / float(done) * 1e6


def ukf_vs_filterpy(model: str = "normalized-bouc-wen", n_filterpy_steps: int = 1500, seed: int = 0) -> dict:
    """Per-step time of our UKF and of filterpy's on the same problem.

    Both filters start from the same prior with the same sigma points, Q and
    R. filterpy runs twice: with the model's right-hand side and RK4 in plain
    Python (what a filterpy user writes — the reference for ``speedup``) and
    with our compiled model step as ``fx``/``hx`` (its own overhead alone).

    Returns
    -------
    dict
        The UKF keys of ``bench`` in docs/CONTRACT.md (times in µs per sample) and a few more.
    """
    import numba

    rec = _signal_I_record(model, seed)
    m = get_model(model)
    settings = ukf.UKFSettings()
    problem = ukf.make_problem(OutputError(m, rec), settings=settings)
    truth = m.theta("structure", {})
    prior = ukf.Prior(problem.coords.to_phi(truth) + 0.1, np.full(len(problem.coords.names), 0.2))
    ours, ours_us = _time_ours_single(problem, prior, settings)
    n = min(n_filterpy_steps, problem.inputs.n - 1)
    models = _filterpy_models(model, rec, problem)
    python_us, diff = _time_filterpy(problem, prior, settings, *models["python"], n, ours["states"])
    compiled_us, _ = _time_filterpy(problem, prior, settings, *models["compiled"], n, None)
    batched_us = _batched_us(problem, settings, seed)
    L = len(problem.p0_states) + len(problem.coords.names)
    return {
        "ukf_model": f"{model} (structure test, {L} augmented states, thesis signal I)",
        "ukf_us_per_step": batched_us,
        "ukf_us_per_step_single": ours_us,
        "filterpy_us_per_step": python_us,
        "filterpy_compiled_fx_us_per_step": compiled_us,
        "speedup": python_us / batched_us,
        "speedup_single": python_us / ours_us,
        "max_state_diff": diff,
        "filterpy_steps_compared": n,
        "threads": numba.get_num_threads(),
    }


def training_100(seed: int = 0) -> dict:
    """Wall time of the thesis-size 100-prior training of dahl on signal I."""
    rec = _signal_I_record("dahl", seed)
    problem = ukf.make_problem(OutputError("dahl", rec))
    priors = ukf.lhs_priors(problem.coords, seed=seed)
    with compiled_here():
        ukf.run_priors(problem, priors[:2])  # compile outside the timing
    t0 = _time.perf_counter()
    out = ukf.run_priors(problem, priors)
    wall = _time.perf_counter() - t0
    ok = out["info"][:, K.I_STATUS] == K.OK
    truth = get_model("dahl").theta("structure", {})
    best = int(np.argmax(np.where(ok, out["info"][:, K.I_LOGLIK], -np.inf)))
    est = problem.coords.to_theta(out["mean"][best, len(problem.p0_states):])
    return {
        "train_100_priors_s": wall,
        "trained_fraction": float(ok.mean()),
        "train_samples": int(problem.inputs.n),
        "train_best_rel_error": dict(zip(problem.coords.names, np.abs(est / truth - 1))),
    }


def _lsq_then_mcmc(lik: OutputError, seed: int, max_evaluations: int | None = None,
                   max_seconds: float | None = None):
    """Least squares, then an emcee posterior started from it: (lsq result, its wall time [s], chain, its wall time [s]).

    ``max_evaluations``: the chain's work budget and ``max_seconds`` its wall-time guard (``MCMCSettings``): the
    budget sets how far the adaptation goes and leaves the chain proper its first steps; the guard only stops a run
    the machine makes far slower than usual (a guard that falls inside the adaptation leaves no chain at all)."""
    from bayes_mr.inference.lsq.least_squares import fit_lsq
    from bayes_mr.inference.mcmc.settings import MCMCSettings
    from bayes_mr.inference.mcmc.sampler import fit_mcmc

    t0 = _time.perf_counter()
    res = fit_lsq(lik)
    lsq_s = _time.perf_counter() - t0
    t0 = _time.perf_counter()
    chain = fit_mcmc(lik, lsq=res, settings=MCMCSettings(seed=seed, progress=False, max_evaluations=max_evaluations,
                                                         max_seconds=max_seconds))
    return res, lsq_s, chain, _time.perf_counter() - t0


def lsq_and_mcmc(seed: int = 0, duration: float = 25.0, fs: float = 1000.0) -> dict:
    """Wall times of least squares and of an emcee posterior for dahl on a 25 s record."""
    from bayes_mr.signals import make_signal

    sig = make_signal("blwn", duration=duration, fs=fs, amplitude=3e-3, fmax=20.0, seed=seed)
    rec = _frame_record("dahl", sig, seed=seed, source="bench: blwn 25 s")
    lik = OutputError("dahl", rec)
    with compiled_here():
        lik.predict(np.atleast_2d(lik.split(0.5 * (lik.lower + lik.upper))[0]))  # compile outside the timing
    res, lsq_s, chain, mcmc_s = _lsq_then_mcmc(lik, seed)
    return {"lsq_s": lsq_s, "mcmc_s": mcmc_s, "mcmc_steps": chain.n_steps, "mcmc_walkers": chain.n_walkers,
            "mcmc_converged": chain.converged, "mcmc_tau_max": float(chain.tau.max()),
            "mcmc_rhat_max": float(chain.rhat.max()), "mcmc_record": f"dahl, {duration:g} s at {fs:g} Hz",
            "mcmc_tau": dict(zip(chain.names, map(float, chain.tau)))}


#: Work budget of the Bouc–Wen benchmark's posterior [log-density evaluations, walker-steps]: its pilot (200 steps of
#: 4d walkers, 5 600), the chain proper's first 250 steps (4 000) and what is left for adaptation rounds; about
#: 11 minutes on two cores at the ~35 ms an evaluation of the 327 680 interpolated samples costs.
BOUCWEN_MCMC_EVALUATIONS = 20_000
#: Its wall-time guard [s]: far above what the budget takes, so it decides nothing on a machine of usual speed.
BOUCWEN_MCMC_GUARD_S = 1800.0


def boucwen_benchmark_timing(seed: int = 0, mcmc_evaluations: int = BOUCWEN_MCMC_EVALUATIONS,
                             mcmc_seconds: float = BOUCWEN_MCMC_GUARD_S) -> dict:
    """Wall times of ``fit --model bouc-wen`` (lsq, then MCMC) on the packaged Bouc–Wen benchmark record.

    The record's inputs are read as ``fit`` reads them (``input_interp`` auto:
    band-limited there). emcee starts from the least-squares optimum under a
    work budget of ``mcmc_evaluations`` log-density evaluations, as the
    package's own posteriors are (``mcmc_seconds`` [s] is only a guard);
    whether it converged, why it stopped, its autocorrelation times and
    R-hat are reported as they are.

    Returns the ``boucwen_*`` keys: ``boucwen_lsq_s``, ``boucwen_mcmc_s`` [s],
    the chain's size, convergence, stop reason, largest τ [steps] and R-hat,
    and ``boucwen_lsq_max_z`` / ``boucwen_mcmc_max_z``: the largest
    |estimate − true| / sd over the parameters (the benchmark's published
    system; a check, never a start).
    """
    from bayes_mr.data import load_packaged

    truth = {"m": 2.0, "c": 10.0, "k": 5.0e4, "beta1": 800.0, "gamma": -1100.0, "n": 1.0}
    lik = OutputError("bouc-wen", load_packaged("boucwen-benchmark"))
    res, lsq_s, chain, mcmc_s = _lsq_then_mcmc(lik, seed, max_evaluations=mcmc_evaluations, max_seconds=mcmc_seconds)
    p = lik.n_params
    draws = lik.par.coords.to_theta(chain.chain[chain.burn:, :, :p].reshape(-1, p))
    z_mcmc = np.abs(draws.mean(axis=0) - [truth[n] for n in lik.par.names]) / draws.std(axis=0)
    z_lsq = [abs(res.theta[n] - truth[n]) / res.sd_theta[n] for n in lik.par.names]
    return {"boucwen_lsq_s": lsq_s, "boucwen_mcmc_s": mcmc_s, "boucwen_mcmc_steps": chain.n_steps,
            "boucwen_mcmc_walkers": chain.n_walkers, "boucwen_mcmc_converged": chain.converged,
            "boucwen_mcmc_pilot_steps": chain.pilot_steps, "boucwen_mcmc_evaluations": chain.evaluations,
            "boucwen_mcmc_stopped": chain.stopped, "boucwen_mcmc_tau_max": float(np.max(chain.tau)),
            "boucwen_mcmc_rhat_max": float(np.max(chain.rhat)),
            "boucwen_mcmc_geometry": chain_geometry(chain.chain[chain.burn:], lik.lower, lik.upper, chain.names,
                                                    chain.tau),
            "boucwen_lsq_max_z": float(max(z_lsq)), "boucwen_mcmc_max_z": float(z_mcmc.max()),
            "boucwen_input_interp": f"{lik.inputs.interp} (×{lik.inputs.upsample})",
            "boucwen_record": f"Bouc–Wen benchmark training record, {lik.y.shape[0]} samples"}


def diagnose_timing(seed: int = 0, duration: float = 30.0, fs: float = 1000.0, offset: float = 2.0) -> dict:
    """Wall time of ``diagnose`` on a 30 s, 1 kHz structure test with a hidden force offset.

    The thesis's numerical frame (m = 50 kg) with a dahl damper whose force
    carries an offset ``offset`` [N] (F_d = 25 N), band-limited ground noise,
    1 % noise on the outputs; the baseline is ``dahl`` (given, as a user would). Timed as on a machine that
    has run the package before: the inlined simulator (one kernel for every candidate model) is compiled first;
    a model's specialised kernel is used where one is on disk, as ``auto`` does.
    """
    from bayes_mr.diagnosis.diagnose import diagnose
    from bayes_mr.signals import make_signal

    sig = make_signal("blwn", duration=duration, fs=fs, amplitude=3e-3, fmax=10.0, seed=seed)
    rec = _frame_record("dahl+force_offset", sig, values={"f0": offset}, seed=seed + 77,
                        source=f"bench: dahl+force_offset, blwn {duration:g} s")
    with compiled_here("inlined"):  # the candidates' simulator, compiled once for every model, outside the timing
        lik = OutputError("dahl+force_offset", rec)
        lik.predict(lik.phi_lo)
    t0 = _time.perf_counter()
    out = diagnose(rec, "dahl", seed=seed, progress=False)
    return {"diagnose_s": _time.perf_counter() - t0, "diagnose_cause": out.cause,
            "diagnose_mse_ratio": out.gain["mse_ratio"],
            "diagnose_record": f"dahl + {offset:g} N force offset hidden, {duration:g} s at {fs:g} Hz"}


#: The forms ``compare_s`` compares (the issue's three: a Dahl record fitted by itself and two rivals).
COMPARE_FORMS = ("dahl", "normalized-bouc-wen", "lugre")


def compare_timing(seed: int = 0, duration: float = 30.0, fs: float = 1000.0, workers: int | None = None) -> dict:
    """Wall time of ``compare`` of :data:`COMPARE_FORMS` × lsq, mcmc, ukf on a 30 s, 1 kHz structure test.

    The thesis's numerical frame (m = 50 kg), a dahl damper, band-limited ground
    noise to 20 Hz, 1 % noise; the evidence route is thermodynamic integration
    (every form has an emcee row). ``workers``: on a local cluster of that many
    one-thread processes (``compare --workers N``), else in process.

    Returns
    -------
    dict
        ``compare_s`` [s], ``compare_workers``, ``compare_selected``, ``compare_selected_by``,
        ``compare_fit_s`` (``"model × engine"`` → wall time of that fit [s]) and ``compare_record``.
    """
    from bayes_mr.selection.comparison import compare
    from bayes_mr.execution.executor import open_executor
    from bayes_mr.signals import make_signal

    sig = make_signal("blwn", duration=duration, fs=fs, amplitude=3e-3, fmax=20.0, seed=seed)
    rec = _frame_record("dahl", sig, seed=seed, source=f"bench: blwn {duration:g} s")
    with open_executor(workers=workers) as ex:
        t0 = _time.perf_counter()
        out = compare(rec, COMPARE_FORMS, engines=("lsq", "mcmc", "ukf"), seed=seed, progress=False, executor=ex)
        wall = _time.perf_counter() - t0
    return {"compare_s": wall, "compare_workers": int(workers or 0), "compare_selected": out.selected,
            "compare_selected_by": out.selected_by or out.refused,
            "compare_fit_s": {f"{r['model']} × {r['engine']}": float(r.get("wall_s", math.nan)) for r in out.rows},
            "compare_record": f"dahl, {duration:g} s at {fs:g} Hz; {', '.join(COMPARE_FORMS)} × lsq, mcmc, ukf"}


def run_bench(seed: int = 0, progress=print, boucwen: bool = False, compare: bool = False,
              spencer: bool = False) -> dict:
    """All benchmark figures (the ``bench`` keys of docs/CONTRACT.md and a few more).

    ``boucwen``: also :func:`boucwen_benchmark_timing` (``bayes-mr bench --boucwen``) — the Bouc–Wen
    benchmark record's fit takes longer than the rest of the bench together, so ``make bench`` leaves it out.
    ``compare``: also :func:`compare_timing` (``bayes-mr bench --compare``; tens of minutes, also left out).
    ``spencer``: also :func:`bayes_mr.bench.spencer.spencer_bench` (``bayes-mr bench --spencer``: spencer least
    squares, diagnose and a five-form compare on device tests; tens of minutes).
    """
    out = {}
    progress("UKF per step, ours vs filterpy …")
    out.update(ukf_vs_filterpy(seed=seed))
    progress("100-prior training at thesis size …")
    out.update(training_100(seed=seed))
    progress("least squares and MCMC …")
    out.update(lsq_and_mcmc(seed=seed))
    progress("compiled kernels, generic vs specialised …")
    out.update(kernel_bench())
    progress("diagnose on a 30 s record at 1 kHz …")
    out.update(diagnose_timing(seed=seed))
    if boucwen:
        progress("bouc-wen on the Bouc–Wen benchmark record (lsq, MCMC) …")
        out.update(boucwen_benchmark_timing(seed=seed))
    if compare:
        progress("compare, three forms × lsq, mcmc, ukf on a 30 s record at 1 kHz …")
        out.update(compare_timing(seed=seed))
    if spencer:
        from bayes_mr.bench.spencer import spencer_bench

        progress("spencer on device tests (lsq, diagnose, compare) …")
        out.update(spencer_bench(seed=seed, progress=progress))
    return out
