# ---
# jupyter:
#   jupytext:
#     formats: py:percent
# ---
# %% [markdown]
# # Thesis Table 3.2 — classic Bouc–Wen identified by the UKF
#
# Sharma (2021) §3.5.2: m = 0.2, c = 0.3, k = 9, β₁ = 2, γ = 1, n = 2, driven by El Centro
# sampled at 50 Hz and scaled until the frame is hysteretic ("50 times the original signal"),
# 1 %, 2 % and 5 % RMS band-limited noise on input (process) and outputs (measurement).
# The thesis ran one filter; here the thesis's training (10 Latin-hypercube prior means ×
# 10 indices of dispersion) is run at each noise level and the run with the highest UKF
# evidence is reported, with the share of runs that completed.
#
# Run: `bayes-mr study table-3-2` (or `python studies/table_3_2.py`).

# %%
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd

from bayes_mr.report import figures
from bayes_mr.report.markdown import markdown_table
from bayes_mr.data.ground_motions import load_ground_motion
from bayes_mr.inference.ukf import filter as ukf
from bayes_mr.inference.ukf import kernel as K
from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.models import get_model
from bayes_mr.simulation.simulate import simulate, synthesize

TRUTH = {"c": 0.3, "k": 9.0, "beta1": 2.0, "gamma": 1.0, "n": 2.0}
MASS = 0.2
SCALE = 50.0
# Table 3.2 of the thesis: estimated values at 1 %, 2 %, 5 % noise
THESIS = {
    0.01: {"c": 0.3008, "k": 8.9979, "beta1": 2.0407, "gamma": 1.0423, "n": 2.0423},
    0.02: {"c": 0.3005, "k": 8.9942, "beta1": 2.0623, "gamma": 1.0418, "n": 2.0607},
    0.05: {"c": 0.2992, "k": 8.9831, "beta1": 2.0076, "gamma": 0.9461, "n": 2.0250},
}


def make_record(noise: float, seed: int):
    """El Centro × 50 at its own 50 Hz, through the Table 3.2 frame, with noise."""
    t, ag = load_ground_motion("elcentro")
    model = get_model("bouc-wen")
    return synthesize(model, model.theta("structure", TRUTH), t, {"ground_acceleration": SCALE * ag},
                      mass=MASS, noise=noise, seed=seed, source=f"El Centro ×{SCALE:g}, 50 Hz, {noise:.0%} noise")


def main(out_dir: str | Path = "results/studies/table-3-2", quick: bool = False, seed: int = 0) -> dict:
    """Run the study; write table (CSV, Markdown) and figures; return the summary."""
    out = Path(out_dir)
    fig_dir = out / "figures"
    model = get_model("bouc-wen")
    rows, summary = [], {}
    n_lhs, taus = (3, (0.01, 0.1, 1.0)) if quick else (10, ukf.TAUS)
    for noise in (0.01, 0.02, 0.05):
        rec = make_record(noise, seed)
        problem = ukf.make_problem(OutputError(model, rec))
        priors = ukf.lhs_priors(problem.coords, n_lhs=n_lhs, taus=taus, seed=seed)
        res = ukf.run_priors(problem, priors)
        ok = res["info"][:, K.I_STATUS] == K.OK
        best = int(np.argmax(np.where(ok, res["info"][:, K.I_LOGLIK], -np.inf)))
        ns = len(problem.p0_states)
        est = dict(zip(problem.coords.names, problem.coords.to_theta(res["mean"][best, ns:])))
        for name, exact in TRUTH.items():
            rows.append({
                "noise": f"{noise:.0%}", "parameter": name, "exact": exact,
                "estimated": est[name], "error_%": 100 * abs(est[name] / exact - 1),
                "thesis_estimated": THESIS[noise][name],
                "thesis_error_%": 100 * abs(THESIS[noise][name] / exact - 1),
            })
        summary[f"{noise:.0%}"] = {
            "max_error_%": max(100 * abs(est[n] / TRUTH[n] - 1) for n in TRUTH),
            "completed": int(ok.sum()), "runs": len(priors), "wall_s": res["wall_s"],
        }
        if noise == 0.01:
            _figures(fig_dir, model, rec, problem, priors[best], res, ok, est)
    table = pd.DataFrame(rows)
    out.mkdir(parents=True, exist_ok=True)
    table.to_csv(out / "table_3_2.csv", index=False)
    lines = ["# Thesis Table 3.2 — classic Bouc–Wen, UKF", "",
             f"{n_lhs} × {len(taus)} priors per noise level; best run by UKF evidence.", "",
             markdown_table(table), "",
             "| noise | largest error | completed runs | wall time |", "|---|---|---|---|"]
    for k, v in summary.items():
        lines.append(f"| {k} | {v['max_error_%']:.2f} % | {v['completed']}/{v['runs']} | {v['wall_s']:.1f} s |")
    lines += ["", "![states](figures/states.png) ![loop](figures/hysteresis.png)",
              "![convergence](figures/convergence.png) ![trained](figures/trained.png)"]
    (out / "table_3_2.md").write_text("\n".join(lines) + "\n")
    return {"table": str(out / "table_3_2.md"), **summary}


def _figures(fig_dir, model, rec, problem, prior, res, ok, est):
    """States, hysteresis loop, convergence and distributions of trained models (1 % noise)."""
    run = ukf.filter_states(problem, prior)
    t = rec["time"].values
    ns = len(problem.p0_states)
    states = run["states"]
    theta = model.theta("structure", TRUTH)
    truth_sim = simulate(model, problem.inputs, theta)
    figures.save(figures.time_series(t, {
        "x": {"simulated (truth)": truth_sim["displacement"], "UKF": states[:, 0]},
        "ẋ": {"simulated (truth)": truth_sim["velocity"], "UKF": states[:, 1]},
        "ẍ + ẍ_g": {"measured": rec["acceleration"].values,
                    "identified model": simulate(model, problem.inputs, model.theta("structure", est))["acceleration"]},
    }, title="Classic Bouc–Wen, 1 % noise: state estimates"), fig_dir / "states.png")
    figures.save(figures.hysteresis(truth_sim["displacement"], {
        "truth k·r": truth_sim["force"], "UKF k·r": est["k"] * states[:, 2]},
        title="Hysteretic force k·r", xlabel="x [-]", scale_x=1.0), fig_dir / "hysteresis.png")
    best = int(np.argmax(np.where(ok, res["info"][:, K.I_LOGLIK], -np.inf)))
    th_hist = problem.coords.to_theta(res["hist_mean"][best][:, ns:])
    th_t = res["hist_index"] * problem.inputs.dt
    figures.save(figures.convergence(th_t, dict(zip(problem.coords.names, th_hist.T)), TRUTH,
                                    title="Parameter convergence (best run)"), fig_dir / "convergence.png")
    final = problem.coords.to_theta(res["mean"][ok][:, ns:])
    figures.save(figures.distributions(dict(zip(problem.coords.names, final.T)), TRUTH,
                                      title="Trained models"), fig_dir / "trained.png")


if __name__ == "__main__":
    print(main(quick="--quick" in sys.argv))
