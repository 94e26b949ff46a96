"""Context for the main job's headline: a paper's parameters and the other residual model.

:func:`published_spencer` predicts the record with Spencer et al. (1997)'s
published parameters next to the identified ones; :func:`noise_sensitivity`
refits every form under the other residual model so the report can say how
the model choice and the Bayes factors move with it.
"""

from __future__ import annotations

import xarray as xr

from bayes_mr.selection.comparison import calibrated_evidence, compare, row_of
from bayes_mr.execution.executor import local_threads
from bayes_mr.inference.identify import predict
from bayes_mr.models import get_model
from bayes_mr.scores import score

#: Where the published Spencer (1997) parameters come from (a secondary source).
SPENCER_SOURCE = ("Spencer, Dyke, Sain & Carlson (1997), J. Eng. Mech. 123(3), prototype damper, "
                  "as quoted in a secondary source (not checked against the paper); converted to SI")


def _laplace_choice(rows: list[dict]) -> dict:
    """Selected model and ln Bayes factors from the least-squares (Laplace) rows."""
    ln_z = {r["model"]: float(r["log_evidence"]) for r in rows if r["engine"] == "lsq" and "error" not in r}
    if not ln_z:
        return {"selected": None, "log_evidence": {}, "bayes_factors": {}}
    sel = max(ln_z, key=ln_z.get)
    ok = [r for r in rows if r["engine"] == "lsq" and "error" not in r]
    cal = calibrated_evidence(ok, "lsq", list(ln_z))  # {} when a row lacks its Laplace terms
    return {"selected": sel, "log_evidence": ln_z, "bayes_factors": {m: ln_z[sel] - z for m, z in ln_z.items()},
            **{k: cal[k] for k in ("selected_calibrated", "bayes_factors_calibrated", "log_evidence_calibrated",
                                   "evidence_scale") if k in cal}}


def noise_sensitivity(part_a: xr.Dataset, forms: tuple[str, ...], noise: str, rows: list[dict], *,
                      seed: int, say) -> dict:
    """The model choice under the other residual model (least squares, Laplace evidence).

    The comparison's own likelihood treats the residual as ``noise``;
    here every form is refitted with the other one (``iid`` ↔ ``ar``), so the
    report can say how the selection and the ln Bayes factors move when the
    residual's correlation in time is (or is not) modelled (an iid
    likelihood's ln BF grows with the sampling rate, an AR one with the
    information in the record).

    Returns
    -------
    dict
        ``{noise: {"selected", "log_evidence", "bayes_factors", "n_eff"}}`` for
        both residual models, each from lsq rows on part A (the raw Laplace
        evidence), with the calibrated evidence's ``selected_calibrated``,
        ``bayes_factors_calibrated``, ``log_evidence_calibrated`` and
        ``evidence_scale`` (:func:`bayes_mr.selection.comparison.calibrated_evidence`).
    """
    other = "ar" if noise == "iid" else "iid"
    say(f"{', '.join(forms)}: least squares under the {other} residual model")
    with local_threads() as pool:  # side by side on this process's threads (the same fits, executor.py)
        alt_rows = compare(part_a, list(forms), engines=["lsq"], seed=seed, progress=say, noise=other,
                           executor=pool).rows
    out = {}
    for name, rs in ((noise, rows), (other, alt_rows)):
        out[name] = _laplace_choice(rs)
        out[name]["n_eff"] = {r["model"]: r.get("n_eff") for r in rs if r["engine"] == "lsq" and "error" not in r}
    return out


def published_spencer(part_a, part_b, rows: list[dict]) -> dict:
    """The published Spencer (1997) parameters on A and B, next to the identified ones."""
    model = get_model("spencer")
    kind = part_b.attrs["kind"]
    names = model.param_names(kind)
    published = dict(zip(names, model.theta(kind, {})))
    out = {"source": SPENCER_SOURCE, "params": published}
    for label, rec in (("part_a", part_a), ("part_b", part_b)):
        try:
            pred = predict(model, rec, published)
            s = score(rec, pred)
            out[label] = {"force_nrmse": s["force_nrmse"], "mse": s["mse"], "force_errors": s["force_errors"]}
        except ValueError as exc:
            out[label] = {"error": str(exc)}
    ident = row_of(rows, "spencer", "lsq")
    if ident is not None:
        out["identified"] = {"engine": "lsq", "params": ident["params"], "params_sd": ident["params_sd"]}
    return out
