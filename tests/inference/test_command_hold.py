"""Least squares on a record whose command was held between samples: read held, it reaches the noise floor.

The record is the reference simulator's spencer device test (``records.held_command_device_record``: scipy,
the contract's equations, a 0/2 V command held from sample to sample, white force noise of known SD). Read
linear, the model's command leads the damper's by half a sample; the fit moves the field's lag η to make up
for it (190 → 158 1/s) and still leaves that lead's residual (MSE 16× the floor's 100, measured); read held,
the fit is at the floor (MSE 102) with η at its true value. The field-dependent coefficients and η are
free, the rest held at the truth, so the check costs seconds.
"""

import pytest
from records import held_command_device_record

import bayes_mr as bm
from bayes_mr.likelihood.output_error import OutputError

#: The parameters that carry the command (its lag η and the field-dependent coefficients); the others are fixed.
FREE = ("eta", "alpha_a", "alpha_b", "c0b", "c1b")


@pytest.fixture(scope="module")
def held():
    return held_command_device_record(duration=4.0, seed=3)


def test_least_squares_reaches_the_floor_only_reading_the_command_held(held):
    record, truth = held
    fixed = {k: v for k, v in truth.items() if k not in FREE and k != "A"}
    out = {}
    for reading in ("linear", "hold"):
        idata = bm.Identify("spencer", bm.LeastSquares(), fixed=fixed, command_interp=reading).fit(record, progress=False)
        out[reading] = bm.summary_of(idata).to_dict()
        assert out[reading]["command_interp"] == reading  # the fit JSON says how it read the command
    # MSE is 100 × the residual's variance over the noise floor's: 100 at the floor
    assert out["hold"]["mse"] < 110, out["hold"]["mse"]
    assert out["linear"]["mse"] > 5 * out["hold"]["mse"], (out["linear"]["mse"], out["hold"]["mse"])
    assert abs(out["hold"]["params"]["eta"] / truth["eta"] - 1) < 0.02
    assert out["linear"]["params"]["eta"] < 0.9 * truth["eta"]  # the lead read as a slower field


def test_a_reading_given_to_the_likelihood_travels_with_its_record(held):
    """A choice that differs from the record's is written into the likelihood's record, so every later reading of
    it (a head race, a refit, the UKF's validation) reads the command the same way; the caller's record is left
    as it was."""
    record, _ = held
    assert "command_interp" not in record.attrs
    lik = OutputError("spencer", record, command_interp="hold")
    assert lik.inputs.hold and lik.record.attrs["command_interp"] == "hold"
    assert "command_interp" not in record.attrs
    assert OutputError("spencer", lik.record).inputs.hold
    assert OutputError("spencer", record).record is record  # linear, as the record reads: nothing to write
    marked = record.assign_attrs(command_interp="hold")
    assert bm.Identify("spencer").likelihood(marked).inputs.hold  # "auto" reads the record's attribute
