"""A command held between samples (a DAC's zero-order hold): how the inputs, the simulator and the fine grid read it.

Linear stays the default and gives the numbers it gave (the goldens of ``tests/test_golden.py`` check the fits;
here a test without a command simulates bit for bit the same either way). Held, each sample interval ends on the
command it started with, so a command that steps at a sample steps there and not across the interval before it;
on a grid S times finer, fine rows S·k … S·k+S−1 carry row k's command.
"""

import numpy as np
import pytest
from records import device_inputs, structure_inputs

from bayes_mr.models import get_model
from bayes_mr.simulation import input_grid
from bayes_mr.simulation.inputs import Inputs
from bayes_mr.simulation.simulate import simulate, synthesize

#: Spencer et al.'s damper (the package's defaults) under a 0/2.25 V square wave that steps at samples.
FS = 500.0
TIGHT = {"c_acc": 0.05, "ros2": False}  # the equations, not two step controls, are compared


def _spencer_device(voltage: bool = True) -> tuple:
    model = get_model("spencer")
    return model, model.theta("device", {}), device_inputs(0.01, n=1500, fs=FS, voltage=voltage)


def _nrmse(a: np.ndarray, b: np.ndarray, ref: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2)) / np.std(ref))


def test_inputs_carry_the_reading_through_every_copy():
    inp = device_inputs(0.01)
    assert inp.command_interp == "linear" and not inp.hold
    held = inp.with_command_interp("hold")
    assert held.hold and held.rows is inp.rows  # a property of the inputs: same rows, another reading
    assert held.slice(10, 400).hold
    assert held.with_rows(inp.rows + 1e-6).hold
    assert held.with_interp("bandlimited").hold and held.with_interp("bandlimited").with_interp("linear").hold
    with pytest.raises(ValueError, match="linear, hold"):
        Inputs("device", 1e-3, inp.rows, command_interp="zoh")


def test_the_record_says_how_its_command_is_read():
    t = np.arange(600) / FS
    inp = device_inputs(0.01, n=600, fs=FS)
    rec = synthesize("dahl+voltage_dependence", get_model("dahl+voltage_dependence").theta("device", {}), t,
                     {"displacement": inp.rows[:, 0], "velocity": inp.rows[:, 1], "voltage": inp.rows[:, 2]},
                     command_interp="hold", source="held.nc")
    assert rec.attrs["command_interp"] == "hold"  # simulate writes how it read the command
    assert Inputs.from_record(rec).hold and Inputs.from_record(rec, command_interp="auto").hold
    assert not Inputs.from_record(rec, command_interp="linear").hold  # a caller's choice overrides the attribute
    del rec.attrs["command_interp"]
    assert Inputs.from_record(rec).command_interp == "linear"  # no attribute: linear, as before
    assert Inputs.from_record(rec, command_interp="hold").hold
    rec.attrs["command_interp"] = "zoh"
    with pytest.raises(ValueError, match=r"held\.nc: attribute command_interp='zoh': valid: linear, hold"):
        Inputs.from_record(rec)
    with pytest.raises(ValueError, match="valid: auto, linear, hold"):
        input_grid.command("zoh")


@pytest.mark.parametrize("name, kind", [("spencer", "device"), ("dahl+voltage_dependence", "structure")])
def test_without_a_command_hold_and_linear_are_the_same_numbers(name, kind):
    """The flag changes the end of an interval's command only: with no command (zeros) nothing else moves."""
    model = get_model(name)
    inp = device_inputs(0.01, voltage=False) if kind == "device" else structure_inputs(3.0, 50.0, voltage=False)
    theta = model.theta(kind, {})
    a, b = simulate(model, inp, theta), simulate(model, inp.with_command_interp("hold"), theta)
    for channel in a.outputs:
        np.testing.assert_array_equal(a[channel], b[channel])
    np.testing.assert_array_equal(a.schedule, b.schedule)


def test_a_held_command_is_a_step_at_the_sample():
    """Held, the coarse simulation is the limit of fine grids on which the command steps within one fine interval.

    On a grid S times finer whose command is row k's on fine rows S·k … S·k+S−1 and linear between fine rows,
    the step is a ramp of Δt/S, so that grid tends to the held coarse one as 1/S; with the fine grid's own
    intervals held as well it is the same integration problem, equal to integration tolerance. Read linear,
    the coarse command ramps over the whole interval before each step and the force differs by 1.4e-2 of its SD
    (fine grids: 1.9e-3 at S = 8, 2.5e-4 at S = 64; held on the fine grid too, 3e-8).
    """
    model, theta, coarse = _spencer_device()
    dt, n = coarse.dt, coarse.n
    held = simulate(model, coarse.with_command_interp("hold"), theta, **TIGHT)["force"]
    linear = simulate(model, coarse, theta, **TIGHT)["force"]
    errors = {}
    for s in (8, 64):
        t = np.arange(s * (n - 1) + 1) * (dt / s)
        t_coarse = np.arange(n) * dt
        fine = Inputs.device(np.interp(t, t_coarse, coarse.rows[:, 0]), np.interp(t, t_coarse, coarse.rows[:, 1]),
                             dt / s, np.repeat(coarse.rows[:, 2], s)[:t.size])
        errors[s] = _nrmse(simulate(model, fine, theta, **TIGHT)["force"][::s], held, held)
        if s == 8:
            errors["fine held"] = _nrmse(simulate(model, fine.with_command_interp("hold"), theta, **TIGHT)["force"][::s],
                                         held, held)
    errors["linear"] = _nrmse(linear, held, held)
    assert errors["fine held"] < 1e-6, errors
    assert errors[64] < errors[8] / 5 and errors[64] < 5e-4, errors
    assert errors["linear"] > 1e-2, errors


def test_the_fine_grid_holds_the_command():
    """Band-limited drive: the command column of the fine grid is row k's on fine rows S·k … S·k+S−1, and the held
    simulation there stays with the coarse held one (their drives differ by a band-limited reconstruction only)."""
    model, theta, coarse = _spencer_device()
    s = 4
    fine = input_grid.upsample(coarse.rows, "device", s, "hold")
    linear = input_grid.upsample(coarse.rows, "device", s)
    np.testing.assert_array_equal(fine[:, 2], np.repeat(coarse.rows[:, 2], s)[:fine.shape[0]])
    np.testing.assert_array_equal(fine[:, :2], linear[:, :2])
    held = coarse.with_command_interp("hold")
    band = held.with_interp("bandlimited")
    band = Inputs(band.kind, band.dt, band.rows, band.mass, band.interp, s, band.command_interp)
    np.testing.assert_array_equal(band.grid_rows[:, 2], fine[:, 2])
    f_band = simulate(model, band, theta, **TIGHT)["force"]
    f_held = simulate(model, held, theta, **TIGHT)["force"]
    f_band_linear = simulate(model, band.with_command_interp("linear"), theta, **TIGHT)["force"]
    assert _nrmse(f_band, f_held, f_held) < 0.05 * _nrmse(f_band_linear, f_held, f_held)
