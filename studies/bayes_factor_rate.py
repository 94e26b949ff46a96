# ---
# jupyter:
#   jupytext:
#     formats: py:percent
# ---
# %% [markdown]
# # Bayes factors against the sampling rate
#
# The working likelihood (iid, or AR by BIC per channel) counts every sample as new information. Under
# model error the residual is smooth in time, so between two *wrong* forms ln BF ≈ (N/2)·ln(SSR ratio)
# grows with the sampling rate at a fixed record length, not with what the record holds. This study
# measures it, and the magnitude-adjusted (calibrated) evidence of `bayes_mr.inference.lsq.evidence_scale`
# beside it, through `compare` itself (least squares, Laplace route).
#
# * **Hidden effect, no true candidate.** Simulated structure tests (50 kg frame, 3 s) of Dahl with a
#   hidden effect of the vocabulary — `asymmetry` (asym = 0.3) or `stiffness_drift` (0.1 /s) — its base
#   parameters drawn log-normally (20 %) about the thesis's values; two signals (El Centro at 50 %, an
#   up–down frequency sweep), each with its own truth draw and noise seed; 2 % RMS noise on the
#   measured input and on both outputs, per sample;
#   recorded at 250 Hz, 1 kHz and 4 kHz (same truth, signal, duration and noise seed). Candidates `dahl`
#   and `normalized-bouc-wen`, both wrong. ln BF = ln Z(dahl) − ln Z(normalized-bouc-wen), raw and
#   calibrated, under `--noise iid` and `ar`.
# * **A true candidate.** Truths of `dahl` and `normalized-bouc-wen` (same draws), the same two
#   candidates, at 250 Hz and 1 kHz: how often the true form is selected by each evidence.
#
# Run: `bayes-mr study bayes-factor-rate` (`--quick`: one truth, 2 s, 250 Hz and 1 kHz).

# %%
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from bayes_mr.inference.results import write_json
from bayes_mr.selection.comparison import compare
from bayes_mr.models import get_model
from bayes_mr.report import figures
from bayes_mr.report.markdown import markdown_table
from bayes_mr.signals import make_signal
from bayes_mr.simulation.simulate import synthesize

MASS, NOISE, DURATION = 50.0, 0.02, 3.0
RATES = (250.0, 1000.0, 4000.0)
TRUE_RATES = (250.0, 1000.0)
#: Centres of the truths' base forms (thesis §3.8; Table 3.5), spread log-normally by TRUTH_SPREAD.
CENTRES = {
    "dahl": {"c": 100.0, "k": 2.0e4, "F_d": 25.0, "sigma": 2500.0},
    "normalized-bouc-wen": {"c": 100.0, "k": 2.0e4, "k_z": 24.5, "rho": 2500.0, "n": 1.05, "sigma": 1.0},
}
TRUTH_SPREAD = 0.2
#: Hidden effects (no candidate has them) and their values.
HIDDEN = {"dahl+asymmetry": {"asym": 0.3}, "dahl+stiffness_drift": {"drift": 0.1}}
CANDIDATES = ("dahl", "normalized-bouc-wen")
SIGNALS = ("elcentro", "freq-sweep-up-down")
RESIDUALS = ("iid", "ar")
#: Truths per candidate form in the true-candidate family (signals alternate).
PER_FORM = 6
#: Truth draws (and noise seeds) per hidden effect × signal.
HIDDEN_SEEDS = 2
#: A hidden-effect record's seed is its seed + SIGNAL_STRIDE × its signal's index.
SIGNAL_STRIDE = 10


def signal(name: str, fs: float, duration: float):
    """The same excitation at any rate (both signals are deterministic: El Centro resampled, a sweep)."""
    if name == "elcentro":
        return make_signal("elcentro", scale=0.5, fs=fs, duration=duration)
    return make_signal("freq-sweep-up-down", amplitude=1.5e-3, fmax=8.0, duration=duration, fs=fs)


def truth(form: str, seed: int, extra: dict | None = None) -> dict:
    """Base-form parameters drawn about :data:`CENTRES` (seeded), plus the hidden effect's ``extra``."""
    base = form.split("+")[0]
    rng = np.random.default_rng([seed, sum(map(ord, base))])
    theta = {k: v * float(np.exp(TRUTH_SPREAD * rng.standard_normal())) for k, v in CENTRES[base].items()}
    return {**theta, **(extra or {})}


def record(form: str, theta: dict, sig_name: str, fs: float, seed: int, duration: float):
    """A structure test of ``form`` at ``theta``, recorded at ``fs`` (noise seeded by ``seed`` alone)."""
    model = get_model(form)
    sig = signal(sig_name, fs, duration)
    return synthesize(model, model.theta("structure", theta), sig.time, sig.as_input("structure"), mass=MASS,
                      noise=NOISE, seed=seed, source=f"bf-rate {form} {sig_name} {fs:g} Hz seed {seed}")


def compare_row(rec, residual: str, seed: int, executor=None) -> dict:
    """`compare` of the two candidates by least squares; ln BF(dahl : normalized-bouc-wen), raw and calibrated."""
    out = compare(rec, CANDIDATES, engines=("lsq",), seed=seed, progress=False, noise=residual, executor=executor)
    a, b = CANDIDATES
    rows = {r["model"]: r for r in out.rows}
    raw = out.bayes_factors[b] - out.bayes_factors[a]  # ln Z(a) − ln Z(b)
    cal = out.bayes_factors_calibrated[b] - out.bayes_factors_calibrated[a]
    return {"residual": residual, "ln_bf": raw, "ln_bf_calibrated": cal, "k_common": out.data["evidence_scale"],
            "selected": out.selected, "selected_calibrated": out.data["selected_calibrated"],
            **{f"k_{m}": rows[m]["evidence_scale"] for m in CANDIDATES},
            **{f"noise_model_{m}": rows[m]["noise_model"] for m in CANDIDATES},
            "n": int(rec.sizes["time"]), "n_eff_acc": rows[a]["n_eff"].get("acceleration"),
            "mse_ratio": rows[a]["mse"] / rows[b]["mse"]}


def hidden_rows(seeds, rates, duration: float, hidden: dict = HIDDEN, signals=SIGNALS, executor=None,
                say=print) -> pd.DataFrame:
    """Every hidden-effect truth × signal × seed × rate × residual model (module header)."""
    rows = []
    for form, extra in hidden.items():
        for i, sig_name in enumerate(signals):
            for s in seeds:
                seed = s + SIGNAL_STRIDE * i  # each signal its own truth draw and noise
                theta = truth(form, seed, extra)
                for fs in rates:
                    rec = record(form, theta, sig_name, fs, seed, duration)
                    for residual in RESIDUALS:
                        r = {"truth": form, "signal": sig_name, "seed": seed, "fs": fs,
                             **compare_row(rec, residual, seed, executor)}
                        rows.append(r)
                        say(f"{form} {sig_name} seed {seed} {fs:g} Hz {residual}: ln BF {r['ln_bf']:.4g} raw, "
                            f"{r['ln_bf_calibrated']:.4g} calibrated (k {r['k_common']:.3g})")
    return pd.DataFrame(rows)


def true_rows(seeds, rates, duration: float, executor=None, say=print) -> pd.DataFrame:
    """Truths of each candidate form × seed × rate × residual: which form each evidence selects."""
    rows = []
    for form in CANDIDATES:
        for seed in seeds:
            sig_name = SIGNALS[seed % len(SIGNALS)]
            theta = truth(form, seed)
            for fs in rates:
                rec = record(form, theta, sig_name, fs, seed, duration)
                for residual in RESIDUALS:
                    r = {"truth": form, "signal": sig_name, "seed": seed, "fs": fs,
                         **compare_row(rec, residual, seed, executor)}
                    r["true_raw"], r["true_calibrated"] = r["selected"] == form, r["selected_calibrated"] == form
                    rows.append(r)
                    say(f"true {form} seed {seed} {fs:g} Hz {residual}: raw picks {r['selected']}, "
                        f"calibrated {r['selected_calibrated']}")
    return pd.DataFrame(rows)


def growth_table(rows: pd.DataFrame) -> pd.DataFrame:
    """Median |ln BF| per truth × residual × rate, raw and calibrated, and the ratio to the lowest rate."""
    rows = rows.assign(abs_raw=rows["ln_bf"].abs(), abs_cal=rows["ln_bf_calibrated"].abs())
    t = rows.groupby(["truth", "residual", "fs"], as_index=False).agg(
        records=("ln_bf", "size"), median_abs_ln_bf=("abs_raw", "median"),
        median_abs_ln_bf_calibrated=("abs_cal", "median"), median_k=("k_common", "median"))
    low = t.groupby(["truth", "residual"])[["median_abs_ln_bf", "median_abs_ln_bf_calibrated"]].transform("first")
    t["raw_vs_lowest_rate"] = t["median_abs_ln_bf"] / low["median_abs_ln_bf"]
    t["calibrated_vs_lowest_rate"] = t["median_abs_ln_bf_calibrated"] / low["median_abs_ln_bf_calibrated"]
    return t


def ratio_table(rows: pd.DataFrame) -> pd.DataFrame:
    """Per record (truth, signal, seed, residual): |ln BF| at the top rate over that at the lowest (raw, calibrated)."""
    lo, hi = rows["fs"].min(), rows["fs"].max()
    key = ["truth", "signal", "seed", "residual"]
    a = rows[rows["fs"] == lo].set_index(key)
    b = rows[rows["fs"] == hi].set_index(key)
    out = pd.DataFrame({"raw": (b["ln_bf"].abs() / a["ln_bf"].abs()),
                        "calibrated": (b["ln_bf_calibrated"].abs() / a["ln_bf_calibrated"].abs()),
                        "sign_kept_raw": np.sign(a["ln_bf"]) == np.sign(b["ln_bf"]),
                        "sign_kept_calibrated": np.sign(a["ln_bf_calibrated"]) == np.sign(b["ln_bf_calibrated"])})
    return out.reset_index()


def selection_table(rows: pd.DataFrame) -> pd.DataFrame:
    """Share of records whose true form is selected, per residual × rate, raw and calibrated."""
    return rows.groupby(["residual", "fs"], as_index=False).agg(
        records=("true_raw", "size"), true_selected_raw=("true_raw", "mean"),
        true_selected_calibrated=("true_calibrated", "mean"))


def main(out_dir: str | Path = "results/studies/bayes-factor-rate", quick: bool = False, seed: int = 0,
         executor=None) -> dict:
    """Run the study (``executor``: `--workers N` fits each comparison's candidates in parallel, same numbers)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    duration = 2.0 if quick else DURATION
    seeds = [seed] if quick else [seed + i for i in range(HIDDEN_SEEDS)]
    rates = TRUE_RATES if quick else RATES
    # the quick run: the first hidden effect and the first signal only
    hidden = hidden_rows(seeds, rates, duration, *((dict(list(HIDDEN.items())[:1]), SIGNALS[:1]) if quick else ()),
                         executor=executor)
    true = true_rows([seed] if quick else [seed + i for i in range(PER_FORM)], TRUE_RATES, duration, executor)
    hidden.to_csv(out / "hidden_rows.csv", index=False)
    true.to_csv(out / "true_rows.csv", index=False)
    return report(out, hidden, true, time.perf_counter() - t0, seed=seed, seeds=seeds, duration=duration,
                  quick=quick)


def report(out: Path, hidden: pd.DataFrame, true: pd.DataFrame, wall: float, *, seed: int, seeds,
           duration: float, quick: bool = False) -> dict:
    """``summary.json``, ``report.md`` and its figure from the rows (also to rebuild them from the CSVs)."""
    rates = sorted(hidden["fs"].unique())
    growth, ratios, sel = growth_table(hidden), ratio_table(hidden), selection_table(true)
    _figure(hidden, out / "ln_bf_vs_rate.png")  # beside report.md: scripts/update_readme.py study copies it
    per_res = ratios.groupby("residual")[["raw", "calibrated"]].median()
    summary = {"quick": quick, "wall_s": wall, "rates_hz": list(rates), "duration_s": duration, "noise": NOISE,
               "seed": seed, "seeds": list(seeds), "signal_stride": SIGNAL_STRIDE,
               "true_seeds": sorted(true["seed"].unique().tolist()),
               "growth": growth.to_dict(orient="records"),
               "ratio_top_over_lowest": ratios.to_dict(orient="records"),
               "median_ratio": per_res.to_dict(orient="index"), "true_selection": sel.to_dict(orient="records")}
    # report.md is built from the JSON as written, so it shows nothing the JSON does not hold
    summary = json.loads(write_json(summary, out / "summary.json").read_text())
    (out / "report.md").write_text(markdown(summary))
    return {"report": str(out / "report.md"), **summary}


def markdown(summary: dict) -> str:
    """``report.md`` from the study's ``summary.json`` (every number in it is a field of that JSON)."""
    rates, per_res, true_seeds = summary["rates_hz"], summary["median_ratio"], summary["true_seeds"]
    lines = ["# Bayes factors against the sampling rate", "",
             f"Least squares (Laplace route) through `compare`; structure tests of {summary['duration_s']:g} s, "
             f"{100 * summary['noise']:g} % RMS noise per sample on the input and both outputs, recorded at "
             f"{', '.join(f'{r:g}' for r in rates)} Hz; hidden-effect records: seeds {summary['seeds']} + "
             f"{summary['signal_stride']} × signal index (truth draw and noise); true-candidate records: seeds "
             f"{true_seeds[0]}…{true_seeds[-1]} per form. Wall time {summary['wall_s'] / 60:.1f} min.", "",
             "### No true candidate (a hidden effect): ln Z(dahl) − ln Z(normalized-bouc-wen)", "",
             markdown_table(pd.DataFrame(summary["growth"])), "",
             f"Per record, |ln BF| at {max(rates):g} Hz over |ln BF| at {min(rates):g} Hz (median): " +
             "; ".join(f"{res}: raw ×{v['raw']:.3g}, calibrated ×{v['calibrated']:.3g}" for res, v in per_res.items())
             + ".", "",
             markdown_table(pd.DataFrame(summary["ratio_top_over_lowest"])), "",
             "![ln BF against the rate](ln_bf_vs_rate.png)", "",
             "### A true candidate: share of records whose true form is selected", "",
             markdown_table(pd.DataFrame(summary["true_selection"])), ""]
    return "\n".join(lines) + "\n"


def _figure(rows: pd.DataFrame, path: Path) -> None:
    """|ln BF| against the rate, per record: raw (solid) and calibrated (dashed), one panel per residual model."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(RESIDUALS), figsize=(5.2 * len(RESIDUALS), 4.0), sharey=True)
    for ax, res in zip(np.atleast_1d(axes), RESIDUALS):
        g = rows[rows["residual"] == res]
        for i, (key, r) in enumerate(g.groupby(["truth", "signal", "seed"])):
            r = r.sort_values("fs")
            ax.plot(r["fs"], r["ln_bf"].abs(), "-o", color=f"C{i}", ms=3, label=" ".join(map(str, key)))
            ax.plot(r["fs"], r["ln_bf_calibrated"].abs(), "--s", color=f"C{i}", ms=3)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xticks(RATES, [f"{r:g}" for r in RATES], minor=False)
        ax.minorticks_off()
        ax.set_xlabel("sampling rate [Hz]")
        ax.set_title(f"--noise {res}: raw (solid), calibrated (dashed)")
    np.atleast_1d(axes)[0].set_ylabel("|ln BF(dahl : normalized-bouc-wen)| [nats]")
    np.atleast_1d(axes)[0].legend(fontsize=6)
    figures.save(fig, path)


if __name__ == "__main__":
    print(main(quick="--quick" in sys.argv))
