"""The main job's posteriors from one pool of seconds, the selected form's first (bayes_mr.mainjob_posteriors)."""

from dataclasses import replace

import pytest
from records import offset_device_record

from bayes_mr.inference.mcmc import MCMCSettings
from bayes_mr.mainjob import FULL, QUICK, Budget
from bayes_mr.mainjob_posteriors import posterior_order, run_posteriors
from bayes_mr.warmup import compile_filter_aside, wait


def test_the_selected_form_runs_first_then_the_evidence_decides():
    bf = {"a": 12.0, "b": 0.0, "c": 3.0, "d": float("nan")}
    assert posterior_order(["a", "b", "c", "d", "e"], "b", bf) == ["b", "c", "a", "d", "e"]
    # the calibrated selection may rank another form above the selected one on the raw factors: it still runs first
    assert posterior_order(["a", "b", "c"], "c", {"a": -1.0, "b": 2.0, "c": 0.0}) == ["c", "a", "b"]
    assert posterior_order(["a", "b"], None, {}) == ["a", "b"]


def test_a_spent_pool_starts_nothing_and_says_who_spent_it():
    """A pool the first form's least squares already used up: that posterior is not run and the report says
    the pool was spent; the next form's chain gets what is left (here too little to start: its measured step
    cost is refused with the budget's numbers, after the least squares it shares with the comparison)."""
    rec = offset_device_record(1.6, fs=250.0)
    budget = replace(QUICK, forms=("dahl", "lugre"), mcmc_pool_s=0.05,
                     mcmc=MCMCSettings(max_steps=300, min_tau_multiple=20.0, rhat_max=1.05))
    fits, skipped = run_posteriors(rec, None, ["dahl", "lugre"], budget, seed=0, lsq_s={"dahl": 1.0},
                                   say=lambda *_: None)
    assert fits == {}
    assert skipped["dahl"] == ("the 0 s left of the posteriors' pool of 0.05 s (spent: nothing yet) do not cover the "
                               "least-squares fit its chain starts from (1 s): not run")
    assert "more than the" in skipped["lugre"] and skipped["lugre"].endswith("not run")


def test_without_a_pool_each_posterior_runs_on_its_own_settings():
    rec = offset_device_record(1.6, fs=250.0)
    budget = replace(QUICK, forms=("dahl",), mcmc=MCMCSettings(max_steps=400, min_tau_multiple=20.0, rhat_max=1.05))
    fits, skipped = run_posteriors(rec, rec, ["dahl"], budget, seed=0, lsq_s={}, say=lambda *_: None)
    assert skipped == {}
    row, idata = fits["dahl"]
    assert row["engine"] == "mcmc" and "error" not in row and idata is not None and "validation" in row


def test_the_budget_refuses_what_it_cannot_run():
    assert FULL.mcmc_pool_s and FULL.mcmc.max_seconds is None  # one pool, no per-posterior cap in make run
    with pytest.raises(ValueError, match="shake_table_engines"):
        replace(FULL, shake_table_engines=("ukf", "mcmc"))
    with pytest.raises(ValueError, match="mcmc_pool_s"):
        Budget(fs=250.0, duration_s=None, mcmc_pool_s=0.0)


def test_the_cli_refuses_a_pool_that_is_not_positive(capsys):
    from bayes_mr.cli import main

    assert main(["run", "--quick", "--mcmc-pool", "0", "--out", "unused", "--no-readme", "--quiet"]) == 2
    assert "mcmc_pool_s must be positive" in capsys.readouterr().err


def test_a_failed_filter_warm_up_is_reported_not_raised():
    """The child that compiles the UKF filter aside (bayes_mr.warmup) only saves time: when it fails, the job is
    told why and goes on (its first UKF fit compiles the filter itself)."""
    said = []
    child = compile_filter_aside(offset_device_record(1.6, fs=250.0), "no-such-form", 1, (0.01,))
    error = wait(child, said.append)
    assert error is not None and "no-such-form" in error
    assert said == [f"the UKF filter's compile aside failed ({error}); the first UKF fit compiles it"]
