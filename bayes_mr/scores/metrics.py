"""Scores of a model's prediction against a record (thesis eqs. 3-44 … 3-49).

* :func:`mse` — the thesis's model-selection score (3-44): the noise-normalised
  squared errors of displacement and acceleration, summed, × 100 / N.
* :func:`force_errors` — E_t, E_x, E_ẋ (3-45 … 3-49), after Spencer et al.
  (1996): force errors over time and weighted by |ẋ| and |ẍ|, each over the SD
  of the measured force.
* :func:`force_nrmse` — RMS(F − F̂)/SD(F) for device tests (SPEC "fit" JSON).

Every function takes an optional ``valid`` mask (the record's ``valid``
variable): masked samples are left out, and N is the number of valid samples.
Only the samples that enter a score are checked for NaN/inf, so a masked
sample may hold anything.
"""

from __future__ import annotations

import numpy as np


def _prepare(arrays: dict[str, object], valid) -> tuple[dict[str, np.ndarray], int]:
    """Same-shape float arrays restricted to the valid samples, and N."""
    out = {name: np.asarray(a, dtype=float) for name, a in arrays.items()}
    shapes = {name: a.shape for name, a in out.items()}
    ref_name, ref_shape = next(iter(shapes.items()))
    if len(ref_shape) != 1:
        raise ValueError(f"{ref_name} must be 1-D (one value per sample), got shape {ref_shape}")
    for name, shape in shapes.items():
        if shape != ref_shape:
            raise ValueError(f"shape mismatch: {ref_name} {ref_shape} vs {name} {shape}")
    if valid is None:
        mask = np.ones(ref_shape, bool)
    else:
        mask = np.asarray(valid)
        if mask.dtype != bool:
            raise ValueError(f"valid must be a boolean mask, got dtype {mask.dtype}")
        if mask.shape != ref_shape:
            raise ValueError(f"shape mismatch: {ref_name} {ref_shape} vs valid {mask.shape}")
    n = int(mask.sum())
    if n == 0:
        raise ValueError("no valid samples to score")
    picked = {name: a[mask] for name, a in out.items()}
    for name, a in picked.items():
        bad = ~np.isfinite(a)
        if bad.any():
            idx = int(np.flatnonzero(mask)[np.argmax(bad)])
            raise ValueError(f"{name} has {int(bad.sum())} non-finite valid samples (first at index {idx})")
    return picked, n


def _positive(name: str, value: float) -> float:
    value = float(value)
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a positive noise SD, got {value!r}")
    return value


def mse(
    x: np.ndarray,
    x_hat: np.ndarray,
    a: np.ndarray,
    a_hat: np.ndarray,
    sigma_d: float,
    sigma_a: float,
    valid: np.ndarray | None = None,
) -> float:
    """Noise-normalised mean square error of displacement and acceleration (3-44).

    ``MSE = 100/N · Σ_i [(x_i − x̂_i)²/σ_d² + (a_i − â_i)²/σ_a²]`` over the valid
    samples, N = number of valid samples. Dimensionless; for a perfect model
    scored on data with noise of exactly σ_d and σ_a it is about 200 (each
    channel contributes 100 · E[e²]/σ² = 100).

    Parameters
    ----------
    x, x_hat : array, shape (n,)
        Measured and predicted displacement [m].
    a, a_hat : array, shape (n,)
        Measured and predicted acceleration [m/s²].
    sigma_d, sigma_a : float
        Noise standard deviations of the displacement [m] and acceleration
        [m/s²] channels (σ_d², σ_a² are the thesis's noise variances).
    valid : bool array, shape (n,), optional
        True for samples to score; default all.

    Returns
    -------
    float

    Raises
    ------
    ValueError
        Shape mismatch, non-1-D input, a non-boolean mask, no valid sample,
        NaN/inf in a valid sample, or σ not positive.
    """
    sd = _positive("sigma_d", sigma_d)
    sa = _positive("sigma_a", sigma_a)
    arr, n = _prepare({"x": x, "x_hat": x_hat, "a": a, "a_hat": a_hat}, valid)
    total = np.sum((arr["x"] - arr["x_hat"]) ** 2) / sd**2 + np.sum((arr["a"] - arr["a_hat"]) ** 2) / sa**2
    return float(100.0 * total / n)


def force_errors(
    f_exp: np.ndarray,
    f_pre: np.ndarray,
    xdot: np.ndarray,
    xddot: np.ndarray,
    valid: np.ndarray | None = None,
) -> dict[str, float]:
    """Force errors E_t, E_x, E_ẋ of the thesis (3-45 … 3-49), as written there.

    With e_i = f_exp,i − f_pre,i over the N valid samples::

        ε_t² = mean(e²)            E_t = ε_t / σ_f
        ε_x² = mean(e² |ẋ|)        E_x = ε_x / σ_f
        ε_ẋ² = mean(e² |ẍ|)        E_ẋ = ε_ẋ / σ_f
        σ_f² = mean((f_exp − mean f_exp)²)

    Implemented exactly as the thesis writes them, which is dimensionally odd:
    E_t is dimensionless, but E_x carries [m/s]^½ and E_ẋ [m/s²]^½, because the
    squared error is weighted by |ẋ| and |ẍ| without normalising the weights
    (the discrete form of ∫ e² |dx| and ∫ e² |dẋ|, errors accumulated along the
    displacement and velocity paths, as in the Spencer et al. definitions the
    thesis cites). E_x and E_ẋ therefore change with the units of ẋ, ẍ — pass
    them in SI — and compare only between models scored on the same record.

    Parameters
    ----------
    f_exp, f_pre : array, shape (n,)
        Measured and predicted damper force [N].
    xdot : array, shape (n,)
        Measured velocity [m/s] (weight of ε_x).
    xddot : array, shape (n,)
        Measured acceleration [m/s²] (weight of ε_ẋ).
    valid : bool array, shape (n,), optional
        True for samples to score; default all.

    Returns
    -------
    dict
        ``{"E_t": float, "E_x": float, "E_xdot": float}``.

    Raises
    ------
    ValueError
        As :func:`mse`, or a constant measured force (σ_f = 0).
    """
    arr, _ = _prepare({"f_exp": f_exp, "f_pre": f_pre, "xdot": xdot, "xddot": xddot}, valid)
    e2 = (arr["f_exp"] - arr["f_pre"]) ** 2
    sigma_f = np.sqrt(np.mean((arr["f_exp"] - arr["f_exp"].mean()) ** 2))
    if sigma_f == 0:
        raise ValueError("measured force is constant over the valid samples (σ_f = 0)")
    return {
        "E_t": float(np.sqrt(np.mean(e2)) / sigma_f),
        "E_x": float(np.sqrt(np.mean(e2 * np.abs(arr["xdot"]))) / sigma_f),
        "E_xdot": float(np.sqrt(np.mean(e2 * np.abs(arr["xddot"]))) / sigma_f),
    }


def force_nrmse(f: np.ndarray, f_hat: np.ndarray, valid: np.ndarray | None = None) -> float:
    """Normalised RMS force error RMS(F − F̂) / SD(F) over the valid samples.

    SD uses ddof = 0, so the value equals the thesis's E_t (3-45, 3-46) on the
    same samples; it is kept as its own name because the SPEC's device-test
    JSON reports it as ``force_nrmse``. A model that predicts the mean force
    scores 1.

    ``f``, ``f_hat`` are the measured and predicted force [N], shape (n,);
    ``valid`` as in :func:`mse`. Raises ValueError as :func:`mse` does, or for
    a constant measured force (SD = 0).
    """
    arr, _ = _prepare({"f": f, "f_hat": f_hat}, valid)
    sd = np.sqrt(np.mean((arr["f"] - arr["f"].mean()) ** 2))
    if sd == 0:
        raise ValueError("measured force is constant over the valid samples (SD = 0)")
    return float(np.sqrt(np.mean((arr["f"] - arr["f_hat"]) ** 2)) / sd)
