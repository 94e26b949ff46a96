"""The screen's stall rule: a crawling refinement stops early, and what is kept is refined to its end."""

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.optimize import least_squares

from bayes_mr.diagnosis import screen as screen_mod
from bayes_mr.diagnosis.fits import fit_model
from bayes_mr.diagnosis.screen import screen_one
from bayes_mr.diagnosis.search import forward_select, settled
from bayes_mr.inference.lsq.least_squares import LSQSettings
from bayes_mr.inference.lsq.refine import Stall
from bayes_mr.models import EFFECTS
from records import signal_record


def rosenbrock(x, a=100.0):
    """Residuals of Rosenbrock's valley: trust-region steps crawl along it."""
    return np.array([a * (x[1] - x[0] ** 2), 1.0 - x[0]])


def test_stall_stops_a_crawl_after_steps_that_gain_less_than_its_nats():
    kw = dict(method="trf", x_scale="jac", xtol=1e-12, ftol=1e-10, gtol=1e-12)
    full = least_squares(rosenbrock, [-1.2, 1.0], **kw)
    seen = []
    rule = Stall(steps=3, nats=0.05)
    check = rule.callback()

    def watch(intermediate_result):
        seen.append(float(intermediate_result.cost))
        check(intermediate_result)

    stopped = least_squares(rosenbrock, [-1.2, 1.0], callback=watch, **kw)
    assert full.status > 0 and full.cost < 1e-12
    assert stopped.status == -2 and stopped.nfev < full.nfev
    assert stopped.cost == pytest.approx(seen[-1]) and stopped.cost > full.cost
    # stopped on the first window of three accepted steps that together gained less than 0.05
    gains = [seen[i - 3] - seen[i] for i in range(3, len(seen))]
    assert gains[-1] < 0.05 and all(g >= 0.05 for g in gains[:-1])


def test_a_fresh_callback_per_refinement():
    rule = Stall(steps=2, nats=1.0)
    first = rule.callback()
    first(SimpleNamespace(cost=10.0))
    first(SimpleNamespace(cost=9.8))
    with pytest.raises(StopIteration):  # 10 -> 9.6 over two steps: 0.4 < 1
        first(SimpleNamespace(cost=9.6))
    second = rule.callback()  # its own history: two costs are no window yet
    second(SimpleNamespace(cost=9.6))
    second(SimpleNamespace(cost=9.5))


@pytest.fixture(scope="module")
def stribeck_record():
    """A dahl device test (6 s at 500 Hz, 1 % noise) with a Stribeck excess hidden: its refit takes several steps."""
    return signal_record("dahl+stribeck_friction", "device", {"F_st": 40.0, "v_s": 0.01}, signal="blwn",
                         signal_seed=0, noise=0.01, seed=3, duration=6.0, fs=500.0, amplitude=10e-3, fmax=10.0)


def test_a_kept_effect_is_refined_past_the_screens_stall(stribeck_record, monkeypatch):
    """With a stall rule that stops every refinement after its first step, the screen's fit of the hidden effect
    is short of its optimum; settled() takes it there: the likelihood, score and values of the rule-free refit."""
    rec = stribeck_record
    base = fit_model(rec, "dahl", LSQSettings(seed=0))
    effect = EFFECTS["stribeck_friction"]
    free = screen_one(rec, base, effect)
    cut = screen_one(rec, base, effect, stall=Stall(steps=1, nats=1e12))
    assert all(r["stalled"] for r in cut.runs) and not any(r["stalled"] for r in free.runs)
    assert cut.fit.result.log_likelihood < free.fit.result.log_likelihood - 0.2
    done = settled(base, cut)
    assert done.fit.result.log_likelihood == pytest.approx(free.fit.result.log_likelihood, abs=1e-3)
    assert done.score == pytest.approx(free.score, rel=1e-4)
    assert done.params()["F_st"] == pytest.approx(free.params()["F_st"], rel=1e-3)
    # forward selection names it from the stalled screen and builds the next round on the settled fit: the offset
    # (absent) gains nothing that the stall had left
    monkeypatch.setattr(screen_mod, "STALL", Stall(steps=1, nats=1e12))
    selected, rounds = forward_select(rec, base, max_effects=2, candidates=("stribeck_friction", "force_offset"))
    assert [c.name for c in selected] == ["stribeck_friction"]
    assert selected[0].fit.result.log_likelihood == pytest.approx(free.fit.result.log_likelihood, abs=1e-3)
    assert [c.name for c in rounds[1]] == ["force_offset"] and rounds[1][0].score < 8.0


def test_restart_allows_stalled_starts_their_slack(monkeypatch):
    """Two refined starts that stopped on the stall rule 0.5 nats apart are one basin (no global search); the same
    spread without a stall, on a cost of 1500 (1e-4 relative is 0.15), is two basins and searches again."""
    from bayes_mr.diagnosis import search
    from bayes_mr.diagnosis.screen import Candidate

    ran = []
    monkeypatch.setattr(search, "global_refit", lambda fit, own, seed=0: (ran.append(own) or fit, {"ran": True}))
    effect = EFFECTS["stribeck_friction"]

    def cand(stalled):
        runs = [{"cost": 1500.0, "stalled": stalled}, {"cost": 1500.5, "stalled": stalled}]
        return Candidate("stribeck_friction", effect, object(), 20.0, runs=runs)

    one = search.restarted(None, cand(True))
    assert "skipped" in one.restart and "stalled" in one.restart["skipped"] and not ran
    two = search.restarted(None, cand(False))
    assert two.restart == {"ran": True} and ran == [["F_st", "v_s"]]
