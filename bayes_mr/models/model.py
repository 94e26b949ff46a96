"""A model = one form + any effects, bound to a kind of test when used.

:class:`Form` (a damper law) and :class:`Model` (a form with effects) live
together here because ``Form + Effect`` builds a ``Model``; the five forms
themselves are in :mod:`bayes_mr.models.forms`, the effects in
:mod:`bayes_mr.models.effects`, and :func:`bayes_mr.models.registry.get_model`
parses a model name. Nothing here imports those catalogues, so the layers
stay acyclic: params, kernel → effects → model → forms → catalog.

>>> from bayes_mr.models import DAHL, FORCE_OFFSET, get_model
>>> (DAHL + FORCE_OFFSET).name
'dahl+force_offset'
>>> get_model("dahl+force_offset").free_names("device")
('c', 'k', 'F_d', 'sigma', 'f0')
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bayes_mr.models import integrate, kernel, term_kernel
from bayes_mr.models.effects import DEVICE_ONLY, ON_COMMAND, Effect
from bayes_mr.models.params import F_V, F_X, Coordinates, ParamSpec, Ratio, Scales

#: The kinds of test a model is bound to: a storey on a shake table, the damper alone, or a
#: mass driven by a measured force (``m ẍ + f_r = p``).
KINDS = ("structure", "device", "forced")

#: Frame parameters a structure test adds to a form without its own ``c``, ``k`` (``spencer``).
FRAME = (
    ParamSpec("c", "N·s/m", "frame viscous damping", 100.0, F_V, (1e-4, 2.0)),
    ParamSpec("k", "N/m", "frame stiffness", 2.5e4, F_X, (1e-3, 3.0)),
)

#: The driven mass of a forced test, identified with the others unless it is known (``--mass``,
#: then held fixed). Its plausible range is relative to F·X/V² — the mass that would take the
#: whole applied force as inertia at the record's frequency (V²/X ≈ ω²X) — down to 1e-3 of it,
#: where the restoring force carries nearly all of it.
MASS = ParamSpec("m", "kg", "mass driven by the applied force (forced tests)", 1.0, (1, 1, -2, 0), (1e-3, 10.0))

#: Kernel codes of the channels a filter can measure.
_OBS_CODE = {"displacement": kernel.OBS_X, "velocity": kernel.OBS_V, "acceleration": kernel.OBS_A,
             "force": kernel.OBS_F}
#: Channels measured by default, by kind of test (all a record of that kind can have).
_OBS_DEFAULT = {"structure": ("displacement", "acceleration"), "device": ("force",),
                "forced": ("displacement", "velocity", "acceleration")}

# Effects a form already contains.
_BUILT_IN = {"spencer": ("voltage_dependence", "low_velocity_rolloff")}
# Forms with a command path of their own (a filtered command state u).
_COMMANDED = ("spencer",)


def _check_kind(kind: str) -> int:
    if kind not in KINDS:
        raise ValueError(f"unknown kind of test '{kind}'; valid: {', '.join(KINDS)}")
    return {"structure": kernel.STRUCT, "device": kernel.DEVICE, "forced": kernel.FORCED}[kind]


@dataclass(frozen=True)
class Form:
    """A model form: the damper law without effects.

    Attributes
    ----------
    name : str
        Contract name (``dahl``, ``lugre``, ...).
    code : int
        Kernel form code.
    title : str
        Human name with the thesis equations.
    params : tuple of ParamSpec
        Parameters in kernel order.
    states : tuple of str
        Hysteretic state names in kernel order.
    frame_in_form : bool
        True when the form's own ``c``, ``k`` also carry the frame (all but
        ``spencer``, whose structure tests get a separate frame ``c``, ``k``).
    fixed : tuple of str
        Redundant parameters held at their value during estimation.
    derived : tuple of Ratio
        Reported parameters computed from estimated ones (``spencer``'s
        ``x0 = F_pre/k1``); accepted as inputs with their denominator.
    ros2 : bool
        Whether stiff intervals may be tried with the Rosenbrock step
        (:mod:`bayes_mr.models.integrate`); False keeps RK4 for every interval.
    """

    name: str
    code: int
    title: str
    params: tuple[ParamSpec, ...]
    states: tuple[str, ...]
    frame_in_form: bool = True
    fixed: tuple[str, ...] = ()
    derived: tuple[Ratio, ...] = ()
    ros2: bool = True

    @property
    def built_in(self) -> tuple[str, ...]:
        """Effects this form models itself (``spencer``'s voltage dependence and low-velocity roll-off), which
        cannot be added to it."""
        return _BUILT_IN.get(self.name, ())

    def __add__(self, effect: Effect) -> Model:
        return Model(self) + effect



@dataclass(frozen=True)
class Model:
    """A model form with effects switched on.

    Build with ``Form + Effect`` (``DAHL + FORCE_OFFSET``) or
    :func:`get_model` (``"dahl+force_offset"``).
    """

    form: Form
    effects: tuple[Effect, ...] = ()

    def __post_init__(self):
        names = [e.name for e in self.effects]
        if len(set(names)) != len(names):
            raise ValueError(f"effect repeated in {self.name}")
        for e in names:
            if e in self.form.built_in:
                raise ValueError(f"'{self.form.name}' already models {e}; drop '+{e}'")

    def __add__(self, effect: Effect) -> "Model":
        if not isinstance(effect, Effect):
            raise TypeError(f"can only add an Effect to a model, not {type(effect).__name__}")
        return Model(self.form, self.effects + (effect,))

    @property
    def name(self) -> str:
        return self.form.name + "".join("+" + e.name for e in self.effects)

    def effect(self, name: str) -> Effect | None:
        for e in self.effects:
            if e.name == name:
                return e
        return None

    @property
    def commanded(self) -> bool:
        """Whether the model has a command path (``spencer``, or ``voltage_dependence`` on)."""
        return self.form.name in _COMMANDED or self.effect("voltage_dependence") is not None

    def check(self, kind: str) -> None:
        """Raise ValueError when an effect cannot apply to a ``kind`` test of this model.

        ``command_saturation`` and ``field_dynamics`` shape a command path the
        model must have; ``inertia`` is a device-test effect. (Checked when the
        model is bound to a kind, not on ``+``, so effects may be added in any order.)
        """
        _check_kind(kind)
        for e in self.effects:
            if e.name in ON_COMMAND and not self.commanded:
                raise ValueError(f"{self.name}: '{e.name}' shapes the command path, which {self.form.name} "
                                 "lacks — use spencer or add voltage_dependence")
            if e.name in DEVICE_ONLY and kind != "device":
                raise ValueError(f"{self.name}: '{e.name}' applies to device tests only ({DEVICE_ONLY[e.name]})")

    # --- parameters ----------------------------------------------------------
    def param_specs(self, kind: str) -> tuple[ParamSpec, ...]:
        """All parameters for a test of ``kind``, in kernel order."""
        self.check(kind)
        specs: list[ParamSpec] = []
        if kind != "device" and not self.form.frame_in_form:
            specs.extend(FRAME)
        specs.extend(self.form.params)
        for e in self.effects:
            specs.extend(e.params)
        if kind == "forced":
            specs.append(MASS)
        return tuple(specs)

    def param_names(self, kind: str) -> tuple[str, ...]:
        return tuple(s.name for s in self.param_specs(kind))

    def free_names(self, kind: str) -> tuple[str, ...]:
        """Names of the estimated parameters (all but the form's fixed ones)."""
        return tuple(n for n in self.param_names(kind) if n not in self.form.fixed)

    def free_specs(self, kind: str) -> tuple[ParamSpec, ...]:
        return tuple(s for s in self.param_specs(kind) if s.name not in self.form.fixed)

    def canonical(self, values: dict[str, float] | None) -> dict[str, float]:
        """``values`` (name → SI) with every derived name replaced by the estimated one it stands for.

        ``x0`` of ``spencer`` given with ``k1`` becomes ``F_pre = k1·x0``; given
        beside ``F_pre`` it must agree with it (a fit's ``point`` carries both).

        Raises
        ------
        ValueError
            A derived name without its denominator, or disagreeing with its numerator.
        """
        out = dict(values or {})
        for d in self.form.derived:
            if d.name not in out:
                continue
            value = float(out.pop(d.name))
            if d.denominator not in out:
                raise ValueError(f"{self.name}: '{d.name}' is {d.numerator}/{d.denominator}; give it with "
                                 f"'{d.denominator}', or give '{d.numerator}' instead")
            implied = value * float(out[d.denominator])
            if d.numerator in out and not np.isclose(float(out[d.numerator]), implied, rtol=1e-6):
                raise ValueError(f"{self.name}: {d.name} = {value} disagrees with {d.numerator}/{d.denominator} = "
                                 f"{float(out[d.numerator]) / float(out[d.denominator])}")
            out[d.numerator] = implied
        return out

    def derived_values(self, kind: str, theta: np.ndarray) -> dict[str, np.ndarray]:
        """Derived parameters (name → array (...)) of full parameter vectors ``theta`` (..., P) [SI]."""
        names = self.param_names(kind)
        theta = np.asarray(theta, float)
        return {d.name: theta[..., names.index(d.numerator)] / theta[..., names.index(d.denominator)]
                for d in self.form.derived}

    def reported(self, kind: str, names: tuple[str, ...], units: tuple[str, ...], free: np.ndarray,
                 full: np.ndarray) -> tuple[tuple[str, ...], tuple[str, ...], np.ndarray]:
        """The free parameters ``names`` and, where one of their inputs is free, the derived ones.

        Parameters
        ----------
        names, units : tuple of str
            The free parameters and their units.
        free : ndarray, shape (..., p)
            Their values [SI] (draws or a point).
        full : ndarray, shape (..., P)
            The same as full parameter vectors [SI].

        Returns
        -------
        names, units : tuple of str
            With the derived parameters appended.
        values : ndarray, shape (..., p + d)
            ``free`` with the derived values appended, computed from each
            row, so their mean, SD and intervals are those of the draws.
        """
        extra = [d for d in self.form.derived if {d.numerator, d.denominator} & set(names)]
        free = np.asarray(free, float)
        if not extra:
            return tuple(names), tuple(units), free
        values = self.derived_values(kind, full)
        return (tuple(names) + tuple(d.name for d in extra), tuple(units) + tuple(d.unit for d in extra),
                np.concatenate([free] + [np.asarray(values[d.name])[..., None] for d in extra], axis=-1))

    def theta(self, kind: str, values: dict[str, float] | None = None, *, defaults: bool = True) -> np.ndarray:
        """Full parameter vector (SI) from ``values``; unknown names are an error.

        Missing names take the spec default when ``defaults`` is True, else
        raise listing what is missing. Derived names are accepted as
        :meth:`canonical` reads them.
        """
        values = self.canonical(values)
        names = self.param_names(kind)
        unknown = [n for n in values if n not in names]
        if unknown:
            raise ValueError(f"unknown parameter(s) {unknown} for {self.name} ({kind} test); valid: {', '.join(names)}")
        out = []
        missing = []
        for spec in self.param_specs(kind):
            if spec.name in values:
                v = float(values[spec.name])
                if spec.positive and not spec.sign_free and not v > 0:
                    raise ValueError(f"parameter '{spec.name}' of {self.name} must be positive, got {v}")
                out.append(v)
            elif defaults:
                out.append(spec.default)
            else:
                missing.append(spec.name)
        if missing:
            raise ValueError(f"{self.name}: missing parameter(s) {', '.join(missing)}")
        return np.array(out, float)

    def free_index(self, kind: str) -> np.ndarray:
        """Indices of the free parameters within the full vector."""
        names = self.param_names(kind)
        return np.array([i for i, n in enumerate(names) if n not in self.form.fixed], dtype=np.int64)

    def coordinates(
        self,
        kind: str,
        scales: Scales | None = None,
        ranges: dict[str, tuple[float, float]] | None = None,
    ) -> Coordinates:
        """Estimation coordinates of the free parameters (thesis 3-37/3-38).

        Plausible ranges come from the record ``scales`` unless overridden by
        ``ranges`` (name → (lo, hi) in SI).
        """
        specs = self.free_specs(kind)
        ranges = dict(ranges or {})
        unknown = [n for n in ranges if n not in [s.name for s in specs]]
        if unknown:
            raise ValueError(f"prior range given for unknown parameter(s) {unknown} of {self.name}")
        full = {s.name: ranges.get(s.name, s.plausible(scales)) for s in specs}
        return Coordinates.build(specs, full)

    # --- states and kernel layout -----------------------------------------------
    def state_names(self, kind: str) -> tuple[str, ...]:
        _check_kind(kind)
        names: list[str] = [] if kind == "device" else ["x", "xdot"]
        names.extend(self.form.states)
        for e in self.effects:
            names.extend(e.states)
        return tuple(names)

    def state_scales(self, kind: str, theta: np.ndarray, scales: Scales) -> np.ndarray:
        """Typical magnitude of each state (for filter initial and process noise).

        x and the amplitude envelope scale with the record's displacement, ẋ
        with its velocity, filtered voltages with 1 V, and hysteretic states
        with their saturation value (1 for normalized forms, min(1/α, X) for LuGre,
        min((β₁+γ)^(−1/n), X) for Bouc–Wen, (A/(β+γ))^(1/n) and X for Spencer's z, y).
        """
        q = dict(zip(self.param_names(kind), np.asarray(theta, float)))
        form = self.form.name
        hyst = {
            "normalized-bouc-wen": {"z": 1.0},
            "dahl": {"z": 1.0},
            # z of LuGre and r of Bouc–Wen move with x until they saturate
            "lugre": {"z": min(1.0 / q.get("alpha", 1.0), scales.displacement)},
            "bouc-wen": {"r": min((q.get("beta1", 1.0) + abs(q.get("gamma", 0.0))) ** (-1.0 / q.get("n", 1.0)),
                                  scales.displacement)},
            "spencer": {
                "y": scales.displacement,
                "z": (q.get("A", 1.0) / (q.get("gamma", 1.0) + q.get("beta", 1.0))) ** (1.0 / q.get("n", 1.0)),
                "u": 1.0,
            },
        }[form]
        out = []
        for name in self.state_names(kind):
            if name in ("x", "envelope"):
                out.append(scales.displacement)
            elif name == "xdot":
                out.append(scales.velocity)
            elif name in hyst:
                out.append(hyst[name])
            else:  # filtered voltage of voltage_dependence, coil current of field_dynamics
                out.append(1.0)
        return np.array(out, float)

    def layout(self, kind: str, channels: tuple[str, ...] | None = None) -> np.ndarray:
        """The int64 layout array the compiled kernel reads (see kernel.L_*).

        ``channels`` are the measured channels a filter predicts, in order
        (default: every output of the kind).
        """
        k = _check_kind(kind)
        lay = np.full(kernel.LAYOUT_SIZE, -1, dtype=np.int64)
        lay[kernel.L_FORM] = self.form.code
        lay[kernel.L_KIND] = k
        names = self.param_names(kind)
        states = self.state_names(kind)
        if kind != "device" and not self.form.frame_in_form:
            lay[kernel.L_PFRAME] = 0
            lay[kernel.L_PFORM] = len(FRAME)
        else:
            lay[kernel.L_PFORM] = 0
        lay[kernel.L_SFORM] = 0 if kind == "device" else 2
        if kind == "forced":
            lay[kernel.L_MASS] = names.index(MASS.name)
        channels = _OBS_DEFAULT[kind] if channels is None else tuple(channels)
        if not 0 < len(channels) <= kernel.N_OBS or any(c not in _OBS_CODE for c in channels):
            raise ValueError(f"measured channels {channels}: give 1 to {kernel.N_OBS} of {', '.join(_OBS_CODE)}")
        for j, c in enumerate(channels):
            lay[kernel.L_OBS + j] = _OBS_CODE[c]
        lay[kernel.L_NS] = len(states)
        lay[kernel.L_NP] = len(names)
        slot = {
            "force_offset": kernel.L_F0,
            "voltage_dependence": kernel.L_VD,
            "stiffness_drift": kernel.L_DRIFT,
            "asymmetry": kernel.L_ASYM,
            "small_amplitude_regime": kernel.L_SA,
            "low_velocity_rolloff": kernel.L_LVR,
            "cubic_stiffness": kernel.L_K3,
            "command_saturation": kernel.L_CSAT,
            "field_dynamics": kernel.L_FD,
            "shear_thinning": kernel.L_ST,
            "stribeck_friction": kernel.L_SF,
            "field_decay": kernel.L_FDEC,
            "command_polynomial": kernel.L_CPOLY,
            "exponential_saturation": kernel.L_CEXP,
        }
        for e in self.effects:
            if e.name in slot:
                lay[slot[e.name]] = names.index(e.params[0].name)
        if self.effect("voltage_dependence"):
            lay[kernel.L_SU] = states.index("u")
        if self.effect("small_amplitude_regime"):
            lay[kernel.L_SE] = states.index("envelope")
        if self.effect("field_dynamics"):
            lay[kernel.L_SC] = states.index("coil")
        self._term_slots(lay, names, states)
        return lay

    def _term_slots(self, lay: np.ndarray, names: tuple[str, ...], states: tuple[str, ...]) -> None:
        """Layout slots of the library terms (:mod:`bayes_mr.models.terms`): θ index and code."""
        terms = [e for e in self.effects if "term_code" in e.options]
        if len(terms) > kernel.N_TERMS:
            raise ValueError(f"{self.name}: at most {kernel.N_TERMS} library terms per model")
        if "u" in states:
            lay[kernel.L_SUL] = states.index("u")
        for j, e in enumerate(terms):
            c = int(e.options["term_code"])
            if lay[kernel.L_SUL] < 0 and term_kernel.TF_UL in (c % 16, (c // 16) % 16, (c // 256) % 16):
                raise ValueError(f"{self.name}: '{e.name}' needs a lagged command (spencer or +voltage_dependence)")
            lay[kernel.L_TP + j] = names.index(e.params[0].name)
            lay[kernel.L_TC + j] = c

    def constants(self, mass: float | None = None, *, c_acc: float = 1.0, n_max: int = 400,
                  ros2: bool = True, hold_branch: bool = True) -> np.ndarray:
        """The float64 constants array the kernel reads (mass, envelope time, step control).

        ``ros2`` False integrates every interval with RK4 (:mod:`bayes_mr.models.integrate`); ``hold_branch``
        False integrates the hysteretic state on its loading branches too (:func:`bayes_mr.models.branch.on_branch`).
        """
        cst = np.zeros(kernel.CONST_SIZE)
        cst[kernel.K_MASS] = float(mass) if mass else 1.0
        cst[kernel.K_IMASS] = 1.0 / cst[kernel.K_MASS]
        sa = self.effect("small_amplitude_regime")
        cst[kernel.K_TENV] = float(sa.options["t_env"]) if sa else 1.0
        cst[kernel.K_CACC] = c_acc
        cst[kernel.K_NMAX] = n_max
        cst[kernel.K_STIFF] = integrate.ROS2_ABOVE if ros2 and self.form.ros2 else np.inf
        cst[kernel.K_RTOL] = integrate.ROS2_RTOL
        cst[kernel.K_BRANCH] = 1.0 if hold_branch else 0.0
        sf = self.effect("stribeck_friction")
        cst[kernel.K_SMOOTH] = float(sf.options["smooth"]) if sf else 0.1
        return cst

    def delay_channel(self, kind: str) -> str | None:
        """The channel ``sensor_delay`` lags (None without that effect)."""
        e = self.effect("sensor_delay")
        if e is None:
            return None
        return e.options.get("channel") or ("force" if kind == "device" else "acceleration")

