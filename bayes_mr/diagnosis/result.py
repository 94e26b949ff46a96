"""What :func:`~bayes_mr.diagnosis.diagnose.diagnose` returns: a :class:`Diagnosis`.

>>> d = bm.diagnose(record, "dahl")                  # doctest: +SKIP
>>> d.cause, d.gain["mse_ratio"], d.verdict           # doctest: +SKIP
>>> d.table()                                         # doctest: +SKIP
>>> d.idata["extended"]                               # doctest: +SKIP

The JSON keys (``diagnose`` of ``docs/CONTRACT.md``, what ``bayes-mr diagnose --json``
writes) are :meth:`Diagnosis.to_dict`; the baseline, the extended model and (when
a term was kept) the term search's model, as ArviZ InferenceData, are :attr:`Diagnosis.idata`.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import cached_property

import pandas as pd

from bayes_mr.report import figures


@dataclass(frozen=True)
class Diagnosis:
    """A model's residual, the effect(s) named as its cause, the extended model and the gain.

    Attributes
    ----------
    data : dict
        The diagnosis's JSON keys (read them through the properties, or
        :meth:`to_dict` for a copy).
    fits : Mapping
        Label (``baseline``, ``extended``, ``terms``) → InferenceData, or a
        function of no argument that builds it; :attr:`idata` builds each once.
    """

    data: dict = field(repr=False)
    fits: Mapping[str, object | Callable[[], object]] = field(default_factory=dict, repr=False, compare=False)

    # --- what users read -------------------------------------------------------------------
    @property
    def cause(self) -> str:
        """The first effect named (``none`` when no effect passed the threshold)."""
        return self.data["cause"]

    @property
    def ambiguous(self) -> list[str]:
        """The cause and the effects the record cannot tell from it, cause first (empty when it stands alone)."""
        return self.data.get("ambiguous", [])

    @property
    def alternatives(self) -> list[dict]:
        """Each ambiguous effect other than the cause: its extended model and the test against the cause."""
        return self.data.get("alternatives", [])

    @property
    def effects(self) -> list[str]:
        """Every effect named, in the order they were added."""
        return self.data.get("effects", [])

    @property
    def causes(self) -> list[dict]:
        """Every candidate effect, ranked: ``name``, ``score``, ``mse_ratio``, ``selected``, …"""
        return self.data["causes"]

    @property
    def baseline(self) -> dict:
        """The fitted baseline: ``model``, ``mse``, ``log_evidence``, ``params``, …"""
        return self.data["baseline"]

    @property
    def extended(self) -> dict:
        """The baseline with the named effect(s): ``model``, ``mse``, ``log_evidence``, ``params``, …"""
        return self.data["extended"]

    @property
    def gain(self) -> dict:
        """``mse_ratio`` (extended/baseline), ``delta_log_evidence`` (raw, calibrated), ``validation_mse_ratio``."""
        return self.data["gain"]

    @property
    def verdict(self) -> str:
        """``at the noise floor``, ``explained by …``, ``unexplained by the vocabulary``, …"""
        return self.data["verdict"]

    @property
    def unexplained(self) -> dict:
        """Measured channel → what the final model leaves (residual over the noise floor, and where)."""
        return self.data["unexplained"]

    @property
    def selection(self) -> list[dict]:
        """Each effect added, in order, with its round, score and fitted parameters."""
        return self.data["selection"]

    @property
    def validation(self) -> dict | None:
        """Errors of baseline and extended model on another record (None without one)."""
        return self.data.get("validation")

    @property
    def terms(self) -> dict | None:
        """The term search (None when it did not run)."""
        return self.data.get("terms")

    @cached_property
    def idata(self) -> dict:
        """Label (``baseline``, ``extended``, ``terms`` when a term was kept) → InferenceData [built once]."""
        return {label: (f() if callable(f) else f) for label, f in self.fits.items()}

    # --- views -----------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """A copy of the JSON keys, exactly what ``bayes-mr diagnose --json`` writes."""
        return copy.deepcopy(self.data)

    def table(self) -> pd.DataFrame:
        """The candidate effects in the diagnosis's ranking: score, MSE ratio, Δ ln Z, whether named.

        One line per entry of :attr:`causes` (index: rank from 1); ``effect`` carries the channel of an
        effect tried on one channel (``sensor_delay (acceleration)``).
        """
        lines = []
        for c in self.causes:
            lines.append({"effect": _label(c), "score": c.get("score"), "mse_ratio": c.get("mse_ratio"),
                          "delta_log_evidence": c.get("delta_log_evidence"), "kappa": c.get("kappa"),
                          "selected": bool(c.get("selected")), "round": c.get("selected_round"),
                          "error": c.get("error", "")})
        df = pd.DataFrame(lines, columns=["effect", "score", "mse_ratio", "delta_log_evidence", "kappa", "selected",
                                          "round", "error"])
        df.index = pd.RangeIndex(1, len(df) + 1, name="rank")
        return df

    def plot(self, *, title: str | None = None):
        """Score and MSE ratio of every candidate effect, the named ones highlighted, the threshold dashed.

        Returns
        -------
        matplotlib.figure.Figure
        """
        df = self.table()
        labels = list(df["effect"])
        panels = {"score": dict(zip(labels, map(_float, df["score"]))),
                  "MSE ratio (extended / baseline)": dict(zip(labels, map(_float, df["mse_ratio"])))}
        reference = {"MSE ratio (extended / baseline)": 1.0}
        if _float(self.data.get("threshold")) is not None:
            reference["score"] = float(self.data["threshold"])
        if title is None:
            title = f"{self.baseline['model']}: {self.verdict}"
        return figures.bars(panels, title=title, highlight=set(df["effect"][df["selected"]]), reference=reference)

    def __repr__(self) -> str:
        return (f"Diagnosis(baseline={self.baseline['model']!r}, cause={self.cause!r}, "
                f"extended={self.extended['model']!r}, mse_ratio={_float(self.gain.get('mse_ratio'))}, "
                f"verdict={self.verdict!r})")

    def _repr_html_(self) -> str:
        return f"<p>{repr(self)}</p>" + self.table().to_html(na_rep="")


def _label(c: Mapping) -> str:
    return f"{c['name']} ({c['channel']})" if c.get("channel") else str(c["name"])


def _float(v) -> float | None:
    try:
        v = float(v)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None
