"""Scores of a model's prediction against a record: the thesis's selection criteria.

One entry point, :func:`score` (and :class:`Scorer`, which prepares a record
once and scores many predictions — the 100 trained runs of a validation):

* ``mse`` — thesis eq. 3-44. Structure test: displacement and absolute
  acceleration, each squared error over its measurement-noise variance,
  ``100/N Σ[(x−x̂)²/σ_d² + (a−â)²/σ_a²]``. Device test (not in the thesis,
  whose tests were all on the frame): the same normalised form on the one
  measured channel, ``100/N Σ (F−F̂)²/σ_F²``. A model that is right to the
  noise therefore scores about 200 on a structure test and about 100 on a
  device test (100 per channel); scores compare between models on the same
  record, not between kinds of test.
* ``force_errors`` — E_t, E_x, E_ẋ (3-45..3-49) wherever the damper force is
  measured: always on a device test (ẋ = the velocity channel, ẍ = its
  gradient), on a structure test when the record has a ``force`` channel
  (predicted damper force = the simulation's ``force`` output; ẋ = smoothed
  derivative of the measured storey displacement, ẍ = measured absolute
  minus ground acceleration, i.e. the storey's relative acceleration — the
  damper's piston motion).
* ``force_nrmse`` — RMS(F−F̂)/SD(F) where the force is measured.

Every score is over the record's ``valid`` samples only; N is their number.
σ are the record's measurement-noise SDs (``noise_sd_<channel>`` attributes,
else the noise floor, :func:`bayes_mr.likelihood.channel_noise`).
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from ..data.derive import smooth_velocity
from ..data.schema import OUTPUTS
from ..likelihood import channel_noise
from .metrics import force_errors, force_nrmse, mse


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
        self.channels = OUTPUTS[self.kind]
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
            if self.kind == "structure":
                x = _bridged(record["displacement"].values.astype(float), self.valid)
                self.xdot = smooth_velocity(x, dt)
                self.xddot = record["acceleration"].values - record["ground_acceleration"].values
            else:
                if "velocity" in record:
                    self.xdot = record["velocity"].values.astype(float)
                else:
                    self.xdot = smooth_velocity(_bridged(record["displacement"].values.astype(float), self.valid), dt)
                self.xddot = np.gradient(self.xdot, dt)

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
        if self.kind == "structure":
            x, a = self.y["displacement"], self.y["acceleration"]
            value = mse(x, predicted["displacement"], a, predicted["acceleration"],
                        self.sigma["displacement"], self.sigma["acceleration"], valid=self.valid)
        else:
            value = _force_mse(self.y["force"], predicted["force"], self.sigma["force"], self.valid)
        errors = nrmse = None
        if self.has_force:
            f_hat = predicted["force"]
            errors = force_errors(self.force, f_hat, self.xdot, self.xddot, valid=self.valid)
            nrmse = force_nrmse(self.force, f_hat, valid=self.valid)
        rmse = {c: float(np.sqrt(np.mean((self.y[c][self.valid] - np.asarray(predicted[c], float)[self.valid]) ** 2)))
                for c in self.channels}
        return {"mse": value, "force_errors": errors, "force_nrmse": nrmse, "rmse": rmse, "n": self.n}


def _force_mse(f: np.ndarray, f_hat: np.ndarray, sigma_f: float, valid: np.ndarray) -> float:
    """``100/N Σ (F−F̂)²/σ_F²`` over the valid samples (3-44 on the one measured channel)."""
    f_hat = np.asarray(f_hat, float)
    if f_hat.shape != f.shape:
        raise ValueError(f"shape mismatch: force {f.shape} vs predicted force {f_hat.shape}")
    if not (np.isfinite(sigma_f) and sigma_f > 0):
        raise ValueError(f"sigma_F must be a positive noise SD, got {sigma_f!r}")
    e = f[valid] - f_hat[valid]
    if not np.all(np.isfinite(e)):
        raise ValueError("force or predicted force is non-finite at a valid sample")
    return float(100.0 * np.sum(e * e) / sigma_f**2 / e.size)


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
        ``mse``, ``force_errors`` (or None), ``force_nrmse`` (or None), ``rmse``, ``n``.
    """
    return Scorer(record, noise_sd=noise_sd)(predicted)
