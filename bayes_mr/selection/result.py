"""What :func:`~bayes_mr.selection.comparison.compare` returns: a :class:`Comparison`.

>>> cmp = bm.compare(record, ["dahl", "lugre"], engines=("lsq",))   # doctest: +SKIP
>>> cmp.selected, cmp.bayes_factors                               # doctest: +SKIP
>>> cmp.table()                                                    # doctest: +SKIP
>>> cmp.idata["dahl", "lsq"]                                       # doctest: +SKIP

The JSON keys (``compare`` of ``docs/CONTRACT.md``, what ``bayes-mr compare --json``
writes) are :meth:`Comparison.to_dict`; the fits themselves, as ArviZ
InferenceData, are :attr:`Comparison.idata`.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import pandas as pd

from bayes_mr.report import figures


@dataclass(frozen=True)
class Comparison:
    """Models × engines fitted on one record, the evidence of each and the model it selects.

    Attributes
    ----------
    data : dict
        The comparison's JSON keys (read them through the properties, or
        :meth:`to_dict` for a copy).
    idata : Mapping
        (model, engine) → :class:`arviz.InferenceData` of every fit that did not fail.
    """

    data: dict = field(repr=False)
    idata: Mapping = field(default_factory=dict, repr=False, compare=False)

    # --- what users read -------------------------------------------------------------------
    @property
    def rows(self) -> list[dict]:
        """One dict per model × engine, in the order fitted: the ``fit`` keys, or ``error``."""
        return self.data["rows"]

    @property
    def selected(self) -> str | None:
        """The selected model (None when the evidence did not converge and the selection was refused)."""
        return self.data["selected"]

    @property
    def selected_by(self) -> str | None:
        """What ``selected`` was chosen on, e.g. ``calibrated laplace evidence`` or ``mse``."""
        return self.data.get("selected_by")

    @property
    def bayes_factors(self) -> dict[str, float]:
        """Model → ln Z(selected) − ln Z(model) on the evidence route [nats]."""
        return self.data["bayes_factors"]

    @property
    def bayes_factors_calibrated(self) -> dict[str, float]:
        """Model → ln Z_k̄(best) − ln Z_k̄(model) of the calibrated evidence (empty without one)."""
        return self.data.get("bayes_factors_calibrated") or {}

    @property
    def evidence_route(self) -> str | None:
        """``ti`` or ``laplace``: the route whose evidence every model has (None: selected by MSE)."""
        return self.data.get("evidence_route")

    @property
    def evidence_engine(self) -> str | None:
        """The engine of that route (``mcmc`` or ``lsq``)."""
        return self.data.get("evidence_engine")

    @property
    def refused(self) -> str | None:
        """Why nothing was selected (an unconverged evidence), else None."""
        return self.data.get("refused")

    @property
    def crosscheck(self) -> dict[str, dict[str, dict[str, float]]]:
        """Model → parameter → UKF against MCMC (``z``, ``sd_ratio``…), where both engines ran."""
        return self.data.get("crosscheck") or {}

    @property
    def models(self) -> list[str]:
        """The models compared, in order."""
        return list(dict.fromkeys(r["model"] for r in self.rows))

    @property
    def engines(self) -> list[str]:
        """The engines run, in order."""
        return list(dict.fromkeys(r["engine"] for r in self.rows))

    def row(self, model: str, engine: str) -> dict | None:
        """The row of ``model`` × ``engine`` (None if it was not run)."""
        return next((r for r in self.rows if r["model"] == model and r["engine"] == engine), None)

    # --- views -----------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """A copy of the JSON keys, exactly what ``bayes-mr compare --json`` writes."""
        return copy.deepcopy(self.data)

    def table(self) -> pd.DataFrame:
        """One line per row: model, engine, ln Z and its route, ln BF (raw, calibrated), MSE, … (:func:`table`)."""
        return table(self.data)

    def plot(self, *, title: str | None = None):
        """Bayes factors and MSE of every model × engine, the selected model's rows highlighted.

        Returns
        -------
        matplotlib.figure.Figure
        """
        df = self.table()
        labels = [f"{m} · {e}" for m, e in zip(df["model"], df["engine"])]
        panels = {}
        for column in ("ln BF vs selected", "ln BF calibrated", "MSE"):
            values = [_float(v) for v in df[column]]
            if any(v is not None for v in values):
                panels[column] = dict(zip(labels, values))
        chosen = {label for label, m in zip(labels, df["model"]) if m == self.selected}
        if title is None:
            title = f"selected: {self.selected}" if self.selected else "no model selected"
        return figures.bars(panels, title=title, highlight=chosen)

    def __repr__(self) -> str:
        how = f" by {self.selected_by}" if self.selected_by else ""
        return (f"Comparison(selected={self.selected!r}{how}, models={self.models}, engines={self.engines}, "
                f"fits={len(self.idata)})")

    def _repr_html_(self) -> str:
        return f"<p>{repr(self)}</p>" + self.table().to_html(index=False, na_rep="")


def _float(v) -> float | None:
    try:
        v = float(v)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def table(out: Mapping) -> pd.DataFrame:
    """One line per row of a comparison: model, engine, residual model and n_eff, ln Z (route, error), ln BF (raw and
    calibrated), MSE, force NRMSE, E_t, wall time. ``out``: the comparison's JSON keys."""
    lines = []
    for r in out["rows"]:
        fe = r.get("force_errors") or {}
        route = (r.get("evidence_routes") or {}).get(r.get("evidence_route") or "", {})
        n_eff = r.get("n_eff") if isinstance(r.get("n_eff"), dict) else {}
        line = {"model": r["model"], "engine": r["engine"], "noise": r.get("noise_model"),
                "n_eff": ", ".join(f"{c} {v:.4g}" for c, v in n_eff.items() if v is not None),
                "ln Z": r.get("log_evidence"), "route": r.get("evidence_route"), "ln Z error": route.get("total_error"),
                "ln BF vs selected": out["bayes_factors"].get(r["model"]) if r["engine"] == out["evidence_engine"]
                else None,
                "ln Z calibrated": (out.get("log_evidence_calibrated") or {}).get(r["model"])
                if r["engine"] == out["evidence_engine"] else None,
                "ln BF calibrated": (out.get("bayes_factors_calibrated") or {}).get(r["model"])
                if r["engine"] == out["evidence_engine"] else None,
                "MSE": r.get("mse"), "force NRMSE": r.get("force_nrmse"), "E_t": fe.get("E_t"),
                "wall [s]": r.get("wall_s"), "error": r.get("error", "")}
        v = r.get("validation")
        if v is not None:
            line["MSE (validation)"] = v.get("mse")
            line["force NRMSE (validation)"] = v.get("force_nrmse")
        lines.append(line)
    return pd.DataFrame(lines)
