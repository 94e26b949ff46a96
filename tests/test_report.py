"""The reporting layer: no global matplotlib state touched; docs/ sections built from JSON by the script."""

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

from docs_sections import bench_section, run_section  # noqa: E402


def test_importing_and_drawing_leave_matplotlib_alone():
    """A notebook's backend and pyplot's figure list are the same after the package drew and saved a figure."""
    code = """
import matplotlib
matplotlib.use("svg")
import bayes_mr.cli.commands, bayes_mr.run.job, bayes_mr.bench.benchmark, bayes_mr.diagnosis.diagnose
from bayes_mr.diagnosis import report as diagnose
from bayes_mr.report import figures
from bayes_mr.run import report as run
import numpy as np, sys, tempfile, pathlib
sys.path.insert(0, "scripts")
import docs_sections
t = np.linspace(0, 1, 50)
figures.save(figures.time_series(t, {"x": {"a": t}}), pathlib.Path(tempfile.mkdtemp()) / "f.png")
import matplotlib.pyplot as plt
assert matplotlib.get_backend() == "svg", matplotlib.get_backend()
assert plt.get_fignums() == [], plt.get_fignums()
"""
    env = {k: v for k, v in os.environ.items() if k != "MPLBACKEND"}
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT, env={**env, "PYTHONPATH": str(ROOT)})


def _script():
    spec = importlib.util.spec_from_file_location("update_readme", ROOT / "scripts" / "update_readme.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


BENCH = {"ukf_model": "dahl (structure test, 7 augmented states, thesis signal I)", "ukf_us_per_step": 6.47,
         "ukf_us_per_step_single": 11.31, "filterpy_us_per_step": 1219.0, "filterpy_compiled_fx_us_per_step": 784.0,
         "speedup": 188.4, "speedup_single": 107.8, "max_state_diff": 1.8e-11, "filterpy_steps_compared": 1500,
         "threads": 2, "train_100_priors_s": 84.8, "trained_fraction": 1.0, "train_samples": 163840,
         "train_best_rel_error": {"c": 0.0011, "k": 0.0002}, "lsq_s": 4.3, "mcmc_s": 254.0, "mcmc_steps": 3000,
         "mcmc_walkers": 24, "mcmc_converged": True, "mcmc_tau_max": 24.0, "mcmc_rhat_max": 1.008,
         "mcmc_record": "dahl, 25 s at 1000 Hz", "diagnose_s": 50.0, "diagnose_cause": "force_offset",
         "diagnose_mse_ratio": 0.007, "diagnose_record": "dahl + 2 N force offset hidden, 30 s at 1000 Hz"}


def test_bench_json_becomes_the_performance_page(tmp_path):
    """A bench file written before the kernel, Bouc–Wen and compare figures still makes a page."""
    docs = tmp_path / "docs"
    bench = tmp_path / "bench.json"
    bench.write_text(json.dumps(BENCH))
    assert _script().main(["bench", "--json", str(bench), "--docs", str(docs)]) == 0
    text = (docs / "performance.md").read_text()
    assert "| speedup (as used / like for like) | 188× / 108× |" in text
    assert bench_section(BENCH) in text and json.loads((docs / "data" / "bench.json").read_text()) == BENCH


def _summary(out: Path) -> dict:
    (out / "force_part_b.png").write_bytes(b"png")
    return {
        "record": {"source": "nees", "duration_s": 21.6, "fs": 250.0, "decimation": 12, "masked": 0,
                   "part_a_s": 13.0, "part_b_s": 8.6},
        "rows": [{"model": "dahl", "engine": "lsq", "force_nrmse": 0.2, "validation": {"force_nrmse": 0.25}}],
        "selected": "dahl", "bayes_factors": {"dahl": 0.0}, "evidence_route": "laplace",
        "best_on_part_b": {"model": "dahl", "engine": "lsq", "force_nrmse": 0.25},
        "spencer_1997": {"part_b": {"force_nrmse": 0.3}}, "diagnose": {}, "shake_table": None,
        "figures": {"force_b": str(out / "force_part_b.png"), "shake_table": str(out / "missing.png")},
        "wall_s": 738.0, "full_job": True,
    }


def test_run_section_from_the_summary_json(tmp_path):
    out = tmp_path / "results"
    out.mkdir()
    summary = _summary(out)
    (out / "summary.json").write_text(json.dumps(summary))
    docs = tmp_path / "docs"
    assert _script().main(["run", "--out", str(out), "--docs", str(docs)]) == 0
    assert (docs / "figures" / "run_force_part_b.png").read_bytes() == b"png"
    text = (docs / "results.md").read_text()
    assert run_section(summary, {"force_b": "figures/run_force_part_b.png"}) in text
    assert "Selected by laplace evidence: **dahl**." in text and "in 12.3 min" in text
    assert "shake_table" not in text  # its PNG does not exist: no broken link


def test_a_quick_run_leaves_docs_alone(tmp_path):
    out = tmp_path / "results"
    out.mkdir()
    (out / "summary.json").write_text(json.dumps({**_summary(out), "full_job": False}))
    docs = tmp_path / "docs"
    _script().main(["run", "--out", str(out), "--docs", str(docs)])
    assert not docs.exists()


def test_study_section_renders_its_summary_json(tmp_path):
    out = tmp_path / "results" / "studies" / "damper-extension"
    out.mkdir(parents=True)
    step = {"effect": "inertia", "kept": True, "score": 1139.0, "force_nrmse_a": 0.1226, "force_nrmse_b": 0.1278}
    summary = {"quick": False, "model": "spencer", "wall_s": 63.0,
               "record": {"source": "nees-ranran-50", "part_a_s": 13.0, "part_b_s": 8.6, "fs": 1001.6},
               "extension": {"base": {"model": "spencer", "force_nrmse_a": 0.1768, "force_nrmse_b": 0.1767},
                             "steps": [step], "added": ["inertia"], "unexplained_ratio_b": 79.5,
                             "extended": {"model": "spencer+inertia", "force_nrmse_a": 0.1226,
                                          "force_nrmse_b": 0.1278}}}
    (out / "summary.json").write_text(json.dumps(summary))
    (out / "extension_part_b.png").write_bytes(b"png")
    docs = tmp_path / "docs"
    assert _script().main(["study", "damper-extension", "--out", str(out), "--docs", str(docs)]) == 0
    text = (docs / "results.md").read_text()
    assert "Added: inertia." in text and "# Extending" not in text and "identifies `spencer`" in text
    assert "| **spencer+inertia** | | | 0.1226 | **0.1278** |" in text
    assert "![part B](figures/damper-extension_extension_part_b.png)" in text
    assert (docs / "figures" / "damper-extension_extension_part_b.png").read_bytes() == b"png"


def test_the_headline_says_which_posterior_did_not_converge_and_why():
    """Each unconverged chain with its length in τ and its R-hat; forms without a posterior
    named, the selected one first."""
    from bayes_mr.run.headline import _posterior_lines

    rows = [{"engine": "mcmc", "model": "dahl", "n_steps": 3250, "tau_max": 24.0, "rhat_max": 1.008,
             "converged": True, "stopped": "converged"},
            {"engine": "mcmc", "model": "lugre", "n_steps": 1000, "tau_max": 25.0, "rhat_max": 1.04,
             "converged": False, "stopped": "max_steps"},
            {"engine": "lsq", "model": "spencer"}]
    skipped = {"normalized-bouc-wen": "6 free parameters", "spencer": "13 free parameters"}
    chains, none = _posterior_lines(rows, "spencer", skipped)
    assert "lugre (step limit: 1000 steps = 40 τ, R-hat 1.0400) NOT converged" in chains and "dahl (" not in chains
    assert none == ("No emcee posterior for spencer (the selected model): 13 free parameters; "
                    "normalized-bouc-wen: 6 free parameters.")
    assert _posterior_lines(rows[:1], "dahl", {}) == [
        "emcee posteriors for dahl (3250 steps; R-hat_max 1.0080): converged (≥ 50 τ, R-hat < 1.01)."]
    # the work each posterior stands on, where the rows carry it
    assert _posterior_lines([dict(rows[0], evaluations=32000)], "dahl", {}) == [
        "emcee posteriors for dahl (3250 steps; 32000 log-density evaluations with their pilots; R-hat_max 1.0080): "
        "converged (≥ 50 τ, R-hat < 1.01)."]
    projected = {"engine": "mcmc", "model": "spencer", "n_steps": 300, "tau_max": 25.0, "rhat_max": 1.7,
                 "converged": False, "stopped": "projected",
                 "projection": {"tau_max": 25.0, "steps_needed": 1375, "steps_allowed": 400,
                                "evaluations_needed": 11000, "evaluations_allowed": 3200}}
    chains, = _posterior_lines([projected], "spencer", {})
    assert ("spencer (stopped when its integrated time (25 steps, a lower bound from a chain this short) projected "
            "the rule to at least ~1375 steps (11000 log-density evaluations) against the 400 (3200) its work "
            "budget left: 300 steps = 12 τ, R-hat 1.7000) NOT converged") in chains
    # a chain just over the rule reads as over it (1.0109 is not "1.01"), and a long one in whole τ
    spent = dict(projected, n_steps=1326, tau_max=12.0, rhat_max=1.0109, stopped="max_evaluations", projection=None,
                 evaluations=56000)
    chains, = _posterior_lines([spent], "spencer", {})
    assert ("spencer (its work budget ran out (56000 log-density evaluations): 1326 steps = 110 τ, R-hat 1.0109) "
            "NOT converged") in chains
    # the wall-time cap is a machine limit, not a result of the work budget: the main job's own sentence for it,
    # else the cap the row ran under
    timed_out = dict(spent, stopped="max_seconds", wall_cap_s=312.4)
    chains, = _posterior_lines([timed_out], "spencer", {})
    assert "spencer (stopped by the wall-time cap of 312 s: a machine limit, not a result: 1326 steps" in chains
    work = {"spencer": {"machine_limit": "stopped by the wall-time cap of 312 s (what the posteriors' 1800 s cap left "
                                         "it): a machine limit, not a result"}}
    chains, = _posterior_lines([timed_out], "spencer", {}, work)
    assert "spencer (stopped by the wall-time cap of 312 s (what the posteriors' 1800 s cap left it)" in chains
    # a chain of independent walkers that met the rule on a proposal with heavy-tailed weights
    tails = dict(timed_out, n_steps=800, tau_max=9.0, rhat_max=1.008, stopped="q_tails", pareto_k=1.3)
    chains, = _posterior_lines([tails], "spencer", {})
    assert ("spencer (met the rule, but its proposals' importance weights have a Pareto k̂ of 1.3: the fitted "
            "proposal underweights part of the posterior, so τ and R-hat do not bound its error: 800 steps = 89 τ, "
            "R-hat 1.0080) NOT converged") in chains


def test_an_unconverged_headline_names_the_shape_that_makes_the_chain_slow():
    """A chain the budget stopped says which coordinates spread over their prior and which lie on a ridge
    (``geometry``, from :func:`bayes_mr.inference.mcmc.geometry.chain_geometry`); a converged one says nothing more."""
    from bayes_mr.run.headline import _posterior_lines

    geometry = {"slowest": [["k1", 9.2]], "spread_over_prior": {"k1": 0.973, "k0": 0.94},
                "ridges": [["gamma", "n", 0.9965]]}
    row = {"engine": "mcmc", "model": "spencer", "n_steps": 200, "tau_max": 9.2, "rhat_max": 1.16,
           "converged": False, "stopped": "max_steps", "geometry": geometry}
    chains, = _posterior_lines([row], "spencer", {})
    assert ("R-hat 1.1600; k1, k0 spread over 97, 94 % of their prior ranges (the record hardly informs them); "
            "gamma and n on a ridge (correlation +0.997: the record fixes a combination of them)) NOT converged"
            ) in chains
    one = dict(row, geometry={"spread_over_prior": {}, "ridges": [["beta1", "gamma", -0.99999]]})
    assert "R-hat 1.1600; beta1 and gamma on a ridge (correlation -1.000" in _posterior_lines([one], "x", {})[0]
    plain = dict(row, geometry={"slowest": [["k1", 9.2]], "spread_over_prior": {}, "ridges": []})
    assert "R-hat 1.1600) NOT converged" in _posterior_lines([plain], "x", {})[0]
    converged = dict(row, converged=True, stopped="converged")
    assert "spread" not in _posterior_lines([converged], "x", {})[0]


def test_the_report_states_each_posterior_s_work_and_a_cap_that_acted():
    """report.md's account of the pool: per form the evaluations, their price and what the pool was charged, with the
    wall time beside it; a form the wall-time cap stopped carries its machine-limit sentence."""
    from bayes_mr.run.report import work_lines

    work = {"spencer": {"evaluations": 38400, "steps_per_evaluation": 66100, "integrator_steps": 38400 * 66100,
                        "pool_left": 5e9, "wall_s": 610.2, "wall_cap_s": 1800.0, "machine_limit": None},
            "dahl": {"evaluations": 0, "steps_per_evaluation": None, "integrator_steps": 0, "pool_left": 2.4e9,
                     "wall_s": 0.0, "wall_cap_s": 0.0, "machine_limit": "not run: the cap … a machine limit"},
            "lugre": {"evaluations": 900, "steps_per_evaluation": 18900, "integrator_steps": 900 * 18900,
                      "pool_left": 2.4e9, "wall_s": 12.0, "wall_cap_s": 3.0,
                      "machine_limit": "stopped by the wall-time cap of 3 s: a machine limit, not a result"}}
    lines = work_lines({"posterior_work": work, "budget": {"mcmc_pool": 5e9, "mcmc_pool_cap_s": 1800.0}})
    assert lines[1] == ("Posteriors' work (a pool of 5e+09 integrator steps, 2.56e+09 spent; wall-time cap 1800 s, "
                        "622 s used):")
    assert "- spencer: 38400 log-density evaluations × 66100 integrator steps = 2.54e+09, 610 s." in lines
    assert "- dahl: no evaluation, 0 s; not run: the cap … a machine limit." in lines
    assert ("- lugre: 900 log-density evaluations × 18900 integrator steps = 1.7e+07, 12 s; stopped by the wall-time "
            "cap of 3 s: a machine limit, not a result.") in lines
    assert work_lines({"budget": {}}) == []  # a run without posteriors (or written before the pool was counted)
    quick = work_lines({"posterior_work": {"lugre": work["lugre"]}, "budget": {"mcmc_pool": None}})
    assert quick[1] == "Posteriors' work (no pool, 1.7e+07 integrator steps spent; no wall-time cap, 12 s used):"
