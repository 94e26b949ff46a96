"""Figures and the Markdown report of a diagnosis (:func:`bayes_mr.diagnosis.diagnose.diagnose`).

Everything drawn here was computed before (:mod:`bayes_mr.diagnosis.residuals`,
:mod:`bayes_mr.diagnosis.screen`); figures are deterministic for a given
diagnosis and drawn with the object API of :mod:`.figures` (no pyplot, no
global backend). This module imports nothing of :mod:`bayes_mr.diagnosis.diagnose` at
run time (the fits and residual views it draws are passed in), so the lazy
call from ``diagnose(out_dir=...)`` makes no import cycle.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import xarray as xr

from bayes_mr.report.figures import save, subplots
from bayes_mr.report.markdown import fmt

if TYPE_CHECKING:  # annotations only
    from bayes_mr.diagnosis.fits import Fit
    from bayes_mr.diagnosis.residuals import Views

#: Most points drawn per line (long records are thinned evenly).
MAX_POINTS = 20000
#: Hysteresis window length [s] (or a fifth of the record if shorter).
LOOP_WINDOW_S = 2.0
UNITS = {"displacement": "m", "acceleration": "m/s²", "force": "N", "time": "s", "velocity": "m/s",
         "envelope": "m", "voltage": "V"}


def _save(fig, path: Path) -> Path:
    # dpi 100 and no "Software" PNG text field: the diagnosis figures as they have always been written
    return save(fig, path, dpi=100, metadata={"Software": None})


def _thin(n: int) -> slice:
    return slice(None, None, max(1, n // MAX_POINTS))


def _restoring(record: xr.Dataset, channels: dict[str, np.ndarray] | None) -> np.ndarray:
    """Force the loops show: device — force; structure — restoring force −m·(absolute acceleration)."""
    src = record if channels is None else channels
    if record.attrs["kind"] == "device":
        return np.asarray(src["force"] if channels else record["force"].values)
    acc = np.asarray(src["acceleration"] if channels else record["acceleration"].values)
    return -float(record.attrs["mass"]) * acc


def _worst_window(record: xr.Dataset, r: np.ndarray) -> slice:
    """The window where the baseline's residual RMS is largest (where the model fails most)."""
    n = record.sizes["time"]
    fs = float(record.attrs["fs"])
    w = int(min(LOOP_WINDOW_S * fs, max(n // 5, 2)))
    power = np.convolve(r * r, np.ones(w), mode="valid")
    i = int(np.argmax(power))
    return slice(i, i + w)


def hysteresis_figure(record: xr.Dataset, base: Fit, ext: Fit, window: slice):
    """Force–displacement loops: measured against the baseline (left) and the extended model (right)."""
    x = record["displacement"].values[window] * 1e3
    f = _restoring(record, None)[window]
    label = "force [N]" if record.attrs["kind"] == "device" else "restoring force −m·a [N]"
    fig, axes = subplots(1, 2, figsize=(10, 4), sharey=True)
    t = record["time"].values[window]
    for ax, fit, title in ((axes[0], base, "before"), (axes[1], ext, "after")):
        ax.plot(x, f, color="0.55", lw=1.2, label="measured")
        ax.plot(x, _restoring(record, fit.predicted)[window], color="tab:red", lw=0.8, label=fit.name)
        ax.set_title(f"{title}: {fit.name}  ({t[0]:.2f}–{t[-1]:.2f} s)", fontsize=9)
        ax.set_xlabel("displacement [mm]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].set_ylabel(label)
    fig.tight_layout()
    return fig


def residual_time_figure(record: xr.Dataset, before: Views, after: Views, base: Fit, ext: Fit):
    """Residual of each measured channel against time, before and after."""
    chans = list(before.channels)
    fig, axes = subplots(len(chans), 1, figsize=(9, 2.2 * len(chans)), sharex=True, squeeze=False)
    t = record["time"].values
    sl = _thin(t.size)
    for ax, c in zip(axes[:, 0], chans):
        ax.plot(t[sl], before.channels[c].residual[sl], lw=0.6, color="tab:blue", label=f"before ({base.name})")
        if after is not before:
            ax.plot(t[sl], after.channels[c].residual[sl], lw=0.6, color="tab:red", alpha=0.8,
                    label=f"after ({ext.name})")
        ax.set_ylabel(f"{c} [{UNITS.get(c, '')}]", fontsize=8)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper right")
    axes[-1, 0].set_xlabel("time [s]")
    axes[0, 0].set_title("residual = measured − simulated")
    fig.tight_layout()
    return fig


def residual_binned_figure(before: Views, after: Views):
    """Standardised residual against each variable (binned mean ± SD), before and after; η² in titles."""
    chans = list(before.channels)
    variables = list(next(iter(before.channels.values())).bins)
    fig, axes = subplots(len(chans), len(variables), figsize=(2.9 * len(variables), 2.4 * len(chans)),
                             squeeze=False)
    for i, c in enumerate(chans):
        for j, v in enumerate(variables):
            ax = axes[i, j]
            for views, color, label in ((before, "tab:blue", "before"), (after, "tab:red", "after")):
                if label == "after" and after is before:
                    continue
                b = views.channels[c].bins[v]
                ax.plot(b.center, b.mean, "o-", ms=2, lw=0.9, color=color, label=f"{label} η²={b.eta2:.3f}")
                ax.fill_between(b.center, b.mean - b.sd, b.mean + b.sd, color=color, alpha=0.12, lw=0)
            ax.axhline(0, color="k", lw=0.5)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=6)
            if i == len(chans) - 1:
                ax.set_xlabel(f"{v} [{UNITS.get(v, '')}]", fontsize=8)
            if j == 0:
                ax.set_ylabel(f"{c} residual / RMS", fontsize=8)
    fig.tight_layout()
    return fig


def whiteness_figure(before: Views, after: Views, n: int):
    """Residual autocorrelation of each channel, before and after, with the white-noise band."""
    chans = list(before.channels)
    fig, axes = subplots(1, len(chans), figsize=(4 * len(chans), 3), squeeze=False)
    band = 1.96 / math.sqrt(n)
    for ax, c in zip(axes[0], chans):
        for views, color, label in ((before, "tab:blue", "before"), (after, "tab:red", "after")):
            if label == "after" and after is before:
                continue
            cv = views.channels[c]
            ax.plot(np.arange(cv.acf.size), cv.acf, color=color, lw=0.9,
                    label=f"{label}: τ={cv.tau:.1f}, Ljung–Box p={cv.ljung_box_p:.2g}")
        ax.axhspan(-band, band, color="0.8", alpha=0.5, lw=0)
        ax.set_title(c, fontsize=9)
        ax.set_xlabel("lag [samples]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    axes[0, 0].set_ylabel("autocorrelation")
    fig.tight_layout()
    return fig


def crosscorr_figure(before: Views, after: Views):
    """Cross-correlation of pairs of channels (measured vs simulated), and residual vs input."""
    pairs = list(before.cross)
    chans = list(before.input_cross)
    ncol = max(len(pairs), len(chans), 1)
    fig, axes = subplots(2, ncol, figsize=(4 * ncol, 5.5), squeeze=False)
    for ax, key in zip(axes[0], pairs):
        lags, cm, cs = before.cross[key]
        ax.plot(lags, cm, color="0.4", lw=1.2, label="measured")
        ax.plot(lags, cs, color="tab:blue", lw=0.8, label="baseline")
        if after is not before:
            ax.plot(lags, after.cross[key][2], color="tab:red", lw=0.8, ls="--", label="extended")
        ax.set_title(key.replace("~", " vs "), fontsize=9)
        ax.set_xlabel("lag [samples]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    for ax, c in zip(axes[1], chans):
        for views, color, label in ((before, "tab:blue", "before"), (after, "tab:red", "after")):
            if label == "after" and after is before:
                continue
            lags, cc = views.input_cross[c]
            ax.plot(lags, cc, color=color, lw=0.9, label=f"{label} (lag {views.channels[c].lag_samples:+.2f})")
        ax.set_title(f"{c} residual vs input", fontsize=9)
        ax.set_xlabel("lag [samples]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    for ax in list(axes[0][len(pairs):]) + list(axes[1][len(chans):]):
        ax.axis("off")
    fig.tight_layout()
    return fig


#: Length of the measured-vs-predicted window [s].
WINDOW_S = 0.5


def window_figure(record: xr.Dataset, base: Fit, ext: Fit, channel: str, centre: int):
    """A :data:`WINDOW_S` window of one channel measured vs predicted, the residual under it."""
    fs = float(record.attrs["fs"])
    half = max(2, int(WINDOW_S * fs / 2))
    sl = slice(max(0, centre - half), min(record.sizes["time"], centre + half))
    t = record["time"].values[sl]
    y = record[channel].values[sl]
    fig, (top, bottom) = subplots(2, 1, figsize=(9, 5), sharex=True, gridspec_kw={"height_ratios": [2, 1]})
    top.plot(t, y, color="0.3", lw=1.4, label="measured")
    fits = ((base, "tab:blue"),) if ext is base else ((base, "tab:blue"), (ext, "tab:red"))
    for fit, color in fits:
        top.plot(t, fit.predicted[channel][sl], color=color, lw=0.9, label=f"predicted: {fit.name}")
        bottom.plot(t, y - fit.predicted[channel][sl], color=color, lw=0.8, label=fit.name)
    unit = UNITS.get(channel, "")
    top.set_ylabel(f"{channel} [{unit}]")
    top.set_title(f"{channel}: the {WINDOW_S:g} s where the final model's residual is largest", fontsize=9)
    bottom.set_ylabel(f"residual [{unit}]")
    bottom.set_xlabel("time [s]")
    bottom.axhline(0, color="k", lw=0.5)
    for ax in (top, bottom):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    return fig


def _bars(ax, rows: list[dict], labels: list[str], title: str, threshold: float) -> None:
    ratios = [r["ratio"] if r["ratio"] is not None else np.nan for r in rows]
    ax.bar(range(len(rows)), ratios, color="tab:purple", alpha=0.8)
    ax.axhline(1.0, color="k", lw=0.8, label="noise floor")
    ax.axhline(threshold, color="k", lw=0.8, ls="--", label=f"{threshold:g} × floor")
    ax.set_xticks(range(len(rows)))
    ax.set_xticklabels(labels, rotation=60, fontsize=6)
    ax.set_title(title, fontsize=8)
    ax.grid(alpha=0.3, axis="y")


def unexplained_figure(unexplained: dict, threshold: float):
    """Residual RMS over the noise floor of each channel by velocity, displacement, command state,
    frequency band and time (the ``unexplained`` JSON's ``where``)."""
    chans = list(unexplained)
    fig, axes = subplots(len(chans), 5, figsize=(16, 3.0 * len(chans)), squeeze=False)
    for row, c in zip(axes, chans):
        w = unexplained[c]["where"]
        _bars(row[0], w["velocity"], [f"{(r['lo'] + r['hi']) / 2:.2g}" for r in w["velocity"]],
              f"{c}: by velocity [m/s]", threshold)
        _bars(row[1], w["displacement"], [f"{(r['lo'] + r['hi']) / 2:.2g}" for r in w["displacement"]],
              f"{c}: by displacement [m]", threshold)
        states = ("on", "off", "after_switch_on", "after_switch_off")
        if w["command"]:
            _bars(row[2], [{"ratio": w["command"][k]} for k in states], list(states), f"{c}: by command state",
                  threshold)
        else:
            row[2].axis("off")
        _bars(row[3], w["frequency"], [f"{r['lo_hz']:g}–{r['hi_hz']:.4g}" for r in w["frequency"]],
              f"{c}: by band [Hz]", threshold)
        _bars(row[4], w["time"], [f"{r['t0']:.3g}" for r in w["time"]], f"{c}: over time [s]", threshold)
        row[0].set_ylabel("residual RMS / noise floor", fontsize=8)
        row[0].legend(fontsize=6)
    fig.tight_layout()
    return fig


def scores_figure(causes: list[dict], threshold: float):
    """Round-one score of every candidate effect with the decision threshold."""
    rows = [c for c in causes if c.get("score") is not None][::-1]
    fig, ax = subplots(figsize=(6.5, 0.35 * len(rows) + 1.2))
    labels = [c["name"] + (f" ({c['channel']})" if c.get("channel") else "") for c in rows]
    values = [c["score"] for c in rows]
    colors = ["tab:red" if c.get("selected") else "tab:gray" for c in rows]
    ax.barh(labels, values, color=colors)
    ax.axvline(threshold, color="k", ls="--", lw=1, label=f"threshold {threshold:g}")
    ax.set_xscale("symlog", linthresh=10)
    ax.set_xlabel("score (κ-corrected ln Bayes factor against the baseline)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, axis="x")
    fig.tight_layout()
    return fig


def _span(unit: str, lo: str = "lo", hi: str = "hi"):
    """Label of a bin: its range and unit."""
    return lambda r: f"{fmt(r[lo])}…{fmt(r[hi])} {unit}"


def _extremes(rows: list[dict], label) -> str:
    rows = [r for r in rows if r.get("ratio") is not None]
    hi, lo = max(rows, key=lambda r: r["ratio"]), min(rows, key=lambda r: r["ratio"])
    return f"{fmt(hi['ratio'])} × the floor at {label(hi)}, {fmt(lo['ratio'])} at {label(lo)}"


def unexplained_text(out: dict) -> list[str]:
    """The report's "What remains unexplained" section: the ratio to the floor, and where it lives."""
    lines = ["## What remains unexplained", "",
             f"**Verdict: {out['verdict']}.** Residual RMS over the channel's noise floor (≈ 1 for a model right "
             f"to the noise; above {fmt(out['floor_ratio_threshold'])} on any fitted channel with no effect named "
             f"is \"unexplained by the vocabulary\"), for the final model `{out['extended']['model']}`.", "",
             "| channel | noise floor | residual RMS | ratio | baseline ratio | variance unexplained | "
             "Ljung–Box p | τ [samples] |", "|---|---|---|---|---|---|---|---|"]
    for c, u in out["unexplained"].items():
        tag = "" if u["in_likelihood"] else " (not fitted)"
        lines.append(f"| {c}{tag} | {fmt(u['noise_floor'])} | {fmt(u['rms'])} | {fmt(u['ratio'])} | "
                     f"{fmt(u['baseline_ratio'])} | {fmt(100 * u['variance_share'])} % | {fmt(u['ljung_box_p'])} | "
                     f"{fmt(u['tau_samples'])} |")
    lines.append("")
    for c, u in out["unexplained"].items():
        w = u["where"]
        bits = [f"by velocity {_extremes(w['velocity'], _span('m/s'))}",
                f"by displacement {_extremes(w['displacement'], _span('m'))}"]
        cmd = w["command"]
        if cmd:
            bits.append(f"command on {fmt(cmd['on'])}, off {fmt(cmd['off'])}, in the {fmt(cmd['switch_window_s'])} s "
                        f"after switching on {fmt(cmd['after_switch_on'])} and off {fmt(cmd['after_switch_off'])} "
                        f"({cmd['switches']} switches)")
        band = max((b for b in w["frequency"] if b["share"] is not None), key=lambda b: b["share"])
        bits.append(f"its largest share of variance ({fmt(100 * band['share'])} %) in {fmt(band['lo_hz'])}–{fmt(band['hi_hz'])} Hz, "
                    f"{fmt(band['ratio'])} × white noise at the floor there")
        bits.append(f"over time {_extremes(w['time'], _span('s', 't0', 't1'))}")
        lines.append(f"- **{c}**: " + "; ".join(bits) + ".")
    return lines + [""]


def terms_text(out: dict) -> list[str]:
    """The report's "Terms outside the vocabulary" section (the term search, when it ran)."""
    t = out.get("terms")
    if not t:
        return []
    lines = ["## Terms outside the vocabulary", "",
             f"Searched ({t['asked']}) by lasso on the library's output sensitivities over the first "
             f"{fmt(100 * (1 - t['holdout']))} % of the record; each proposal refitted inside the model; it passes "
             f"if its score passes the threshold, Δ ln Z > 0 and the error falls on the held-out last "
             f"{fmt(100 * t['holdout'])} % (in ≥ 8 of 10 blocks), and is kept only if it passes again with the "
             f"first {fmt(100 * t['holdout'])} % held out instead (other fold).", "",
             "| term | score | Δ ln Z | held-out MSE ratio | blocks better | other fold: ratio, blocks | kept |",
             "|---|---|---|---|---|---|---|"]
    for r in t["proposed"]:
        o = r.get("other_fold")
        lines.append(f"| `{r['term']}` | {fmt(r.get('score'))} | {fmt(r.get('delta_log_evidence'))} | "
                     f"{fmt(r.get('heldout_mse_ratio'))} | {r.get('heldout_blocks_better', '–')} | "
                     + (f"{fmt(o.get('heldout_mse_ratio'))}, {o.get('heldout_blocks_better', '–')}" if o else "–")
                     + f" | {'yes' if r['kept'] else 'no'} |")
    lines.append("")
    if t["kept"]:
        lines += [f"Kept: `{t['model']}` (whole record: MSE ratio {fmt(t['mse_ratio'])}, "
                  f"Δ ln Z {fmt(t['delta_log_evidence'])} against `{out['extended']['model']}`)."]
        lines += [f"- {s}" for s in t["sentences"]]
        v, vt = out.get("validation") or {}, t.get("validation") or {}
        if vt:
            lines += ["", f"On the validation record ({v.get('source', '')}): force NRMSE "
                          f"{fmt(v.get('extended_force_nrmse'))} with `{out['extended']['model']}`, "
                          f"{fmt(vt.get('force_nrmse'))} with the kept terms (MSE {fmt(v.get('extended_mse'))} → "
                          f"{fmt(vt.get('mse'))})."]
    else:
        lines.append("No term kept.")
    return lines + [""]


def _markdown(out: dict, figures: dict[str, Path]) -> str:
    rec = out["record"]
    lines = [f"# Diagnosis of `{rec['source']}`", "",
             f"{rec['kind']} test, {rec['samples']} samples at {rec['fs']:.6g} Hz ({rec['duration_s']:.3g} s); "
             f"{out['masked']} samples masked by quality control.", ""]
    named = out["effects"]
    lines += ["## Verdict", "",
              f"**Cause: `{out['cause']}`**" + (f" (all named: {', '.join(f'`{n}`' for n in named)})"
                                               if len(named) > 1 else "") + f" — {out['verdict']}", ""]
    g = out["gain"]
    lines += [f"- baseline `{out['baseline']['model']}`: MSE {fmt(out['baseline']['mse'])}, "
              f"ln Z {fmt(out['baseline']['log_evidence'], 8)}",
              f"- extended `{out['extended']['model']}`: MSE {fmt(out['extended']['mse'])}, "
              f"ln Z {fmt(out['extended']['log_evidence'], 8)}",
              f"- MSE ratio (extended/baseline) {fmt(g['mse_ratio'])}; Δ ln Z (Laplace, iid) "
              f"{fmt(g['delta_log_evidence'])}; validation MSE ratio {fmt(g['validation_mse_ratio'])}",
              f"- decision threshold on the score: {fmt(out['threshold'])}; wall time {fmt(out.get('wall_s'))} s", ""]
    lines += unexplained_text(out)
    lines += terms_text(out)
    if out.get("baselines"):
        lines += ["## Baseline chosen by evidence", "", "| model | ln Z (Laplace) | MSE |", "|---|---|---|"]
        for row in out["baselines"]:
            lines.append(f"| {row['model']} | {fmt(row['log_evidence'], 8)} | {fmt(row['mse'])} |")
        lines.append("")
    lines += ["## Candidate effects (round 1, against the baseline)", "",
              "score = Δℓ/κ + Occam: Δℓ the log-likelihood gain, κ the variance inflation of correlated "
              "residuals for the effect's parameters, Occam ≤ 0 their posterior-to-prior volume.", "",
              "| effect | score | κ | Δℓ | Occam | Δ ln Z (iid) | MSE ratio | parameters | named |",
              "|---|---|---|---|---|---|---|---|---|"]
    for c in out["causes"]:
        name = c["name"] + (f" ({c['channel']})" if c.get("channel") else "")
        params = ", ".join(f"{k}={fmt(v)}" for k, v in c.get("params", {}).items())
        lines.append(f"| {name} | {fmt(c['score'])} | {fmt(c['kappa'])} | {fmt(c['delta_loglik'])} | "
                     f"{fmt(c['occam'])} | {fmt(c['delta_log_evidence'])} | {fmt(c['mse_ratio'])} | {params} | "
                     f"{'yes' if c.get('selected') else ''} |")
    if len(out["selection"]) > 1:
        lines += ["", "Forward selection: " + " → ".join(
            f"`{s['name']}` (score {fmt(s['score'])} in round {s['round']})" for s in out["selection"])]
    lines += ["", "## Residuals", "",
              "η² = share of the residual variance explained by its binned dependence on each variable; "
              "τ = integrated autocorrelation time [samples]; lag = samples by which the measured channel "
              "trails its simulation.", "",
              "| channel | | RMS | η² time | η² displacement | η² velocity | η² envelope | η² voltage | τ | "
              "Ljung–Box p | lag |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for stage in ("before", "after"):
        for c, s in out["residuals"][stage].items():
            e = s["eta2"]
            lines.append(f"| {c} | {stage} | {fmt(s['rms'])} | {fmt(e.get('time'))} | {fmt(e.get('displacement'))} | "
                         f"{fmt(e.get('velocity'))} | {fmt(e.get('envelope'))} | {fmt(e.get('voltage', float('nan')))} | "
                         f"{fmt(s['tau_samples'])} | {fmt(s['ljung_box_p'])} | {fmt(s['lag_samples'])} |")
    if out.get("validation"):
        v = out["validation"]
        lines += ["", "## Validation (method 2)", "",
                  f"On `{v['source']}`: baseline MSE {fmt(v['baseline_mse'])}, extended MSE {fmt(v['extended_mse'])}, "
                  f"ratio {fmt(v['mse_ratio'])}; force NRMSE baseline {fmt(v.get('baseline_force_nrmse'))}, "
                  f"extended {fmt(v.get('extended_force_nrmse'))}."]
    titles = {"hysteresis": "Loops where the baseline fails most, before and after",
              "residuals_time": "Residuals against time", "residuals_binned": "Residuals against the variables",
              "whiteness": "Whiteness of the residuals", "crosscorr": "Cross-correlations",
              "scores": "Scores of the candidate effects",
              "unexplained": "Where the residual lives (RMS over the noise floor)"}
    titles.update({k: f"{k.split('_', 1)[1]}: measured vs predicted, residual under it"
                   for k in figures if k.startswith("window_")})
    lines += ["", "## Figures", ""]
    for key, path in figures.items():
        lines += [f"### {titles.get(key, key)}", "", f"![{key}]({path.name})", ""]
    return "\n".join(lines) + "\n"


def write_report(out: dict, record: xr.Dataset, base: Fit, ext: Fit, before: Views, after: Views,
                 rounds, out_dir: Path) -> dict[str, Path]:
    """Write the figures and ``diagnose.md`` into ``out_dir``; return name → path (``report`` included)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    power = sum((cv.residual / cv.sigma) ** 2 for cv in before.channels.values() if cv.sigma > 0)
    window = _worst_window(record, np.sqrt(power))
    figures = {
        "hysteresis": _save(hysteresis_figure(record, base, ext, window), out_dir / "hysteresis.png"),
        "residuals_time": _save(residual_time_figure(record, before, after, base, ext), out_dir / "residuals_time.png"),
        "residuals_binned": _save(residual_binned_figure(before, after), out_dir / "residuals_binned.png"),
        "whiteness": _save(whiteness_figure(before, after, record.sizes["time"]), out_dir / "whiteness.png"),
        "crosscorr": _save(crosscorr_figure(before, after), out_dir / "crosscorr.png"),
    }
    for c, cv in after.channels.items():  # where the final model is worst, for each channel
        w = max(2, int(WINDOW_S * float(record.attrs["fs"])))
        centre = int(np.argmax(np.convolve(cv.residual**2, np.ones(w), mode="same")))
        figures[f"window_{c}"] = _save(window_figure(record, base, ext, c, centre), out_dir / f"window_{c}.png")
    figures["unexplained"] = _save(unexplained_figure(out["unexplained"], out["floor_ratio_threshold"]),
                                   out_dir / "unexplained.png")
    if out["causes"]:
        figures["scores"] = _save(scores_figure(out["causes"], out["threshold"]), out_dir / "scores.png")
    report = out_dir / "diagnose.md"
    report.write_text(_markdown(out, figures))
    return {**figures, "report": report}

