"""The main job's posteriors from one pool of work, the selected form's first (bayes_mr.run.posteriors)."""

import time
from dataclasses import replace

import numpy as np
import pytest
from records import offset_device_record

from bayes_mr.inference.mcmc.budget import MIN_CHAIN_STEPS, check_budget
from bayes_mr.inference.mcmc.settings import MCMCSettings
from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.run.plan import FULL, QUICK, Budget
from bayes_mr.run.posteriors import evaluation_price, least_squares_pass, posterior_order, run_posteriors
from bayes_mr.run.warmup import compile_filter_aside, wait

#: The posteriors' settings of these tests: QUICK's rule on short chains.
SHORT = MCMCSettings(max_steps=300, min_tau_multiple=20.0, rhat_max=1.05)


def quiet(*_):
    """A progress sink."""


def test_the_selected_form_runs_first_then_the_evidence_decides():
    bf = {"a": 12.0, "b": 0.0, "c": 3.0, "d": float("nan")}
    assert posterior_order(["a", "b", "c", "d", "e"], "b", bf) == ["b", "c", "a", "d", "e"]
    # the calibrated selection may rank another form above the selected one on the raw factors: it still runs first
    assert posterior_order(["a", "b", "c"], "c", {"a": -1.0, "b": 2.0, "c": 0.0}) == ["c", "a", "b"]
    assert posterior_order(["a", "b"], None, {}) == ["a", "b"]


def test_a_pool_too_small_skips_with_its_reason_in_evaluations(monkeypatch):
    """A pool that holds fewer evaluations than a form's pilot and shortest chain need: the posterior is refused
    before any evaluation, with the numbers in log-density evaluations and the pool's integrator steps, and a
    refusal spends nothing, so the next form is judged on the same pool. A pool below one evaluation's price
    starts nothing. Neither refits the least squares of the first pass (the chain starts from it)."""
    rec = offset_device_record(1.6, fs=250.0)
    rows, idata, fitted = least_squares_pass(rec, None, ["dahl", "lugre"], seed=0, noise="iid", say=quiet)
    assert [r["engine"] for r in rows] == ["lsq", "lsq"] and set(idata) == {("dahl", "lsq"), ("lugre", "lsq")}

    def refit(*_):
        raise AssertionError("the posterior refitted least squares")

    monkeypatch.setattr("bayes_mr.selection.fit_jobs.fit_lsq", refit)
    monkeypatch.setattr("bayes_mr.run.posteriors.least_squares", refit)
    price = evaluation_price(*fitted["dahl"])
    budget = replace(QUICK, forms=("dahl", "lugre"), mcmc_pool=1000.0 * price, mcmc=SHORT)
    fits, skipped, work = run_posteriors(rec, None, ["dahl", "lugre"], budget, seed=0, fitted=fitted, say=quiet)
    assert fits == {}
    need = check_budget(SHORT.walkers(5), SHORT.pilot_length, 10**9, 8)  # dahl on a device test: 4 + σ
    assert skipped["dahl"] == (
        f"its pilot and first adaptation round ({SHORT.pilot_length} steps × {SHORT.walkers(5)} walkers) and the "
        f"fewest steps a chain has met the rule in ({MIN_CHAIN_STEPS} × 8 walkers) need {need} log-density "
        f"evaluations, more than the 1000 its work budget leaves it: not run (the pool has {1000.0 * price:.3g} of "
        f"its {1000.0 * price:.3g} integrator steps left, {price} an evaluation)")
    assert "log-density evaluations, more than the" in skipped["lugre"]
    assert work["dahl"]["evaluations"] == work["lugre"]["evaluations"] == 0
    assert work["dahl"]["steps_per_evaluation"] == price and work["dahl"]["machine_limit"] is None
    spent = replace(budget, mcmc_pool=0.5 * price)
    fits, skipped, _ = run_posteriors(rec, None, ["dahl", "lugre"], spent, seed=0, fitted=fitted, say=quiet)
    assert fits == {} and skipped == {m: f"the posteriors' pool of {0.5 * price:.3g} integrator steps is spent "
                                         "(nothing yet): not run" for m in ("dahl", "lugre")}


def test_the_same_posteriors_on_a_slow_machine(monkeypatch):
    """The decisive one: the same pool with the likelihood made slow (10 ms a call, as beside another job) gives
    the same posteriors: the same forms started and skipped for the same reasons, the same chains and numbers, the
    same work charged. The pool holds dahl's whole posterior and half of what lugre needs at least, so the work
    budget, not the clock, decides that lugre is not run. (A pool in seconds fails this: at three times what both
    posteriors take with the fast likelihood, the slow one stops dahl's chain early on the clock and leaves lugre
    unstarted.)"""
    rec = offset_device_record(1.6, fs=250.0)
    _, _, fitted = least_squares_pass(rec, None, ["dahl", "lugre"], seed=0, noise="iid", say=quiet)
    free, _, spent = run_posteriors(rec, None, ["dahl"], replace(QUICK, forms=("dahl",), mcmc=SHORT), seed=0,
                                    fitted=fitted, say=quiet)
    assert free["dahl"][0]["converged"]
    lugre_needs = check_budget(SHORT.walkers(6), SHORT.pilot_length, 10**9, 8)
    pool = spent["dahl"]["integrator_steps"] + 0.5 * lugre_needs * evaluation_price(*fitted["lugre"])
    budget = replace(QUICK, forms=("dahl", "lugre"), mcmc=SHORT, mcmc_pool=pool, mcmc_pool_cap_s=3600.0)
    fast = run_posteriors(rec, None, ["dahl", "lugre"], budget, seed=0, fitted=fitted, say=quiet)
    call = OutputError.__call__

    def slow(self, x):
        time.sleep(0.01)
        return call(self, x)

    monkeypatch.setattr(OutputError, "__call__", slow)
    slowed = run_posteriors(rec, None, ["dahl", "lugre"], budget, seed=0, fitted=fitted, say=quiet)
    assert set(fast[0]) == set(slowed[0]) == {"dahl"} and fast[1] == slowed[1] and set(fast[1]) == {"lugre"}
    (row, data), (slow_row, slow_data) = fast[0]["dahl"], slowed[0]["dahl"]
    for key in ("params", "params_sd", "log_evidence", "mse", "n_steps", "pilot_steps", "adapt_acceptance",
                "evaluations", "stopped", "tau_max", "rhat_max"):
        assert row[key] == slow_row[key] == free["dahl"][0][key], key
    for name in data.posterior.data_vars:
        assert np.array_equal(data.posterior[name].values, slow_data.posterior[name].values), name
    for form in ("dahl", "lugre"):
        mine, theirs = dict(fast[2][form]), dict(slowed[2][form])
        for w in (mine, theirs):
            w.pop("wall_s"), w.pop("wall_cap_s")  # the clock's, and the cap what it left
        assert mine == theirs


def test_the_wall_time_cap_is_reported_as_a_machine_limit():
    """A cap far below what a posterior needs: the first chain is stopped by it, flagged "max_seconds" and reported
    as a machine limit, not a result; the next form finds the cap spent and is not run, again as a machine limit."""
    rec = offset_device_record(1.6, fs=250.0)
    _, _, fitted = least_squares_pass(rec, None, ["dahl", "lugre"], seed=0, noise="iid", say=quiet)
    budget = replace(QUICK, forms=("dahl", "lugre"), mcmc=SHORT, mcmc_pool_cap_s=1e-3)
    fits, skipped, work = run_posteriors(rec, None, ["dahl", "lugre"], budget, seed=0, fitted=fitted, say=quiet)
    row = fits["dahl"][0]
    assert row["stopped"] == "max_seconds" and not row["converged"] and row["wall_cap_s"] == pytest.approx(1e-3)
    assert work["dahl"]["machine_limit"] == ("stopped by the wall-time cap of 0.001 s (what the posteriors' 0.001 s "
                                             "cap left it): a machine limit, not a result")
    assert skipped["lugre"].startswith("not run: the posteriors' wall-time cap of 0.001 s is spent (dahl ")
    assert skipped["lugre"].endswith("): a machine limit, not a result")
    assert work["lugre"]["machine_limit"] == skipped["lugre"] and work["lugre"]["evaluations"] == 0


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
    fits, skipped, work = run_posteriors(rec, rec, ["dahl"], budget, seed=3, fitted=fitted, say=lambda *_: None)
    assert skipped == {} and work["dahl"]["evaluations"] == fits["dahl"][0]["evaluations"] > 0
    row, idata = fits["dahl"]
    assert row["engine"] == "mcmc" and "error" not in row and idata is not None and "validation" in row
    est = {"mcmc": Emcee(settings=replace(mcmc, seed=3, progress=False), evidence=budget.evidence),
           "lsq": LeastSquares(settings=LSQSettings(seed=3))}
    ref = compare(rec, ["dahl"], engines=("lsq", "mcmc"), validate=rec, seed=3, progress=False, estimators=est)
    for mine, theirs in ((rows[0], ref.rows[0]), (row, ref.rows[1])):
        assert mine["params"] == theirs["params"] and mine["log_evidence"] == theirs["log_evidence"], (mine, theirs)
        assert mine["validation"]["mse"] == theirs["validation"]["mse"]


def test_the_budget_refuses_what_it_cannot_run():
    # make run: one pool of work under one wall-time cap, no per-posterior budget or cap
    assert FULL.mcmc_pool and FULL.mcmc_pool_cap_s and FULL.mcmc.max_seconds is None
    assert FULL.mcmc.max_evaluations is None and QUICK.mcmc_pool is None and QUICK.mcmc_pool_cap_s is None
    with pytest.raises(ValueError, match="shake_table_engines"):
        replace(FULL, shake_table_engines=("ukf", "mcmc"))
    with pytest.raises(ValueError, match="mcmc_pool must be a positive number of integrator steps"):
        Budget(fs=250.0, duration_s=None, mcmc_pool=0.0)
    with pytest.raises(ValueError, match="mcmc_pool_cap_s must be positive seconds"):
        Budget(fs=250.0, duration_s=None, mcmc_pool_cap_s=0.0)


#: What each form's posterior spends unbudgeted on the packaged record at 1 kHz, seed 0: (log-density evaluations,
#: integrator steps an evaluation), from ``scripts/measure_posterior_work.py`` (FULL's comment).
MEASURED = {"normalized-bouc-wen": (10400, 60700), "dahl": (8000, 19400), "lugre": (10400, 18900),
            "bouc-wen": (25200, 28400), "spencer": (38400, 66100)}


def test_the_full_pool_is_the_five_posteriors_work_and_a_quarter_more():
    """FULL's pool is derived from the chains' measured work, not tuned: their sum and a quarter, which holds each
    posterior taking one more adaptation round (100 steps of its ensemble) and two more checks (2 × 50 steps of 8
    walkers) than measured."""
    need = {m: e * p for m, (e, p) in MEASURED.items()}
    assert set(need) == set(FULL.forms)
    assert FULL.mcmc_pool == pytest.approx(1.25 * sum(need.values()), rel=0.01)
    walkers = {"normalized-bouc-wen": 28, "dahl": 20, "lugre": 24, "bouc-wen": 24, "spencer": 56}
    more = sum((100 * walkers[m] + 2 * 50 * 8) * MEASURED[m][1] for m in MEASURED)
    assert FULL.mcmc_pool - sum(need.values()) >= more


def test_the_cli_refuses_a_pool_that_is_not_positive(capsys):
    from bayes_mr.cli.commands import main

    assert main(["run", "--quick", "--mcmc-pool", "0", "--out", "unused", "--no-readme", "--quiet"]) == 2
    assert "mcmc_pool must be a positive number of integrator steps" in capsys.readouterr().err
    assert main(["run", "--quick", "--mcmc-cap", "-1", "--out", "unused", "--no-readme", "--quiet"]) == 2
    assert "mcmc_pool_cap_s must be positive seconds" in capsys.readouterr().err


def test_a_failed_filter_warm_up_is_reported_not_raised():
    """The child that compiles the UKF filter aside (bayes_mr.run.warmup) only saves time: when it fails, the job is
    told why and goes on (its first UKF fit compiles the filter itself)."""
    said = []
    child = compile_filter_aside(offset_device_record(1.6, fs=250.0), "no-such-form", 1, (0.01,))
    error = wait(child, said.append)
    assert error is not None and "no-such-form" in error
    assert said == [f"the UKF filter's compile aside failed ({error}); the first UKF fit compiles it"]
