"""The effects of ``docs/CONTRACT.md``, each an extension that composes with any form.

An effect is what a model can miss in a measured record; switched on, it adds
parameters (and sometimes a state) to the model. The kernel applies them as:

* ``force_offset`` — f_r += f0 (accumulator preload, load-cell bias);
* ``voltage_dependence`` — filtered voltage u̇ = η(v − u); hysteretic force
  × (1 + a_v·u) and an added viscous term c_v·u·ẋ;
* ``stiffness_drift`` — stiffness and hysteretic strength × (1 + drift·t);
* ``asymmetry`` — hysteretic force × (1 + asym·sgn z): yield force
  (1 ± asym)·F in tension and compression;
* ``small_amplitude_regime`` — hysteretic strength × r_s while the
  displacement amplitude envelope (peak-following, decay time ``t_env``)
  is below x_s, with a smooth switch 10 % of x_s wide;
* ``low_velocity_rolloff`` — a series dashpot c_s: the hysteretic element
  moves at ẋ − F_h/c_s, so the force rolls off at low velocity;
* ``sensor_delay`` — one measured channel lags the others by ``delay``
  seconds (applied to the simulated output; fractional samples by linear
  interpolation);
* ``cubic_stiffness`` — a hardening frame, f_r += k3·x³.

Effects the MR-damper literature knows (each cited in its
constant's comment; equations in ``docs/CONTRACT.md``):

* ``command_saturation`` — the field saturates with the command: the filtered
  command u enters every field-dependent coefficient (the hysteretic strength,
  and spencer's c0, c1 or ``voltage_dependence``'s c_v) as u_s·tanh(u/u_s);
* ``field_dynamics`` — a second lag between command and field (coil current
  i̇ = (v − i)/τ_c feeding the existing field lag);
* ``shear_thinning`` — Herschel–Bulkley post-yield viscous force
  c_p·v_p·sgn(ẋ)·((1 + |ẋ|/v_p)^m − 1)/m;
* ``stribeck_friction`` — the Stribeck excess of seal friction, F_st·e^{−(ẋ/v_s)²}·tanh(ẋ/(ε·v_s))
  (its Coulomb level is the form's own friction or yield force);
* ``inertia`` — piston and fluid inertia m_e·ẍ in the force a device test
  measures (device tests only);
* ``field_decay`` — the field decays at its own rate: the command-to-field lag
  runs at r_d·η while the field's magnitude falls, at η while it rises;
* ``command_polynomial`` — a current law cubic in the command: u enters the
  field-dependent coefficients as u·(1 + b2·u + b3·u²);
* ``exponential_saturation`` — a first-order saturation of the field with the
  command: u enters them as sgn(u)·u_e·(1 − e^{−|u|/u_e}).

``command_saturation``, ``field_dynamics``, ``field_decay`` and the current laws act on a command
path: the model must have one (``spencer``, or ``+voltage_dependence``), which
:meth:`~bayes_mr.models.model.Model.param_specs` checks.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from bayes_mr.models.params import ParamSpec


@dataclass(frozen=True)
class Effect:
    """An extension of a model form.

    Attributes
    ----------
    name : str
        Contract name (``docs/CONTRACT.md``).
    description : str
        What happens in the device or frame.
    params : tuple of ParamSpec
        Added parameters; the first is the *primary* one, set by
        ``--effect NAME=value``.
    states : tuple of str
        Added states.
    options : dict
        Non-estimated settings (``channel`` of ``sensor_delay``; ``t_env``
        of ``small_amplitude_regime``).
    needs_voltage : bool
        Only meaningful when the record has a varying voltage channel.
    """

    name: str
    description: str
    params: tuple[ParamSpec, ...] = ()
    states: tuple[str, ...] = ()
    options: dict = field(default_factory=dict, compare=False, hash=False)
    needs_voltage: bool = False

    @property
    def primary(self) -> str:
        return self.params[0].name

    def with_options(self, **options) -> "Effect":
        """A copy with ``options`` changed (unknown option names are an error)."""
        unknown = set(options) - set(self.options)
        if unknown:
            raise ValueError(
                f"effect '{self.name}' has no option {sorted(unknown)}; options: {sorted(self.options) or 'none'}"
            )
        return Effect(self.name, self.description, self.params, self.states, {**self.options, **options}, self.needs_voltage)

    def __add__(self, other):
        raise TypeError("add effects to a form or model: Dahl() + ForceOffset(), not effect + effect")


def _zero_centred(symbol: str, unit: str, meaning: str, dims: tuple[int, int, int, int], bound: float) -> ParamSpec:
    """A signed parameter, default 0 (effect off), plausible within ±bound × the record scale of ``dims``."""
    return ParamSpec(symbol, unit, meaning, 0.0, dims, (0.0, bound), positive=False)


FORCE_OFFSET = Effect(
    "force_offset", "a constant force f0 added to f_r (accumulator preload, load-cell bias)",
    (_zero_centred("f0", "N", "constant force offset", (1, 0, 0, 0), 1.0),),
)
VOLTAGE_DEPENDENCE = Effect(
    "voltage_dependence", "damper strength depends on the command voltage through a first-order lag",
    (
        ParamSpec("a_v", "1/V", "hysteretic strength gain per volt of filtered voltage", 1.0, (0, 0, 0, 0), (1e-3, 100.0)),
        ParamSpec("c_v", "N·s/(m·V)", "viscous damping per volt of filtered voltage", 300.0, (1, 0, -1, 0), (1e-5, 10.0)),
        ParamSpec("eta", "1/s", "voltage lag: 1/time constant", 190.0, (0, -1, 1, 0), (0.01, 100.0)),
    ),
    ("u",),
    needs_voltage=True,
)
STIFFNESS_DRIFT = Effect(
    "stiffness_drift", "a stiffness or strength that drifts with time over the record (heating)",
    (_zero_centred("drift", "1/s", "relative change of stiffness and strength per second", (0, 0, 0, -1), 0.5),),
)
ASYMMETRY = Effect(
    "asymmetry", "different yield force in tension and compression (misaligned paddle)",
    (_zero_centred("asym", "-", "relative yield-force difference: (1 ± asym)·F", (0, 0, 0, 0), 0.9),),
)
SMALL_AMPLITUDE_REGIME = Effect(
    "small_amplitude_regime", "a different hysteresis below a displacement threshold (thesis §5.2: under 2 mm)",
    (
        ParamSpec("r_s", "-", "hysteretic strength below the threshold relative to above", 0.5, (0, 0, 0, 0), (0.02, 50.0)),
        ParamSpec("x_s", "m", "displacement-amplitude threshold", 0.002, (0, 1, 0, 0), (0.05, 1.0)),
    ),
    ("envelope",),
    options={"t_env": 1.0},
)
LOW_VELOCITY_ROLLOFF = Effect(
    "low_velocity_rolloff", "force rolls off at low velocity (series dashpot, as in spencer)",
    (ParamSpec("c_s", "N·s/m", "series dashpot", 1.0e4, (1, 0, -1, 0), (0.1, 1000.0)),),
)
SENSOR_DELAY = Effect(
    "sensor_delay", "one measured channel lags the others by a few samples",
    (ParamSpec("delay", "s", "lag of the delayed channel", 1e-3, (0, 0, 0, 0), (1e-5, 0.05)),),
    options={"channel": None},
)
CUBIC_STIFFNESS = Effect(
    "cubic_stiffness", "a hardening frame, k3·x³",
    (ParamSpec("k3", "N/m³", "cubic stiffness", 1e8, (1, -3, 0, 0), (1e-3, 10.0)),),
)

# Yield stress of MR fluids saturates with the field as the particles saturate magnetically
# (Yang et al. 2004, "Dynamic modeling of large-scale MR fluid dampers"; Wang & Liao 2011 review,
# Smart Mater. Struct. 20 023001, §3: α(u) fitted by saturating polynomials or exponentials).
# It is the field that saturates, so every coefficient the field sets sees the saturated command:
# the yield force and the field-induced viscous terms (spencer's c0(u), c1(u); c_v·u·ẋ), as in the
# current-dependent c0, c1 of Yang et al. 2004. The off value is u_s → ∞ (linear in u).
COMMAND_SATURATION = Effect(
    "command_saturation", "the field saturates with the command: u enters every field-dependent coefficient "
                          "as u_s·tanh(u/u_s)",
    (ParamSpec("u_s", "V", "command at which the yield-force gain saturates (A for a current command)", 2.0,
               (0, 0, 0, 0), (0.05, 20.0)),),
    needs_voltage=True,
)
# Command → current → field: the coil's L/R time constant (or a current driver's closed loop) and eddy
# currents put a second lag before the field (Yang et al. 2004 model the current driver and the coil
# inductance as two first-order stages; Spencer et al. 1997 keep one). A pure driver delay is close to a
# short lag at the sample rates of damper tests. The off value is τ_c → 0.
FIELD_DYNAMICS = Effect(
    "field_dynamics", "a second command-to-field lag (coil inductance, eddy currents, driver) before the field lag",
    (ParamSpec("tau_c", "s", "coil/driver time constant before the field lag", 0.01, (0, 1, -1, 0), (1e-3, 1.0)),),
    ("coil",),
    needs_voltage=True,
)
# Post-yield flow of MR fluids is shear thinning (Herschel–Bulkley, τ = τ_y + K·γ̇^m, m < 1): Wang &
# Gordaninejad 1999; Şahin, Gordaninejad et al. 2010 (J. Intell. Mater. Syst. Struct.); regularised here
# by v_p so the force has the finite slope c_p at ẋ = 0 (a structure test integrates it).
SHEAR_THINNING = Effect(
    "shear_thinning", "post-yield viscous force of a shear-thinning fluid (Herschel–Bulkley, regularised)",
    (
        ParamSpec("c_p", "N·s/m", "low-velocity slope of the post-yield viscous force", 500.0, (1, 0, -1, 0),
                  (1e-3, 10.0)),
        ParamSpec("m_hb", "-", "Herschel–Bulkley flow index (< 1 shear thinning)", 0.5, (0, 0, 0, 0), (0.1, 2.0)),
        ParamSpec("v_p", "m/s", "velocity where the power law takes over", 0.01, (0, 0, 1, 0), (1e-3, 1.0)),
    ),
)
# Seal friction with a Stribeck curve (Armstrong-Hélouvry et al. 1994; Canudas de Wit et al. 1995):
# a breakaway force F_st above the Coulomb level falling to it over the Stribeck velocity v_s; sgn ẋ
# smoothed by tanh(ẋ/(ε·v_s)), ε = option ``smooth``. The Coulomb level itself is not a parameter here:
# every form already has a friction or yield force it cannot be told from (a separate F_c made clean
# dahl records name this effect, score 13.7 > 8 on the structure record of test_diagnose's CLEAN).
STRIBECK_FRICTION = Effect(
    "stribeck_friction", "seal friction with a Stribeck curve: breakaway force above Coulomb at low velocity",
    (
        ParamSpec("F_st", "N", "Stribeck excess of the breakaway over the Coulomb force", 10.0, (1, 0, 0, 0),
                  (1e-3, 1.0)),
        # from 5 % of the record's peak velocity: a narrower Stribeck peak is a force pulse at each
        # reversal that fits the response's own structure there (on test_diagnose's clean dahl structure
        # record a 0.2 N pulse at v_s = 0.3 mm/s scored 10.8 > 8; from 2 % of V, 9.9; from 5 %, 4.7)
        ParamSpec("v_s", "m/s", "Stribeck velocity", 0.005, (0, 0, 1, 0), (0.05, 0.5)),
    ),
    options={"smooth": 0.1},
)
# The moving piston, rod and the fluid it accelerates through the orifice add m_e·ẍ to the force a
# load cell measures on a device test (Kwok et al. 2006 and Wang & Liao 2011 discuss it as the
# inertial error of quasi-static damper models at high frequency). ẍ is the Savitzky–Golay derivative
# of the imposed velocity (bayes_mr.simulation.simulate.Inputs.acceleration).
INERTIA = Effect(
    "inertia", "piston and fluid inertia m_e·ẍ in the force of a device test",
    (ParamSpec("m_e", "kg", "effective moving mass (piston, rod, accelerated fluid)", 1.0, (1, 1, -2, 0),
               (1e-4, 1.0)),),
)

# The field of an MR damper does not fall as it rises: after a command step the force rises and
# decays with different response times, set by the coil and driver (a voltage-driven coil charges
# through L/R but discharges through the driver's own path), eddy currents in the steel and the
# fluid's chain structure (Koo, Goncalves & Ahmadian 2006, "A comprehensive analysis of the response
# time of MR dampers", Smart Mater. Struct. 15:351–358, measured different rise and fall times;
# Yang et al. 2004 model the driver and coil separately for that reason). One extra rate ratio on
# the existing first-order field lag: u̇ = η·(v − u) while |u| rises, r_d·η·(v − u) while it falls.
# The off value is r_d = 1 (Spencer et al. 1997's symmetric lag).
FIELD_DECAY = Effect(
    "field_decay", "the command-to-field lag decays at its own rate: r_d·η while the field falls, η while it rises",
    (ParamSpec("r_d", "-", "rate of the field lag while the field falls, relative to while it rises", 1.0,
               (0, 0, 0, 0), (0.05, 20.0)),),
    needs_voltage=True,
)

# Current laws beside the linear one of Spencer et al. 1997 (α, c0, c1 linear in the filtered command u).
# Each maps u to g(u), which every field-dependent coefficient then sees in place of u (as
# command_saturation's tanh does): it is the field that is nonlinear in the current, so one shape serves
# the yield force and the field-induced viscous terms alike. Identified across the currents of a test
# matrix: a record at one constant current sees only g at that current, the product of the gain and the
# shape (bayes_mr.likelihood.joint sums the records that separate them).
#
# Yang, Spencer, Carlson & Sain 2002 ("Large-scale MR fluid dampers: modeling and dynamic performance
# considerations", Eng. Struct. 24:309–323) fitted α, c0 and c1 of a 20-t damper as cubic polynomials of
# the coil current. Here α_a + α_b·u becomes α_a + α_b·u·(1 + b2·u + b3·u²): a cubic in u through the
# zero-current level; b2 = b3 = 0 is the linear law (the off value). A cubic's three coefficients above
# the zero-current level need three non-zero currents.
COMMAND_POLYNOMIAL = Effect(
    "command_polynomial", "the field-dependent coefficients are cubic in the command: u enters them as "
                          "u·(1 + b2·u + b3·u²)",
    (
        _zero_centred("b2", "1/V", "quadratic coefficient of the current law (1/A for a current command)",
                      (0, 0, 0, 0), 3.0),
        _zero_centred("b3", "1/V²", "cubic coefficient of the current law (1/A² for a current command)",
                      (0, 0, 0, 0), 3.0),
    ),
    needs_voltage=True,
)
# A first-order saturation: the yield stress of an MR fluid stops growing with the field as the particles'
# magnetisation saturates (Ginder, Davis & Elie 1996, "Magnetorheological fluids: scaling of the yield
# stress", Int. J. Mod. Phys. B 10:3293–3303), so a damper's force flattens at high current. The first-order
# (exponential) approach is the simplest law that rises with slope 1 at u = 0 like the linear one and
# flattens at the command scale u_e; its knee is softer than command_saturation's tanh (g = u − u²/(2u_e) + …
# against u − u³/(3u_s²) + …): the two differ in how early the gain falls, which a matrix of three or more
# currents tells apart. The off value is u_e → ∞.
EXPONENTIAL_SATURATION = Effect(
    "exponential_saturation", "the field saturates with the command at first order: u enters every "
                              "field-dependent coefficient as sgn(u)·u_e·(1 − e^{−|u|/u_e})",
    (ParamSpec("u_e", "V", "command scale of the first-order saturation (A for a current command)", 2.0,
               (0, 0, 0, 0), (0.05, 20.0)),),
    needs_voltage=True,
)

EFFECTS: dict[str, Effect] = {
    e.name: e
    for e in (
        FORCE_OFFSET,
        VOLTAGE_DEPENDENCE,
        STIFFNESS_DRIFT,
        ASYMMETRY,
        SMALL_AMPLITUDE_REGIME,
        LOW_VELOCITY_ROLLOFF,
        SENSOR_DELAY,
        CUBIC_STIFFNESS,
        COMMAND_SATURATION,
        FIELD_DYNAMICS,
        SHEAR_THINNING,
        STRIBECK_FRICTION,
        INERTIA,
        FIELD_DECAY,
        COMMAND_POLYNOMIAL,
        EXPONENTIAL_SATURATION,
    )
}
#: Effects that act on a command path (a form that has one, or ``voltage_dependence``).
ON_COMMAND = ("command_saturation", "field_dynamics", "field_decay", "command_polynomial", "exponential_saturation")
#: Effects only a device test can have, and why.
DEVICE_ONLY = {"inertia": "the force of a structure or forced test is not measured at the damper; "
                          "the moving mass there is part of the storey (or forced) mass"}
#: What diagnose answers when the model explains the data to the noise level.
NONE = "none"
