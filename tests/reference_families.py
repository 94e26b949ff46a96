"""Records of the reference simulator written as a lab writes them, for diagnose to read as a user does.

A record is simulated by :mod:`reference_sim` (not the package's kernel) under a clean input, then written
as a CSV with units in its headers (``time [s]``, ``displacement [m]``, ``force [N]``, ``voltage [V]``, …)
carrying what sensors give:

* the *measured input* with 1–3 % white noise (of its RMS): the simulation was driven by the clean input,
  the file carries the noisy one (a device's displacement transducer, a table's accelerometer);
* every output with coloured noise: AR(1) with ρ drawn in 0.3–0.8, its stationary SD 1–3 % of the channel's RMS;
* the command (``voltage``) as commanded: linear between samples in the simulation, or held from each sample
  to the next as a DAC holds it (``Case.command_interp="zoh"``; read it with ``command_interp="hold"``).

``bm.load(path, mass=...)`` then reads it with no ``noise_sd_*`` attribute, so every noise floor the
diagnosis uses is estimated. Every draw (input, noise levels, ρ) comes from the case's ``seed``.

Drives. Structure tests: band-limited white ground acceleration (4th-order Butterworth, 8 Hz, 0.15 m/s² RMS), a 0.2 s
ramp in; device tests: band-limited white displacement (5 Hz, 10 mm RMS). ``envelope="up-down"`` modulates
either by a triangle (zero → peak → zero), so the amplitude crosses a small-amplitude threshold. Both bands
lie below 0.039 fs at 500 Hz, where ``input_interp="auto"`` reads the input linear — as this simulator does.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.signal import butter, lfilter, sosfiltfilt

from reference_sim import simulate_reference

MASS = 50.0  # kg, the thesis's numerical frame (§3.8)
#: The thesis's dahl frame (§3.8) and the same law as a damper alone.
DAHL = {"c": 100.0, "k": 2.0e4, "F_d": 25.0, "sigma": 2500.0}
LUGRE = {"c": 100.0, "k": 2.0e4, "beta": 6.1484e4, "epsilon": 38.39, "alpha": 2442.0}
NBW = {"c": 100.0, "k": 2.0e4, "k_z": 24.51, "rho": 2508.0, "n": 1.06, "sigma": 1.03}
#: Spencer et al. 1997's damper.
SPENCER = {"alpha_a": 1.40e4, "alpha_b": 6.95e4, "c0a": 2.10e3, "c0b": 3.50e2, "k0": 4.69e3, "c1a": 2.83e4,
           "c1b": 2.95e2, "k1": 5.00e2, "F_pre": 71.5, "gamma": 3.63e6, "beta": 3.63e6, "A": 301.0, "n": 2.0,
           "eta": 190.0}
TRUTHS = {"dahl": DAHL, "lugre": LUGRE, "normalized-bouc-wen": NBW, "spencer": SPENCER}

#: Each hidden effect in a dahl baseline: the kind of test that shows it, its values, the drive's envelope and
#: whether the test has a switching command. Magnitudes are the larger of ``test_diagnose``'s two.
HIDDEN = {
    "force_offset": ("structure", {"f0": 2.0}, "flat", False),
    "stiffness_drift": ("structure", {"drift": 0.015}, "flat", False),            # 15 % over 10 s
    "asymmetry": ("structure", {"asym": 0.3}, "flat", False),
    "small_amplitude_regime": ("structure", {"r_s": 0.5, "x_s": 2e-4}, "up-down", False),
    "low_velocity_rolloff": ("device", {"c_s": 5e3}, "flat", False),
    "cubic_stiffness": ("structure", {"k3": 8e9}, "flat", False),                  # ~20 % of k x at 1.5 mm
    "sensor_delay": ("structure", {"delay": 0.006}, "flat", False),
    "voltage_dependence": ("device", {"a_v": 1.0, "c_v": 50.0, "eta": 50.0}, "flat", True),
}
#: Clean records: (kind, form, switching command).
CLEAN = {
    "dahl-structure": ("structure", "dahl", False),
    "lugre-structure": ("structure", "lugre", False),
    "normalized-bouc-wen-device": ("device", "normalized-bouc-wen", False),
    "spencer-device": ("device", "spencer", True),
}

#: RMS ground acceleration [m/s²]: the dahl frame's response ≈ 0.7 mm RMS, F_d = 25 N against k x ≈ 15 N.
GROUND_RMS = 0.15
OUTPUT_NOISE = (0.01, 0.03)
AR_RHO = (0.3, 0.8)
INPUT_NOISE = (0.01, 0.03)
UNITS = {"time": "s", "displacement": "m", "ground_acceleration": "m/s²", "acceleration": "m/s²",
         "force": "N", "voltage": "V"}


@dataclass
class Case:
    """One record of a family: what was hidden, and how it was drawn."""

    name: str
    kind: str
    form: str
    effects: dict = field(default_factory=dict)
    seed: int = 0
    duration: float = 10.0
    fs: float = 500.0
    envelope: str = "flat"
    command: bool = False
    command_interp: str = "linear"

    @property
    def expected(self) -> str:
        return next(iter(self.effects), "none")

    @property
    def label(self) -> str:
        return f"{self.name}-s{self.seed}" + ("-held" if self.command_interp == "zoh" else "")


def hidden_case(effect: str, seed: int, duration: float = 10.0, fs: float = 500.0) -> Case:
    kind, values, envelope, command = HIDDEN[effect]
    return Case(effect, kind, "dahl", {effect: values}, seed, duration, fs, envelope, command)


def clean_case(name: str, seed: int, duration: float = 10.0, fs: float = 500.0) -> Case:
    kind, form, command = CLEAN[name]
    return Case(f"clean-{name}", kind, form, {}, seed, duration, fs, "flat", command)


def _band(n: int, fs: float, band: float, rng) -> np.ndarray:
    y = sosfiltfilt(butter(4, band, fs=fs, output="sos"), rng.standard_normal(n))
    return y / y.std()


def _envelope(t: np.ndarray, kind: str) -> np.ndarray:
    ramp = np.clip(t / 0.2, 0.0, 1.0)
    if kind == "up-down":
        return ramp * (1.0 - np.abs(2.0 * t / t[-1] - 1.0))
    return ramp


def switching_voltage(n: int, fs: float, rng, high: float = 2.0, mean_hold: float = 0.5) -> np.ndarray:
    """On/off command [V] with exponentially distributed hold times [s]."""
    v = np.zeros(n)
    i, level = 0, 0.0
    while i < n:
        hold = max(1, int(rng.exponential(mean_hold) * fs))
        v[i:i + hold] = level
        i += hold
        level = high - level
    return v


def ar1_noise(n: int, sd: float, rho: float, rng) -> np.ndarray:
    """AR(1) noise of stationary SD ``sd``, started in its stationary distribution."""
    e = rng.standard_normal(n) * sd * np.sqrt(1.0 - rho**2)
    e[0] = rng.standard_normal() * sd
    y, _ = lfilter([1.0], [1.0, -rho], e[1:], zi=[rho * e[0]])
    return np.concatenate([[e[0]], y])


def simulate_case(case: Case) -> tuple[dict, dict]:
    """The clean inputs and the reference simulator's clean outputs of ``case`` (channel → array)."""
    rng = np.random.default_rng([case.seed, 1])
    n = int(round(case.duration * case.fs))
    t = np.arange(n) / case.fs
    env = _envelope(t, case.envelope)
    params = dict(TRUTHS[case.form])
    for values in case.effects.values():
        params.update(values)
    inputs = {"time": t}
    if case.command:
        inputs["voltage"] = switching_voltage(n, case.fs, rng)
    if case.kind == "device":
        x = 10e-3 * _band(n, case.fs, 5.0, rng) * env
        inputs["displacement"] = x
        out = simulate_reference(case.form, params, t, kind="device", effects=list(case.effects), displacement=x,
                                 voltage=inputs.get("voltage"), command=case.command_interp)
        outputs = {"force": out["force"]}
    else:
        ag = GROUND_RMS * _band(n, case.fs, 8.0, rng) * env
        inputs["ground_acceleration"] = ag
        out = simulate_reference(case.form, params, t, kind="structure", effects=list(case.effects),
                                 ground_acceleration=ag, voltage=inputs.get("voltage"), mass=MASS,
                                 command=case.command_interp)
        outputs = {"displacement": out["displacement"], "acceleration": out["acceleration"]}
    return inputs, outputs


def write_case(case: Case, directory: str | Path) -> Path:
    """Simulate ``case`` and write it as a lab's CSV (module docstring); returns the path."""
    inputs, outputs = simulate_case(case)
    rng = np.random.default_rng([case.seed, 2])
    columns = {"time": inputs["time"]}
    drive = "displacement" if case.kind == "device" else "ground_acceleration"
    clean = inputs[drive]
    columns[drive] = clean + rng.uniform(*INPUT_NOISE) * np.sqrt(np.mean(clean**2)) * rng.standard_normal(clean.size)
    for name, y in outputs.items():
        sd = rng.uniform(*OUTPUT_NOISE) * np.sqrt(np.mean(y**2))
        columns[name] = y + ar1_noise(y.size, sd, rng.uniform(*AR_RHO), rng)
    if "voltage" in inputs:
        columns["voltage"] = inputs["voltage"]
    path = Path(directory) / f"{case.label}.csv"
    header = ",".join(f"{name} [{UNITS[name]}]" for name in columns)
    np.savetxt(path, np.column_stack(list(columns.values())), delimiter=",", header=header, comments="", fmt="%.9e")
    return path


def load_case(path: str | Path, case: Case):
    """``path`` read as a user reads a record: ``bm.load(path, mass=...)``."""
    import bayes_mr as bm

    return bm.load(path, mass=MASS if case.kind == "structure" else None)
