# ---
# jupyter:
#   jupytext:
#     formats: py:percent
# ---
# %% [markdown]
# # Calibrating diagnose's threshold on one set of records, checking it on another
#
# `diagnose` names an effect when its score (a κ-corrected log Bayes factor) passes `THRESHOLD`
# (`bayes_mr/diagnosis/screen.py`). That constant was set on records the package wrote itself
# (`synthesize`: its own kernel, white noise, and the true noise SDs handed to the likelihood). Here the
# records come from an independent simulator (`tests/reference_sim.py`: scipy LSODA on the contract's
# equations) and are written as a lab writes them (`tests/reference_families.py`): CSV with units in the
# headers, AR(1) output noise (ρ 0.3–0.8, 1–3 % of RMS), 1–3 % noise on the measured input, read back by
# `bm.load(path, mass=...)` with no `noise_sd_*` attribute, so every noise floor is estimated.
#
# * Set A (calibration seeds 100–199): clean records of four forms (dahl and lugre structure tests,
#   normalized Bouc–Wen and spencer device tests, spencer with a switching command linear between
#   samples). The threshold is **the largest best score (`causes[0].score`) of a clean record of A, plus
#   a margin of 1** (a ratio e ≈ 2.7 of evidence above anything a clean record reached).
# * Set B (check seeds 200–299): new clean records of the same four kinds, and the eight core effects
#   hidden in a dahl baseline (`reference_families.HIDDEN`). Reported: the false-alarm rate (clean
#   records where an effect is named) and the detection rate (hidden effects named as the cause), each
#   with a Clopper–Pearson 90 % interval — at the package's `THRESHOLD` (what `diagnose` answered) and at
#   the calibrated one (a record counts as flagged when its best score passes it, as detected when its
#   top candidate is the hidden effect and its score passes it).
#
# Run: `bayes-mr study diagnosis-calibration` (`--quick`: 8 s at 500 Hz, four seeds per clean kind in each set
# — spencer left out, `SLOW_KINDS` — and one per effect; the full study: 30 s at 1 kHz, every clean kind, five
# seeds per kind, two per effect). On 2 shared cores a quick record takes 10–30 s to generate and diagnose,
# a spencer device test about 15 min.

# %%
from __future__ import annotations

import importlib
import json
import math
import sys
import time
from pathlib import Path

import pandas as pd
from scipy import stats

import bayes_mr as bm
from bayes_mr.diagnosis.screen import THRESHOLD
from bayes_mr.report.markdown import markdown_table

#: Seeds of the calibration set (A) and of the check set (B); the test suite uses 900–999.
SEEDS_A, SEEDS_B = 100, 200
#: What the calibrated threshold adds to the largest clean score of A.
MARGIN = 1.0
#: Clean kinds left out of ``--quick``: diagnosing a spencer device test (14 parameters, a stiff law) takes
#: about 15 min of a shared core at 8 s × 500 Hz, the whole quick study's budget.
SLOW_KINDS = ("spencer-device",)
LEVEL = 0.90


def _families():
    """``tests/reference_families.py`` (and the simulator beside it) as modules: they live with the tests."""
    tests = Path(__file__).resolve().parent.parent / "tests"
    if str(tests) not in sys.path:
        sys.path.insert(0, str(tests))
    return importlib.import_module("reference_families")


def clopper_pearson(k: int, n: int, level: float = LEVEL) -> list[float | None]:
    """Two-sided Clopper–Pearson interval of a binomial proportion k/n."""
    if n == 0:
        return [None, None]
    a = (1 - level) / 2
    lo = 0.0 if k == 0 else float(stats.beta.ppf(a, k, n - k + 1))
    hi = 1.0 if k == n else float(stats.beta.ppf(1 - a, k + 1, n - k))
    return [lo, hi]


def _rate(flags: list[bool]) -> dict:
    k, n = int(sum(flags)), len(flags)
    return {"k": k, "n": n, "rate": k / n if n else None, "ci90": clopper_pearson(k, n)}


def _row(fam, case, directory: Path, say) -> dict:
    t0 = time.perf_counter()
    path = fam.write_case(case, directory)
    record = fam.load_case(path, case)
    assert not [k for k in record.attrs if k.startswith("noise_sd")]
    t1 = time.perf_counter()
    try:
        out = bm.diagnose(record, case.form, progress=False).to_dict()
    except Exception as exc:  # a failure is a row, not the end of the study
        say(f"{case.label}: failed ({exc})")
        return {"record": case.label, "form": case.form, "kind": case.kind, "expected": case.expected,
                "error": str(exc)}
    top = out["causes"][0] if out["causes"] else {}
    row = {"record": case.label, "form": case.form, "kind": case.kind, "expected": case.expected,
           "cause": out["cause"], "ambiguous": out["ambiguous"],
           "best": top.get("name"), "best_score": top.get("score"),
           "top3": [{k: c.get(k) for k in ("name", "score", "delta_loglik", "kappa", "mse_ratio")}
                    for c in out["causes"][:3]],
           "verdict": out["verdict"], "unexplained_ratio": out["unexplained_ratio"],
           "generate_s": round(t1 - t0, 1), "diagnose_s": round(time.perf_counter() - t1, 1)}
    say(f"{case.label}: {row['cause']} (best {row['best']} {row['best_score']}), "
        f"{row['generate_s'] + row['diagnose_s']:.0f} s")
    return row


def _score(row) -> float:
    s = row.get("best_score")
    return -math.inf if s is None else float(s)


def main(out_dir: str | Path = "results/studies/diagnosis-calibration", quick: bool = False, seed: int = 0,
         per_kind: int | None = None, per_effect: int | None = None) -> dict:
    """Both sets, the calibrated threshold and the rates on B; ``per_kind`` clean records of each kind in each
    set and ``per_effect`` records of each hidden effect (defaults: quick 4 and 1, full 5 and 2)."""
    out = Path(out_dir)
    (out / "records").mkdir(parents=True, exist_ok=True)
    fam = _families()
    say = lambda msg: print(f"  … {msg}", file=sys.stderr, flush=True)  # noqa: E731
    size = dict(duration=8.0, fs=500.0) if quick else dict(duration=30.0, fs=1000.0)
    n_clean, n_effect = (4, 1) if quick else (5, 2)
    n_clean, n_effect = per_kind or n_clean, per_effect or n_effect
    kinds = [k for k in fam.CLEAN if not (quick and k in SLOW_KINDS)]
    t0 = time.perf_counter()
    set_a = [fam.clean_case(name, SEEDS_A + seed + 10 * j + i, **size)
             for j, name in enumerate(kinds) for i in range(n_clean)]
    clean_b = [fam.clean_case(name, SEEDS_B + seed + 10 * j + i, **size)
               for j, name in enumerate(kinds) for i in range(n_clean)]
    hidden_b = [fam.hidden_case(effect, SEEDS_B + seed + 50 + 5 * j + i, **size)
                for j, effect in enumerate(fam.HIDDEN) for i in range(n_effect)]
    rows_a = [_row(fam, c, out / "records", say) for c in set_a]
    rows_clean = [_row(fam, c, out / "records", say) for c in clean_b]
    rows_hidden = [_row(fam, c, out / "records", say) for c in hidden_b]
    ok = lambda rows: [r for r in rows if "error" not in r]  # noqa: E731
    clean_a_scores = [_score(r) for r in ok(rows_a)]
    calibrated = max(clean_a_scores) + MARGIN if clean_a_scores else None
    at_package = {
        "threshold": THRESHOLD,
        "false_alarm": _rate([r["cause"] != "none" for r in ok(rows_clean)]),
        "detection": _rate([r["cause"] == r["expected"] for r in ok(rows_hidden)]),
        "false_alarm_set_a": _rate([r["cause"] != "none" for r in ok(rows_a)]),
    }
    at_calibrated = None if calibrated is None else {
        "threshold": calibrated,
        "false_alarm": _rate([_score(r) > calibrated for r in ok(rows_clean)]),
        "detection": _rate([r["best"] == r["expected"] and _score(r) > calibrated for r in ok(rows_hidden)]),
    }
    wall = time.perf_counter() - t0
    summary = {
        "rule": f"calibrated threshold = largest best score of set A's clean records + {MARGIN:g}",
        "package_threshold": THRESHOLD, "calibrated_threshold": calibrated,
        "clean_best_scores_a": {r["record"]: r.get("best_score") for r in rows_a},
        "at_package_threshold": at_package, "at_calibrated_threshold": at_calibrated,
        "records": {**size, "clean_kinds": kinds, "effects": list(fam.HIDDEN),
                    "clean_per_kind": n_clean, "per_effect": n_effect, "seeds_a": SEEDS_A + seed,
                    "seeds_b": SEEDS_B + seed, "output_noise": list(fam.OUTPUT_NOISE), "ar_rho": list(fam.AR_RHO),
                    "input_noise": list(fam.INPUT_NOISE)},
        "rows": {"a": rows_a, "b_clean": rows_clean, "b_hidden": rows_hidden},
        "missed": [{"record": r["record"], "expected": r["expected"], "got": r["cause"], "top3": r["top3"]}
                   for r in ok(rows_hidden) if r["cause"] != r["expected"]],
        "false_alarms": [{"record": r["record"], "got": r["cause"], "top3": r["top3"]}
                         for r in ok(rows_a + rows_clean) if r["cause"] != "none"],
        "failed": [r["record"] for r in rows_a + rows_clean + rows_hidden if "error" in r],
        "quick": quick, "wall_s": round(wall, 1),
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=1, default=float))
    (out / "report.md").write_text(markdown(summary))
    return summary


def _fmt(rate: dict) -> str:
    lo, hi = rate["ci90"]
    return f"{rate['k']}/{rate['n']} ({lo:.2f}–{hi:.2f})" if lo is not None else "–"


def markdown(summary: dict) -> str:
    """The study's report, from its summary alone (``docs/results.md`` shows the same text)."""
    rec, rows = summary["records"], summary["rows"]
    at_package, at_calibrated = summary["at_package_threshold"], summary["at_calibrated_threshold"]
    calibrated = summary["calibrated_threshold"]
    table = [{"threshold": f"package {summary['package_threshold']:g}", "false alarms (B)": _fmt(at_package["false_alarm"]),
              "detections (B)": _fmt(at_package["detection"])}]
    if at_calibrated:
        table.append({"threshold": f"calibrated {calibrated:.3g}", "false alarms (B)": _fmt(at_calibrated["false_alarm"]),
                      "detections (B)": _fmt(at_calibrated["detection"])})
    every = rows["a"] + rows["b_clean"] + rows["b_hidden"]
    per_record = [{"record": r["record"], "expected": r["expected"], "cause": r.get("cause", r.get("error")),
                   "best": r.get("best"), "score": r.get("best_score")} for r in every]
    lines = ["# diagnose's threshold on records of an independent simulator", "",
             f"Records {rec['duration']:g} s at {rec['fs']:g} Hz, CSV read by `bm.load` (noise floors estimated). "
             f"Set A: {len(rows['a'])} clean records; set B: {len(rows['b_clean'])} clean, {len(rows['b_hidden'])} "
             f"with one hidden effect. Wall time {summary['wall_s'] / 60:.1f} min.", "",
             f"Rule: {summary['rule']}. Calibrated threshold: "
             + (f"{calibrated:.3g}" if calibrated is not None else "none")
             + f" (package: {summary['package_threshold']:g}).", "",
             "Rates on B with Clopper–Pearson 90 % intervals:", "", markdown_table(pd.DataFrame(table)), "",
             "## Every record", "", markdown_table(pd.DataFrame(per_record)), "",
             "Failed: " + (", ".join(summary["failed"]) or "none") + "."]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(json.dumps({k: v for k, v in main(quick="--quick" in sys.argv).items() if k != "rows"}, indent=1,
                     default=float))
