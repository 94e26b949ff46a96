"""Open-ended term discovery: library terms in the kernel, the search, the refit."""

import numpy as np
import pytest

from bayes_mr.diagnosis.fits import fit_model
from bayes_mr.diagnosis.library import library
from bayes_mr.diagnosis.term_search import MIN_BLOCKS, folds, search_terms
from bayes_mr.inference.identify import predict
from bayes_mr.likelihood.output_error import record_scales
from bayes_mr.models import get_model
from bayes_mr.models import terms as lib
from bayes_mr.simulation.simulate import Inputs, simulate
from tests.records import signal_record

OPTS = dict(noise=0.01, seed=1, signal_seed=3, duration=4.0, fs=500.0)


def test_term_names_round_trip_and_code_table():
    m = get_model("spencer+term(abs(xdot)*u)+zterm(abs(x)*xdot)")
    assert m.name == "spencer+term(u*abs(xdot))+zterm(xdot*abs(x))"
    assert get_model(m.name).name == m.name
    assert m.free_names("device")[-2:] == ("tf_u_axd", "tz_xd_ax")
    with pytest.raises(ValueError, match="lagged command"):
        get_model("dahl+term(ulag)").layout("device")
    with pytest.raises(ValueError, match="factors"):
        get_model("dahl+term(y*x)")


def test_force_term_adds_theta_times_basis():
    """A force-map term on a device test adds exactly θ·b(x, ẋ) to the force."""
    base, ext = get_model("dahl"), get_model("dahl+term(abs(x)*xdot)")
    t = np.arange(500) / 500.0
    x = 0.01 * np.sin(2 * np.pi * 2 * t)
    xd = 0.01 * 2 * np.pi * 2 * np.cos(2 * np.pi * 2 * t)
    inputs = Inputs.device(x, xd, 1 / 500.0)
    f0 = simulate(base, inputs, base.theta("device"))["force"]
    f1 = simulate(ext, inputs, ext.theta("device", {"tf_xd_ax": 3e4}))["force"]
    np.testing.assert_allclose(f1 - f0, 3e4 * np.abs(x) * xd, atol=1e-9 * np.abs(f0).max())


def _record(truth: str, strength: float = 0.0):
    """A dahl device record (1 % noise) with a term of ``strength`` × the record's force scale."""
    sc = record_scales(signal_record("dahl", "device", **OPTS))
    model = get_model(truth)
    extra = model.param_names("device")[4:]
    values = {extra[0]: strength * sc.force / (sc.displacement * sc.velocity)} if extra else {}
    return signal_record(truth, "device", values, **OPTS)


def test_search_finds_and_refits_a_term_outside_the_vocabulary():
    """|x|·ẋ damping (no named effect has it): proposed first, refitted, kept; the extended model
    reaches what the true model gives on the same record."""
    rec = _record("dahl+term(abs(x)*xdot)", 0.3)
    base = fit_model(rec, "dahl")
    out, whole = search_terms(rec, base, seed=0)
    assert out["proposed"][0]["term"] == "term(xdot*abs(x))"
    assert out["kept"] == ["term(xdot*abs(x))"]
    assert out["proposed"][0]["heldout_mse_ratio"] < 0.1
    # and again with the first 30 % held out instead: a real term helps wherever the record is held out
    other = out["proposed"][0]["other_fold"]
    assert other["passed"] and other["heldout_mse_ratio"] < 0.1 and other["heldout_blocks_better"] >= MIN_BLOCKS
    assert out["other_fold_until_s"] == pytest.approx(0.3 * 4.0, abs=2e-3)
    truth = fit_model(rec, "dahl+term(abs(x)*xdot)")
    assert whole.mse < 1.05 * truth.mse and whole.mse / base.mse < 0.1
    theta_true = 0.3 * record_scales(signal_record("dahl", "device", **OPTS)).force
    sc = record_scales(signal_record("dahl", "device", **OPTS))
    assert out["params"]["tf_xd_ax"] == pytest.approx(theta_true / (sc.displacement * sc.velocity), rel=0.1)
    assert "grows with ẋ·|x|" in out["sentences"][0]
    # the JSON's model and params are the whole fitted model: they predict what the fit predicts
    assert set(out["params"]) == set(whole.params())
    np.testing.assert_allclose(predict(out["model"], rec, out["params"])["force"], whole.predicted["force"],
                               rtol=1e-9, atol=1e-9 * np.abs(whole.predicted["force"]).max())


def test_search_keeps_nothing_on_a_clean_record():
    rec = _record("dahl")
    base = fit_model(rec, "dahl")
    out, whole = search_terms(rec, base, seed=0)
    assert out["kept"] == [] and whole is base
    assert len(out["proposed"]) >= 1  # something was proposed and refused, not a search that saw nothing
    assert all(r["other_fold"] is None or not r["other_fold"]["passed"] for r in out["proposed"])


def test_folds_hold_out_the_end_then_the_start():
    rec = _record("dahl")
    n = rec.sizes["time"]
    end, start = folds(rec, 0.3)
    assert (end.held.start, start.held.stop) == (1400, 600) and n == 2000
    assert not end.train["valid"].values[1400:].any() and end.train["valid"].values[:1400].all()
    assert not start.train["valid"].values[:600].any() and start.train["valid"].values[600:].all()


def test_library_has_no_repeated_or_model_terms():
    rec = _record("dahl")
    names = library(get_model("dahl"), rec)
    assert len(set(names)) == len(names)
    assert "term(x)" not in names and "term(xdot)" not in names
    assert "term(x*sgn(x))" not in names and "zterm(abs(xdot))" in names
    assert all(lib.is_term(n) for n in names)
