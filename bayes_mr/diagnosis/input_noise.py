"""What the recorded motion's own noise gives an effect: the input-noise null of a device test's diagnosis.

A device test's model is driven by the *recorded* motion, its noise included (errors in variables): the
force it predicts carries that noise through the damper's dynamics, and an extension whose feature is built
from the same motion (inertia's ẍ, a delay, a velocity law) can fit part of it. On a clean simulated 4 s,
5 mm / 3 Hz sine test with 1 % noise on the recorded motion, ``spencer + inertia`` gains 59 nats over
``spencer``; with the same record's motion noise-free it gains nothing.

So an effect that passes on a device test is screened once more, on a *null record* that has the same
errors in variables and no effect: the base fit's own force on the recorded motion, plus Gaussian noise of
the base's fitted σ, as the measured force; the recorded displacement and velocity, each plus white noise
of its estimated level (:func:`~bayes_mr.data.noise_floor.differencing_sd`), as the measured motion. The
base is refitted there from its optimum and the effect screened as on the record (:func:`.screen.screen_one`);
the score it reaches is what the motion's noise gives it, and the effect passes only if its own score
exceeds the threshold by that much more (:func:`.screen.passes`). A motion with no noise (a noise-free
simulation) adds next to nothing, and the null scores no more than a fit of noise does.

Limits: one null replica (its score carries that replica's noise, a fraction of a nat to a few); the two
motion channels' noises are drawn independent and white (a velocity differentiated from the displacement
has correlated, coloured noise); the forward route of a single record only (a matrix's diagnosis and the
ranked route do not run it).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import xarray as xr

from bayes_mr.data.noise_floor import differencing_sd
from bayes_mr.diagnosis.fits import Fit, refit
from bayes_mr.diagnosis.screen import STALL, Candidate, effect_ranges, screen_one

#: The recorded motion channels of a device test that drive its model.
MOTION = ("displacement", "velocity")


def motion_noise(record: xr.Dataset) -> dict[str, float]:
    """Estimated white-noise SD of each recorded motion channel [m, m/s] (over its valid samples)."""
    valid = record["valid"].values.astype(bool) if "valid" in record else slice(None)
    return {c: differencing_sd(record[c].values[valid]) for c in MOTION if c in record}


def null_record(base: Fit, record: xr.Dataset, noise: dict[str, float], seed: int = 0) -> xr.Dataset | None:
    """The null record of the module docstring, the motion re-noised at ``noise`` (:func:`motion_noise`), or None
    when the record has no motion noise to model."""
    if not any(s > 0 for s in noise.values()):
        return None
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x1A7]))
    null = record.copy(deep=True)
    n = record.sizes["time"]
    for name, sd in noise.items():
        null[name].values[:] = record[name].values + sd * rng.standard_normal(n)
    for c, ch in enumerate(base.lik.channels):
        null[ch].values[:] = base.predicted[ch] + base.result.sigma[c] * rng.standard_normal(n)
    null.attrs["source"] = f"input-noise null of: {record.attrs.get('source', 'a record')}"
    return null


def null_score(record: xr.Dataset, base: Fit, cand: Candidate, seed: int = 0) -> dict:
    """The score ``cand``'s effect reaches on the null record of ``base`` (``score``; 0 when the record's motion
    has no noise), its log-likelihood gain over the base refitted there, and the motion noise used."""
    sd = motion_noise(record)
    null = null_record(base, record, sd, seed)
    noise = {f"{k}_sd": v for k, v in sd.items()}
    if null is None:
        return {"score": 0.0, **noise}
    lik = type(base.lik)(base.model, null, ranges=effect_ranges(base.model, null, base.lik.scales),
                         scales=base.lik.scales, residual=base.lik.residual)
    null_base, _ = refit(lik, np.atleast_2d(base.result.phi), base.result.sigma, n_refine=1, stall=STALL)
    on_null = screen_one(null, null_base, cand.effect, seed=seed, stall=STALL)
    score = on_null.score if math.isfinite(on_null.score) else 0.0
    return {"score": float(score), "delta_loglik": float(on_null.delta_loglik), **noise}


def checked(record: xr.Dataset, base: Fit, cand: Candidate, seed: int = 0) -> Candidate:
    """``cand`` with its input-noise null (:func:`null_score`) attached, on a device test; as it is otherwise."""
    if base.lik.kind != "device" or cand.fit is None:
        return cand
    return replace(cand, input_noise=null_score(record, base, cand, seed))
