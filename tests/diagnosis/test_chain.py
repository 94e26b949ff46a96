"""diagnosis.chain: the decimation filter applied to the prediction as to the data."""

import numpy as np

from bayes_mr.data.derive import decimate_record
from bayes_mr.diagnosis.measurement_chain import ChainOutputError, through_chain
from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.models import get_model
from bayes_mr.signals import make_signal
from bayes_mr.simulation.simulate import Inputs, simulate, synthesize


def _record(fs: float = 2000.0, seed: int = 5):
    """A clean dahl+voltage_dependence damper, 20 mm BLWN to 60 Hz, command switching every 10 ms at random:
    force with sharp transitions, content above 0.8 × the Nyquist frequency of a 4× decimated record."""
    model = get_model("dahl+voltage_dependence")
    sig = make_signal("blwn", duration=2.0, fs=fs, amplitude=20e-3, fmax=60.0, seed=seed)
    inputs = sig.as_input("device")
    rng = np.random.default_rng(seed)
    hold = int(0.01 * fs)
    inputs["voltage"] = np.repeat(rng.integers(0, 2, len(sig) // hold + 1) * 2.0, hold)[: len(sig)]
    theta = model.theta("device", {"a_v": 1.0, "c_v": 50.0, "eta": 300.0})
    rec = synthesize(model, theta, sig.time, inputs, noise=0.0, seed=seed, source="chain")
    return model, theta, rec


def test_the_chain_is_the_identity_on_a_record_that_was_not_decimated():
    model, theta, rec = _record()
    y = np.random.default_rng(0).normal(size=rec.sizes["time"])
    np.testing.assert_array_equal(through_chain(rec, y), y)
    lik, chained = OutputError(model, rec), ChainOutputError(model, rec)
    phi = lik.par.coords.to_phi(theta[lik.par.free_idx])
    np.testing.assert_array_equal(lik.predict(phi)[0], chained.predict(phi)[0])


def test_the_true_model_through_the_chain_predicts_the_decimated_force():
    """Decimated by 8, the true model's force at the kept samples misses what the filter took out of the
    data; through the same filter the error falls (what is left comes from the inputs, filtered too, driving
    a nonlinear model: seeds 5–7, factors 4 and 8 give ratios 0.73–0.90, measured; this seed 0.79)."""
    model, theta, rec = _record()
    dec = decimate_record(rec, 8)
    pred = simulate(model, Inputs.from_record(dec), theta)["force"]
    inner = slice(20, -20)
    f = dec["force"].values[inner]
    raw = np.sqrt(np.mean((f - pred[inner]) ** 2))
    chained = np.sqrt(np.mean((f - through_chain(dec, pred)[inner]) ** 2))
    assert chained < 0.9 * raw


def test_extensions_keep_the_base_fits_measurement_chain():
    """A base fitted through the chain hands it to every extension diagnose or extend fits."""
    from bayes_mr.diagnosis.extend import fit_at
    from bayes_mr.diagnosis.screen import screen_one
    from bayes_mr.models import EFFECTS

    model, theta, rec = _record()
    dec = decimate_record(rec, 8)
    base = fit_at(dec, model, dict(zip(model.param_names("device"), theta)), chain=True)
    assert isinstance(base.lik, ChainOutputError)
    cand = screen_one(dec, base, EFFECTS["force_offset"])
    assert isinstance(cand.fit.lik, ChainOutputError)
