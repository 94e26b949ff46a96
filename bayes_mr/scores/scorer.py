"""Scores of a model's prediction against a record: the thesis's selection criteria.

One entry point, :func:`score` (and :class:`Scorer`, which prepares a record
once and scores many predictions — the 100 trained runs of a validation):

* ``mse`` — thesis eq. 3-44 over the output channels the record measures
  (``mse_channels``). Structure test with both: displacement and absolute
  acceleration, each squared error over its measurement-noise variance,
  ``100/N Σ[(x−x̂)²/σ_d² + (a−â)²/σ_a²]``. Any other set of channels (a
  device test's force, a forced test's displacement, velocity and/or
  acceleration, a structure test with one of its two) gets the same
  normalised form summed over its channels, ``100/N Σ_c Σ (y_c−ŷ_c)²/σ_c²``.
  A model that is right to the noise therefore scores about 100 per measured
  channel; scores compare between models on the same record, not between
  records that measure different channels.
* ``force_errors`` — E_t, E_x, E_ẋ (3-45..3-49) wherever the damper force is
  measured: always on a device test (ẋ = the velocity channel, ẍ = its
  gradient), on a structure or forced test when the record has a ``force``
  channel and measures the motion (predicted damper force = the
  simulation's ``force`` output; ẋ = the velocity channel, else the smoothed
  derivative of the measured displacement; ẍ = the measured acceleration
  (minus the ground's on a structure test: the piston's relative motion),
  else the derivative of ẋ).
* ``force_nrmse`` — RMS(F−F̂)/SD(F) where the force is measured.

Every score is over the record's ``valid`` samples only; N is their number.
σ are the record's measurement-noise SDs (``noise_sd_<channel>`` attributes,
else the noise floor, :func:`bayes_mr.likelihood.output_error.channel_noise`).
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from bayes_mr.data.derive import smooth_velocity
from bayes_mr.data.schema import outputs_of
from bayes_mr.likelihood.output_error import channel_noise
from bayes_mr.scores.metrics import force_errors, force_nrmse, mse


def _bridged(x: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """x with masked samples replaced by linear interpolation (so a spike does not smear into the derivative)."""
    if valid.all() or not valid.any():
        return x
    idx = np.arange(x.size)
    return np.interp(idx, idx[valid], x[valid])


class Scorer:
    """Scores of predictions against one record (the record's part computed once).

    Parameters
    ----------
    record : xarray.Dataset
        Record in the package schema (``valid`` mask honoured).
    noise_sd : dict, optional
        Measurement-noise SD per measured channel [channel units], overriding
        the record's (e.g. ``{"displacement": 1e-5, "acceleration": 0.02}``).

    Attributes
    ----------
    kind : str
    channels : tuple of str
        The channels ``mse`` is computed on.
    sigma : dict
        Channel → noise SD used by ``mse``.
    n : int
        Number of valid samples.
    has_force : bool
        True when force errors are computed (force measured).
    """

    def __init__(self, record: xr.Dataset, *, noise_sd: dict[str, float] | None = None):
        self.kind = record.attrs["kind"]
        self.channels = outputs_of(record)
        n_time = record.sizes["time"]
        self.valid = record["valid"].values.astype(bool) if "valid" in record else np.ones(n_time, bool)
        self.n = int(self.valid.sum())
        if self.n == 0:
            raise ValueError(f"{record.attrs.get('source', 'record')}: no valid samples to score")
        sd = channel_noise(record, self.channels)
        overrides = dict(noise_sd or {})
        unknown = [c for c in overrides if c not in self.channels]
        if unknown:
            raise ValueError(f"noise_sd for {unknown}, which the score does not use; channels: {self.channels}")
        self.sigma = {c: float(overrides.get(c, s)) for c, s in zip(self.channels, sd)}
        self.y = {c: record[c].values.astype(float) for c in self.channels}
        dt = float(record.attrs["dt"])
        self.has_force = "force" in record
        self.force = record["force"].values.astype(float) if self.has_force else None
        self.xdot = self.xddot = None
        if self.has_force:
            self.xdot, self.xddot = _piston_motion(record, self.valid, dt)

    def __call__(self, predicted: dict[str, np.ndarray]) -> dict:
        """Score one prediction.

        Parameters
        ----------
        predicted : dict
            Channel → simulated values, shape (N,): the measured channels
            (``displacement``, ``acceleration`` or ``force``) and, where force
            errors are computed, the damper ``force`` (``simulate``'s outputs).

        Returns
        -------
        dict
            ``mse`` (float), ``force_errors`` (``{"E_t", "E_x", "E_xdot"}`` or
            None), ``force_nrmse`` (float or None), ``rmse`` (measured channel →
            RMS error over the valid samples [channel units]), ``n`` (valid
            samples).

        Raises
        ------
        ValueError
            A predicted channel is missing, has the wrong length, or is
            non-finite at a valid sample.
        """
        need = self.channels + (("force",) if self.has_force else ())
        missing = [c for c in need if c not in predicted]
        if missing:
            raise ValueError(f"prediction lacks channel(s) {missing}")
        if self.channels == ("displacement", "acceleration"):
            x, a = self.y["displacement"], self.y["acceleration"]
            value = mse(x, predicted["displacement"], a, predicted["acceleration"],
                        self.sigma["displacement"], self.sigma["acceleration"], valid=self.valid)
        else:
            value = sum(_channel_mse(c, self.y[c], predicted[c], self.sigma[c], self.valid) for c in self.channels)
        errors = nrmse = None
        if self.has_force:
            f_hat = predicted["force"]
            if self.xdot is not None:
                errors = force_errors(self.force, f_hat, self.xdot, self.xddot, valid=self.valid)
            nrmse = force_nrmse(self.force, f_hat, valid=self.valid)
        rmse = {c: float(np.sqrt(np.mean((self.y[c][self.valid] - np.asarray(predicted[c], float)[self.valid]) ** 2)))
                for c in self.channels}
        return {"mse": value, "mse_channels": list(self.channels), "force_errors": errors, "force_nrmse": nrmse,
                "rmse": rmse, "n": self.n}


def _piston_motion(record: xr.Dataset, valid: np.ndarray, dt: float):
    """(ẋ, ẍ) of the damper's motion from what the record measures, or (None, None) when it cannot tell."""
    kind = record.attrs["kind"]

    def values(name):
        return record[name].values.astype(float)

    if "velocity" in record:
        xdot = values("velocity")
    elif "displacement" in record:
        xdot = smooth_velocity(_bridged(values("displacement"), valid), dt)
    else:
        return None, None
    if kind == "device" or "acceleration" not in record:
        return xdot, np.gradient(xdot, dt)
    xddot = values("acceleration")
    if kind == "structure":
        xddot = xddot - values("ground_acceleration")
    return xdot, xddot


def _channel_mse(name: str, y: np.ndarray, y_hat: np.ndarray, sigma: float, valid: np.ndarray) -> float:
    """``100/N Σ (y−ŷ)²/σ²`` over the valid samples (3-44's term of one measured channel)."""
    y_hat = np.asarray(y_hat, float)
    if y_hat.shape != y.shape:
        raise ValueError(f"shape mismatch: {name} {y.shape} vs predicted {name} {y_hat.shape}")
    if not (np.isfinite(sigma) and sigma > 0):
        raise ValueError(f"the noise SD of {name} must be positive, got {sigma!r}")
    e = y[valid] - y_hat[valid]
    if not np.all(np.isfinite(e)):
        raise ValueError(f"{name} or predicted {name} is non-finite at a valid sample")
    return float(100.0 * np.sum(e * e) / sigma**2 / e.size)


def score(record: xr.Dataset, predicted: dict[str, np.ndarray], *, noise_sd: dict[str, float] | None = None) -> dict:
    """Thesis scores of one prediction of ``record`` (see the module docstring).

    Parameters
    ----------
    record : xarray.Dataset
        The measured record.
    predicted : dict
        Channel → simulated values, shape (N,) (e.g. ``simulate(...).outputs``).
    noise_sd : dict, optional
        Noise SD per measured channel, overriding the record's.

    Returns
    -------
    dict
        ``mse``, ``mse_channels``, ``force_errors`` (or None), ``force_nrmse`` (or None), ``rmse``, ``n``.
    """
    return Scorer(record, noise_sd=noise_sd)(predicted)
