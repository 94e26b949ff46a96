"""Library terms: a parameter θ times a product of states and inputs, outside the named effects.

A term is an :class:`~bayes_mr.models.effects.Effect` whose one parameter θ
multiplies a *basis* b — a product of up to three factors of

========== ==================================================
factor     meaning
========== ==================================================
``x``      displacement [m]
``xdot``   velocity [m/s]
``z``      the form's hysteretic state (spencer: its z)
``u``      the command (voltage or current) as measured
``ulag``   the command through the model's first-order lag (spencer, or ``+voltage_dependence``)
``abs(F)`` |F| of ``x``, ``xdot`` or ``z``
``sgn(F)`` sign of ``x``, ``xdot`` or ``z``
========== ==================================================

and is added either to the damper force (``term(EXPR)``: f_d += θ·b) or to
the hysteretic law (``zterm(EXPR)``: ż += θ·b). ``EXPR`` is the factors
joined by ``*``: ``spencer+term(u*abs(xdot))`` is a yield-like force that grows
with u·|ẋ|, ``dahl+term(abs(x)*xdot)`` a damping that grows with |x|. The
kernel evaluates the basis from an integer code (:mod:`bayes_mr.models.kernel`,
``TF_*``, ``TERM_*``), so any term composes with any form and effect, up to
``kernel.N_TERMS`` of them per model.

θ is signed, default 0 (the term off), and its plausible range is ±
:data:`SPAN` × the record scale of its unit (force over the basis's scale;
for a law term, the hysteretic state's scale per displacement × velocity
over the basis's scale).
"""

from __future__ import annotations

from bayes_mr.models import term_kernel
from bayes_mr.models.effects import Effect
from bayes_mr.models.params import ParamSpec

#: Factor name → (kernel code, short token of the parameter name, base quantity).
FACTORS = {
    "x": (term_kernel.TF_X, "x", "x"), "xdot": (term_kernel.TF_XD, "xd", "xdot"), "z": (term_kernel.TF_Z, "z", "z"),
    "u": (term_kernel.TF_U, "u", "u"), "ulag": (term_kernel.TF_UL, "ul", "ulag"),
    "abs(x)": (term_kernel.TF_AX, "ax", "x"), "abs(xdot)": (term_kernel.TF_AXD, "axd", "xdot"),
    "abs(z)": (term_kernel.TF_AZ, "az", "z"),
    "sgn(x)": (term_kernel.TF_SX, "sx", None), "sgn(xdot)": (term_kernel.TF_SXD, "sxd", None),
    "sgn(z)": (term_kernel.TF_SZ, "sz", None),
}
_ORDER = {name: i for i, name in enumerate(FACTORS)}
#: Term kinds: model-name prefix → (kernel target, parameter-name prefix).
TARGETS = {"term": (term_kernel.TERM_FORCE, "tf_"), "zterm": (term_kernel.TERM_LAW, "tz_")}
#: Forms whose hysteretic state is dimensionless (the others' z is a displacement).
UNIT_Z_FORMS = ("normalized-bouc-wen", "dahl")
#: Plausible |θ| up to SPAN × its record-scale reference.
SPAN = 30.0
#: Words a report uses for each factor.
WORDS = {"x": "x", "xdot": "ẋ", "z": "z", "u": "u", "ulag": "lagged u", "abs(x)": "|x|", "abs(xdot)": "|ẋ|",
         "abs(z)": "|z|", "sgn(x)": "sgn x", "sgn(xdot)": "sgn ẋ", "sgn(z)": "sgn z"}


def is_term(name: str) -> bool:
    """Whether a model-name part (``term(...)``, ``zterm(...)``) names a library term."""
    head = name.split("(", 1)[0]
    return head in TARGETS and name.endswith(")") and "(" in name


def parse(name: str) -> tuple[str, tuple[str, ...]]:
    """``"term(u*abs(xdot))"`` → ("term", ("u", "abs(xdot)")) with factors in canonical order."""
    if not is_term(name):
        raise ValueError(f"not a library term: '{name}' (write term(EXPR) or zterm(EXPR))")
    head, body = name.split("(", 1)
    factors = tuple(f.strip() for f in body[:-1].replace(" ", "").split("*") if f.strip())
    bad = [f for f in factors if f not in FACTORS]
    if bad or not 0 < len(factors) <= 3:
        raise ValueError(f"term '{name}': give 1 to 3 factors of {', '.join(FACTORS)} joined by '*'"
                         + (f" (unknown: {', '.join(bad)})" if bad else ""))
    return head, tuple(sorted(factors, key=_ORDER.__getitem__))


def code(target: str, factors: tuple[str, ...]) -> int:
    """Kernel code of a term (factor codes in base 16, target × 4096)."""
    c = 0
    for k, f in enumerate(factors):
        c += FACTORS[f][0] * 16**k
    return c + 4096 * TARGETS[target][0]


def _dims(factors: tuple[str, ...], target: str, form: str) -> tuple[tuple[int, int, int, int], str]:
    """Record-scale exponents (force, displacement, velocity, duration) and unit of θ."""
    z_dims, z_unit = ((0, 0, 0, 0), "") if form in UNIT_Z_FORMS else ((0, 1, 0, 0), "m")
    base = {"x": ((0, 1, 0, 0), "m"), "xdot": ((0, 0, 1, 0), "m/s"), "z": (z_dims, z_unit),
            "u": ((0, 0, 0, 0), "V"), "ulag": ((0, 0, 0, 0), "V"), None: ((0, 0, 0, 0), "")}
    # the law's ż: the state's scale per displacement × velocity
    top = ((1, 0, 0, 0), "N") if target == "term" else (tuple(a + b for a, b in zip(z_dims, (0, -1, 1, 0))),
                                                         f"{z_unit or '1'}/s")
    dims = list(top[0])
    units = []
    for f in factors:
        d, u = base[FACTORS[f][2]]
        dims = [a - b for a, b in zip(dims, d)]
        if u:
            units.append(u)
    unit = top[1] + ("/(" + "·".join(units) + ")" if units else "")
    return tuple(dims), unit


def make(name: str, form: str) -> Effect:
    """The :class:`Effect` of library term ``name`` on a model of ``form``.

    Parameters
    ----------
    name : str
        ``term(EXPR)`` or ``zterm(EXPR)``.
    form : str
        The model form's name (the unit of z depends on it).
    """
    target, factors = parse(name)
    expr = "*".join(factors)
    pname = TARGETS[target][1] + "_".join(FACTORS[f][1] for f in factors)
    dims, unit = _dims(factors, target, form)
    spec = ParamSpec(pname, unit, f"{describe(target, factors)}: coefficient", 0.0, dims, (0.0, SPAN),
                     positive=False)
    return Effect(f"{target}({expr})", describe(target, factors), (spec,),
                  options={"term_code": code(target, factors)},
                  needs_voltage=any(f in ("u", "ulag") for f in factors))


def describe(target: str, factors: tuple[str, ...], theta: float | None = None) -> str:
    """The term in words, e.g. "a damper force that grows with u·|ẋ|"."""
    prod = "·".join(WORDS[f] for f in factors)
    sense = "grows" if theta is None or theta >= 0 else "falls"
    if target == "term":
        return f"a damper force that {sense} with {prod}"
    return f"a hysteretic-state rate ż that {sense} with {prod}"


def term_effects(effects) -> list[Effect]:
    """The library terms among ``effects``."""
    return [e for e in effects if "term_code" in e.options]
