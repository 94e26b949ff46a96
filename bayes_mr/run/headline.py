"""The main job's headline: the sentences a structural engineer reads first, each number from the run's summary.

:func:`headline` builds them from the summary written to ``summary.json``
(docs/results.md's run section and ``report.md`` both start with them);
:func:`diagnosis_sentence` and :func:`second_record_sentence` are also the
report's sections' first lines.
"""

from __future__ import annotations

import math

from bayes_mr.inference.mcmc.budget import cap_message
from bayes_mr.selection.comparison import row_of as _row
from bayes_mr.report.markdown import fmt


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


def _rhat(value) -> str:
    """R-hat to four decimals: against the rule's 1.01, 1.0109 must not read as 1.01."""
    return f"{value:.4f}" if isinstance(value, float) and math.isfinite(value) else fmt(value)


def _multiple(value: float) -> str:
    """A chain's length in integrated times: two digits below 10, whole numbers above (110, not 1.1e+02)."""
    return fmt(value, 2) if value < 10 else f"{value:.0f}"


#: Why an emcee chain stopped unconverged (its ``stopped``), in words: the headline and the bench table.
STOP_REASONS = {"max_steps": "step limit", "max_evaluations": "work budget", "max_seconds": "wall-time cap",
                "projected": "projection", "q_tails": "proposal's tails"}


def _stop_reason(row: dict, machine_limit: str | None = None) -> str:
    """Why a chain stopped unconverged; a projected stop gives the steps and evaluations the rule would need at
    least: τ estimated from a chain shorter than 50 τ is biased low (emcee's own caution), and on the packaged
    damper it kept growing with the chain (convergence.projection), so the projection is a floor, not a
    near miss. A chain the wall-time cap stopped says so as a machine limit (``machine_limit``: the main job's
    sentence for it, :func:`bayes_mr.inference.mcmc.budget.cap_message`), never as a result of its work budget."""
    p = row.get("projection")
    stopped = row.get("stopped")
    if stopped == "projected" and p:
        return (f"stopped when its integrated time ({fmt(p['tau_max'], 2)} steps, a lower bound from a chain this "
                f"short) projected the rule to at least ~{p['steps_needed']} steps "
                f"({p['evaluations_needed']} log-density evaluations) against the {p['steps_allowed']} "
                f"({p['evaluations_allowed']}) its work budget left")
    if stopped == "max_evaluations":
        return f"its work budget ran out ({row.get('evaluations')} log-density evaluations)"
    if stopped == "max_seconds":
        return machine_limit or cap_message(row.get("wall_cap_s"))
    if stopped == "q_tails" and row.get("pareto_k") is not None:
        return (f"met the rule, but its proposals' importance weights have a Pareto k̂ of {fmt(row['pareto_k'], 2)}: "
                f"the fitted proposal underweights part of the posterior, so τ and R-hat do not bound its error")
    return STOP_REASONS.get(stopped, "budget")


def chain_shape(geometry: dict | None) -> str:
    """What makes a chain slow, from its ``geometry`` (:func:`~bayes_mr.inference.mcmc.geometry.chain_geometry`): the
    coordinates spread over their prior range and the ridges; empty when it found neither."""
    if not geometry:
        return ""
    parts = []
    spread = geometry.get("spread_over_prior") or {}
    if spread:
        one = len(spread) == 1
        parts.append(f"{', '.join(spread)} spread over {', '.join(f'{100 * f:.0f}' for f in spread.values())} % of "
                     f"{'its prior range' if one else 'their prior ranges'} (the record hardly informs "
                     f"{'it' if one else 'them'})")
    for a, b, r in geometry.get("ridges") or []:
        parts.append(f"{a} and {b} on a ridge (correlation {r:+.3f}: the record fixes a combination of them)")
    return "; " + "; ".join(parts) if parts else ""


def _posterior_lines(rows: list[dict], selected: str | None, skipped: dict[str, str],
                     work: dict[str, dict] | None = None) -> list[str]:
    """The headline's emcee sentence: which posteriors converged, which did not and why (the chain's length in
    integrated autocorrelation times and its R-hat against the ≥ 50 τ and R-hat < 1.01 asked, and the shape that
    makes it slow: :func:`chain_shape`; a wall-time cap that acted, as a machine limit), and which forms got none
    (the selected one named first). ``work``: ``summary.json``'s ``posterior_work``."""
    chains = [r for r in rows if r["engine"] == "mcmc" and "error" not in r]
    work = work or {}
    lines = []
    if chains:
        unconverged = [f"{r['model']} ({_stop_reason(r, work.get(r['model'], {}).get('machine_limit'))}: "
                       f"{r.get('n_steps')} steps = "
                       f"{_multiple((r.get('n_steps') or 0) / r['tau_max']) if r.get('tau_max') else '?'} τ, "
                       f"R-hat {_rhat(r.get('rhat_max'))}{chain_shape(r.get('geometry'))})"
                       for r in chains if not r.get("converged")]
        evaluations = [r.get("evaluations") for r in chains]  # the work each stands on (absent from older runs)
        spent = ("" if None in evaluations else
                 f"{', '.join(str(n) for n in evaluations)} log-density evaluations with their pilots; ")
        lines.append(f"emcee posteriors for {', '.join(r['model'] for r in chains)} "
                     f"({', '.join(str(r.get('n_steps')) for r in chains)} steps; {spent}R-hat_max "
                     f"{', '.join(_rhat(r.get('rhat_max')) for r in chains)}): "
                     + (f"{', '.join(unconverged)} NOT converged (≥ 50 τ and R-hat < 1.01 asked)."
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
    lines += _posterior_lines(rows, sel, summary.get("mcmc_skipped") or {}, summary.get("posterior_work"))
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
