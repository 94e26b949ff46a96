"""The main job's report (:func:`bayes_mr.mainjob.run`): its figures, its headline and ``report.md``.

Every sentence and table is built from the run's summary (the dict written
to ``summary.json``), so the README's run section (:mod:`.readme`) can be
rebuilt from that file alone.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from ..comparison import row_of as _row, simulating_point
from ..identify import predict
from .figures import binned, command_loops, hysteresis, save, time_series
from .markdown import fmt, markdown_table


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
        :func:`bayes_mr.mainjob_context.published_spencer` (``params`` [SI]).
    vst : dict or None
        :func:`bayes_mr.mainjob.shake_table` with its private arrays (``_vst_b``, ``_force_b``).
    diag : dict, optional
        :func:`bayes_mr.mainjob.diagnose_selected` (``{model: diagnose JSON, "_part_b": part B at its rate}``).
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


def _runner_up(factors: dict, sel: str) -> tuple[str | None, float | None]:
    """(runner-up, its ln BF) among ``factors`` = ln Z(best) − ln Z(model)."""
    bf = {m: v for m, v in factors.items() if m != sel}
    return (min(bf, key=bf.get), min(bf.values())) if bf else (None, None)


def _selection_lines(summary: dict) -> list[str]:
    """The selected model, on which evidence, and what the raw (working-likelihood) evidence says beside it."""
    sel = summary["selected"]
    if not sel:
        unc = summary.get("unconverged")
        return [f"No model selected: the {summary.get('evidence_route')} evidence did not converge"
                + (f" ({', '.join(unc)})." if unc else ".")]
    raw = summary["bayes_factors"]  # ln Z(selected) − ln Z(model) on the raw evidence: re-centred on its own best
    raw_best = min(raw, key=raw.get)
    r_run, r_bf = _runner_up({m: v - raw[raw_best] for m, v in raw.items()}, raw_best)
    raw_txt = (f"the raw {summary['evidence_route']} evidence of the working likelihood picks **{raw_best}** "
               f"(ln BF {fmt(r_bf, 3)} over {r_run})" if r_run else "")
    if summary.get("selected_on") == "calibrated":
        c_run, c_bf = _runner_up(summary["bayes_factors_calibrated"], sel)
        return [f"Selected by the calibrated evidence: **{sel}** (ln BF {fmt(c_bf, 3)} over the runner-up, "
                f"{c_run}). It is the Laplace evidence of the likelihood raised to k = "
                f"{fmt(summary.get('evidence_scale'), 3)}, the power at which its curvature matches the calibrated "
                f"covariance (residual correlation, input noise), so it counts the information in the record, not "
                f"the number of samples; " + raw_txt + "."]
    return [f"Selected by {summary['evidence_route']} evidence: **{sel}**"
            + (f" (ln Bayes factor {fmt(r_bf, 3)} over the runner-up, {r_run})." if r_run else ".")]


def _noise_lines(summary: dict) -> list[str]:
    """How the least-squares model choice and ln BF move between the iid and the AR residual model."""
    sens = summary.get("noise_sensitivity")
    if not sens or "iid" not in sens or "ar" not in sens:
        return []
    iid, ar = sens["iid"], sens["ar"]
    if not iid["selected"] or not ar["selected"]:
        return []

    (ri, bi), (ra, ba) = _runner_up(iid["bayes_factors"], iid["selected"]), _runner_up(ar["bayes_factors"], ar["selected"])
    n_eff = ar["n_eff"].get(ar["selected"]) or {}
    n_txt = ", ".join(f"{ch} {fmt(v, 3)}" for ch, v in n_eff.items()) if isinstance(n_eff, dict) else fmt(n_eff, 3)
    same = "the same model" if iid["selected"] == ar["selected"] else "a different model"
    return [f"Residual model (least squares, Laplace evidence): with independent residuals (iid) "
            f"**{iid['selected']}** wins by ln BF {fmt(bi, 3)} over {ri}; with the AR residual model, which "
            f"counts the residual's correlation in time (effective independent samples: {n_txt}), "
            f"**{ar['selected']}** ({same}) wins by ln BF {fmt(ba, 3)} over {ra}. The comparison above uses "
            f"`--noise {summary.get('noise', 'iid')}`." + "".join(
                f" Calibrated under {name}: **{d['selected_calibrated']}** by ln BF "
                f"{fmt(_runner_up(d['bayes_factors_calibrated'], d['selected_calibrated'])[1], 3)} (k = "
                f"{fmt(d.get('evidence_scale'), 3)})." for name, d in (("iid", iid), ("ar", ar))
                if d.get("selected_calibrated"))]


def _floor_sentence(rec: dict) -> str:
    """Where the measurement-noise floor the UKF, the input-noise replicas and the diagnosis use came from."""
    sd, how = rec.get("noise_sd") or {}, (rec.get("noise_floor") or {})
    if not sd:
        return ""
    methods = sorted(set((how.get("methods") or {}).values()))
    seg = how.get("segment")
    where = f" ({', '.join(methods)}" + (f", {seg[0]:.1f}–{seg[1]:.1f} s of the untrimmed record)" if seg else ")")
    return (" Noise floor" + where + ": " + ", ".join(f"{c} {fmt(v, 3)}" for c, v in sd.items()) + " (SI).")


def _terms_clause(t: dict | None, v: dict) -> str:
    """What the term search beyond the vocabulary kept, and its part-B error ('' when it did not run)."""
    if not t:
        return ""
    if not t.get("kept"):
        return f" A search of the term library beyond the vocabulary kept nothing ({len(t.get('proposed', []))} tried)."
    vb = (t.get("validation") or {}).get("force_nrmse")
    return (f" A search of the term library beyond the vocabulary kept {len(t['kept'])}: "
            + "; ".join(t.get("sentences") or t["kept"])
            + f" (MSE ratio on A {fmt(t.get('mse_ratio'), 3)}, Δ ln Z {fmt(t.get('delta_log_evidence'), 4)}"
            + (f"; part B force NRMSE {fmt(v.get('extended_force_nrmse'), 4)} → {fmt(vb, 4)}" if vb is not None else "")
            + ").")


def diagnosis_sentence(model: str, d: dict) -> str:
    """What the diagnosis of ``model`` added, what it gained on A and on B, and what it still leaves."""
    g, v, rec = d["gain"], d.get("validation") or {}, d["record"]
    head = (f"Diagnosis of {model} (on {rec['duration_s']:.1f} s of part A at {rec['fs']:.0f} Hz): "
            f"cause **{d['cause']}**")
    if d["effects"]:
        head += (f" (effects {', '.join(d['effects'])}); extended model {d['extended']['model']}: MSE ratio on A "
                 f"{fmt(g['mse_ratio'], 3)}, Δ ln Z {fmt(g['delta_log_evidence'], 4)} (calibrated "
                 f"{fmt(g.get('delta_log_evidence_calibrated'), 4)}); part B force NRMSE "
                 f"{fmt(v.get('baseline_force_nrmse'), 4)} → {fmt(v.get('extended_force_nrmse'), 4)}.")
    else:
        head += " — no effect passes the calibrated threshold."
    ratio = d.get("unexplained_ratio")
    if ratio is not None:
        head += (f" What {'the extended' if d['effects'] else 'the'} model leaves on A is {fmt(ratio, 3)} × the "
                 f"noise floor (worst channel; {'at the floor' if d.get('at_noise_floor') else 'model error, not noise'}).")
    return head + _terms_clause(d.get("terms"), v)


def second_record_sentence(summary: dict) -> str | None:
    """How the fits of part A predict a second record of the same damper (None when the run had none)."""
    s = summary.get("second_record")
    if not s:
        return None
    rec, sel = s["record"], summary["selected"]
    ok = [r for r in s["rows"] if r.get("force_nrmse") is not None]
    line = (f"Second record of the same damper ({rec['source']}; {rec['duration_s']:.1f} s at {rec['fs']:.0f} Hz, "
            "never fitted): ")
    sel_row = _row(ok, sel, "lsq")
    parts = []
    if sel_row is not None:
        parts.append(f"the selected model ({sel}, least squares) predicts it with force NRMSE "
                     f"{fmt(sel_row['force_nrmse'], 3)}")
    if ok:
        best = min(ok, key=lambda r: r["force_nrmse"])
        parts.append(f"the best fit of the comparison on it is {best['model']} ({best['engine']}), "
                     f"{fmt(best['force_nrmse'], 3)}")
    failed = [f"{r['model']} ({r['engine']})" for r in s["rows"] if "error" in r]
    if failed:
        parts.append(f"{', '.join(failed)} could not predict it")
    d = s.get("diagnosis")
    if d:
        parts.append(f"at {d['fs']:.0f} Hz the diagnosis's {d['baseline_model']} gives "
                     f"{fmt(d.get('baseline_force_nrmse'), 4)} and its extension {d['extended_model']} "
                     f"{fmt(d.get('extended_force_nrmse'), 4)}"
                     + (f", with the terms found beyond the vocabulary {fmt(d.get('terms_force_nrmse'), 4)}"
                        if "terms_model" in d else ""))
    return line + ("; ".join(parts) or "no fit could predict it") + "."


def _posterior_lines(rows: list[dict], selected: str | None, skipped: dict[str, str]) -> list[str]:
    """The headline's emcee sentence: which posteriors converged, which did not and why (the chain's length in
    integrated autocorrelation times and its R-hat against the ≥ 50 τ and R-hat < 1.01 asked), and which forms
    got none (the selected one named first)."""
    chains = [r for r in rows if r["engine"] == "mcmc" and "error" not in r]
    why = {"max_steps": "step limit", "max_seconds": "time limit"}
    lines = []
    if chains:
        unconverged = [f"{r['model']} ({why.get(r.get('stopped'), 'budget')}: {r.get('n_steps')} steps = "
                       f"{fmt((r.get('n_steps') or 0) / r['tau_max'], 2) if r.get('tau_max') else '?'} τ, "
                       f"R-hat {fmt(r.get('rhat_max'), 3)})" for r in chains if not r.get("converged")]
        lines.append(f"emcee posteriors for {', '.join(r['model'] for r in chains)} "
                     f"({', '.join(str(r.get('n_steps')) for r in chains)} steps; R-hat_max "
                     f"{', '.join(fmt(r.get('rhat_max'), 3) for r in chains)}): "
                     + (f"{', '.join(unconverged)} NOT converged in this budget (≥ 50 τ and R-hat < 1.01 asked)."
                        if unconverged else "converged (≥ 50 τ, R-hat < 1.01)."))
    if skipped:
        order = sorted(skipped, key=lambda m: m != selected)
        lines.append("No emcee posterior for " + "; ".join(
            f"{m}{' (the selected model)' if m == selected else ''}: {skipped[m]}" for m in order) + ".")
    return lines


def headline(summary: dict) -> list[str]:
    """The sentences a structural engineer reads first (every number from this run)."""
    rows, sel = summary["rows"], summary["selected"]
    lines = []
    rec = summary["record"]
    lines.append(f"Record: {rec['source']} — {rec['duration_s']:.1f} s at {rec['fs']:.0f} Hz after trimming and "
                 f"decimation by {rec['decimation']} (inputs {rec.get('input_interp') or 'auto'} between samples); "
                 f"{rec['masked']} samples masked by quality control. "
                 f"Part A (training) {rec['part_a_s']:.1f} s, part B (never fitted) {rec['part_b_s']:.1f} s."
                 + _floor_sentence(rec))
    lines += _selection_lines(summary)
    lines += _noise_lines(summary)
    lines += _posterior_lines(rows, sel, summary.get("mcmc_skipped") or {})
    best = summary["best_on_part_b"]
    sp = summary["spencer_1997"].get("part_b", {})
    if best:
        lines.append(f"On part B the best prediction is {best['model']} ({best['engine']}), force NRMSE "
                     f"{fmt(best['force_nrmse'], 3)}; Spencer et al. (1997)'s published parameters give "
                     f"{fmt(sp.get('force_nrmse'), 3)} on the same part.")
    sel_lsq = _row(rows, sel, "lsq") if sel else None
    if sel_lsq and sel_lsq.get("validation"):
        lines.append(f"The selected model ({sel}, least squares) predicts part B with force NRMSE "
                     f"{fmt(sel_lsq['validation']['force_nrmse'], 3)} (on its training part A: "
                     f"{fmt(sel_lsq['force_nrmse'], 3)}).")
    for model, d in (summary.get("diagnose") or {}).items():
        if "error" in d:
            lines.append(f"Diagnosis of {model} failed: {d['error']}")
            continue
        lines.append(diagnosis_sentence(model, d))
    second = second_record_sentence(summary)
    if second:
        lines.append(second)
    v = summary.get("shake_table")
    if v and "ukf" in v and "error" not in v["ukf"]:
        u = v["ukf"]
        lines.append(f"Virtual shake table ({v['model']}, thesis frame m = {v['frame']['mass']:g} kg): the UKF, "
                     f"from displacement and acceleration only, implies a damper force (its restoring force less the "
                     f"known frame's) with NRMSE {fmt(u.get('force_nrmse_a'), 3)} on A and "
                     f"{fmt(u.get('force_nrmse_b'), 3)} on B against the measured force (its hysteretic part alone, the "
                     f"structure model's force output: {fmt(u.get('hysteretic_nrmse_b'), 3)} on B; "
                     f"{u.get('trained')} UKF runs trained, {u.get('diverged')} diverged).")
    return lines


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
        out += ["", "MCMC diagnostics: " + "; ".join(
            f"{r['model']}: {r.get('n_steps')} steps, τ_max {fmt(r.get('tau_max'), 3)}, R-hat_max "
            f"{fmt(r.get('rhat_max'), 4)}, {'converged' if r.get('converged') else 'NOT converged (' + str(r.get('stopped', 'budget')) + ')'}"
            for r in conv) + "."]
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
    return "\n".join(out)
