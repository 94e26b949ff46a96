"""Record recipes shared by the test folders (one place instead of one copy per file).

Each recipe is deterministic in its arguments (seeds included), so a test that
switched from its own copy to these gets the same record, bit for bit. The
builders are plain functions because several tests call them at module level
(parametrised cases, module-scoped fixtures); ``tests/conftest.py`` also hands
them out as fixtures. ``pyproject.toml`` puts ``tests/`` on ``sys.path``
(``[tool.pytest.ini_options] pythonpath``) so that ``from records import ...``
works from every sub-folder.
"""

from __future__ import annotations

import numpy as np
import reference_families
import xarray as xr

from bayes_mr.data.schema import make_record
from bayes_mr.models import get_model
from bayes_mr.signals import make_signal
from bayes_mr.simulation.simulate import Inputs, simulate, synthesize

# --- ground and imposed motions --------------------------------------------------------


def blwn_ground(n: int, fs: float, seed: int, rms: float = 1.0, band: float = 8.0) -> np.ndarray:
    """Band-limited random ground acceleration [m/s²], starting from rest.

    Parameters
    ----------
    n : int
        Samples.
    fs : float
        Sampling rate [Hz].
    seed : int
        Seed of the white noise.
    rms : float
        RMS of the result [m/s²] (before the 0.2 s start-up ramp).
    band : float
        Low-pass corner of the 4th-order zero-phase Butterworth filter [Hz].
    """
    from scipy.signal import butter, sosfiltfilt

    rng = np.random.default_rng(seed)
    sos = butter(4, band, fs=fs, output="sos")
    ag = sosfiltfilt(sos, rng.standard_normal(n))
    ag *= rms / ag.std()
    ag *= np.clip(np.arange(n) / (0.2 * fs), 0, 1)
    return ag


def _excitation(n: int, dt: float, seed: int):
    """Five random sines (0.5–6 Hz) and their derivatives, ramped in over 0.2 s."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    freqs = rng.uniform(0.5, 6.0, 5)
    amps = rng.uniform(0.3, 1.0, 5)
    phases = rng.uniform(0, 2 * np.pi, 5)
    x = sum(a * np.sin(2 * np.pi * f * t + p) for a, f, p in zip(amps, freqs, phases))
    xd = sum(a * 2 * np.pi * f * np.cos(2 * np.pi * f * t + p) for a, f, p in zip(amps, freqs, phases))
    xdd = -sum(a * (2 * np.pi * f) ** 2 * np.sin(2 * np.pi * f * t + p) for a, f, p in zip(amps, freqs, phases))
    ramp = np.clip(t / 0.2, 0, 1)  # start from rest
    return t, x * ramp, xd * ramp, xdd * ramp


def _voltage(t: np.ndarray) -> np.ndarray:
    """A 0 / 2.25 V square wave at 0.7 Hz [V]."""
    return np.where(np.sin(2 * np.pi * 0.7 * t) > 0, 2.25, 0.0)


def device_inputs(amplitude: float, n: int = 1500, fs: float = 1000.0, seed: int = 0, voltage: bool = True) -> Inputs:
    """Imposed damper motion (five sines) with peak ``amplitude`` [m] and, optionally, a square-wave voltage."""
    t, x, xd, _ = _excitation(n, 1 / fs, seed)
    scale = amplitude / np.abs(x).max()
    return Inputs.device(x * scale, xd * scale, 1 / fs, _voltage(t) if voltage else None)


def structure_inputs(accel: float, mass: float, n: int = 1500, fs: float = 1000.0, seed: int = 1,
                     voltage: bool = True) -> Inputs:
    """Ground acceleration (five sines) with peak ``accel`` [m/s²] under a storey of ``mass`` [kg]."""
    t, _, _, xdd = _excitation(n, 1 / fs, seed)
    return Inputs.structure(xdd * accel / np.abs(xdd).max(), 1 / fs, mass, _voltage(t) if voltage else None)


# --- whole records ---------------------------------------------------------------------


def structure_record(model, values, *, n=6000, fs=1000.0, mass=50.0, noise=0.01, seed=0, rms=3.0, process=True):
    """Simulated structure test with noise on the outputs and (``process``) on the input.

    Parameters
    ----------
    model : str
        Model name (``dahl``, ``lugre``, ...).
    values : dict
        Parameter overrides [SI]; the rest take the model's defaults.
    n, fs : int, float
        Samples and sampling rate [Hz].
    mass : float
        Storey mass [kg].
    noise : float
        Noise SD as a fraction of each channel's SD.
    seed : int
        Seed of the ground motion (``seed``) and of the noise (``seed + 1000``).
    rms : float
        RMS ground acceleration [m/s²].
    process : bool
        Also put noise on the ground acceleration fed to the simulation.

    Returns
    -------
    (xarray.Dataset, ndarray)
        The record and the true θ [SI].
    """
    model = get_model(model)
    rng = np.random.default_rng(seed + 1000)
    ag = blwn_ground(n, fs, seed, rms=rms)
    theta = model.theta("structure", values)
    sd_ag = noise * ag.std() if process else 0.0
    sim = simulate(model, Inputs.structure(ag + sd_ag * rng.standard_normal(n), 1 / fs, mass), theta)
    x, a = sim["displacement"], sim["acceleration"]
    sd_x, sd_a = noise * x.std(), noise * a.std()
    rec = make_record(
        np.arange(n) / fs,
        dict(ground_acceleration=ag, displacement=x + sd_x * rng.standard_normal(n),
             acceleration=a + sd_a * rng.standard_normal(n), force=sim["force"]),
        mass=mass, source="test",
        attrs=dict(noise_sd_displacement=sd_x, noise_sd_acceleration=sd_a,
                   noise_sd_ground_acceleration=sd_ag if process else 1e-6 * ag.std()),
    )
    return rec, theta


def signal_record(model, kind: str, values: dict | None = None, *, signal: str = "blwn", signal_seed: int | None = None,
                  mass: float | None = None, noise: float = 0.0, seed=None, source: str = "simulate",
                  **signal_options) -> xr.Dataset:
    """A test record of ``model`` driven by a named signal: ``make_signal`` then ``synthesize``.

    Parameters
    ----------
    model : str or Model
        Model name (``dahl+force_offset``, ...) or a :class:`~bayes_mr.models.Model`.
    kind : {"structure", "device"}
    values : dict, optional
        Parameter overrides [SI].
    signal : str
        Signal name of :func:`bayes_mr.signals.make_signal`.
    signal_seed : int, optional
        Seed of a random signal (``make_signal(seed=...)``); omitted when None.
    mass : float, optional
        Storey mass [kg] (structure tests).
    noise : float
        Noise SD as a fraction of each channel's RMS (``synthesize(noise=...)``).
    seed : int, optional
        Seed of the noise (``synthesize(seed=...)``).
    source : str
        The record's ``source`` attribute.
    **signal_options
        ``duration`` [s], ``fs`` [Hz], ``amplitude``, ``fmax`` [Hz], ``scale`` of ``make_signal``.
    """
    model = get_model(model) if isinstance(model, str) else model
    if signal_seed is not None:
        signal_options["seed"] = signal_seed
    sig = make_signal(signal, **signal_options)
    return synthesize(model, model.theta(kind, values or {}), sig.time, sig.as_input(kind), mass=mass, noise=noise,
                      seed=seed, source=source)


def offset_device_record(duration: float, offset: float = -60.0, seed: int = 3, fs: float = 500.0) -> xr.Dataset:
    """A Dahl device test with a force offset ``offset`` [N] hidden in it (1 % noise)."""
    return signal_record(
        "dahl+force_offset", "device", {"c": 800.0, "k": 300.0, "F_d": 200.0, "sigma": 3000.0, "f0": offset},
        duration=duration, fs=fs, amplitude=0.01, fmax=5.0, signal_seed=seed, noise=0.01, seed=seed + 1,
        source=f"dahl+force_offset-{seed}",
    )


def masked_structure_record() -> xr.Dataset:
    """A 2 s Dahl structure test at 200 Hz, 2 % noise, with samples 50–79 masked (the likelihood tests' record)."""
    rec = signal_record("dahl", "structure", duration=2.0, fs=200.0, amplitude=3e-3, fmax=10.0, signal_seed=3,
                        mass=50.0, noise=0.02, seed=4, source="test: masked")
    valid = np.ones(rec.sizes["time"], bool)
    valid[50:80] = False
    rec["valid"] = ("time", valid)
    return rec


# --- diagnose cases: which effect was hidden, and whether diagnose named it ---------------------

def effect_cases(structure: dict, device: dict, default: list[tuple]) -> list[tuple]:
    """(kind, effect, magnitude index, seed) of every effect of the magnitude tables, two magnitudes and two
    seeds each, less the ``default`` cases (the slow matrix beside the default suite's cases)."""
    full = [(k, e, m, s) for k, table in (("structure", structure), ("device", device))
            for e in table for m in (0, 1) for s in (0, 1)]
    return [c for c in full if c not in default]


def case_id(case: tuple) -> str:
    """pytest id of an :func:`effect_cases` case."""
    return f"{case[0]}-{case[1]}-m{case[2]}-s{case[3]}"


def naming_failures(out: dict, effect: str, threshold: float, *, top_first: bool = True) -> list[str]:
    """What is wrong with a diagnosis that should name ``effect`` and gain by it (empty: nothing).

    Named as the cause, the extended model holds it, MSE falls, ln Z rises, and the top candidate's score
    passes ``threshold`` (with ``top_first``, the top candidate is ``effect`` itself).
    """
    causes = [(c["name"], c["score"]) for c in out["causes"]]
    checks = {
        f"cause {out['cause']} is not {effect} ({causes})": out["cause"] == effect,
        f"MSE ratio {out['gain']['mse_ratio']} ≥ 1": out["gain"]["mse_ratio"] < 1.0,
        f"Δ ln Z {out['gain']['delta_log_evidence']} ≤ 0": out["gain"]["delta_log_evidence"] > 0,
        f"extended model {out['extended']['model']} lacks {effect}": effect in out["extended"]["model"].split("+"),
        f"top score {causes[0] if causes else None} ≤ {threshold}": bool(causes) and causes[0][1] > threshold,
    }
    if top_first:
        checks[f"top candidate is not {effect} ({causes[:2]})"] = bool(causes) and causes[0][0] == effect
    return [msg for msg, ok in checks.items() if not ok]


def coverage_study():
    """``studies/coverage.py`` as a module (its families of simulated records; a study, not a package module)."""
    import importlib.util

    from bayes_mr.cli.commands import studies_dir

    spec = importlib.util.spec_from_file_location("coverage_study", studies_dir() / "coverage.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# --- hidden-effect records of the diagnosis tests ---------------------------------------------

MASS = 50.0  # kg, the thesis's numerical frame (§3.8)

#: Two magnitudes of each effect hidden in a dahl frame (m = 50 kg, c = 100 N·s/m,
#: k = 20 kN/m, F_d = 25 N, σ = 2500 /m; response ≈ 0.6 mm RMS).
STRUCTURE_MAGNITUDES = {
    "force_offset": [0.5, 2.0],                                     # N (F_d = 25 N)
    "stiffness_drift": [0.005, 0.02],                               # 1/s: 3 % and 12 % over 6 s
    "asymmetry": [0.1, 0.3],
    "small_amplitude_regime": [{"r_s": 0.75, "x_s": 2e-4}, {"r_s": 0.5, "x_s": 2e-4}],
    "low_velocity_rolloff": [5e4, 1.5e4],                           # N·s/m
    "sensor_delay": [0.004, 0.01],                                  # s: 2 and 5 samples at 500 Hz
    "cubic_stiffness": [2e9, 8e9],                                  # N/m³: ~5 % and 20 % of k x at 1.5 mm
    "voltage_dependence": [{"a_v": 0.3, "c_v": 20.0, "eta": 50.0}, {"a_v": 1.0, "c_v": 50.0, "eta": 50.0}],
}
DEVICE_MAGNITUDES = {
    "low_velocity_rolloff": [2e4, 5e3],
    "voltage_dependence": [{"a_v": 0.3, "c_v": 20.0, "eta": 50.0}, {"a_v": 1.0, "c_v": 50.0, "eta": 50.0}],
}


def switching_voltage(n: int, fs: float, seed: int, high: float = 2.0, mean_hold: float = 0.5) -> np.ndarray:
    """On/off command voltage [V] with exponentially distributed hold times [s] (like the NEES tests)."""
    return reference_families.switching_voltage(n, fs, np.random.default_rng(seed + 500), high, mean_hold)


def simulated_record(kind="structure", form="dahl", effects=None, *, duration=6.0, fs=500.0, seed=0,
                     signal="blwn", voltage=False, noise=0.01):
    """A simulated test of ``form`` with ``effects`` (name → primary value or dict of values) hidden in it."""
    effects = dict(effects or {})
    model = get_model(form + "".join("+" + e for e in effects))
    values = {}
    for name, v in effects.items():
        values.update(v if isinstance(v, dict) else {model.effect(name).primary: v})
    if kind == "structure":
        sig = {
            "blwn": lambda: make_signal("blwn", duration=duration, fs=fs, amplitude=3e-3, fmax=10.0, seed=seed),
            "amp": lambda: make_signal("amp-sweep-up-down", duration=duration, fs=fs, amplitude=0.6e-3, fmax=4.0),
            "chirp": lambda: make_signal("freq-sweep-up-down", duration=duration, fs=fs, amplitude=0.8e-3, fmax=10.0),
            "elcentro": lambda: make_signal("elcentro", duration=duration, fs=fs, scale=0.3),
        }[signal]()
    else:
        sig = {
            "blwn": lambda: make_signal("blwn", duration=duration, fs=fs, amplitude=10e-3, fmax=10.0, seed=seed),
            "amp": lambda: make_signal("amp-sweep-up-down", duration=duration, fs=fs, amplitude=2e-3, fmax=2.0),
            "chirp": lambda: make_signal("freq-sweep-up-down", duration=duration, fs=fs, amplitude=2e-3, fmax=5.0),
        }[signal]()
    inputs = sig.as_input(kind)
    if voltage:
        inputs["voltage"] = switching_voltage(len(sig), fs, seed)
    return synthesize(model, model.theta(kind, values), sig.time, inputs, mass=MASS if kind == "structure" else None,
                      noise=noise, seed=seed + 77, source=f"{model.name}-{signal}-{seed}")


def effect_case(kind, effect, magnitude, seed):
    table = STRUCTURE_MAGNITUDES if kind == "structure" else DEVICE_MAGNITUDES
    return simulated_record(kind, "dahl", {effect: table[effect][magnitude]}, seed=seed,
                            signal="amp" if effect == "small_amplitude_regime" else "blwn",
                            voltage=effect == "voltage_dependence")


def held_command_device_record(duration: float = 4.0, fs: float = 500.0, seed: int = 3,
                               noise: float = 0.005) -> tuple[xr.Dataset, dict]:
    """A spencer device test whose switching command a DAC held between samples, from the reference simulator.

    ``tests/reference_sim.py`` (scipy, the contract's equations) integrates Spencer et al.'s damper under a
    band-limited displacement (5 Hz, 10 mm RMS) and an on/off voltage held from each sample to the next; the
    record carries the imposed displacement and velocity as given, the voltage, and the force with white noise
    of SD ``noise`` × its SD (its ``noise_sd_force`` attribute), and no ``command_interp`` attribute: reading
    the command is left to the caller. Returns the record and the truth (parameter name → value [SI]).
    """
    from scipy.signal import butter, sosfiltfilt

    from reference_sim import simulate_reference

    n = int(round(duration * fs))
    t = np.arange(n) / fs
    rng = np.random.default_rng(seed)
    x = sosfiltfilt(butter(4, 5.0, fs=fs, output="sos"), rng.standard_normal(n))
    x *= 10e-3 / x.std() * np.clip(t / 0.2, 0.0, 1.0)
    xd = np.gradient(x, 1 / fs)
    volt = reference_families.switching_voltage(n, fs, rng)
    truth = dict(reference_families.SPENCER)
    force = simulate_reference("spencer", truth, t, kind="device", displacement=x, velocity=xd, voltage=volt,
                               command="zoh")["force"]
    sd = noise * float(np.std(force))
    channels = {"displacement": x, "velocity": xd, "force": force + sd * rng.standard_normal(n), "voltage": volt}
    return make_record(t, channels, kind="device", source=f"held-spencer-{seed}", attrs={"noise_sd_force": sd}), truth
