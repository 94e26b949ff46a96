"""The point every engine reports simulates, and Spencer's preload is what is estimated.

A small simulated device test of ``spencer`` with the accumulator pair free:
``k1`` and the preload ``F_pre = k1·x0`` are estimated, ``x0`` is reported as
``F_pre/k1`` from the draws. Each engine — least squares, a short emcee run,
a short UKF training — must report a ``point`` that simulates on the record
it came from without divergence, and the summary must carry ``x0`` beside the
preload, with the preload's interval narrower (relatively) than x0's.
"""

from __future__ import annotations

import numpy as np
import pytest

from bayes_mr.inference import results
from bayes_mr.inference.identify import Identify
from bayes_mr.inference.estimators import UKF, Emcee, LeastSquares
from bayes_mr.inference.mcmc.settings import MCMCSettings
from bayes_mr.models import get_model
from bayes_mr.simulation.simulate import Inputs, simulate, synthesize

FS = 1000.0
FREE = ("k0", "k1", "F_pre", "c0a", "alpha_a")


@pytest.fixture(scope="module")
def spencer_device():
    """0.6 s of a two-tone displacement through the published Spencer damper at 1 V, 1 % noise."""
    m = get_model("spencer")
    t = np.arange(0.0, 0.6, 1.0 / FS)
    x = 0.008 * np.sin(2 * np.pi * 2.5 * t) + 0.002 * np.sin(2 * np.pi * 7.1 * t + 1.0)
    v = np.gradient(x, t)
    theta = m.theta("device", {})
    rec = synthesize(m, theta, t, {"displacement": x, "velocity": v, "voltage": np.ones_like(t)},
                     noise=0.01, seed=5)
    fixed = {n: float(val) for n, val in zip(m.param_names("device"), theta) if n not in FREE and n != "A"}
    return rec, fixed


ENGINES = {
    "lsq": lambda: LeastSquares(n_draws=200),
    "mcmc": lambda: Emcee(MCMCSettings(n_walkers=14, max_steps=60, check_every=30, progress=False), evidence="laplace"),
    "ukf": lambda: UKF(n_lhs=2, taus=(0.01, 0.1), n_draws=200),
}


@pytest.mark.parametrize("engine", list(ENGINES))
def test_point_simulates_and_preload_is_reported(spencer_device, engine):
    rec, fixed = spencer_device
    idata = Identify("spencer", ENGINES[engine](), fixed=fixed).fit(rec, progress=False)
    s = results.summary_of(idata)
    m = get_model("spencer")
    theta = m.theta("device", {**fixed, **s.point})  # the point with x0 beside F_pre must be consistent
    sim = simulate(m, Inputs.device(rec["displacement"].values, rec["velocity"].values, 1.0 / FS,
                                    rec["voltage"].values), theta[None])
    assert sim.ok.all(), f"{engine}: the point diverged at sample {sim.failed}"
    assert s.mse is not None and np.isfinite(s.mse)
    # x0 is reported (derived, draw by draw) beside the estimated preload
    assert {"k1", "F_pre", "x0"} <= set(s.params) and {"k1", "F_pre", "x0"} <= set(s.point)
    assert s.point["x0"] == pytest.approx(s.point["F_pre"] / s.point["k1"], rel=1e-12)
    draws = idata.posterior
    ratio = (draws["F_pre"] / draws["k1"]).values
    assert draws["x0"].values == pytest.approx(ratio, rel=1e-12)
    assert s.params_sd["x0"] == pytest.approx(np.std(ratio, ddof=0 if engine != "mcmc" else 1), rel=1e-9)


def test_x0_is_read_as_the_preload_it_implies():
    m = get_model("spencer")
    names = m.param_names("device")
    th = m.theta("device", {"k1": 400.0, "x0": 0.2})
    assert th[names.index("F_pre")] == pytest.approx(80.0)
    with pytest.raises(ValueError, match="give it with 'k1'"):
        m.theta("device", {"x0": 0.2})
    with pytest.raises(ValueError, match="disagrees"):
        m.theta("device", {"k1": 400.0, "x0": 0.2, "F_pre": 50.0})
