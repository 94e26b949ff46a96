"""The main job's posteriors from one pool of seconds, the selected form's first (bayes_mr.run.posteriors)."""

from dataclasses import replace

import pytest
from records import offset_device_record

from bayes_mr.inference.mcmc.settings import MCMCSettings
from bayes_mr.run.plan import FULL, QUICK, Budget
from bayes_mr.run.posteriors import least_squares_pass, posterior_order, run_posteriors
from bayes_mr.run.warmup import compile_filter_aside, wait


def test_the_selected_form_runs_first_then_the_evidence_decides():
    bf = {"a": 12.0, "b": 0.0, "c": 3.0, "d": float("nan")}
    assert posterior_order(["a", "b", "c", "d", "e"], "b", bf) == ["b", "c", "a", "d", "e"]
    # the calibrated selection may rank another form above the selected one on the raw factors: it still runs first
    assert posterior_order(["a", "b", "c"], "c", {"a": -1.0, "b": 2.0, "c": 0.0}) == ["c", "a", "b"]
    assert posterior_order(["a", "b"], None, {}) == ["a", "b"]


def test_a_spent_pool_starts_nothing_and_says_who_spent_it(monkeypatch):
    """A pool too small for the first form's chain: its measured step cost is refused with the budget's numbers,
    and that refusal spends what was left, so the next form is not started and the report says who spent it.
    Neither refits the least squares of the first pass (the chain starts from it)."""
    rec = offset_device_record(1.6, fs=250.0)
    budget = replace(QUICK, forms=("dahl", "lugre"), mcmc_pool_s=1e-6,
                     mcmc=MCMCSettings(max_steps=300, min_tau_multiple=20.0, rhat_max=1.05))
    rows, idata, fitted = least_squares_pass(rec, None, ["dahl", "lugre"], seed=0, noise="iid", say=lambda *_: None)
    assert [r["engine"] for r in rows] == ["lsq", "lsq"] and set(idata) == {("dahl", "lsq"), ("lugre", "lsq")}

    def refit(*_):
        raise AssertionError("the posterior refitted least squares")

    monkeypatch.setattr("bayes_mr.selection.fit_jobs.fit_lsq", refit)
    fits, skipped = run_posteriors(rec, None, ["dahl", "lugre"], budget, seed=0, fitted=fitted, say=lambda *_: None)
    assert fits == {}
    assert "more than the" in skipped["dahl"] and skipped["dahl"].endswith("not run")
    assert skipped["lugre"].startswith("the posteriors' pool of 1e-06 s is spent (dahl 0 s)"), skipped["lugre"]


def test_the_first_pass_and_the_posterior_are_compare_s_rows():
    """The first pass's ``lsq`` row and the posterior from its fit are the rows ``compare`` gives for ``lsq`` and
    ``mcmc`` of the same form and seed (one least-squares fit for both there too), without a pool each posterior
    on its own settings."""
    from bayes_mr.selection.comparison import compare
    from bayes_mr.inference.identify import Emcee, LeastSquares
    from bayes_mr.inference.lsq.least_squares import LSQSettings

    rec = offset_device_record(1.6, fs=250.0)
    mcmc = MCMCSettings(max_steps=400, min_tau_multiple=20.0, rhat_max=1.05)
    budget = replace(QUICK, forms=("dahl",), mcmc=mcmc)
    rows, _, fitted = least_squares_pass(rec, rec, ["dahl"], seed=3, noise="iid", say=lambda *_: None)
    fits, skipped = run_posteriors(rec, rec, ["dahl"], budget, seed=3, fitted=fitted, say=lambda *_: None)
    assert skipped == {}
    row, idata = fits["dahl"]
    assert row["engine"] == "mcmc" and "error" not in row and idata is not None and "validation" in row
    est = {"mcmc": Emcee(settings=replace(mcmc, seed=3, progress=False), evidence=budget.evidence),
           "lsq": LeastSquares(settings=LSQSettings(seed=3))}
    ref = compare(rec, ["dahl"], engines=("lsq", "mcmc"), validate=rec, seed=3, progress=False, estimators=est)
    for mine, theirs in ((rows[0], ref.rows[0]), (row, ref.rows[1])):
        assert mine["params"] == theirs["params"] and mine["log_evidence"] == theirs["log_evidence"], (mine, theirs)
        assert mine["validation"]["mse"] == theirs["validation"]["mse"]


def test_the_budget_refuses_what_it_cannot_run():
    assert FULL.mcmc_pool_s and FULL.mcmc.max_seconds is None  # one pool, no per-posterior cap in make run
    with pytest.raises(ValueError, match="shake_table_engines"):
        replace(FULL, shake_table_engines=("ukf", "mcmc"))
    with pytest.raises(ValueError, match="mcmc_pool_s"):
        Budget(fs=250.0, duration_s=None, mcmc_pool_s=0.0)


def test_the_cli_refuses_a_pool_that_is_not_positive(capsys):
    from bayes_mr.cli.commands import main

    assert main(["run", "--quick", "--mcmc-pool", "0", "--out", "unused", "--no-readme", "--quiet"]) == 2
    assert "mcmc_pool_s must be positive" in capsys.readouterr().err


def test_a_failed_filter_warm_up_is_reported_not_raised():
    """The child that compiles the UKF filter aside (bayes_mr.run.warmup) only saves time: when it fails, the job is
    told why and goes on (its first UKF fit compiles the filter itself)."""
    said = []
    child = compile_filter_aside(offset_device_record(1.6, fs=250.0), "no-such-form", 1, (0.01,))
    error = wait(child, said.append)
    assert error is not None and "no-such-form" in error
    assert said == [f"the UKF filter's compile aside failed ({error}); the first UKF fit compiles it"]
