"""Band-limited input reconstruction: closer to the truth near Nyquist, chosen per record."""

import json

import numpy as np
import pytest

from bayes_mr.simulation import input_grid
from bayes_mr.models import get_model
from bayes_mr.simulation.simulate import Inputs, simulate, synthesize

FS = 750.0
BENCHMARK = {"c": 10.0, "k": 5e4, "beta1": 800.0, "gamma": -1100.0, "n": 1.0, "m": 2.0}
# the same oscillator with a negligible hysteretic term: linear, k_eff = 2k
LINEAR = {**BENCHMARK, "beta1": 1e-9, "gamma": 0.0}


def multisine(t: np.ndarray, f_lo: float, f_hi: float, seed: int, rms: float = 20.0) -> np.ndarray:
    """A random-phase multisine on 1 Hz lines [N], switched on by a 0.2 s cosine ramp (band-limited from t = 0)."""
    f = np.arange(f_lo, f_hi + 1e-9, 1.0)
    phase = np.random.default_rng(seed).uniform(0, 2 * np.pi, f.size)
    u = np.sin(2 * np.pi * f[:, None] * t[None] + phase[:, None]).sum(0) * rms / np.sqrt(f.size / 2)
    ramp = np.where(t < 0.2, 0.5 - 0.5 * np.cos(np.pi * np.clip(t / 0.2, 0, 1)), 1.0)
    return u * ramp


def errors(params: dict, f_lo: float, f_hi: float, seconds: float = 2.0, fine: int = 32):
    """RMS displacement errors [m] of linear and band-limited inputs against the analytic input at 32× the rate."""
    model = get_model("bouc-wen")
    theta = model.theta("forced", params)
    n = int(seconds * FS)
    t_fine = np.arange((n - 1) * fine + 1) / (FS * fine)
    truth = simulate(model, Inputs.forced(multisine(t_fine, f_lo, f_hi, 1), 1 / (FS * fine)), theta)
    x_true = truth["displacement"][::fine]
    coarse = Inputs.forced(multisine(np.arange(n) / FS, f_lo, f_hi, 1), 1 / FS)
    out = {}
    for interp in input_grid.INTERPS:
        x = simulate(model, coarse.with_interp(interp), theta)["displacement"]
        out[interp] = float(np.sqrt(np.mean((x - x_true) ** 2)))
    return out, float(np.std(x_true))


@pytest.mark.parametrize("params", [LINEAR, BENCHMARK], ids=["linear-oscillator", "benchmark-bouc-wen"])
def test_bandlimited_is_ten_times_closer_near_nyquist(params):
    err, _ = errors(params, 5.0, 150.0)
    assert err["bandlimited"] * 10 <= err["linear"], err


@pytest.mark.parametrize("params", [LINEAR, BENCHMARK], ids=["linear-oscillator", "benchmark-bouc-wen"])
def test_both_agree_on_a_slow_input(params):
    err, rms = errors(params, 1.0, 5.0)
    assert max(err.values()) < 1e-4 * rms, (err, rms)


def test_upsample_keeps_samples_and_holds_the_command():
    n = 400
    rows = np.zeros((n, 3))
    rows[:, 0] = multisine(np.arange(n) / FS, 5.0, 150.0, 2)
    rows[:, 2] = np.where(np.arange(n) % 100 < 50, 0.0, 2.5)  # a switching command
    fine = input_grid.upsample(rows, "forced", 4)
    assert fine.shape == (4 * (n - 1) + 1, 3)
    np.testing.assert_array_equal(fine[::4, 0], rows[:, 0])
    # the command is linear between samples: no overshoot (Gibbs) at its steps
    assert fine[:, 2].min() == 0.0 and fine[:, 2].max() == 2.5


def _record(f_hi: float, fs: float, **kw):
    t = np.arange(int(1.0 * fs)) / fs
    return synthesize("bouc-wen", get_model("bouc-wen").theta("forced", BENCHMARK), t,
                      {"applied_force": multisine(t, 1.0, f_hi, 3)}, seed=0, **kw)


def test_auto_choice():
    low = _record(5.0, FS)
    fast = _record(150.0, FS)
    assert low.attrs["input_interp"] == "linear" and fast.attrs["input_interp"] == "linear"
    assert Inputs.from_record(fast).interp == "linear"  # simulated linear: read as it was made
    for rec in (low, fast):
        del rec.attrs["input_interp"]
    assert Inputs.from_record(low).interp == "linear"
    assert Inputs.from_record(fast).interp == "bandlimited"
    assert Inputs.from_record(fast).upsample == 8  # f_bw ≈ fs/5
    assert Inputs.from_record(fast, "linear").interp == "linear"
    assert _record(150.0, FS, input_interp="auto").attrs["input_interp"] == "bandlimited"
    with pytest.raises(ValueError, match="valid"):
        _record(150.0, FS, input_interp="cubic")


def test_json_key_and_cli_flag(tmp_path):
    from bayes_mr.cli.commands import main

    path = tmp_path / "rec.nc"
    assert main(["simulate", "--model", "dahl", "--signal", "blwn", "--duration", "1.5", "--fs", "500",
                 "--fmax", "5", "--mass", "50", "--noise", "0.01", "-o", str(path)]) == 0
    out = {}
    for interp in ("auto", "bandlimited"):
        js = tmp_path / f"{interp}.json"
        assert main(["fit", str(path), "--model", "dahl", "--engine", "lsq", "--mass", "50", "--quiet",
                     "--input-interp", interp, "--json", str(js)]) == 0
        out[interp] = json.loads(js.read_text())
    assert out["auto"]["input_interp"] == "linear"
    assert out["bandlimited"]["input_interp"] == "bandlimited"


def test_perturbed_input_keeps_its_grid_and_a_foreign_schedule_is_refused():
    """Noise widens a band-limited drive's bandwidth, so it would choose a finer grid; ``with_rows`` keeps the
    grid, so the clean input's sub-step schedule replays on the noisy one (the input-noise replicas of
    :mod:`bayes_mr.inference.calibrate` do this), and a schedule of another grid is an error, never read past."""
    n = int(2.0 * FS)
    clean = Inputs.forced(multisine(np.arange(n) / FS, 1.0, 40.0, 2), 1 / FS).with_interp("bandlimited")
    noisy_rows = clean.rows.copy()
    noisy_rows[:, 0] += np.random.default_rng(0).normal(0.0, 0.3 * clean.rows[:, 0].std(), n)
    assert Inputs.forced(noisy_rows[:, 0], 1 / FS).with_interp("bandlimited").upsample > clean.upsample
    noisy = clean.with_rows(noisy_rows)
    assert noisy.upsample == clean.upsample and noisy.slice(0, n // 2).upsample == clean.upsample
    theta = get_model("bouc-wen").theta("forced", BENCHMARK)
    sim = simulate("bouc-wen", clean, theta)
    replayed = simulate("bouc-wen", noisy, theta, schedule=sim.schedule)
    assert replayed.ok and np.isfinite(replayed["displacement"]).all()
    with pytest.raises(ValueError, match="schedule has"):
        simulate("bouc-wen", Inputs.forced(noisy_rows[:, 0], 1 / FS).with_interp("bandlimited"), theta,
                 schedule=sim.schedule)
