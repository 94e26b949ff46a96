"""The measured documents, docs/results.md and docs/performance.md, built from the JSON under docs/data/.

A repository tool, not part of the package: ``scripts/update_readme.py``
(called by ``make run`` and ``make bench``) copies a run's JSON into
``docs/data/`` and rebuilds both documents here from those files alone. The
text is fixed sentences with every number filled from a JSON field (the main
job's headline comes from :mod:`bayes_mr.run.headline`, a study's tables from
the study's own ``markdown(summary)``, the function that writes its
``report.md``), so no number in docs/ is typed by hand; ``tests/test_docs.py``
checks that the committed documents are what this module makes of
``docs/data/``. Nothing here writes a file.
"""

from __future__ import annotations

import importlib.util
import json
import re
from pathlib import Path

from bayes_mr.run.headline import STOP_REASONS, chain_shape, headline

ROOT = Path(__file__).resolve().parents[1]
#: The generated documents' folder and, under it, their data and figures.
DOCS = ROOT / "docs"
GENERATED = "<!-- Written by scripts/update_readme.py from docs/data/*.json: do not edit by hand. -->"

#: The run's figures shown in docs/results.md, in order (keys of :func:`run_figures`).
RUN_FIGURES = ("force_b", "force_velocity_b", "residual_velocity_b", "force_second", "diagnose_hysteresis",
               "shake_table")

#: The studies docs/results.md shows, in order: name → (section title, what the study does).
STUDIES = {
    "damper-extension": (
        "What the best model of the measured damper still misses",
        "identifies `{model}` on the main job's part A, ranks every effect of the vocabulary that applies to it by "
        "`diagnose`'s own score, adds the passing ones best first (each kept only if it still passes as an "
        "extension of the model so far) and scores the base and the extended model on part B, which no fit saw "
        "(`studies/damper_extension.py`). `make run`'s diagnosis runs the same procedure through `diagnose "
        "--search ranked`, from the comparison's optimum."),
    "coverage": (
        "Coverage of the reported intervals",
        "simulates families of structure tests with noise on the measured input and on the outputs, and a family "
        "of device tests, fits each record with every engine under each residual model and counts how often the "
        "reported interval holds the true value (`studies/coverage.py`)."),
    "bayes-factor-rate": (
        "Bayes factors against the sampling rate",
        "measures, on simulated structure tests recorded at several rates, how the Bayes factor between two wrong "
        "forms moves with the rate: the working likelihood's grows with the number of samples, not with what the "
        "record holds; the calibrated one (`bayes_factors_calibrated`: the Laplace evidence of the likelihood "
        "raised to the power `evidence_scale` at which its curvature matches the calibrated covariance) should "
        "not (`studies/bayes_factor_rate.py`)."),
    "boucwen-benchmark": (
        "The Bouc–Wen benchmark",
        "fits the five forms to the packaged training record of the hysteretic benchmark (Noël & Schoukens 2016) "
        "with no mass given and no prior, selects by the calibrated evidence, lists `bouc-wen`'s parameters "
        "beside the benchmark's true values and scores a held-out multisine period after training on the "
        "periods before it (`studies/boucwen_benchmark.py`)."),
    "diagnosis-calibration": (
        "Diagnosis on records the package did not write",
        "writes clean and hidden-effect records with an independent simulator (`tests/reference_sim.py`: scipy's "
        "LSODA on the contract's equations) as a lab writes them — CSV with units in the headers, AR(1) output "
        "noise, noise on the measured input — reads them with `bm.load` (every noise floor estimated), "
        "calibrates `diagnose`'s threshold on one set of seeds and counts false alarms and detections on another "
        "it never saw (`studies/diagnosis_calibration.py`)."),
    "damper-matrix": (
        "A constant-current test matrix: joint fit, diagnosis, held-out conditions",
        "simulates a damper's test matrix (`{model}`: 3 amplitudes × 3 frequencies × 3 constant currents, 1 % "
        "force noise, the current held between samples), writes it as CSVs and a manifest, reads it back with "
        "`load_records`, fits the true model jointly over every test and counts how often its 90 % intervals "
        "hold the truth, diagnoses its tests at one frequency (every amplitude and current) from plain "
        "`{baseline}` and predicts each test by the true model fitted from scratch without its condition "
        "(`studies/damper_matrix.py`). The matrix of its first noise realisation ships with the package as "
        "`load_packaged(\"damper-matrix-sim\")`."),
}
#: What a study's ``--quick`` variant leaves out, said where the document shows a quick run.
QUICK = {"boucwen-benchmark": "least squares only and one held-out period; the full study adds emcee and the UKF "
                              "for every form",
         "diagnosis-calibration": "short records, spencer left out; the full study has 30 s at 1 kHz and every "
                                  "clean kind",
         "damper-matrix": "6 short tests, two noise realisations, two effects screened and one added; the full "
                          "study has the 27-test matrix"}


# --- the main job ------------------------------------------------------------------------------------------------

def run_figures(summary: dict) -> dict[str, str]:
    """Figures of the run the results show: key → path of the PNG the run wrote.

    The part-B force and the shake-table force of the main job, and the
    loops before/after of the diagnosis that named a cause (else of the
    first diagnosis that ran).
    """
    figs = dict(summary.get("figures", {}))
    diags = [d for d in (summary.get("diagnose") or {}).values() if "error" not in d]
    named = [d for d in diags if d["effects"]] or diags
    if named and named[0].get("figures", {}).get("hysteresis"):
        figs["diagnose_hysteresis"] = named[0]["figures"]["hysteresis"]
    return {k: figs[k] for k in RUN_FIGURES if k in figs}


def run_figure_name(src: str) -> str:
    """The name of a run's figure in docs/figures/."""
    return f"run_{Path(src).name}"


def run_section(summary: dict, links: dict[str, str] | None = None) -> str:
    """The main job's headline and figures.

    Parameters
    ----------
    summary : dict
        The run's ``summary.json``.
    links : dict, optional
        Figure key → link relative to the document; None: no figures.
    """
    lines = [f"- {s}" for s in headline(summary)]
    if links:
        lines.append("")
        for key in RUN_FIGURES:
            if key in links:
                lines += [f"![{key}]({links[key]})", ""]
    else:
        lines.append("")
    lines += [f"Written by `bayes-mr run` in {summary['wall_s'] / 60:.1f} min; data: "
              "[`data/run.json`](data/run.json), full report of that run: `results/report.md`."]
    return "\n".join(lines).rstrip() + "\n"


# --- the benchmark -----------------------------------------------------------------------------------------------

def _kernel_rows(r: dict) -> list[tuple[str, str]]:
    """Rows of the compiled-kernel figures (absent from bench files written before the kernels were timed)."""
    if "kernel_speedup" not in r:
        return []
    rows = []
    for form, v in r["simulate_ns_per_step"].items():
        if "inlined" in v:
            rows.append((f"simulate, {form}, structure test, per sample (generic → inlined → specialised kernel)",
                         f"{v['generic']:.0f} → {v['inlined']:.0f} → {v['specialised']:.0f} ns"))
        else:
            rows.append((f"simulate, {form}, structure test, per sample (generic → specialised kernel)",
                         f"{v['generic']:.0f} → {v['specialised']:.0f} ns"))
    for form, v in r.get("simulate_stiff_corners", {}).items():
        held, plain = (f"{v[f'{how}_{cap}']['ns_per_sample']:.0f}" for how, cap in (("held", 400), ("rk4", 400)))
        caps = sorted({int(k.split("_")[1]) for k in v if k.startswith("held_")})
        rows.append((f"simulate, {form}, the stiffest {v['timed']} of {v['draws']} prior draws, per sample, cap "
                     f"{caps[0]} → {caps[-1]} sub-steps: branch held ({v[f'held_{caps[0]}']['substeps_per_interval']:.2f}"
                     f" sub-steps per interval, {100 * v[f'held_{caps[-1]}']['share_at_cap']:.2g} % at the cap) / "
                     f"every interval integrated ({v[f'rk4_{caps[0]}']['substeps_per_interval']:.2f}, "
                     f"{100 * v[f'rk4_{caps[-1]}']['share_at_cap']:.2g} %)",
                     f"{held} → {v[f'held_{caps[-1]}']['ns_per_sample']:.0f} ns / "
                     f"{plain} → {v[f'rk4_{caps[-1]}']['ns_per_sample']:.0f} ns"))
    rows.append(("specialised kernel speedup, dahl structure step", f"{r['kernel_speedup']:.1f}×"))
    if "inlined_speedup" in r:
        rows.append(("inlined kernel speedup (any model, before its specialised kernel), dahl structure step",
                     f"{r['inlined_speedup']:.1f}×"))
    rows.append(("kernel compile, first run on a fresh machine / from the disk cache",
                 f"{r['compile_s']['cold']:.0f} s / {r['compile_s']['warm']:.1f} s"))
    return rows


def _adaptation(r: dict, key: str) -> str:
    """A bench chain's pilot and adaptation steps and its evaluations, where the bench file has them."""
    if f"{key}_pilot_steps" not in r:
        return ""
    return f"{r[f'{key}_evaluations']} evaluations in all ({r[f'{key}_pilot_steps']} pilot and adaptation steps), then "


def _chain_summary(r: dict, key: str) -> str:
    """τ_max and R-hat_max of a bench chain, or why it has none (a wall-time cap that fell in the adaptation leaves
    the chain proper too few steps to estimate either)."""
    tau, rhat = r.get(f"{key}_tau_max"), r.get(f"{key}_rhat_max")
    if tau is None or rhat is None:
        return f"τ and R-hat not estimable from {r[f'{key}_steps']} step(s) of the chain proper"
    return f"τ_max {tau:.0f}, R-hat_max {rhat:.3f}"


def _spencer_rows(r: dict) -> list[tuple[str, str]]:
    """Rows of ``bench --spencer`` (absent from bench files written without it)."""
    if "spencer_lsq_s" not in r:
        return []
    rows = []
    for key in ("spencer", "spencer_sine"):
        ex, fd = r[f"{key}_lsq"], r[f"{key}_lsq_fd"]
        rows.append((f"least squares, spencer, {r['spencer_records'][key]}: exact Jacobians ({ex['sensitivity_runs']} "
                     f"sensitivity runs, {ex['sims']} simulations) against finite differences ({fd['sims']} + "
                     f"{fd['sims_replayed']} simulations); {100 * fd['share_at_cap']:.1f} % of intervals at the "
                     f"sub-step cap, {fd['substeps_per_interval']:.1f} sub-steps per interval",
                     f"{r[f'{key}_lsq_s']:.0f} s against {r[f'{key}_lsq_fd_s']:.0f} s "
                     f"({r[f'{key}_lsq_speedup']:.1f}×)"))
        d = r[f"{key}_diagnose"]
        rows.append((f"diagnose, spencer baseline, {r['spencer_records'][key]}: cause named {d['cause']}",
                     f"{r[f'{key}_diagnose_s']:.0f} s"))
    rows.append((f"compare, five forms × lsq, {r['spencer_records']['spencer_sine']} (selected "
                 f"{r['spencer_compare']['selected']})", f"{r['spencer_compare_s']:.0f} s"))
    if "spencer_fresh_fit_s" in r:
        rows.append((f"a first `bayes-mr fit` on a machine that never ran the package ({r['spencer_fresh_fit_record']}): "
                     "empty kernel cache, then the same command again",
                     f"{r['spencer_fresh_fit_s']:.0f} s, then {r['spencer_warm_fit_s']:.0f} s (compile "
                     f"{r['spencer_compile_s']:.0f} s)"))
    return rows


def bench_section(r: dict) -> str:
    """The table of a benchmark run.

    Parameters
    ----------
    r : dict
        :func:`bayes_mr.bench.benchmark.run_bench` as written to its JSON (times in s and µs).
    """
    rel = r.get("train_best_rel_error", {})
    worst = max(rel.values()) if rel else float("nan")
    rows = [
        ("UKF, ours (a training's LHS priors at once, all cores), per run and sample filtered",
         f"{r['ukf_us_per_step']:.2f} µs"),
        ("UKF, ours (one run, one thread), per sample", f"{r['ukf_us_per_step_single']:.2f} µs"),
        ("filterpy UnscentedKalmanFilter, model in Python, per sample", f"{r['filterpy_us_per_step']:.0f} µs"),
        ("filterpy with our compiled model step, per sample", f"{r['filterpy_compiled_fx_us_per_step']:.0f} µs"),
        ("speedup (as used / like for like)", f"{r['speedup']:.0f}× / {r['speedup_single']:.0f}×"),
        ("largest state difference from filterpy", f"{r['max_state_diff']:.1e} standard deviations"),
        (f"thesis-size training (every LHS prior × dispersion), dahl, thesis signal I ({r['train_samples']} "
         "samples)", f"{r['train_100_priors_s']:.1f} s"),
        ("trained fraction", f"{100 * r['trained_fraction']:.0f} %"),
        ("best trained run, largest parameter error", f"{100 * worst:.2f} %"),
        (f"least squares, {r['mcmc_record']}", f"{r['lsq_s']:.1f} s"),
        (f"emcee posterior, {r['mcmc_record']}: {r['mcmc_steps']} steps × {r['mcmc_walkers']} walkers, "
         f"{_chain_summary(r, 'mcmc')}{'' if r['mcmc_converged'] else ' (NOT converged)'}", f"{r['mcmc_s']:.0f} s"),
        (f"diagnose, {r['diagnose_record']}: cause named {r['diagnose_cause']}, MSE ratio "
         f"{r['diagnose_mse_ratio']:.3f}", f"{r['diagnose_s']:.0f} s"),
    ]
    rows += _kernel_rows(r)
    if "boucwen_lsq_s" in r:
        verdict = ("converged" if r["boucwen_mcmc_converged"] else
                   f"NOT converged: stopped on its {STOP_REASONS.get(r.get('boucwen_mcmc_stopped'), 'budget')}"
                   f"{chain_shape(r.get('boucwen_mcmc_geometry'))}")
        rows += [(f"least squares, bouc-wen, {r['boucwen_record']}, {r['boucwen_input_interp']} inputs "
                  f"(estimate within {r['boucwen_lsq_max_z']:.2g} sd of the true values)",
                  f"{r['boucwen_lsq_s']:.0f} s"),
                 (f"emcee, same: {_adaptation(r, 'boucwen_mcmc')}{r['boucwen_mcmc_steps']} steps × "
                  f"{r['boucwen_mcmc_walkers']} walkers, {_chain_summary(r, 'boucwen_mcmc')}, mean within "
                  f"{r['boucwen_mcmc_max_z']:.2g} sd ({verdict})", f"{r['boucwen_mcmc_s']:.0f} s")]
    rows += _spencer_rows(r)
    if "compare_s" in r:
        where = f"{r['compare_workers']} workers" if r["compare_workers"] else "in process"
        rows.append((f"compare, {r['compare_record']}, TI evidence ({where}; selected {r['compare_selected']})",
                     f"{r['compare_s'] / 60:.1f} min"))
    lines = ["| measured | value |", "|---|---|"] + [f"| {a} | {b} |" for a, b in rows]
    lines.append("")
    lines.append(f"UKF model: {r['ukf_model']}; {r['threads']} threads.")
    return "\n".join(lines) + "\n"


# --- the studies -------------------------------------------------------------------------------------------------

def study_module(name: str):
    """``studies/NAME.py`` as a module (its ``markdown(summary)`` writes the study's report)."""
    path = ROOT / "studies" / (name.replace("-", "_") + ".py")
    spec = importlib.util.spec_from_file_location(f"bayes_mr_study_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def study_figure_name(name: str, link: str) -> str:
    """The name of a study's figure in docs/figures/."""
    return f"{name}_{Path(link).name}"


_IMAGE = re.compile(r"!\[([^\]]*)\]\(([^)]+)\)")


def study_section(name: str, summary: dict, figures: Path | None = None) -> str:
    """A study's section: what it does, the command that made the data, its report demoted one heading level.

    The report's figures link to ``figures/NAME_FILE.png`` beside the document;
    with ``figures`` (that folder) given, a figure not in it is left out.
    """
    title, what = STUDIES[name]
    report = study_module(name).markdown(summary).splitlines()
    if report and report[0].startswith("# "):
        report = report[1:]
    while report and not report[0].strip():
        report = report[1:]
    body = []
    for line in report:
        if line.startswith("#"):
            line = "#" + line
        images = []
        for alt, link in _IMAGE.findall(line):
            target = study_figure_name(name, link)
            if figures is None or (figures / target).is_file():
                images.append(f"![{alt}](figures/{target})")
        if _IMAGE.search(line):
            line = " ".join(images)
        body.append(line)
    quick = bool(summary.get("quick"))
    command = f"`bayes-mr study {name}{' --quick' if quick else ''}`"
    variant = (f" This is the study's quick variant ({QUICK.get(name, 'smaller than the full study')})."
               if quick else "")
    head = [f"## {title}", "", f"{command} {what.format(**summary)}{variant} Data: "
            f"[`data/{name}.json`](data/{name}.json).", ""]
    return "\n".join(head + body).rstrip() + "\n"


# --- the documents -----------------------------------------------------------------------------------------------

def _anchor(title: str) -> str:
    """GitHub's anchor of a heading."""
    return re.sub(r"[^\w\- ]", "", title.lower()).replace(" ", "-")


def results_document(data: Path, figures: Path) -> str:
    """docs/results.md from ``data`` (run.json and one NAME.json per study); figures linked if in ``figures``."""
    titles = ["The main job on the packaged damper record"] + [STUDIES[n][0] for n in STUDIES]
    lines = [GENERATED, "", "# Measured results", "",
             "Every number on this page is read from a JSON file under [`data/`](data/) by "
             "`scripts/update_readme.py`; the figures are those runs' own. Timings are on [a page of their "
             "own](performance.md); the fixed names (columns, models, verbs, JSON keys) are in "
             "[CONTRACT.md](CONTRACT.md).", ""]
    lines += [f"- [{t}](#{_anchor(t)})" for t in titles] + [""]
    lines += [f"## {titles[0]}", "",
              "`make run` (`bayes-mr run --out results`) takes the packaged MR-damper record through the thesis's "
              "procedure and beyond: it trims and decimates the record and splits it into part A, which the fits "
              "see, and part B, which none sees; fits every form by least squares and by the UKF and selects by "
              "the calibrated evidence; gives the emcee posteriors one shared pool of work (log-density evaluations "
              "priced in integrator steps, so the same posteriors on any machine; the wall clock only caps it), "
              "the selected form's first; refits the choice under the other residual model; diagnoses the selected model on "
              "part A (the MR-damper effects ranked and the passing ones added, then a search of the term library "
              "beyond them) and predicts part B with every model; and identifies the damper from a virtual shake "
              "table's displacement and acceleration alone.", ""]
    run = data / "run.json"
    if run.is_file():
        summary = json.loads(run.read_text())
        links = {k: f"figures/{run_figure_name(src)}" for k, src in run_figures(summary).items()
                 if (figures / run_figure_name(src)).is_file()}
        lines += [run_section(summary, links)]
    else:
        lines += ["Not measured yet: `make run` writes `data/run.json` and this section.", ""]
    for name in STUDIES:
        path = data / f"{name}.json"
        if path.is_file():
            lines += [study_section(name, json.loads(path.read_text()), figures)]
        else:
            lines += [f"## {STUDIES[name][0]}", "", f"Not measured yet: `bayes-mr study {name}`, then "
                      f"`python scripts/update_readme.py study {name}`.", ""]
    return "\n".join(lines).rstrip() + "\n"


def performance_document(data: Path) -> str:
    """docs/performance.md from ``data/bench.json`` (a page that says how to make it when there is none)."""
    lines = [GENERATED, "", "# Performance", "",
             "Measured by `bayes-mr bench` in one run; `make bench` runs it (meant for a quiet machine: other "
             "work on the cores slows every figure) and `scripts/update_readme.py bench` writes this page from its "
             "JSON ([`data/bench.json`](data/bench.json)). "
             "Absolute times move between machines and between hours on one; the ratios measured within one run "
             "(our UKF against filterpy's, the specialised kernel against the generic one) hold much better. "
             "What each figure times is in `bayes_mr/bench/benchmark.py` and the `bench` keys of "
             "[CONTRACT.md](CONTRACT.md#bench).", ""]
    bench = data / "bench.json"
    if bench.is_file():
        lines += [bench_section(json.loads(bench.read_text()))]
    else:
        lines += ["Not measured yet: `make bench` (on a quiet machine) writes `data/bench.json` and this page.", ""]
    return "\n".join(lines).rstrip() + "\n"


def documents(docs: Path = DOCS) -> dict[str, str]:
    """File name under ``docs`` → text of every generated document, from ``docs/data`` and ``docs/figures`` alone."""
    data, figures = docs / "data", docs / "figures"
    return {"results.md": results_document(data, figures), "performance.md": performance_document(data)}
