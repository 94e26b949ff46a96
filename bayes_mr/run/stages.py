"""The main job's stages that need only the first pass: the diagnosis of the selected form and the virtual
shake table.

Both start from what every form's least squares and UKF gave on part A (the
rows of :func:`bayes_mr.run.job.first_pass`), so they can run beside the
posteriors (:mod:`bayes_mr.run.aside`). :func:`diagnose_selected`
diagnoses the selected form at the record's own rate; :func:`shake_table`
builds the thesis's frame around the measured damper and identifies the
best of the thesis's forms on it from displacement and acceleration only.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import xarray as xr

from bayes_mr.inference import results
from bayes_mr.selection.comparison import row_of, simulating_point
from bayes_mr.data.virtual_table import THESIS_FRAME, implied_damper_force, virtual_shake_table
from bayes_mr.inference.identify import UKF, Identify, LeastSquares, predict
from bayes_mr.inference.lsq.least_squares import LSQSettings
from bayes_mr.run.records import diagnosis_dir, prepare
from bayes_mr.scores import force_nrmse, score

if TYPE_CHECKING:
    from bayes_mr.run.plan import Budget


#: The forms the thesis identified on its shake table (Spencer's model is a device model with 14 parameters).
THESIS_FORMS = ("normalized-bouc-wen", "dahl", "lugre", "bouc-wen")


def best_thesis_form(comp: dict) -> str | None:
    """The thesis form with the highest evidence on the selection route (for the virtual shake table)."""
    ln_z = {r["model"]: float(r["log_evidence"]) for r in comp["rows"]
            if r["engine"] == comp["evidence_engine"] and "error" not in r and r["model"] in THESIS_FORMS}
    return max(ln_z, key=ln_z.get) if ln_z else None


def shake_table(part_a, part_b, model: str, budget: Budget, *, seed: int = 0, out_dir: Path, say) -> dict:
    """The thesis's UKF on a virtual shake table built from the measured damper (A to train, B to check).

    The identified model's ``c`` and ``k`` hold the frame's and the damper's
    linear terms together, so the damper force it implies is its restoring
    force less the known frame's (:func:`~bayes_mr.data.virtual_table.implied_damper_force`);
    ``force_nrmse_a``/``_b`` score that against the measured force. The
    hysteretic part alone (the structure model's ``force`` output) is scored
    beside it as ``hysteretic_nrmse_a``/``_b``.
    """
    vst = {"a": virtual_shake_table(part_a), "b": virtual_shake_table(part_b)}
    out = {"frame": dict(THESIS_FRAME), "model": model}
    # least squares from its two best convex-screened starts: on the 13-s part A the normalized Bouc–Wen
    # fit takes ~120 s so (~190 s from four, to the same optimum, measured); the UKF is the thesis's method
    estimators = {"ukf": UKF(n_lhs=budget.ukf_lhs, taus=budget.ukf_taus),
                  "lsq": LeastSquares(LSQSettings(n_starts=2))}
    for label in budget.shake_table_engines:
        est = estimators[label]
        say(f"virtual shake table: {model} × {label} (displacement and acceleration only)")
        try:
            idata = Identify(model, est).fit(vst["a"], seed=seed, progress=False)
        except (RuntimeError, ValueError) as exc:
            out[label] = {"error": str(exc)}
            continue
        results.save(idata, out_dir / "fits" / f"shake_table__{model.replace('+', '_')}__{label}.nc")
        summ = results.summary_of(idata)
        theta = results.point_of(idata)
        entry = {"params": summ.params, "mse": summ.mse, "trained": summ.trained, "diverged": summ.diverged,
                 "wall_s": summ.wall_s}
        for part, rec in vst.items():
            try:
                pred = predict(model, rec, theta)
            except ValueError as exc:
                entry[f"error_{part}"] = str(exc)
                continue
            s = score(rec, pred)  # its force NRMSE is that of the model's force output, the hysteretic part
            implied = implied_damper_force(rec, pred)
            entry[f"force_nrmse_{part}"] = force_nrmse(rec["force"].values, implied, rec["valid"].values.astype(bool))
            entry[f"hysteretic_nrmse_{part}"] = s["force_nrmse"]
            entry[f"mse_{part}"] = s["mse"]
            entry[f"_force_{part}"] = implied
        out[label] = entry
    out["_vst_b"] = vst["b"]
    return out


def diagnose_selected(record: xr.Dataset | None, model: str, budget: Budget, *, rows: list[dict],
                      seed: int, out_dir: Path, say) -> dict[str, dict]:
    """Diagnose the selected model on part A at :attr:`Budget.diagnose_fs`, its extension validated on B.

    The record is prepared again at the diagnosis's rate (same trim and split
    as the comparison's, :func:`prepare`); the model is refitted there from
    its least-squares optimum of the comparison (:func:`bayes_mr.diagnosis.extend.fit_at`,
    no search from scratch), and :func:`~bayes_mr.diagnosis.diagnose.diagnose` ranks
    the MR-damper effects (:data:`~bayes_mr.diagnosis.extend.CANDIDATES`) once against it and adds the passing
    ones best first (``search="ranked"``). The report, figures, ``baseline.nc``
    and ``extended.nc`` go to ``out_dir/diagnose_MODEL``; the extended model,
    as fitted on A, predicts part B at the same rate (``validation``).

    Returns
    -------
    dict
        ``{model: diagnose JSON}`` (``{"error": …}`` when it failed), plus the
        private ``_part_b`` (part B at the diagnosis's rate) for the figures.
    """
    from bayes_mr.diagnosis.diagnose import Search, diagnose
    from bayes_mr.diagnosis.extend import CANDIDATES

    row = row_of(rows, model, "lsq")
    if row is None:
        return {model: {"error": f"{model} has no least-squares fit to start the diagnosis from"}}
    _, a_hi, b_hi, _ = prepare(replace(budget, fs=budget.diagnose_fs or budget.fs), record)
    window = a_hi if budget.diagnose_s is None else a_hi.isel(
        time=slice(0, int(budget.diagnose_s * float(a_hi.attrs["fs"]))))
    say(f"diagnosing {model} on {window.sizes['time'] / float(a_hi.attrs['fs']):.1f} s of part A at "
        f"{float(a_hi.attrs['fs']):.0f} Hz (from its least-squares optimum)")
    try:
        out = diagnose(window, model, start=simulating_point(row),
                       search=Search("ranked", candidates=CANDIDATES, max_effects=5), validate=b_hi, seed=seed,
                       terms=budget.terms, progress=say, noise=budget.noise,
                       out_dir=diagnosis_dir(out_dir, model)).to_dict()
    except (RuntimeError, ValueError) as exc:
        out = {"error": str(exc)}
    return {model: out, "_part_b": b_hi}
