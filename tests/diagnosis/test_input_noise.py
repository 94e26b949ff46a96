"""The input-noise null: errors in variables alone do not name an effect (bayes_mr.diagnosis.input_noise)."""

import numpy as np

from bayes_mr.bench.spencer import sine_record
from bayes_mr.diagnosis.diagnose import diagnose
from bayes_mr.diagnosis.fits import fit_model
from bayes_mr.diagnosis.input_noise import motion_noise, null_score
from bayes_mr.diagnosis.screen import THRESHOLD, screen_one
from bayes_mr.models import EFFECTS


def _clean_motion(rec):
    """``rec`` with its recorded motion replaced by the imposed one (noise-free)."""
    out = rec.copy(deep=True)
    t = out["time"].values
    x = 5e-3 * np.sin(2 * np.pi * 3.0 * t)
    out["displacement"].values[:] = x
    out["velocity"].values[:] = np.gradient(x, t[1] - t[0])
    return out


def test_the_motion_noise_is_estimated_from_the_record():
    """The differencing estimate recovers the simulated motion noise (1 % of each channel's RMS) within 10 %,
    and finds next to none in a noise-free motion."""
    rec = sine_record(seed=2)
    est = motion_noise(rec)
    for c in ("displacement", "velocity"):
        assert abs(est[c] / rec.attrs[f"noise_sd_{c}"] - 1.0) < 0.1, (c, est[c])
    clean = motion_noise(_clean_motion(rec))
    assert all(clean[c] < 1e-3 * est[c] for c in est), clean


def test_errors_in_variables_alone_do_not_name_inertia():
    """A clean spencer sine test (5 mm, 3 Hz, 1 % noise on the recorded motion and the force): inertia fits part
    of the motion's noise as it passes through the damper and scores far above the threshold; on the null
    record it scores about as much, so it is not named. With the motion noise-free the same effect's null score
    is that of a fit of noise."""
    rec = sine_record(seed=0)
    out = diagnose(rec, "spencer", seed=0, progress=False).to_dict()
    assert out["cause"] == "none", out["cause"]
    inertia = next(c for c in out["causes"] if c["name"] == "inertia")
    assert inertia["score"] > THRESHOLD  # the false alarm the null is there for
    assert inertia["input_noise"]["score"] > THRESHOLD
    assert inertia["score"] <= THRESHOLD + inertia["input_noise"]["score"]

    clean = _clean_motion(rec)
    base = fit_model(clean, "spencer")
    cand = screen_one(clean, base, EFFECTS["inertia"], seed=0)
    assert null_score(clean, base, cand)["score"] < 1.0
