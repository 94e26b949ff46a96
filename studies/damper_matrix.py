# ---
# jupyter:
#   jupytext:
#     formats: py:percent
# ---
# %% [markdown]
# # A simulated constant-current test matrix: joint identification, diagnosis and held-out conditions
#
# A lab characterises an MR damper by a test matrix: sine tests at several amplitudes × frequencies × constant
# coil currents. This study writes such a matrix with the package's own simulator, as a lab would have it (one
# CSV per test with units in the headers, a manifest CSV with each test's current, amplitude and frequency),
# reads it back through the public loader (:func:`bayes_mr.data.records.load_records`) and asks three questions:
#
# 1. does one least-squares fit of the true model over all tests (one likelihood summed over the records)
#    recover the truth within its 90 % intervals, over a few noise realisations (coverage)?
# 2. does ``diagnose``, started from plain ``spencer`` (the linear current law of Spencer et al. 1997), name the
#    planted current law and the small-amplitude regime, each kept only because it predicts held-out conditions?
# 3. does the true model, fitted from scratch on the other conditions alone, predict each condition's test at the
#    noise floor (leave-one-condition-out: no fit sees the test it predicts)?
#
# The truth is ``spencer`` with the published parameters of Spencer et al. (1997) (the form's defaults), an
# ``exponential_saturation`` current law (u_e = 0.5 A: the force gains less from 0.5 to 1 A than from 0 to
# 0.5 A, as a magnetically saturating fluid does) and a ``small_amplitude_regime`` (hysteretic strength × 0.6
# below 4 mm of displacement amplitude, between the smallest and the middle test amplitude). The command is a
# constant current given per test in the manifest and held between samples (``command_interp="hold"`` in the
# simulation and in every fit). The force noise is white, 1 % of each test's force standard deviation, so the
# noise floor of every test's force NRMSE is 0.01; the displacement and velocity are recorded without noise
# (a servo-hydraulic actuator's measured motion), so the fits see no errors in their input.
#
# Run: `bayes-mr study damper-matrix` (`--quick`: 2 amplitudes × 1 frequency × 3 currents, short tests, a smoke
# test of every step).

# %%
from __future__ import annotations

import csv
import json
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy import stats

from bayes_mr.data.records import RecordSet, load_records
from bayes_mr.diagnosis.diagnose import diagnose
from bayes_mr.diagnosis.search import Search
from bayes_mr.execution.progress import say as progress_say
from bayes_mr.inference.identify import by_condition, predict
from bayes_mr.inference.lsq.joint import JointResiduals, fit_joint, laplace_joint
from bayes_mr.inference.lsq.least_squares import LSQSettings, ml_sd
from bayes_mr.inference.lsq.refine import refine
from bayes_mr.inference.results import write_json
from bayes_mr.likelihood.joint import JointLikelihood
from bayes_mr.models import get_model
from bayes_mr.report.figures import condition_map
from bayes_mr.selection.loco import leave_one_out
from bayes_mr.simulation.simulate import synthesize

#: The true model: spencer with a saturating current law and a small-amplitude regime.
MODEL = "spencer+exponential_saturation+small_amplitude_regime"
#: The baseline diagnose starts from: spencer's own linear current law, no regime.
BASELINE = "spencer"
#: The planted effects' parameters [SI]; spencer's are its published defaults (Spencer et al. 1997).
EFFECT_TRUTH = {"u_e": 0.5, "r_s": 0.6, "x_s": 0.004}
#: The planted effects, as diagnose should name them.
PLANTED = ("exponential_saturation", "small_amplitude_regime")
#: Current laws: naming any of them says the current dependence is not linear.
CURRENT_LAWS = ("exponential_saturation", "command_saturation", "command_polynomial")
#: Effects diagnose screens: the current laws, the regime and distractors the matrix could be mistaken for (a
#: load-cell offset, a tension/compression asymmetry). Every effect
#: of the vocabulary would multiply the study's run time; these are the ones a saturating, amplitude-dependent
#: force could be confused with.
CANDIDATES = CURRENT_LAWS + ("small_amplitude_regime", "force_offset", "asymmetry")
#: Force noise: white, this fraction of each test's force standard deviation.
NOISE = 0.01
#: Level of the reported intervals.
LEVEL = 0.90
#: The target of held-out prediction: pooled held-out NRMSE at most this multiple of the noise floor's.
TARGET = 1.2

#: The full matrix: 3 amplitudes [m] × 3 frequencies [Hz] × 3 currents [A]; per frequency the cycles of each test
#: (at least 300 samples, the loader's minimum); sampling rate [Hz]; noise realisations of the coverage count.
#: ``diagnose_at``: the frequencies [Hz] of the tests diagnose runs on, chosen by one rule: the tests of the middle
#: frequency, which keep every amplitude and current (the regime and the current law both need them). Diagnose
#: refits the baseline and every passing effect once per held-out condition on the joint likelihood of the
#: tests it is given, so its cost grows faster than the number of tests.
FULL = {"amplitudes": (0.002, 0.006, 0.020), "frequencies": (0.5, 1.5, 4.0), "currents": (0.0, 0.5, 1.0),
        "cycles": {0.5: 2, 1.5: 2, 4.0: 3}, "fs": 400.0, "seeds": 4, "diagnose_at": (1.5,)}
QUICK = {"amplitudes": (0.002, 0.006), "frequencies": (2.0,), "currents": (0.0, 0.5, 1.0),
         "cycles": {2.0: 2}, "fs": 300.0, "seeds": 2, "diagnose_at": (2.0,)}


def truth() -> dict:
    """Every parameter of :data:`MODEL` [SI]: spencer's published defaults and :data:`EFFECT_TRUTH`."""
    model = get_model(MODEL)
    return dict(zip(model.param_names("device"), map(float, model.theta("device", EFFECT_TRUTH))))


def clean_tests(grid: dict) -> list[dict]:
    """The noise-free tests of the matrix: per test its conditions, time [s], displacement [m], velocity [m/s]
    and the true force [N] (``spencer`` with the planted effects, the current held between samples)."""
    model = get_model(MODEL)
    theta = model.theta("device", EFFECT_TRUTH)
    tests = []
    for amp in grid["amplitudes"]:
        for freq in grid["frequencies"]:
            for cur in grid["currents"]:
                n = int(round(grid["cycles"][freq] / freq * grid["fs"]))
                t = np.arange(n) / grid["fs"]
                w = 2.0 * np.pi * freq
                inputs = {"displacement": amp * np.sin(w * t), "velocity": amp * w * np.cos(w * t),
                          "current": np.full(n, cur)}
                rec = synthesize(model, theta, t, inputs, noise=0.0, command_interp="hold")
                tests.append({"amplitude": amp, "frequency": freq, "current": cur, "time": t,
                              "displacement": inputs["displacement"], "velocity": inputs["velocity"],
                              "force": rec["force"].values.astype(float)})
    return tests


def write_matrix(tests: list[dict], folder: Path, seed: int, *, gzip: bool = False) -> Path:
    """The tests with force noise (:data:`NOISE`, seeded by ``seed``) written as a lab has them: one CSV per
    test (units in the headers: s, mm, mm/s, N; no current column) and ``manifest.csv`` (file, current [A],
    amplitude [mm], frequency [Hz]). Returns the manifest's path."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    rows = []
    for k, test in enumerate(tests):
        f = test["force"]
        noisy = f + NOISE * float(np.std(f)) * rng.standard_normal(f.size)
        name = (f"a{1e3 * test['amplitude']:g}mm_f{test['frequency']:g}hz_i{test['current']:g}a.csv"
                + (".gz" if gzip else ""))
        lines = ["time [s],displacement [mm],velocity [mm/s],force [N]"]
        lines += [f"{t:.6f},{1e3 * x:.6f},{1e3 * v:.5f},{F:.4f}"
                  for t, x, v, F in zip(test["time"], test["displacement"], test["velocity"], noisy)]
        text = "\n".join(lines) + "\n"
        if gzip:
            import gzip as gz

            # mtime 0: the same matrix gives the same bytes
            with gz.GzipFile(folder / name, "wb", mtime=0) as fh:
                fh.write(text.encode())
        else:
            (folder / name).write_text(text)
        rows.append([name, f"{test['current']:g}", f"{1e3 * test['amplitude']:g}", f"{test['frequency']:g}"])
    manifest = folder / "manifest.csv"
    with open(manifest, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["file", "current [A]", "amplitude [mm]", "frequency [Hz]"])
        w.writerows(rows)
    return manifest


def joint_fit(matrix: RecordSet, seed: int, start: np.ndarray | None = None, settings: LSQSettings | None = None):
    """Least squares of :data:`MODEL` over every test of ``matrix`` (one likelihood summed over the records).

    From scratch (:func:`~bayes_mr.inference.lsq.joint.fit_joint`: starts searched, refined, re-weighted,
    Laplace posterior) when ``start`` is None; otherwise the same refine, re-weight and Laplace steps from
    ``start`` [φ] (a fit of another noise realisation of the same matrix, which only the noise moves).

    Returns
    -------
    (JointLikelihood, LSQResult)
    """
    settings = settings or LSQSettings(seed=seed)
    lik = JointLikelihood(MODEL, list(matrix), command_interp="hold")
    if start is None:
        return lik, fit_joint(lik, settings)
    sds = [p.noise_sd.copy() for p in lik.parts]
    phi = refine(lik, start, None, settings.max_nfev, residuals=JointResiduals(lik.parts, sds)).x
    sds = [ml_sd(p, p.predict(phi)[0][0]) for p in lik.parts]
    phi = refine(lik, phi, None, settings.max_nfev, residuals=JointResiduals(lik.parts, sds)).x
    return lik, laplace_joint(lik, phi, replicas=settings.input_noise_replicas)


def intervals(lik: JointLikelihood, res, level: float = LEVEL) -> dict:
    """Name → (estimate, lower, upper) [SI]: the Laplace posterior's central ``level`` interval, Gaussian in the
    fit's coordinates φ (log scale for positive parameters), mapped to θ."""
    z = float(stats.norm.ppf(0.5 + level / 2))
    sd = np.sqrt(np.clip(np.diag(res.cov_phi), 0.0, None))
    lo = lik.par.coords.to_theta(res.phi - z * sd)
    hi = lik.par.coords.to_theta(res.phi + z * sd)
    mid = lik.par.coords.to_theta(res.phi)
    return {n: (float(m), float(min(a, b)), float(max(a, b))) for n, m, a, b in zip(lik.par.names, mid, lo, hi)}


def coverage(rows: list[dict], level: float = LEVEL) -> dict:
    """Share of (seed, parameter) intervals that hold the truth, its binomial standard error and Clopper–Pearson
    95 % interval. The parameters of one fit are correlated, so the binomial error is a lower bound."""
    n = len(rows)
    k = sum(r["inside"] for r in rows)
    lo = float(stats.beta.ppf(0.025, k, n - k + 1)) if k > 0 else 0.0
    hi = float(stats.beta.ppf(0.975, k + 1, n - k)) if k < n else 1.0
    p = k / n
    return {"level": level, "inside": k, "n": n, "share": p, "se": math.sqrt(p * (1 - p) / n), "cp_level": 0.95,
            "cp95": [lo, hi]}


def held_out(matrix: RecordSet, seed: int, settings: LSQSettings, progress=None) -> list[dict]:
    """Leave-one-condition-out prediction of every test by :data:`MODEL`.

    :func:`~bayes_mr.selection.loco.leave_one_out` fits the model on the other conditions' tests alone, from
    scratch (starts searched by ``settings``, seeded by ``seed``, as ``bayes-mr fit --engine lsq``), and predicts
    each held-out test: no fit has seen the test it predicts. Each row: the test's conditions and scores
    (:func:`~bayes_mr.inference.identify.by_condition`: ``force_nrmse``, ``peak_force_error``, ``energy_error``),
    the same scores of the true model's noise-free force (``floor_*``: what the noise alone leaves) and the sums
    the pooled NRMSE needs (``sse``, ``sst``, ``sse_floor``).
    """
    # the folds' Laplace covariances are not used (a prediction needs the optimum alone): no input-noise replicas.
    # leave_one_out reads the command's interpolation from the records; a constant current is the same held or
    # interpolated, so its fits are the study's "hold" fits
    out = leave_one_out(matrix, MODEL, seed=seed, settings=replace(settings, input_noise_replicas=0),
                        progress=progress)
    model = get_model(MODEL)
    names = model.param_names("device")
    theta_true = dict(zip(names, model.theta("device", EFFECT_TRUTH)))
    rows = []
    for i, fold in enumerate(out["table"]):
        rec = matrix[i]
        # the fold's own prediction, to pool its squared errors (leave_one_out pools over all channels)
        f_hat = predict(MODEL, rec, fold["params"], command_interp="hold")["force"]
        f_true = predict(model, rec, theta_true, command_interp="hold")["force"]
        floor = by_condition(rec, f_true, matrix, i)
        valid = rec["valid"].values.astype(bool)
        f = rec["force"].values
        rows.append({"record": i, "fold": fold["fold"], "file": Path(matrix.files[i]).name,
                     "amplitude_mm": round(1e3 * fold["amplitude"], 6),
                     **{k: fold[k] for k in ("amplitude", "frequency", "command", "command_value", "force_nrmse",
                                             "peak_force_error", "energy_error")},
                     "floor_force_nrmse": floor["force_nrmse"], "floor_peak_force_error": floor["peak_force_error"],
                     "floor_energy_error": floor["energy_error"],
                     "sse": float(np.sum((f - f_hat)[valid] ** 2)),
                     "sse_floor": float(np.sum((f - f_true)[valid] ** 2)),
                     "sst": float(np.sum((f[valid] - f[valid].mean()) ** 2))})
    return rows


def pooled(rows: list[dict]) -> dict:
    """Held-out force NRMSE pooled over every test, sqrt(Σ SSE / Σ SST) (each test's SST about its own mean),
    the noise floor's (the true model's noise-free force in place of the prediction) and their ratio."""
    sst = sum(r["sst"] for r in rows)
    nrmse = math.sqrt(sum(r["sse"] for r in rows) / sst)
    floor = math.sqrt(sum(r["sse_floor"] for r in rows) / sst)
    return {"force_nrmse": nrmse, "floor_force_nrmse": floor, "ratio": nrmse / floor, "target": TARGET,
            "met": nrmse <= TARGET * floor}


def main(out_dir: str | Path = "results/studies/damper-matrix", quick: bool = False, seed: int = 0) -> dict:
    t0 = time.perf_counter()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    say = progress_say(True, clock=True)
    grid = QUICK if quick else FULL
    settings = LSQSettings(seed=seed, n_candidates=8, n_starts=1, max_nfev=60) if quick else LSQSettings(seed=seed)
    tests = clean_tests(grid)
    say(f"{len(tests)} tests simulated ({sum(t['time'].size for t in tests)} samples at {grid['fs']:g} Hz)")
    true = truth()

    # (a) the joint fit and its intervals, over noise realisations seed, seed + 1, …
    fits, rows, first = [], [], None
    for s in range(seed, seed + grid["seeds"]):
        matrix = load_records(write_matrix(tests, out_dir / "matrix" / f"seed{s}", s))
        t1 = time.perf_counter()
        lik, res = joint_fit(matrix, s, None if first is None else first[1].phi, settings)
        if first is None:
            first = (lik, res, matrix)
        est = intervals(lik, res)
        for name, (m, lo, hi) in est.items():
            rows.append({"seed": s, "name": name, "truth": true[name], "estimate": m, "lower": lo, "upper": hi,
                         "inside": bool(lo <= true[name] <= hi)})
        fits.append({"seed": s, "wall_s": time.perf_counter() - t1,
                     "inside": sum(lo <= true[n] <= hi for n, (_, lo, hi) in est.items()), "n": len(est)})
        say(f"seed {s}: {fits[-1]['inside']}/{len(est)} parameters inside their {LEVEL:.0%} intervals")
    lik, res, matrix = first
    table = [{"name": n, "truth": true[n], "estimate": m, "lower": lo, "upper": hi, "inside": bool(lo <= true[n] <= hi)}
             for n, (m, lo, hi) in intervals(lik, res).items()]

    # (b) diagnose from plain spencer on the first realisation, as a user would run it, on the tests of
    # grid["diagnose_at"]
    keep = [i for i, c in enumerate(matrix.conditions) if c["frequency"] in grid["diagnose_at"]]
    sub = RecordSet(tuple(matrix[i] for i in keep), tuple(matrix.conditions[i] for i in keep),
                    tuple(matrix.roles[i] for i in keep), matrix.source, matrix.units)
    say(f"diagnose from {BASELINE} over {len(sub)} tests")
    search = Search(candidates=CANDIDATES if not quick else ("exponential_saturation", "small_amplitude_regime"),
                    max_effects=1 if quick else 2)
    d = diagnose(sub, BASELINE, search=search, seed=seed, settings=settings, progress=say).to_dict()
    named = list(d["effects"])
    diagnosis = {
        "baseline": BASELINE, "candidates": list(search.candidates), "max_effects": search.max_effects,
        "n_tests": len(sub), "frequencies_hz": list(grid["diagnose_at"]),
        "effects": named, "cause": d["cause"], "verdict": d["verdict"], "model": d["extended"]["model"],
        "current_law": next((e for e in named if e in CURRENT_LAWS), None),
        "regime": "small_amplitude_regime" in named,
        "causes": [{k: c.get(k) for k in ("name", "score", "training_gain", "held_out_gain", "transfers", "selected",
                                          "note")} for c in d["causes"]],
        "selection": [{k: c.get(k) for k in ("round", "name", "score", "training_gain", "held_out_gain")}
                      for c in d["selection"]],
        "gain": d["gain"], "params": {k: v for k, v in d["extended"]["params"].items() if k in EFFECT_TRUTH},
        "wall_s": d["wall_s"]}
    say(f"diagnose named {', '.join(named) or 'nothing'}")

    # (c) leave-one-condition-out prediction of the true model, (d) its heat map
    say("leave-one-condition-out")
    t1 = time.perf_counter()
    loco = held_out(matrix, seed, settings, say)
    loco_wall = time.perf_counter() - t1
    fig = condition_map(loco, value="force_nrmse", label="held-out force NRMSE [-]",
                        title=f"{MODEL}: each test predicted by the fit without its condition")
    fig.savefig(out_dir / "loco_heatmap.png", dpi=120)

    out = {"quick": quick, "model": MODEL, "baseline": BASELINE, "truth": true, "effect_truth": EFFECT_TRUTH,
           "x_s_mm": 1e3 * EFFECT_TRUTH["x_s"],
           "grid": {"amplitudes_m": list(grid["amplitudes"]), "amplitudes_mm": [1e3 * a for a in grid["amplitudes"]],
                    "frequencies_hz": list(grid["frequencies"]),
                    "currents_a": list(grid["currents"]), "cycles": {f"{k:g}": v for k, v in grid["cycles"].items()},
                    "fs": grid["fs"], "n_tests": len(tests), "n_samples": int(sum(t["time"].size for t in tests))},
           "noise": NOISE, "command_interp": "hold", "seed": seed,
           "fit": {"params": table, "log_evidence": res.log_evidence, "wall_s": fits[0]["wall_s"]},
           "coverage": {**coverage(rows), "n_seeds": len(fits), "seeds": fits},
           "diagnosis": diagnosis,
           "loco": {"table": [{k: v for k, v in r.items() if k not in ("sse", "sse_floor", "sst")} for r in loco],
                    "pooled": pooled(loco), "wall_s": loco_wall,
                    "worst": max(loco, key=lambda r: r["force_nrmse"])["file"]},
           "wall_s": time.perf_counter() - t0}
    # report.md is built from the JSON as written, so it shows nothing the JSON does not hold
    out = json.loads(write_json(out, out_dir / "summary.json").read_text())
    (out_dir / "report.md").write_text(markdown(out))
    say(f"written {out_dir / 'report.md'}")
    return out


def _pct(v) -> str:
    """A relative error as a signed percentage, or a dash when there is none."""
    return "–" if v is None else f"{100 * v:+.1f} %"


def markdown(out: dict) -> str:
    """``report.md`` from the study's ``summary.json`` (every number in it is a field of that JSON)."""
    g, cov, dg, lo = out["grid"], out["coverage"], out["diagnosis"], out["loco"]
    p = lo["pooled"]
    params = ["| parameter | truth | estimate | interval | inside |", "|---|---|---|---|---|"]
    params += [f"| `{r['name']}` | {r['truth']:.4g} | {r['estimate']:.4g} | {r['lower']:.4g} – {r['upper']:.4g} | "
               f"{'yes' if r['inside'] else '**no**'} |" for r in out["fit"]["params"]]
    causes = ["| effect | score | training gain | held-out gain | transfers | kept |", "|---|---|---|---|---|---|"]
    causes += [f"| `{c['name']}` | {_g(c['score'])} | {_g(c['training_gain'])} | {_g(c['held_out_gain'])} | "
               f"{'–' if c['transfers'] is None else ('yes' if c['transfers'] else 'no')} | "
               f"{'yes' if c['selected'] else ''} |" for c in dg["causes"]]
    loco = ["| amplitude [mm] | frequency [Hz] | current [A] | force NRMSE | floor NRMSE | peak-force error | "
            "floor peak-force error | energy-per-cycle error |", "|---|---|---|---|---|---|---|---|"]
    loco += [f"| {r['amplitude_mm']:g} | {r['frequency']:g} | {r['command_value']:g} | "
             f"{r['force_nrmse']:.4f} | {r['floor_force_nrmse']:.4f} | {_pct(r['peak_force_error'])} | "
             f"{_pct(r['floor_peak_force_error'])} | {_pct(r['energy_error'])} |"
             for r in sorted(lo["table"], key=lambda r: (r["command_value"], r["amplitude"], r["frequency"]))]
    law = dg["current_law"]
    # a subset of the matrix is chosen by a rule the report states
    subset = ("" if dg["n_tests"] == g["n_tests"] else
              f"; of the {g['n_tests']} tests, those of the middle frequency, which keep every amplitude and current")
    e = out["effect_truth"]
    return "\n".join([
        "# A simulated constant-current test matrix", "",
        f"Truth `{out['model']}`: spencer's published parameters, u_e = {e['u_e']:g} A, r_s = {e['r_s']:g} below "
        f"x_s = {out['x_s_mm']:g} mm. {g['n_tests']} sine tests: amplitudes "
        f"{', '.join(f'{a:g}' for a in g['amplitudes_mm'])} mm × frequencies {', '.join(f'{f:g}' for f in g['frequencies_hz'])} Hz × currents "
        f"{', '.join(f'{c:g}' for c in g['currents_a'])} A, {g['n_samples']} samples at {g['fs']:g} Hz; force noise "
        f"{100 * out['noise']:g} % of each test's force SD; the current held between samples. Written as CSVs with a "
        "manifest and read back by `load_records`.", "",
        "## Joint fit of the true model", "",
        f"Least squares over every test, noise seed {out['seed']} ({out['fit']['wall_s']:.0f} s); intervals central "
        f"{100 * cov['level']:g} %:", "",
        *params, "",
        f"Coverage over {cov['n_seeds']} noise realisations: {cov['inside']} of {cov['n']} intervals "
        f"({100 * cov['share']:.1f} % ± {100 * cov['se']:.1f} %; Clopper–Pearson {100 * cov['cp_level']:g} % "
        f"{100 * cov['cp95'][0]:.0f}–{100 * cov['cp95'][1]:.0f} %) hold the truth at the {100 * cov['level']:g} % "
        "level. The binomial error treats the parameters of one fit as independent, which they are not.", "",
        "## Diagnosis from plain spencer", "",
        f"`diagnose` from `{dg['baseline']}` on the {dg['n_tests']} tests at "
        f"{', '.join(f'{f:g}' for f in dg['frequencies_hz'])} Hz ({dg['wall_s']:.0f} s{subset}; effects allowed: "
        f"{', '.join(f'`{c}`' for c in dg['candidates'])}; at most {dg['max_effects']} added) names "
        f"{', '.join(f'`{e}`' for e in dg['effects']) or 'nothing'}: current law "
        f"{'`' + law + '`' if law else 'not named'}, small-amplitude regime "
        f"{'named' if dg['regime'] else 'not named'}. The first round's screen, on plain spencer:", "",
        *causes, "",
        "Added, round by round (each re-screens the remaining effects on the model so far): "
        + "; ".join(f"round {c['round']}: `{c['name']}` (score {_g(c['score'])}, training gain "
                    f"{_g(c['training_gain'])}, held-out gain {_g(c['held_out_gain'])})" for c in dg["selection"])
        + ".", "",
        f"The extended model's training gain {_g(dg['gain']['training_gain'])}, held-out gain "
        f"{_g(dg['gain']['held_out_gain'])}; its effect parameters: "
        f"{', '.join(f'{k} = {v:.4g}' for k, v in dg['params'].items()) or 'none'}.", "",
        "## Held-out conditions", "",
        f"Each test predicted by `{out['model']}` fitted on the other conditions' tests alone, from scratch "
        f"(`leave_one_out`, one fold per condition, {lo['wall_s']:.0f} s), so no fit has seen the test it "
        "predicts; the floor is the true model's noise-free force scored the same way. A measured peak holds the "
        "noise's largest excursion near it, so the noise-free truth misses it by as much as the prediction does "
        "(the floor's peak-force error).", "",
        *loco, "",
        f"Pooled held-out force NRMSE {p['force_nrmse']:.4f} against the noise floor's {p['floor_force_nrmse']:.4f}: "
        f"{p['ratio']:.3f}× the floor (target ≤ {p['target']:g}×: {'met' if p['met'] else '**not met**'}).", "",
        "![held-out force NRMSE by condition](loco_heatmap.png)", "",
        f"Wall time {out['wall_s']:.0f} s.", ""])


def _g(v) -> str:
    """A score for a table: four significant digits, or a dash."""
    return "–" if v is None else f"{v:.4g}"


#: Noise realisation of the matrix that ships with the package (``bayes_mr.data.load_packaged("damper-matrix-sim")``).
PACKAGED_SEED = 0


def package(folder: str | Path) -> Path:
    """Write the packaged matrix: the full grid's tests at noise seed :data:`PACKAGED_SEED`, gzipped, with their
    manifest, into ``folder`` (``bayes_mr/data/resources/damper_matrix_sim``). Returns the manifest's path."""
    return write_matrix(clean_tests(FULL), Path(folder), PACKAGED_SEED, gzip=True)


if __name__ == "__main__":
    import sys

    if len(sys.argv) != 3 or sys.argv[1] != "package":
        print("usage: python studies/damper_matrix.py package FOLDER", file=sys.stderr)
        raise SystemExit(2)
    print(f"wrote {package(sys.argv[2])}")
