"""Scores over several records: each record's scores pooled into those of the whole set.

A joint fit over a test matrix is scored on every record at once. Pooling
keeps each score's definition over the union of the records' valid samples,
each sample normalised by its own record's noise SD:

* ``mse`` — eq. 3-44 over all N = Σ N_r samples: Σ_r N_r MSE_r / N;
* ``rmse`` — per channel, √(Σ_r N_r RMSE_r² / N) [channel units];
* ``force_nrmse`` — RMS(F − F̂) over all samples / SD(F) of all samples
  (the measured forces pooled: a set of tests at several currents has the
  force spread of all of them);
* ``force_errors`` — E_t, E_x, E_ẋ as the N_r-weighted means of the records'.

A score that one record lacks (None) is None for the set.
"""

from __future__ import annotations

import numpy as np
import xarray as xr


def pooled(records: list[xr.Dataset], scores: list[dict]) -> dict:
    """The scores of a set of records from each record's (:func:`bayes_mr.scores.score` dicts).

    Parameters
    ----------
    records : list of xarray.Dataset
        The records (their ``force`` and ``valid`` give the pooled SD(F)).
    scores : list of dict
        Per record: ``mse``, ``rmse``, ``force_nrmse``, ``force_errors``, ``n`` (valid samples).

    Returns
    -------
    dict
        ``mse``, ``rmse``, ``force_nrmse``, ``force_errors``, ``n`` of the set (module docstring).
    """
    n = np.array([s["n"] for s in scores], float)
    total = float(n.sum())
    out = {"n": int(total), "mse_channels": scores[0].get("mse_channels")}
    out["mse"] = None if any(s["mse"] is None for s in scores) else float(
        sum(w * s["mse"] for w, s in zip(n, scores)) / total)
    if any(s.get("rmse") is None for s in scores):
        out["rmse"] = None
    else:
        names = [c for c in scores[0]["rmse"] if all(c in s["rmse"] for s in scores)]
        out["rmse"] = {c: float(np.sqrt(sum(w * s["rmse"][c] ** 2 for w, s in zip(n, scores)) / total))
                       for c in names}
    if any(s.get("force_errors") is None for s in scores):
        out["force_errors"] = None
    else:
        out["force_errors"] = {k: float(sum(w * s["force_errors"][k] for w, s in zip(n, scores)) / total)
                               for k in scores[0]["force_errors"]}
    out["force_nrmse"] = None if any(s.get("force_nrmse") is None for s in scores) else _pooled_nrmse(
        records, scores, n, total)
    return out


def _pooled_nrmse(records: list[xr.Dataset], scores: list[dict], n: np.ndarray, total: float) -> float:
    """RMS(F − F̂)/SD(F) over every record's valid samples, from each record's NRMSE and force SD (ddof 0)."""
    forces, sse = [], 0.0
    for rec, s, w in zip(records, scores, n):
        valid = rec["valid"].values.astype(bool) if "valid" in rec else np.ones(rec.sizes["time"], bool)
        f = rec["force"].values[valid]
        sse += w * (s["force_nrmse"] * np.sqrt(np.mean((f - f.mean()) ** 2))) ** 2
        forces.append(f)
    f = np.concatenate(forces)
    return float(np.sqrt(sse / total) / np.sqrt(np.mean((f - f.mean()) ** 2)))
