"""The main job's report (:func:`bayes_mr.run.job.run`): its figures and ``report.md`` (its headline: :mod:`.headline`).

Every sentence and table is built from the run's summary (the dict written
to ``summary.json``), so the main job's section of docs/results.md (``scripts/docs_sections.py``)
can be rebuilt from that file alone.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from bayes_mr.selection.comparison import row_of as _row, simulating_point
from bayes_mr.inference.identify import predict
from bayes_mr.report.figures import binned, command_loops, hysteresis, save, time_series
from bayes_mr.run.headline import chain_shape, diagnosis_sentence, headline, second_record_sentence
from bayes_mr.report.markdown import fmt, markdown_table


def run_figures(out_dir: Path, part_b: xr.Dataset, rows: list[dict], selected: str | None, best: dict | None,
                spencer: dict, vst: dict | None, diag: dict | None = None) -> dict[str, str]:
    """Force on B (measured, extended and selected identified, published Spencer), loops, and the shake-table force.

    Parameters
    ----------
    out_dir : Path
        Folder of the PNGs.
    part_b : xarray.Dataset
        Part B of the record (never fitted).
    rows : list of dict
        The comparison's rows (``model``, ``engine``, ``params`` [SI], ``validation``).
    selected : str or None
        The model selected by evidence.
    best : dict or None
        The row with the lowest force NRMSE on part B.
    spencer : dict
        :func:`bayes_mr.run.context.published_spencer` (``params`` [SI]).
    vst : dict or None
        :func:`bayes_mr.run.stages.shake_table` with its private arrays (``_vst_b``, ``_force_b``).
    diag : dict, optional
        :func:`bayes_mr.run.stages.diagnose_selected` (``{model: diagnose JSON, "_part_b": part B at its rate}``).
        When the diagnosis ran, the part-B figures are drawn at its rate with the model with the terms found
        beyond the vocabulary first (when it kept any), the extended model (the package's best model of named
        physics, fitted on A), then the selected model as refitted there; with a second
        record of the same damper (``"_other"``, at the diagnosis's rate) the same four figures are drawn for it.

    Returns
    -------
    dict
        Figure name → path of the PNG.
    """
    figs = {}
    t = part_b["time"].values
    curves = {"measured": part_b["force"].values}
    diagnosed = _diagnosed(diag)
    if diagnosed is not None:
        part_b, d = diagnosed
        curves = _diagnosis_curves(part_b, d)
    # without a diagnosis: the selected model as the comparison fitted it, and the best on B beside it
    sel = _row(rows, selected, "lsq") if diagnosed is None else None
    best = best if diagnosed is None else None
    if best is not None and sel is not None and (best["model"], best["engine"]) == (sel["model"], "lsq"):
        best = None  # the selected model is also the best on B: one curve
    for label, r in ((f"{selected} (lsq, selected by evidence)", sel),
                     (f"{best['model']} ({best['engine']}, best on B)" if best else "", best)):
        if r is not None and label not in curves:
            try:
                curves[label] = predict(r["model"], part_b, simulating_point(r))["force"]
            except ValueError:
                pass
    _add_published(curves, part_b, spencer)
    figs.update(_prediction_figures(out_dir, part_b, curves))
    if diagnosed is not None and "_other" in diag:  # the second record of the same damper, never fitted
        other = diag["_other"]
        curves = _diagnosis_curves(other, diagnosed[1])
        _add_published(curves, other, spencer)
        figs.update(_prediction_figures(out_dir, other, curves, key="second", stem="second_record",
                                        what="second record"))
    if vst is not None and "_vst_b" in vst:
        window = (0.0, min(4.0, float(t[-1])))
        v = vst["_vst_b"]
        panel = {"measured damper force": v["force"].values}
        for label in ("ukf", "lsq"):
            implied = vst.get(label, {}).get("_force_b")
            if implied is not None:
                panel[f"implied by {label} fit (from x and a only)"] = implied
        figs["shake_table"] = str(save(time_series(v["time"].values, {"force [N]": panel}, window=window,
                                                 title="virtual shake table, part B"),
                                     out_dir / "shake_table_force.png"))
    return figs


def _diagnosis_curves(rec: xr.Dataset, d: dict) -> dict[str, np.ndarray]:
    """Measured force and the diagnosis's predictions of ``rec`` [N]: the model with the terms the term search kept
    (when it kept any), the extended model (when effects were added), then the selected model as refitted; a
    prediction that diverges is left out."""
    curves = {"measured": rec["force"].values}
    fs = float(rec.attrs["fs"])
    t = d.get("terms") or {}
    drawn = [("with terms found beyond the vocabulary", t)] if t.get("kept") else []
    drawn += [("extended on A", d["extended"])] if d["effects"] else []  # nothing added: one curve
    drawn.append(("selected, refitted on A", d["baseline"]))
    for what, fit in drawn:
        try:
            curves[f"{fit['model']} ({what} at {fs:.0f} Hz)"] = predict(fit["model"], rec, fit["params"])["force"]
        except ValueError:
            pass
    return curves


def _add_published(curves: dict[str, np.ndarray], rec: xr.Dataset, spencer: dict) -> None:
    """Spencer et al. (1997)'s published parameters' prediction of ``rec``, added last (unless it diverges)."""
    try:
        curves["Spencer 1997 published"] = predict("spencer", rec, spencer["params"])["force"]
    except ValueError:
        pass


def _diagnosed(diag: dict | None) -> tuple[xr.Dataset, dict] | None:
    """(part B at the diagnosis's rate, the diagnosis) when the main job's diagnosis ran and succeeded."""
    if not diag or "_part_b" not in diag:
        return None
    d = next((v for k, v in diag.items() if not k.startswith("_") and "error" not in v), None)
    return None if d is None else (diag["_part_b"], d)


#: Length of the part-B window the force figure shows [s]: a few cycles of the record's motion, readable.
WINDOW_S = 0.5


def _prediction_figures(out_dir: Path, part_b: xr.Dataset, curves: dict[str, np.ndarray], *, key: str = "b",
                        stem: str = "part_b", what: str = "part B") -> dict[str, str]:
    """A held-out record as a reader checks a prediction: a 0.5 s window with the residuals under it, the loops,
    the force–velocity plane coloured by the command, and the residual of the first prediction binned by velocity.

    ``curves`` holds the measured force first, then each prediction [N]. The window is the one where the
    first prediction misses most (a 0.5 s moving RMS of its residual), so the figure shows the problem,
    not a quiet stretch. Figure keys end in ``_{key}``, files in ``_{stem}.png``; ``what`` names the record
    in the titles.
    """
    figs = {}
    t, x = part_b["time"].values, part_b["displacement"].values
    measured = curves["measured"]
    preds = {k: v for k, v in curves.items() if k != "measured"}
    n_win = max(2, min(int(WINDOW_S * float(part_b.attrs["fs"])), t.size))
    if preds:
        r0 = measured - next(iter(preds.values()))
        ms = np.convolve(np.nan_to_num(r0) ** 2, np.ones(n_win), mode="valid")
        start = int(np.argmax(ms))
    else:
        start = 0
    window = (float(t[start]), float(t[min(start + n_win, t.size) - 1]))
    panels = {"force [N]": curves, "residual [N]": {k: measured - f for k, f in preds.items()}}
    colors = {k: f"C{i}" for i, k in enumerate(curves)}
    figs[f"force_{key}"] = str(save(time_series(t, panels, window=window, colors=colors,
                                              title=f"{what} (never fitted): damper force, the {WINDOW_S:g} s window "
                                                    "missed most"), out_dir / f"force_{stem}.png"))
    sl = slice(start, start + n_win)
    figs[f"hysteresis_{key}"] = str(save(hysteresis(x, curves, window=sl,
                                                   title=f"{what}: force–displacement (same window)"),
                                        out_dir / f"hysteresis_{stem}.png"))
    command = next((part_b[c].values for c in ("voltage", "current") if c in part_b), None)
    if command is not None and "velocity" in part_b:
        first = dict(list(curves.items())[:2])
        figs[f"force_velocity_{key}"] = str(save(command_loops(part_b["velocity"].values, first, command,
                                                               title=f"{what}: force–velocity, coloured by command"),
                                               out_dir / f"force_velocity_{stem}.png"))
    if preds and "velocity" in part_b:
        label, f = next(iter(preds.items()))
        figs[f"residual_velocity_{key}"] = str(save(binned({"velocity [m/s]": part_b["velocity"].values,
                                                            "displacement [m]": x}, measured - f,
                                                           title=f"{what} residual of {label} [N]"),
                                                  out_dir / f"residual_velocity_{stem}.png"))
    return figs


def spencer_table(spencer: dict) -> pd.DataFrame:
    """Published Spencer (1997) parameters [SI] beside the identified ones (least squares on part A, and SD)."""
    params = pd.DataFrame({"parameter": list(spencer["params"]),
                           "published (SI)": list(spencer["params"].values())})
    if "identified" in spencer:
        params["identified (lsq, part A)"] = [spencer["identified"]["params"].get(k) for k in spencer["params"]]
        params["sd"] = [spencer["identified"]["params_sd"].get(k) for k in spencer["params"]]
    return params


def _second_record_section(summary: dict) -> list[str]:
    """The report's section on the second record: every fit's prediction of it, and its figures."""
    s = summary.get("second_record")
    if not s:
        return []
    tab = pd.DataFrame([{"model": r["model"], "engine": r["engine"], "force NRMSE": r.get("force_nrmse"),
                         "MSE": r.get("mse"), "error": r.get("error", "")} for r in s["rows"]])
    out = ["## Second record of the same damper (never fitted)", "", second_record_sentence(summary), "",
           markdown_table(tab.drop(columns=[] if tab["error"].astype(bool).any() else ["error"])), ""]
    if s.get("diagnosis"):
        out += ["![force on the second record](force_second_record.png)", "",
                "![force–velocity by command](force_velocity_second_record.png)", ""]
    return out


def work_lines(summary: dict) -> list[str]:
    """The report's account of the posteriors' work: per form the log-density evaluations, their price and what the
    pool was charged, the wall time beside it, and any wall-time cap that acted (a machine limit, not a result)."""
    work = summary.get("posterior_work") or {}
    if not work:
        return []
    budget = summary.get("budget") or {}
    pool, cap = budget.get("mcmc_pool"), budget.get("mcmc_pool_cap_s")
    spent = sum(w["integrator_steps"] for w in work.values())
    charged = (f"a pool of {pool:.3g} integrator steps, {float(spent):.3g} spent" if pool else
               f"no pool, {float(spent):.3g} integrator steps spent")
    head = (f"Posteriors' work ({charged}; {f'wall-time cap {cap:.0f} s' if cap else 'no wall-time cap'}, "
            f"{sum(w['wall_s'] for w in work.values()):.0f} s used):")
    lines = ["", head, ""]
    for form, w in work.items():
        price = w["steps_per_evaluation"]
        charged = (f"{w['evaluations']} log-density evaluations × {price} integrator steps = "
                   f"{float(w['integrator_steps']):.3g}" if price else "no evaluation")
        lines.append(f"- {form}: {charged}, {w['wall_s']:.0f} s"
                     + (f"; {w['machine_limit']}" if w.get("machine_limit") else "") + ".")
    return lines


def report_markdown(summary: dict, tab: pd.DataFrame, params: pd.DataFrame) -> str:
    """``report.md`` of the main job."""
    out = ["# bayes_mr main job: the measured MR damper", ""]
    out += [f"- {s}" for s in headline(summary)]
    out += ["", "## Models × estimators (trained on part A; validation = part B)", "",
            markdown_table(tab.drop(columns=[c for c in ("error",) if not tab[c].astype(bool).any()])), "",
            f"ln Z route for selection: {summary['evidence_route']}. ln BF = ln Z(selected) − ln Z(model). "
            "MSE: thesis eq. 3-44 on the force channel (≈ 100 when the model is right to the noise). "
            "ln Z of each engine's rows by route: " + ", ".join(
                f"{e} {r}" for e, r in dict.fromkeys((x["engine"], x.get("evidence_route")) for x in summary["rows"]
                                                      if "error" not in x)) + ".", ""]
    for form, why in summary["mcmc_skipped"].items():
        out.append(f"- {form}: {why}.")
    conv = [r for r in summary["rows"] if r["engine"] == "mcmc" and "error" not in r]
    if conv:
        out += ["", "MCMC diagnostics (with what makes a chain slow, read from its draws):", ""] + [
            f"- {r['model']}: {r.get('n_steps')} steps, τ_max {fmt(r.get('tau_max'), 3)}, R-hat_max "
            f"{fmt(r.get('rhat_max'), 4)}, {'converged' if r.get('converged') else 'NOT converged (' + str(r.get('stopped', 'budget')) + ')'}"
            f"{chain_shape(r.get('geometry'))}." for r in conv]
    out += work_lines(summary)
    out += ["", "![force on part B](force_part_b.png)", "", "![loops on part B](hysteresis_part_b.png)", "",
            "![force–velocity by command](force_velocity_part_b.png)", "",
            "![residual by velocity](residual_velocity_part_b.png)", "",
            "## Spencer et al. (1997): published against identified", "",
            f"Source: {summary['spencer_1997']['source']}.", "", markdown_table(params), ""]
    for model, d in (summary.get("diagnose") or {}).items():
        out += [f"## Diagnosis of {model}", ""]
        if "error" in d:
            out.append(f"Diagnosis failed: {d['error']}")
        else:
            folder = f"diagnose_{model.replace('+', '_')}"
            ranked = ", ".join(f"{c['name']} {fmt(c['score'], 3)}" for c in d["causes"][:4])
            out.append(f"Full report: [{folder}/diagnose.md]({folder}/diagnose.md). "
                       + diagnosis_sentence(model, d) + f" Ranking (scores, threshold {fmt(d['threshold'], 3)}): "
                       f"{ranked}.")
            out += ["", f"![residuals]({folder}/residuals_time.png)"]
        out.append("")
    out += _second_record_section(summary)
    v = summary.get("shake_table")
    if v:
        out += ["## Virtual shake table", "",
                f"Frame m = {v['frame']['mass']:g} kg, k = {v['frame']['k']:g} N/m, c = {v['frame']['c']:g} N·s/m "
                "around the measured damper (inverse dynamics); identification from displacement and absolute "
                "acceleration only. The damper force the identified model implies is its restoring force −m â "
                "less the frame's c ẋ + k x (its own c and k hold frame and damper together); the hysteretic "
                "part alone is shown beside it.", ""]
        for label in ("ukf", "lsq"):
            e = v.get(label, {})
            if "error" in e:
                out.append(f"- {label}: failed ({e['error']})")
            elif e:
                out.append(f"- {label}: implied damper force NRMSE {fmt(e.get('force_nrmse_a'), 3)} (A), "
                           f"{fmt(e.get('force_nrmse_b'), 3)} (B); hysteretic part alone "
                           f"{fmt(e.get('hysteretic_nrmse_a'), 3)} (A), {fmt(e.get('hysteretic_nrmse_b'), 3)} (B); "
                           f"MSE {fmt(e.get('mse'), 4)} (A), {fmt(e.get('mse_b'), 4)} (B)")
        out += ["", "![shake table](shake_table_force.png)", ""]
    out += ["## Time", "", ", ".join(f"{k} {v:.0f} s" for k, v in summary["stages_s"].items())
            + f"; total {summary['wall_s']:.0f} s.", ""]
    where = summary.get("stages_where")
    if where and where["stages"]:
        wait = " (`beside_wait`: what the job waited for them after its posteriors)" \
            if "beside_wait" in summary["stages_s"] else ""
        out += [f"{', '.join(where['stages'])} ran in {where['ran_in']}{wait}; `bayes_mr/mainjob_aside.py`.", ""]
    return "\n".join(out)
