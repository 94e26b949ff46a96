"""The main job's stages beside the posteriors (bayes_mr.run.aside): the in-process results, whatever happens
to the child."""

from __future__ import annotations

import os
from dataclasses import replace

import pytest

from bayes_mr.run.job import QUICK, run
from bayes_mr.run.aside import Stage, start


def _square(x, *, say):
    say(f"squaring {x} in {os.getpid()}")
    return x * x, os.getpid()


def _exit_unless_in(pid, *, say):
    """End the process it runs in unless that is ``pid`` (a child that dies: killed, out of memory)."""
    if os.getpid() != pid:
        os._exit(3)
    return "here"


def _raise(*, say):
    raise ValueError("no such channel")


def _collect(stages):
    said = []
    out, waited, where = start(stages, t0=0.0, live=False).collect(said.append)
    return out, where, said


def test_stages_run_in_a_child_in_order_and_their_progress_is_passed_on():
    out, where, said = _collect([Stage("a", _square, (3,)), Stage("b", _square, (4,))])
    assert list(out) == ["a", "b"]
    (a, pid_a), _ = out["a"]
    (b, pid_b), _ = out["b"]
    assert (a, b) == (9, 16) and pid_a == pid_b != os.getpid()
    assert where == "a child process beside the posteriors"
    assert [m for m in said if m.startswith("(beside)")] == [f"(beside) squaring 3 in {pid_a}",
                                                             f"(beside) squaring 4 in {pid_a}"]


def test_a_child_that_dies_costs_time_only_its_stages_run_here():
    out, where, said = _collect([Stage("x", _exit_unless_in, (os.getpid(),))])
    assert out["x"][0] == "here"
    assert "exit code 3" in where and any("running them here" in m for m in said)


def test_stages_that_cannot_be_shipped_run_here():
    out, where, _ = _collect([Stage("x", _square, (2,), {}), Stage("y", lambda *, say: 5)])
    assert out["x"][0][1] == os.getpid() and out["y"][0] == 5
    assert "could not start" in where


def test_a_stage_that_raises_in_the_child_raises_here_with_its_name():
    with pytest.raises(RuntimeError, match="stage boom, run beside the posteriors, failed: ValueError: no such"):
        _collect([Stage("boom", _raise)])


#: The quick job made smaller (short chains, no term search): what is compared is where the stages run, not
#: how much they compute.
SMALL = replace(QUICK, forms=("dahl", "lugre"), duration_s=3.0, terms=False,
                mcmc=replace(QUICK.mcmc, max_steps=200))


def _without_times(d):
    """``d`` without wall times and paths (what may differ between two runs of the same computation)."""
    if isinstance(d, dict):
        return {k: _without_times(v) for k, v in d.items()
                if k not in ("wall_s", "figures", "report", "results") and not k.endswith("_s")}
    if isinstance(d, list):
        return [_without_times(v) for v in d]
    return d


def test_the_main_job_beside_the_posteriors_gives_the_in_process_numbers(tmp_path):
    budget = replace(SMALL, forms=("dahl",))
    assert not budget.aside  # off in make run (module docstring)
    here = run(tmp_path / "here", budget=budget, progress=False)
    beside = run(tmp_path / "beside", budget=replace(budget, aside=True), progress=False)
    assert here["stages_where"]["ran_in"] == "this process, after the posteriors"
    assert beside["stages_where"]["ran_in"] == "a child process beside the posteriors"
    assert beside["stages_where"]["stages"] == ["noise_sensitivity", "diagnose", "shake_table"]
    for key in ("noise_sensitivity", "diagnose", "shake_table"):
        assert _without_times(beside[key]) == _without_times(here[key]), key


def test_without_the_child_the_stages_are_planned_for_the_final_selection(tmp_path, monkeypatch):
    """When the posteriors change the first pass's choice, the diagnosis runs once, for the final selection."""
    import bayes_mr.run.job as mainjob

    real_posteriors, real_diagnose, firsts, diagnosed = mainjob.with_posteriors, mainjob.diagnose_selected, [], []

    def switched(first, *args, **kwargs):  # posteriors that end with the other form selected
        firsts.append(first["selected"])
        comp = real_posteriors(first, *args, **kwargs)
        return {**comp, "selected": next(m for m in ("dahl", "lugre") if m != first["selected"])}

    def spied(record, model, *args, **kwargs):
        diagnosed.append(model)
        return real_diagnose(record, model, *args, **kwargs)

    monkeypatch.setattr(mainjob, "with_posteriors", switched)
    monkeypatch.setattr(mainjob, "diagnose_selected", spied)
    budget = replace(SMALL, shake_table_engines=())
    out = run(tmp_path, budget=budget, progress=False, stages=("compare", "diagnose"))
    assert out["selected"] != firsts[0]
    assert diagnosed == [out["selected"]] and out["selected"] in out["diagnose"]
