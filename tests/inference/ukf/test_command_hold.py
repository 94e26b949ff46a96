"""The UKF's prediction reads the command as the record says: held between samples, or linear.

The filter propagates its sigma points over each sample interval with the model's integrator; with the
command held, the interval ends on the command it started with, as in the simulator. A filter whose
parameter and state spreads are negligible, with no process noise and no update, is the simulator run
sample by sample: its state means give the simulator's force, the held one under ``hold`` and the linear one
under ``linear``. Filtering the held record, the held reading explains the force better (a larger
innovation log-likelihood).
"""

import dataclasses

import numpy as np
import pytest
from records import held_command_device_record

from bayes_mr.inference.ukf import filter as ukf
from bayes_mr.inference.ukf import kernel as K
from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.simulation.simulate import simulate


@pytest.fixture(scope="module")
def held():
    return held_command_device_record(duration=1.5, seed=5)


def _problem(record, reading: str, settings: ukf.UKFSettings, predict_only: bool):
    lik = OutputError("spencer", record, noise="fixed", command_interp=reading)
    problem = ukf.make_problem(lik, settings)
    if predict_only:  # no update, and spreads too small for the sigma points' mean to leave the simulation
        problem = dataclasses.replace(problem, valid=np.zeros_like(problem.valid), p0_states=problem.p0_states * 1e-12)
    return lik, problem


def _filtered_force(record, truth: dict, reading: str) -> tuple[np.ndarray, np.ndarray]:
    """The force of the predict-only filter's state means, and the simulator's, under one reading."""
    settings = ukf.UKFSettings(state_walk=0.0)
    lik, problem = _problem(record, reading, settings, predict_only=True)
    theta = lik.model.theta("device", truth)
    free = theta[lik.par.free_idx]
    prior = ukf.Prior(problem.coords.to_phi(free), np.full(free.size, 1e-6))
    out = ukf.filter_states(problem, prior, settings)
    assert out["info"][K.I_STATUS] == K.OK
    args = ukf._kernel_args(problem, settings)
    ns = len(problem.p0_states)
    rows, h = problem.inputs.rows, problem.inputs.dt
    force = np.array([K.measure(args["lay"], args["cst"], theta, k * h, rows[k], out["states"][k, :ns].copy(), 1)[0]
                      for k in range(rows.shape[0])])
    # the filter integrates z on its loading branches too (the simulator holds it there: branch.on_branch)
    return force, simulate(lik.model, lik.inputs, theta, hold_branch=False)["force"]


def test_the_filter_predicts_as_the_simulator_under_either_reading(held):
    record, truth = held
    got = {reading: _filtered_force(record, truth, reading) for reading in ("hold", "linear")}
    sd = float(np.std(got["hold"][1]))
    for reading, (filtered, simulated) in got.items():
        assert np.sqrt(np.mean((filtered - simulated) ** 2)) < 1e-6 * sd, reading
    gap = np.sqrt(np.mean((got["hold"][0] - got["linear"][0]) ** 2))
    assert gap > 5e-3 * sd, gap / sd  # the two readings are different predictions


def test_the_held_reading_explains_a_held_record_better(held):
    record, truth = held
    loglik = {}
    for reading in ("hold", "linear"):
        lik, problem = _problem(record, reading, ukf.UKFSettings(), predict_only=False)
        free = lik.model.theta("device", truth)[lik.par.free_idx]
        prior = ukf.Prior(problem.coords.to_phi(free), np.full(free.size, 1e-3))
        res = ukf.run_priors(problem, [prior], parallel=False)
        assert res["info"][0, K.I_STATUS] == K.OK
        loglik[reading] = float(res["info"][0, K.I_LOGLIK])
    assert loglik["hold"] > loglik["linear"] + 100.0, loglik
