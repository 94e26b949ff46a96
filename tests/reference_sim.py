"""A reference simulator of the damper laws, written from docs/CONTRACT.md alone.

It imports nothing of ``bayes_mr.models`` or ``bayes_mr.simulation``: the equations below are those of
the contract's Models and Effects tables, integrated by scipy's ``solve_ivp`` with a stiff method
(LSODA by default — it switches to BDF where the law is stiff —, or Radau; tolerances 1e-8 relative, the step never longer than the sample interval), so that a
record it writes tests the package against the physics rather than against its own RK4/ROS2 kernel.

Kinds
-----
* ``device`` — imposed displacement x(t), output ``force`` = f_r. x is linear between samples; its velocity
  is that line's slope (``velocity=None``), or — the reading of a record that carries a ``velocity`` column —
  the given velocity samples, linear between samples.
* ``structure`` — m ẍ + f_r(x, ẋ, z) = −m ẍ_g, ẍ_g linear between samples; outputs ``displacement`` = x
  and ``acceleration`` = ẍ + ẍ_g = −f_r/m (and ``force``, the damper force f_d).

The command v (``voltage``) is linear between samples (``command="linear"``) or held (``"zoh"``, as a DAC
gives). Every state starts at 0 at the first sample.

Forms (parameters by the contract's names, SI)
----------------------------------------------
* ``dahl``: f_r = c ẋ + k x + F_d z, ż = σ ẋ (1 − z sgn ẋ)
* ``normalized-bouc-wen``: f_r = c ẋ + k x + k_z z, ż = ρ(ẋ − σ|ẋ| sgn(z)|z|ⁿ + (σ − 1) ẋ |z|ⁿ)
* ``lugre``: f_r = c ẋ + k x + β z + ε ż, ż = ẋ − α|ẋ| z
* ``spencer``: f_d = c1 ẏ + k1 x − F_pre, ẏ = (α z + c0 ẋ + k0 (x − y))/(c0 + c1),
  ż = −γ|ẋ − ẏ| sgn(z)|z|ⁿ − β(ẋ − ẏ)|z|ⁿ + A(ẋ − ẏ), α, c0, c1 = a + b·u, u̇ = −η(u − v);
  a structure test adds the frame's c ẋ + k x.

Effects (the contract's Effects table)
--------------------------------------
The *hysteretic force* F_h is F_d z, k_z z, β z (LuGre's ε ż is scaled with it), spencer's α z.

* ``force_offset``: f_d += f0
* ``voltage_dependence``: u̇ = η(v − u); F_h × (1 + a_v u); f_d += c_v u ẋ
* ``stiffness_drift``: F_h and the stiffness (k; spencer's k1 x − F_pre) × (1 + drift·t)
* ``asymmetry``: F_h × (1 + asym·sgn z)
* ``small_amplitude_regime``: F_h × (r_s + (1 − r_s)·S), S = 1/(1 + exp(−(e − x_s)/(0.1 x_s))), e the amplitude
  envelope e(t) = max_{τ ≤ t} |x(τ)| exp(−(t − τ)/t_env) (t_env = 1 s); integrated here as the stiff relaxation
  ė = −e/t_env + K·max(|x| − e, 0), K = :data:`ENVELOPE_GAIN` (e trails a rising |x| by |ẋ|/K)
* ``low_velocity_rolloff``: the hysteretic law is driven by w = ẋ − F_h/c_s instead of ẋ (forms other than spencer)
* ``cubic_stiffness``: f_r += k3 x³
* ``sensor_delay``: the delayed channel (``force`` of a device test, ``acceleration`` of a structure test, or
  ``delay_channel``) is y(t − delay), read from the solver's continuous solution, held at y(0) before the start
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp

FORMS = ("dahl", "normalized-bouc-wen", "lugre", "spencer")
EFFECTS = ("force_offset", "voltage_dependence", "stiffness_drift", "asymmetry", "small_amplitude_regime",
           "low_velocity_rolloff", "cubic_stiffness", "sensor_delay")
#: Rate [1/s] at which the amplitude envelope catches a rising |x| (see the module docstring).
ENVELOPE_GAIN = 1.0e5
#: Envelope decay time of ``small_amplitude_regime`` [s] (the contract's option ``t_env``).
T_ENV = 1.0


def _sgn(v: float) -> float:
    return 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)


class _Signal:
    """Samples on a uniform grid read at any time: linear between samples, or held (``zoh``)."""

    def __init__(self, t0: float, dt: float, values, hold: bool = False):
        self.t0, self.dt, self.v, self.hold = t0, dt, np.asarray(values, float), hold
        self.n = self.v.size

    def __call__(self, t: float) -> float:
        r = (t - self.t0) / self.dt
        i = int(math.floor(r))
        if i < 0:
            return float(self.v[0])
        if i >= self.n - 1:
            return float(self.v[-1])
        if self.hold:
            return float(self.v[i])
        f = r - i
        return float(self.v[i] + f * (self.v[i + 1] - self.v[i]))


class _Slope:
    """The velocity of a displacement that is linear between samples: each interval's slope (at a sample
    itself, the mean of the two slopes beside it)."""

    def __init__(self, t0: float, dt: float, x):
        self.t0, self.dt = t0, dt
        self.s = np.diff(np.asarray(x, float)) / dt
        self.n = self.s.size

    def __call__(self, t: float) -> float:
        r = (t - self.t0) / self.dt
        i = int(math.floor(r + 1e-9))
        if i <= 0:
            return float(self.s[0])
        if i >= self.n:
            return float(self.s[-1])
        if abs(r - round(r)) < 1e-9:
            return float(0.5 * (self.s[i - 1] + self.s[i]))
        return float(self.s[i])


class _Law:
    """Right-hand side and outputs of one form with its effects."""

    def __init__(self, form: str, kind: str, p: dict, effects, mass, drive, command):
        if form not in FORMS:
            raise ValueError(f"reference simulator: unknown form {form!r}")
        unknown = set(effects) - set(EFFECTS)
        if unknown:
            raise ValueError(f"reference simulator: unknown effects {sorted(unknown)}")
        self.form, self.kind, self.p, self.eff = form, kind, dict(p), set(effects)
        self.mass, self.drive, self.command = mass, drive, command
        names = ["x", "xd"] if kind == "structure" else []
        names += ["y", "z", "u"] if form == "spencer" else ["z"]
        if "voltage_dependence" in self.eff:
            names.append("uv")
        if "small_amplitude_regime" in self.eff:
            names.append("env")
        self.names = names
        self.ix = {n: j for j, n in enumerate(names)}

    def motion(self, t, s):
        if self.kind == "structure":
            return s[0], s[1]
        return self.drive[0](t), self.drive[1](t)

    def evaluate(self, t, s):
        """(ṡ, f_r, f_d) at time t and state s."""
        p, eff, ix = self.p, self.eff, self.ix
        x, xd = self.motion(t, s)
        v = self.command(t) if self.command is not None else 0.0
        ds = np.zeros(len(s))
        strength, stiff = 1.0, 1.0
        if "stiffness_drift" in eff:
            g = 1.0 + p["drift"] * t
            strength *= g
            stiff = g
        uv = 0.0
        if "voltage_dependence" in eff:
            uv = s[ix["uv"]]
            ds[ix["uv"]] = p["eta"] * (v - uv)
            strength *= 1.0 + p["a_v"] * uv
        if "small_amplitude_regime" in eff:
            e = s[ix["env"]]
            ds[ix["env"]] = -e / T_ENV + ENVELOPE_GAIN * max(abs(x) - e, 0.0)
            arg = (e - p["x_s"]) / (0.1 * p["x_s"])
            sw = 1.0 / (1.0 + math.exp(-arg)) if arg > -700 else 0.0
            strength *= p["r_s"] + (1.0 - p["r_s"]) * sw
        asym = p["asym"] if "asymmetry" in eff else 0.0

        if self.form == "spencer":
            y, z, u = s[ix["y"]], s[ix["z"]], s[ix["u"]]
            ds[ix["u"]] = -p["eta"] * (u - v)
            alpha = (p["alpha_a"] + p["alpha_b"] * u) * strength
            c0 = p["c0a"] + p["c0b"] * u
            c1 = p["c1a"] + p["c1b"] * u
            yd = (alpha * z * (1.0 + asym * _sgn(z)) + c0 * xd + p["k0"] * (x - y)) / (c0 + c1)
            r = xd - yd
            zn = abs(z) ** p["n"]
            ds[ix["y"]] = yd
            ds[ix["z"]] = -p["gamma"] * abs(r) * _sgn(z) * zn - p["beta"] * r * zn + p["A"] * r
            f_d = c1 * yd + stiff * (p["k1"] * x - p["F_pre"])
            frame = p["c"] * xd + stiff * p["k"] * x if self.kind == "structure" else 0.0
        else:
            z = s[ix["z"]]
            coef = {"dahl": "F_d", "normalized-bouc-wen": "k_z", "lugre": "beta"}[self.form]
            f_h = strength * p[coef] * z * (1.0 + asym * _sgn(z))
            w = xd - f_h / p["c_s"] if "low_velocity_rolloff" in eff else xd
            if self.form == "dahl":
                zd = p["sigma"] * w * (1.0 - z * _sgn(w))
            elif self.form == "lugre":
                zd = w - p["alpha"] * abs(w) * z
            else:
                zn = abs(z) ** p["n"]
                zd = p["rho"] * (w - p["sigma"] * abs(w) * _sgn(z) * zn + (p["sigma"] - 1.0) * w * zn)
            ds[ix["z"]] = zd
            f_d = f_h + (strength * p["epsilon"] * zd if self.form == "lugre" else 0.0)
            frame = p["c"] * xd + stiff * p["k"] * x
        if "force_offset" in eff:
            f_d += p["f0"]
        if "voltage_dependence" in eff:
            f_d += p["c_v"] * uv * xd
        f_r = frame + f_d
        if "cubic_stiffness" in eff:
            f_r += p["k3"] * x ** 3
        if self.kind == "structure":
            ds[0] = xd
            ds[1] = -self.drive(t) - f_r / self.mass
        return ds, f_r, f_d

    def outputs(self, t, s) -> dict:
        _, f_r, f_d = self.evaluate(t, s)
        if self.kind == "device":
            return {"force": f_r}
        return {"displacement": s[0], "acceleration": -f_r / self.mass, "force": f_d}


def simulate_reference(form: str, params: dict, time, *, kind: str, effects=(), displacement=None, velocity=None,
                       ground_acceleration=None, voltage=None, mass: float | None = None,
                       command: str = "linear", delay_channel: str | None = None, method: str = "LSODA",
                       rtol: float = 1e-8, atol: float = 1e-12) -> dict:
    """Outputs of ``form`` with ``effects`` under a record's inputs (module docstring).

    Parameters
    ----------
    form : str
        One of :data:`FORMS`.
    params : dict
        Parameter name → value [SI], the contract's names (the form's and every effect's).
    time : array
        Uniform sample times [s].
    kind : {"device", "structure"}
    effects : iterable of str
        Names of :data:`EFFECTS` switched on.
    displacement, velocity : array, optional
        Device test: imposed x [m] (linear between samples) and, optionally, ẋ samples [m/s] (linear between
        samples; default the slope of x).
    ground_acceleration : array, optional
        Structure test: ẍ_g [m/s²], linear between samples.
    voltage : array, optional
        The damper command [V].
    mass : float, optional
        Storey mass [kg] (structure test).
    command : {"linear", "zoh"}
        The command between samples.
    delay_channel : str, optional
        Channel ``sensor_delay`` delays (default ``force`` for a device, ``acceleration`` for a structure test).
    method, rtol, atol
        ``solve_ivp``'s stiff method and tolerances (atol per state [state units]).

    Returns
    -------
    dict
        Channel → array on ``time``; also ``nfev`` (right-hand-side evaluations).
    """
    t = np.asarray(time, float)
    dt = float(t[1] - t[0])
    t0 = float(t[0])
    if command not in ("linear", "zoh"):
        raise ValueError("command is 'linear' or 'zoh'")
    cmd = _Signal(t0, dt, voltage, hold=command == "zoh") if voltage is not None else None
    if kind == "device":
        xs = _Signal(t0, dt, displacement)
        vs = _Signal(t0, dt, velocity) if velocity is not None else _Slope(t0, dt, displacement)
        drive = (xs, vs)
    elif kind == "structure":
        if mass is None:
            raise ValueError("a structure test needs the storey mass")
        drive = _Signal(t0, dt, ground_acceleration)
    else:
        raise ValueError(f"kind {kind!r}: 'device' or 'structure'")
    law = _Law(form, kind, params, effects, mass, drive, cmd)
    delayed = "sensor_delay" in law.eff
    sol = solve_ivp(lambda tt, s: law.evaluate(tt, s)[0], (t0, float(t[-1])), np.zeros(len(law.names)),
                    method=method, t_eval=t, rtol=rtol, atol=atol, max_step=dt, dense_output=delayed)
    if not sol.success:
        raise RuntimeError(f"reference simulator: {sol.message}")
    rows = [law.outputs(tt, sol.y[:, j]) for j, tt in enumerate(t)]
    out = {name: np.array([r[name] for r in rows]) for name in rows[0]}
    if delayed:
        channel = delay_channel or ("force" if kind == "device" else "acceleration")
        td = t - params["delay"]
        before = td < t0
        td = np.where(before, t0, td)
        states = sol.sol(td)
        y = np.array([law.outputs(tt, states[:, j])[channel] for j, tt in enumerate(td)])
        y[before] = out[channel][0]
        out[channel] = y
    out["nfev"] = int(sol.nfev)
    return out
