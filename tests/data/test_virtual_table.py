"""The virtual shake table: inverse dynamics around a damper test."""

import numpy as np
import pytest

from bayes_mr.data import load_packaged
from bayes_mr.data.virtual_table import implied_damper_force, virtual_shake_table
from bayes_mr.models import get_model
from bayes_mr.simulation.simulate import Inputs, simulate
from records import signal_record


def test_frame_driven_by_the_virtual_table_follows_the_damper_motion():
    """Simulate a Dahl damper test, build the table, and drive frame + damper with it."""
    damper = get_model("dahl")
    values = dict(c=800.0, k=300.0, F_d=200.0, sigma=3000.0)
    dev = signal_record(damper, "device", values, duration=6.0, fs=2000.0, amplitude=0.03, fmax=8.0, signal_seed=4)
    frame = dict(mass=27.0, k=25_000.0, c=100.0)
    table = virtual_shake_table(dev, **frame)
    assert table.attrs["kind"] == "structure"
    np.testing.assert_array_equal(table["force"].values, dev["force"].values)
    # frame + damper is the same Dahl law with c and k summed
    whole = damper.theta("structure", dict(values, c=values["c"] + frame["c"], k=values["k"] + frame["k"]))
    sim = simulate(damper, Inputs.from_record(table), whole)
    x = dev["displacement"].values
    inner = slice(200, -200)  # the differentiator's edges
    err = np.sqrt(np.mean((sim["displacement"][inner] - x[inner]) ** 2)) / x.std()
    assert err < 0.02
    # the structure's "force" is the hysteretic part; the damper's own c ẋ + k x completes it
    damper_force = sim["force"] + values["c"] * sim["velocity"] + values["k"] * sim["displacement"]
    f = dev["force"].values
    f_err = np.sqrt(np.mean((damper_force[inner] - f[inner]) ** 2)) / f.std()
    assert f_err < 0.05
    # what a user of an identified structure model has: its outputs and the known frame
    implied = implied_damper_force(table, sim.outputs)
    assert np.sqrt(np.mean((implied[inner] - f[inner]) ** 2)) / f.std() < 0.05
    with pytest.raises(ValueError, match="not a virtual shake table"):
        implied_damper_force(dev, sim.outputs)


def test_table_from_the_measured_record_is_a_valid_structure_test():
    dev = load_packaged()
    table = virtual_shake_table(dev)
    assert table.attrs["mass"] == 27.0
    assert np.isfinite(table["ground_acceleration"].values).all()
    # absolute acceleration balances frame and damper forces exactly
    a = table["acceleration"].values
    assert np.abs(a * 27.0 + table["force"].values).max() < 0.1 * np.abs(table["force"].values).max()


def test_a_structure_test_cannot_be_put_on_a_table():
    dev = load_packaged()
    table = virtual_shake_table(dev)
    with pytest.raises(ValueError, match="device test"):
        virtual_shake_table(table)
