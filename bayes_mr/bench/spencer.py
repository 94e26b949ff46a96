"""``bayes-mr bench --spencer``: the model measured dampers select, timed as a user runs it.

Two device tests of Spencer et al.'s (1997) damper (its published parameters, :data:`bayes_mr.models.forms.SPENCER`),
simulated by the package with 1 % noise on the imposed motion and on the force:

* a **20 s, 1 kHz** test under band-limited random motion (4th-order Butterworth at 5 Hz, 10 mm RMS, a 0.2 s
  ramp in) and an on/off command (0 / 2 V, hold times exponential with a 0.5 s mean) — the fields and
  velocities a damper meets in service, its stiff corners included;
* a **4 s, 1 kHz sine test**, 5 mm at 3 Hz under a constant 1 V command — the lab's characterisation test.

On each, ``spencer`` least squares (:func:`bayes_mr.inference.lsq.least_squares.fit_lsq`, its default settings)
is timed, and every simulation it makes is counted (:func:`bayes_mr.simulation.simulate.tally`): the
parameter sets simulated on their own sub-step choice (residuals, screening) and on a replayed schedule (the
perturbed sets of the finite-difference Jacobian), the wall time of each kind, and the sub-step statistics of
the former — mean RK4 sub-steps per sample interval and the share of intervals at the cap ``n_max``.
Timed as on a machine that has run the package before: the inlined simulator and the sensitivity kernel are
compiled first, outside the timing.
"""

from __future__ import annotations

import time as _time

import numpy as np

from bayes_mr._compile.specialise import compiled_here
from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.models import get_model
from bayes_mr.simulation.simulate import synthesize, tally


def _switching(n: int, fs: float, rng: np.random.Generator, high: float = 2.0, mean_hold: float = 0.5) -> np.ndarray:
    """On/off command [V]: ``high`` and 0 in turn, each held an exponentially distributed time [s]."""
    v = np.zeros(n)
    i, level = 0, 0.0
    while i < n:
        hold = max(1, int(rng.exponential(mean_hold) * fs))
        v[i:i + hold] = level
        i += hold
        level = high - level
    return v


def _record(time: np.ndarray, x: np.ndarray, command: np.ndarray, seed: int, source: str):
    """A spencer device test driven by ``x`` [m] (its velocity from the same samples) and ``command`` [V]."""
    model = get_model("spencer")
    xd = np.gradient(x, time[1] - time[0])
    return synthesize(model, model.theta("device", {}), time, {"displacement": x, "velocity": xd, "voltage": command},
                      noise=0.01, seed=seed, source=source)


def random_record(duration: float = 20.0, fs: float = 1000.0, seed: int = 0):
    """The 20 s, 1 kHz device test of the module docstring (random motion, switching command)."""
    from scipy.signal import butter, sosfiltfilt

    n = int(round(duration * fs))
    t = np.arange(n) / fs
    rng = np.random.default_rng(seed)
    x = sosfiltfilt(butter(4, 5.0, fs=fs, output="sos"), rng.standard_normal(n))
    x *= 10e-3 / x.std() * np.clip(t / 0.2, 0.0, 1.0)
    return _record(t, x, _switching(n, fs, rng), seed,
                   f"bench: random motion, switching command, {duration:g} s at {fs:g} Hz")


def sine_record(duration: float = 4.0, fs: float = 1000.0, amplitude: float = 5e-3, freq: float = 3.0,
                volts: float = 1.0, seed: int = 0):
    """The sine test of the module docstring: ``amplitude`` [m] at ``freq`` [Hz] under ``volts`` [V]."""
    n = int(round(duration * fs))
    t = np.arange(n) / fs
    x = amplitude * np.sin(2 * np.pi * freq * t)
    return _record(t, x, np.full(n, volts), seed,
                   f"bench: sine {amplitude * 1e3:g} mm at {freq:g} Hz, {volts:g} V, {duration:g} s at {fs:g} Hz")


def summarise(calls: list[dict]) -> dict:
    """Counts of a :func:`~bayes_mr.simulation.simulate.tally`: simulations on their own schedule and replayed
    (parameter sets, wall time [s]), mean sub-steps per interval and the share of intervals at the cap."""
    own = [c for c in calls if not c["replayed"]]
    rep = [c for c in calls if c["replayed"] and not c.get("sensitivities")]
    sens = [c for c in calls if c.get("sensitivities")]
    intervals = sum(c["members"] * c["intervals"] for c in own)
    return {"sims": sum(c["members"] for c in own), "sims_replayed": sum(c["members"] for c in rep),
            "sensitivity_runs": len(sens), "calls": len(own), "calls_replayed": len(rep),
            "sim_s": sum(c["wall_s"] for c in own), "sim_replayed_s": sum(c["wall_s"] for c in rep),
            "sensitivity_s": sum(c["wall_s"] for c in sens),
            "substeps_per_interval": sum(c["substeps"] for c in own) / max(intervals, 1),
            "share_at_cap": sum(c["at_cap"] for c in own) / max(intervals, 1)}


def time_lsq(rec, settings=None) -> dict:
    """Wall time [s] of spencer least squares on ``rec``, the process's CPU time [s] over it (all threads: on a
    shared machine the steadier figure), its simulation counts (:func:`summarise`), the optimum's
    log-likelihood and the largest |log(θ̂/θ_true)| over the free parameters."""
    from bayes_mr.inference.lsq.least_squares import LSQSettings, fit_lsq
    from bayes_mr.inference.lsq.refine import Residuals

    lik = OutputError("spencer", rec)
    with compiled_here("inlined"):  # the simulator compiled once for every model, outside the timing
        lik.predict(lik.phi_lo)
    warm = Residuals(lik, lik.noise_sd, exact=(settings or LSQSettings()).exact_jacobian)
    mid = 0.5 * (lik.phi_lo + lik.phi_hi)
    warm(mid)
    warm.jacobian(mid)  # the sensitivity kernel too (a machine that has run the package has it compiled)
    with tally() as calls:
        t0, c0 = _time.perf_counter(), _time.process_time()
        res = fit_lsq(lik, settings or LSQSettings())
        wall, cpu = _time.perf_counter() - t0, _time.process_time() - c0
    truth = dict(zip(get_model("spencer").param_names("device"), get_model("spencer").theta("device", {})))
    err = max(abs(np.log(res.theta[n] / truth[n])) for n in lik.par.names)
    return {"s": wall, "cpu_s": cpu, **summarise(calls), "log_likelihood": float(res.log_likelihood),
            "max_log_error": float(err), "n_params": lik.n_params, "samples": int(lik.y.shape[0])}


#: The forms ``spencer_compare_s`` compares on the sine test: all five.
FORMS = ("normalized-bouc-wen", "dahl", "lugre", "bouc-wen", "spencer")


def time_diagnose(rec, seed: int = 0) -> dict:
    """Wall time [s] of ``diagnose`` with a ``spencer`` baseline on ``rec``, the cause it names and its MSE ratio."""
    from bayes_mr.diagnosis.diagnose import diagnose

    t0 = _time.perf_counter()
    out = diagnose(rec, "spencer", seed=seed, progress=False)
    return {"s": _time.perf_counter() - t0, "cause": out.cause, "mse_ratio": float(out.gain["mse_ratio"])}


def time_compare(rec, seed: int = 0) -> dict:
    """Wall time [s] of ``compare`` of :data:`FORMS` × lsq on ``rec`` (in process), the form it selects."""
    from bayes_mr.selection.comparison import compare

    t0 = _time.perf_counter()
    out = compare(rec, FORMS, engines=("lsq",), seed=seed, progress=False)
    return {"s": _time.perf_counter() - t0, "selected": out.selected,
            "fit_s": {r["model"]: float(r.get("wall_s", float("nan"))) for r in out.rows}}


def spencer_bench(seed: int = 0, progress=print) -> dict:
    """The ``spencer_*`` keys of ``bench`` (module docstring).

    Least squares on each record twice in the same run: with the Jacobian from the forward sensitivities
    (what ``fit`` does) and with finite differences (``LSQSettings(exact_jacobian=False)``, the code path
    before them), so their ratio holds where the machine's speed does not; then ``diagnose`` on both records
    and ``compare`` of the five forms × lsq on the sine test.

    Returns
    -------
    dict
        ``spencer_lsq_s``, ``spencer_lsq_fd_s``, ``spencer_sine_lsq_s``, ``spencer_sine_lsq_fd_s``,
        ``spencer_diagnose_s``, ``spencer_sine_diagnose_s``, ``spencer_compare_s`` [s];
        ``spencer_lsq_speedup``, ``spencer_sine_lsq_speedup`` (finite differences' time over the exact's); under
        ``spencer_lsq``, ``spencer_lsq_fd``, … each fit's counts (:func:`time_lsq`); under ``spencer_diagnose``,
        ``spencer_sine_diagnose`` and ``spencer_compare`` what :func:`time_diagnose` and :func:`time_compare`
        return; ``spencer_records`` the two records' descriptions; ``spencer_fresh_fit_s``,
        ``spencer_warm_fit_s``, ``spencer_compile_s`` (:func:`fresh_compile`).
    """
    from bayes_mr.inference.lsq.least_squares import LSQSettings

    records = dict(spencer=random_record(seed=seed), spencer_sine=sine_record(seed=seed))
    out = {"spencer_records": {k: rec.attrs["source"].removeprefix("bench: ") for k, rec in records.items()}}
    for key, rec in records.items():
        progress(f"{key}: least squares, exact Jacobians and finite differences …")
        for suffix, exact in (("", True), ("_fd", False)):
            r = time_lsq(rec, LSQSettings(exact_jacobian=exact))
            out[f"{key}_lsq{suffix}_s"] = r["s"]
            out[f"{key}_lsq{suffix}"] = r
        out[f"{key}_lsq_speedup"] = out[f"{key}_lsq_fd_s"] / out[f"{key}_lsq_s"]
    for key, rec in records.items():
        progress(f"{key}: diagnose …")
        r = time_diagnose(rec, seed)
        out[f"{key}_diagnose_s"] = r["s"]
        out[f"{key}_diagnose"] = r
    progress("spencer_sine: compare of five forms × lsq …")
    r = time_compare(records["spencer_sine"], seed)
    out["spencer_compare_s"] = r["s"]
    out["spencer_compare"] = r
    progress("spencer: a first fit from an empty kernel cache …")
    out.update({f"spencer_{k}": v for k, v in fresh_compile(seed).items()})
    return out


def fresh_compile(seed: int = 0) -> dict:
    """What a first ``bayes-mr fit`` costs on a machine that has never run the package: its wall time [s] from an
    empty kernel cache, the same command's again on the cache it left, and their difference, the compile.

    The command is ``spencer`` least squares on a 1 s, 1 kHz sine test (:func:`sine_record`), run in a fresh
    process each time with ``BAYES_MR_CACHE`` pointing at a new folder (``NUMBA_CACHE_DIR`` unset, so that
    folder is the cache), as a user runs it: the simulator, its sensitivities and the fit compile on the way.
    """
    import os
    import subprocess
    import sys
    import tempfile
    from pathlib import Path

    from bayes_mr.data.write import write_record

    with tempfile.TemporaryDirectory() as tmp:
        data = write_record(sine_record(duration=1.0, seed=seed), Path(tmp) / "sine.csv")
        env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
        env["BAYES_MR_CACHE"] = str(Path(tmp) / "cache")
        cmd = [sys.executable, "-m", "bayes_mr", "fit", str(data), "--model", "spencer", "--engine", "lsq",
               "--json", str(Path(tmp) / "fit.json")]
        walls = []
        for _ in range(2):
            t0 = _time.perf_counter()
            subprocess.run(cmd, env=env, check=True, capture_output=True)
            walls.append(_time.perf_counter() - t0)
    return {"fresh_fit_s": walls[0], "warm_fit_s": walls[1], "compile_s": walls[0] - walls[1],
            "fresh_fit_record": "spencer lsq, 1 s sine test at 1 kHz (bayes-mr fit in a new process)"}
