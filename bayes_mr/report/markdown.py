"""Small helpers for Markdown reports (tables, number formatting)."""

from __future__ import annotations

import math

import pandas as pd


def fmt(value, digits: int = 4) -> str:
    """A number with ``digits`` significant digits (ints and text as they are)."""
    if isinstance(value, bool) or value is None:
        return str(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            return "—"
        return f"{value:.{digits}g}"
    return str(value)


def markdown_table(df: pd.DataFrame, digits: int = 4) -> str:
    """A pipe table of ``df`` (index dropped)."""
    cols = [str(c) for c in df.columns]
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for row in df.itertuples(index=False):
        lines.append("| " + " | ".join(fmt(v.item() if hasattr(v, "item") else v, digits) for v in row) + " |")
    return "\n".join(lines)
