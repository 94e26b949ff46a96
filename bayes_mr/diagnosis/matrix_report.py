"""The Markdown report and figures of a diagnosis over a test matrix (:func:`bayes_mr.diagnosis.matrix.diagnose_matrix`).

What a lab asks of a matrix diagnosis is where the model misses — by condition — and what the worst test looks
like: the condition heat map of the baseline's (and the extension's) force NRMSE
(:func:`bayes_mr.report.figures.condition_map`) and the force window of the test the baseline misses most, drawn
as one record's diagnosis draws its windows (:func:`.report.window_figure`). Like :mod:`.report`, nothing here
computes a fit: the JSON and the fits are passed in.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from bayes_mr.diagnosis.report import WINDOW_S, _save, window_figure
from bayes_mr.report.markdown import fmt

if TYPE_CHECKING:  # annotations only
    from bayes_mr.diagnosis.fits import Fit


def _condition_rows(table: list[dict], label: str) -> list[dict]:
    """``by_condition``'s rows flattened for :func:`bayes_mr.report.figures.condition_map`: the condition and
    the ``label`` fit's force NRMSE."""
    keys = ("amplitude", "frequency", "command", "command_value")
    return [{**{k: row.get(k) for k in keys}, "force_nrmse": row[label]["force_nrmse"]}
            for row in table if row.get(label) and row.get("amplitude") is not None
            and row.get("frequency") is not None]


class _OneRecord:
    """What :func:`window_figure` reads of a fit (``name``, ``predicted``) for one record of a joint fit."""

    def __init__(self, fit: Fit, r: int):
        self.name, self.predicted = fit.name, fit.predicted[r]


def _matrix_markdown(out: dict, figures: dict[str, Path]) -> str:
    rec = out["record"]
    lines = [f"# Diagnosis of a test matrix: `{rec['source']}`", "",
             f"{out['n_records']} {rec['kind']} tests in {out['n_folds']} conditions, {rec['samples']} samples "
             f"({rec['duration_s']:.3g} s); {out['masked']} samples masked by quality control"
             + ("; a force offset per test (`f0[r]`) in every fit" if out.get("record_offsets") else "") + ".", ""]
    named = out["effects"]
    lines += ["## Verdict", "",
              f"**Cause: `{out['cause']}`**" + (f" (all named: {', '.join(f'`{n}`' for n in named)})"
                                               if len(named) > 1 else "") + f" — {out['verdict']}", ""]
    if out["ambiguous"]:
        lines += ["The joint likelihood cannot tell the cause from "
                  + ", ".join(f"`{a['name']}` (D = {fmt(a['difference'])} ± {fmt(a['sd'])}, z {fmt(a['z'])})"
                              for a in out["alternatives"]) + ": either explains the matrix as well.", ""]
    g = out["gain"]
    lines += [f"- baseline `{out['baseline']['model']}`: MSE {fmt(out['baseline']['mse'])}, "
              f"ln Z {fmt(out['baseline']['log_evidence'], 8)}",
              f"- extended `{out['extended']['model']}`: MSE {fmt(out['extended']['mse'])}, "
              f"ln Z {fmt(out['extended']['log_evidence'], 8)}",
              f"- training gain {fmt(g['training_gain'])}; held-out gain (leave one condition out) "
              f"{fmt(g['held_out_gain'])}; Δ ln Z (Laplace, iid) {fmt(g['delta_log_evidence'])}",
              f"- decision threshold on the score: {fmt(out['threshold'])}; wall time {fmt(out.get('wall_s'))} s", ""]
    if out.get("baselines"):
        lines += ["## Baseline chosen by joint evidence", "", "| model | ln Z (Laplace) | MSE |", "|---|---|---|"]
        lines += [f"| {r['model']} | {fmt(r['log_evidence'], 8)} | {fmt(r['mse'])} |" for r in out["baselines"]]
        lines.append("")
    lines += ["## Candidate effects (round 1, against the baseline)", "",
              "An effect is kept only when its gain carries to conditions it was not fitted on.", "",
              "| effect | score | κ | Δℓ | MSE ratio | training gain | held-out gain | transfers | note |",
              "|---|---|---|---|---|---|---|---|---|"]
    for c in out["causes"]:
        lines.append(f"| {c['name']} | {fmt(c['score'])} | {fmt(c['kappa'])} | {fmt(c['delta_loglik'])} | "
                     f"{fmt(c['mse_ratio'])} | {fmt(c.get('training_gain'))} | {fmt(c.get('held_out_gain'))} | "
                     f"{'yes' if c.get('transfers') else ''} | {c.get('note', '')} |")
    labels = ["baseline"] + (["extended"] if named else [])
    lines += ["", "## By condition", "", "| record | file | amplitude [mm] | frequency [Hz] | command | "
              + " | ".join(f"{lab} force NRMSE" for lab in labels) + " |",
              "|---|---|---|---|---|" + "---|" * len(labels)]
    for row in out["by_condition"]:
        cmd = f"{row['command']} {fmt(row['command_value'])}" if row.get("command") else ""
        amp = 1e3 * row["amplitude"] if row.get("amplitude") is not None else None
        lines.append(f"| {row['record']} | `{row['file']}` | {fmt(amp)} | {fmt(row.get('frequency'))} | {cmd} | "
                     + " | ".join(fmt(row[lab]["force_nrmse"]) for lab in labels) + " |")
    w = out["worst_condition"]
    lines += ["", f"Missed most by the baseline: record {w['record']} (`{w['file']}`), force NRMSE "
                  f"{fmt(w['baseline_force_nrmse'])}.", ""]
    titles = {"condition_map": "Baseline force NRMSE by condition",
              "condition_map_extended": "Extended model's force NRMSE by condition",
              "window_worst": "The worst condition: measured vs predicted force, residual under it"}
    lines += ["## Figures", ""]
    for key, path in figures.items():
        lines += [f"### {titles.get(key, key)}", "", f"![{key}]({path.name})", ""]
    return "\n".join(lines) + "\n"


def write_matrix_report(out: dict, records, base: Fit, ext: Fit, out_dir: Path) -> dict[str, Path]:
    """Write a matrix diagnosis's figures and ``diagnose.md`` into ``out_dir``; return name → path (``report``
    included). The figures: the baseline's (and the extension's) force NRMSE by condition
    (:func:`bayes_mr.report.figures.condition_map`), and the :data:`WINDOW_S` window of the test the baseline
    misses most (``worst_condition``) where its force residual is largest, measured against predicted."""
    from bayes_mr.report.figures import condition_map

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    figures = {}
    for label, key in (("baseline", "condition_map"), ("extended", "condition_map_extended")):
        rows = _condition_rows(out["by_condition"], label)
        if rows:
            model = out[label]["model"]
            figures[key] = _save(condition_map(rows, title=f"force NRMSE by condition: {model}, fitted jointly"),
                                 out_dir / f"{key}.png")
    r = int(out["worst_condition"]["record"])
    record = records[r]
    resid = record["force"].values - ext.predicted[r]["force"]  # where the final model misses most, as titled
    resid = np.where(record["valid"].values.astype(bool), resid, 0.0)
    w = max(2, int(WINDOW_S * float(record.attrs["fs"])))
    centre = int(np.argmax(np.convolve(resid**2, np.ones(w), mode="same")))
    one = _OneRecord(base, r)
    other = one if ext is base else _OneRecord(ext, r)
    figures["window_worst"] = _save(window_figure(record, one, other, "force", centre), out_dir / "window_worst.png")
    report = out_dir / "diagnose.md"
    report.write_text(_matrix_markdown(out, figures))
    return {**figures, "report": report}
