"""The README's measured sections, built from the JSON a run or a benchmark wrote.

The library never writes README.md: ``scripts/update_readme.py`` (called by
``make run`` and ``make bench``) reads ``results/summary.json`` or the
benchmark's JSON, builds the sections here (plain text; nothing here writes
a file) and puts each between ``<!-- NAME:start -->`` and ``<!-- NAME:end -->``,
so no number in the README is typed by hand.
"""

from __future__ import annotations

from pathlib import Path

from bayes_mr.run.headline import STOP_REASONS, chain_shape, headline

#: The run's figures shown in the README, in order (keys of :func:`readme_figures`).
RUN_FIGURES = ("force_b", "force_velocity_b", "residual_velocity_b", "force_second", "diagnose_hysteresis",
               "shake_table")


def readme_figures(summary: dict) -> dict[str, str]:
    """Figures of the run the README shows: key → path of the PNG the run wrote.

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


def run_section(summary: dict, out_dir: str | Path, links: dict[str, str] | None = None) -> str:
    """The README's run section: the headline and figures of a main-job run.

    Parameters
    ----------
    summary : dict
        The run's ``summary.json``.
    out_dir : path
        The run's output folder (named in the last line).
    links : dict, optional
        Figure key → link relative to the README (the copies beside it); None: no figures.
    """
    lines = [f"- {s}" for s in headline(summary)]
    if links is not None:
        lines.append("")
        for key in RUN_FIGURES:
            if key in links:
                lines += [f"![{key}]({links[key]})", ""]
    lines += ["", f"Written by `make run` in {summary['wall_s'] / 60:.1f} min on this project's 2-core machine; "
              f"full report: `{out_dir}/report.md`."]
    return "\n".join(lines)


def _kernel_rows(r: dict) -> list[tuple[str, str]]:
    """Rows of the compiled-kernel figures (absent from bench files written before issue 16)."""
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
    rows.append(("specialised kernel speedup, dahl structure step", f"{r['kernel_speedup']:.1f}×"))
    if "inlined_speedup" in r:
        rows.append(("inlined kernel speedup (any model, before its specialised kernel), dahl structure step",
                     f"{r['inlined_speedup']:.1f}×"))
    rows.append(("kernel compile, first run on a fresh machine / from the disk cache",
                 f"{r['compile_s']['cold']:.0f} s / {r['compile_s']['warm']:.1f} s"))
    return rows


def bench_section(r: dict) -> str:
    """The README's bench section: the table of a benchmark run.

    Parameters
    ----------
    r : dict
        :func:`bayes_mr.bench.benchmark.run_bench` as written to its JSON (times in s and µs).
    """
    rel = r.get("train_best_rel_error", {})
    worst = max(rel.values()) if rel else float("nan")
    rows = [
        ("UKF, ours (100 priors at once, all cores), per run and sample filtered", f"{r['ukf_us_per_step']:.2f} µs"),
        ("UKF, ours (one run, one thread), per sample", f"{r['ukf_us_per_step_single']:.2f} µs"),
        ("filterpy UnscentedKalmanFilter, model in Python, per sample", f"{r['filterpy_us_per_step']:.0f} µs"),
        ("filterpy with our compiled model step, per sample", f"{r['filterpy_compiled_fx_us_per_step']:.0f} µs"),
        ("speedup (as used / like for like)", f"{r['speedup']:.0f}× / {r['speedup_single']:.0f}×"),
        ("largest state difference from filterpy", f"{r['max_state_diff']:.1e} standard deviations"),
        (f"100-prior training, dahl, thesis signal I ({r['train_samples']} samples)", f"{r['train_100_priors_s']:.1f} s"),
        ("trained fraction (thesis: 32–42 %)", f"{100 * r['trained_fraction']:.0f} %"),
        ("best trained run, largest parameter error", f"{100 * worst:.2f} %"),
        (f"least squares, {r['mcmc_record']}", f"{r['lsq_s']:.1f} s"),
        (f"emcee posterior, {r['mcmc_record']}: {r['mcmc_steps']} steps × {r['mcmc_walkers']} walkers, "
         f"τ_max {r['mcmc_tau_max']:.0f}, R-hat_max {r['mcmc_rhat_max']:.3f}"
         f"{'' if r['mcmc_converged'] else ' (NOT converged)'}", f"{r['mcmc_s']:.0f} s"),
        (f"diagnose, {r['diagnose_record']}: cause named {r['diagnose_cause']}, MSE ratio "
         f"{r['diagnose_mse_ratio']:.3f}", f"{r['diagnose_s']:.0f} s"),
    ]
    rows += _kernel_rows(r)
    if "boucwen_lsq_s" in r:
        verdict = ("converged" if r["boucwen_mcmc_converged"] else
                   f"NOT converged: stopped on its {STOP_REASONS.get(r.get('boucwen_mcmc_stopped'), 'budget')}"
                   f"{chain_shape(r.get('boucwen_mcmc_geometry'))}")
        rows += [(f"least squares, bouc-wen, {r['boucwen_record']}, {r['boucwen_input_interp']} inputs "
                  f"(estimate within {r['boucwen_lsq_max_z']:.2g} sd of the true values)", f"{r['boucwen_lsq_s']:.0f} s"),
                 (f"emcee, same: {r['boucwen_mcmc_steps']} steps × {r['boucwen_mcmc_walkers']} walkers, τ_max "
                  f"{r['boucwen_mcmc_tau_max']:.0f}, R-hat_max {r['boucwen_mcmc_rhat_max']:.3f}, mean within "
                  f"{r['boucwen_mcmc_max_z']:.2g} sd ({verdict})", f"{r['boucwen_mcmc_s']:.0f} s")]
    if "compare_s" in r:
        where = f"{r['compare_workers']} workers" if r["compare_workers"] else "in process"
        rows.append((f"compare, {r['compare_record']}, TI evidence ({where}; selected {r['compare_selected']})",
                     f"{r['compare_s'] / 60:.1f} min"))
    lines = ["| measured | value |", "|---|---|"] + [f"| {a} | {b} |" for a, b in rows]
    lines.append("")
    lines.append(f"UKF model: {r['ukf_model']}; {r['threads']} threads. Written by `bayes-mr bench`.")
    return "\n".join(lines)
