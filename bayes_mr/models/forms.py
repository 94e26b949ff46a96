"""The five model forms of ``docs/CONTRACT.md``: parameter specs and state names.

The right-hand sides live in :mod:`bayes_mr.models.kernel` (one compiled
kernel for all forms); each form here names its kernel code. Defaults are the
thesis's values (Tables 3.2, 3.3, 3.5 and §3.8) or, for ``spencer``, the
published prototype parameters of Spencer et al. (1997) converted to SI.

Plausible ranges are relative to the record's force F, displacement X,
velocity V and duration T (:class:`~bayes_mr.models.params.Scales`).
Bouc–Wen exponents are kept at n ≥ 1: below 1, |z|^(n−1) is unbounded at
z = 0, the law is not Lipschitz there and an explicit integrator needs
arbitrarily many sub-steps (a least-squares fit of the measured damper spent
13 minutes at n = 0.5 before this bound). The normalized form's σ is kept
at σ ≥ 1/2, where |z| ≤ 1 is invariant (Ikhrouane & Rodellar 2005); below it
an unloading branch can push z outward and the filter diverges.

Signs: every parameter is positive (log scale) except the classic
``bouc-wen``'s ``gamma``, which is *sign-free*: its default range is ±100 X⁻²,
carried on the signed-log coordinate asinh(s·γ) (log-like on both signs, so
the thesis's softening loops, Table 3.2, keep the resolution the UKF needs and
a hardening loop's negative γ is reachable without a user range); a range
given with lo > 0 keeps it positive on the log scale. In the
classic law ṙ = ẋ − β₁|ẋ||r|^{n−1}r −
γẋ|r|^n the loading branch is ṙ = ẋ(1 − (β₁+γ)|r|^n) and the unloading one
ṙ = ẋ(1 + (β₁−γ)|r|^n): β₁ > 0 is the dissipation (loop area), while γ of
either sign is admissible (Wen 1976; Ikhouane & Rodellar 2007 classify the
bounded, softening cases −β₁ < γ ≤ β₁; γ < −β₁ is a hardening loop, bounded
only over the record's range, which is the Bouc–Wen benchmark of Noël &
Schoukens 2016: β₁ = 800 /m, γ = −1100 /m at n = 1). The other forms' laws
are written so that their parameters are positive by construction (Dahl's
and LuGre's rates, the normalized form's ρ, σ ≥ 1/2); Spencer's γ, β are the
same Bouc–Wen pair and could in principle carry the same sign freedom, but
the published MR-damper fits (Spencer et al. 1997 and after) are all
positive with γ ≈ β, and a negative one there would make the damper's
hysteretic force grow without bound, so they stay positive. A law that
blows up in a run is a recorded divergence (the simulator flags the sample),
never a crash.
"""

from __future__ import annotations

from bayes_mr.models import kernel
from bayes_mr.models.model import Form
from bayes_mr.models.params import F_, F_V, F_X, ONE, PER_X, PER_X2, ParamSpec, Ratio

C = ParamSpec("c", "N·s/m", "viscous damping (frame + damper)", 100.0, F_V, (1e-3, 2.0))
K = ParamSpec("k", "N/m", "stiffness (frame + damper)", 2.0e4, F_X, (1e-4, 3.0))


def _with_c_k(name: str, code: int, title: str, *hysteretic: ParamSpec) -> Form:
    """A thesis form (3-52..3-70): shared c, k (:data:`C`, :data:`K`), its hysteretic parameters, one state z."""
    return Form(name, code, title, (C, K, *hysteretic), ("z",))


NORMALIZED_BOUC_WEN = _with_c_k(
    "normalized-bouc-wen", kernel.NBW, "normalized Bouc–Wen (thesis 3-52..3-58)",
    ParamSpec("k_z", "N", "hysteretic force amplitude", 24.51, F_, (1e-3, 1.0)),
    ParamSpec("rho", "1/m", "initial slope of z", 2508.0, PER_X, (0.3, 1000.0)),
    ParamSpec("n", "-", "smoothness of the transition", 1.06, ONE, (1.0, 4.0)),
    ParamSpec("sigma", "-", "loop shape (σ ≥ 1/2 keeps |z| ≤ 1)", 1.03, ONE, (0.5, 5.0)),
)

DAHL = _with_c_k(
    "dahl", kernel.DAHL, "modified Dahl (thesis 3-59..3-64)",
    ParamSpec("F_d", "N", "Coulomb (Dahl) friction force", 25.0, F_, (1e-3, 1.0)),
    ParamSpec("sigma", "1/m", "Dahl loop shape (pre-sliding stiffness / F_d)", 2500.0, PER_X, (0.3, 1000.0)),
)

LUGRE = _with_c_k(
    "lugre", kernel.LUGRE, "modified LuGre (thesis 3-65..3-70)",
    ParamSpec("beta", "N/m", "generalised stiffness of z", 6.1484e4, F_X, (1e-2, 1000.0)),
    ParamSpec("epsilon", "N·s/m", "generalised damping of z", 38.39, F_V, (1e-4, 1.0)),
    ParamSpec("alpha", "1/m", "generalised stiffness parameter of ż", 2442.0, PER_X, (0.3, 1000.0)),
)

BOUC_WEN = Form(
    "bouc-wen", kernel.BW, "classic Bouc–Wen (thesis 3-31, 3-32)",
    (
        ParamSpec("c", "N·s/m", "viscous damping", 0.3, F_V, (1e-3, 2.0)),
        ParamSpec("k", "N/m", "stiffness (elastic and hysteretic)", 9.0, F_X, (1e-4, 3.0)),
        ParamSpec("beta1", "1/m^n", "Bouc–Wen β₁ (scale relative to X⁻² assumes n ≈ 2)", 2.0, PER_X2, (1e-4, 100.0)),
        # sign-free: γ < 0 hardens the loading branch (the Bouc–Wen benchmark's γ is −1100 /m at n = 1);
        # default range ±100 X⁻² on the signed-log coordinate asinh(s·γ), floor 1e-4 X⁻²
        ParamSpec("gamma", "1/m^n", "Bouc–Wen γ, either sign (γ < 0: a hardening loop)", 1.0, PER_X2,
                  (1e-4, 100.0), sign_free=True),
        ParamSpec("n", "-", "Bouc–Wen exponent", 2.0, ONE, (1.0, 4.0)),
    ),
    ("r",),
)

# Spencer et al. (1997) prototype damper, published in cm units; converted to SI.
SPENCER = Form(
    "spencer", kernel.SPENCER, "Spencer et al. (1997) phenomenological model",
    params=(
        ParamSpec("alpha_a", "N/m", "Bouc–Wen stiffness α at 0 V", 1.40e4, F_X, (1e-3, 10.0)),
        ParamSpec("alpha_b", "N/(m·V)", "α per volt", 6.95e4, F_X, (1e-3, 10.0)),
        ParamSpec("c0a", "N·s/m", "high-velocity damping c0 at 0 V", 2.10e3, F_V, (1e-3, 10.0)),
        ParamSpec("c0b", "N·s/(m·V)", "c0 per volt", 3.50e2, F_V, (1e-4, 10.0)),
        ParamSpec("k0", "N/m", "stiffness at high velocity", 4.69e3, F_X, (1e-5, 10.0)),
        ParamSpec("c1a", "N·s/m", "low-velocity (series) damping c1 at 0 V", 2.83e4, F_V, (1e-3, 100.0)),
        ParamSpec("c1b", "N·s/(m·V)", "c1 per volt", 2.95e2, F_V, (1e-4, 10.0)),
        ParamSpec("k1", "N/m", "accumulator stiffness", 5.00e2, F_X, (1e-6, 1.0)),
        # the accumulator force k1 (x − x0) = k1 x − F_pre: a record determines the preload F_pre, not x0 —
        # k1 → 0 with k1·x0 fixed barely changes the force, so (k1, x0) is a sloppy pair whose draws run
        # along a hyperbola (Ma et al. 2004); F_pre is estimated and x0 = F_pre/k1 reported from the draws
        ParamSpec("F_pre", "N", "accumulator preload k1·x0 (x0 = F_pre/k1 is reported)", 5.00e2 * 0.143, F_,
                  (1e-4, 1.0)),
        ParamSpec("gamma", "1/m²", "Bouc–Wen γ", 3.63e6, PER_X2, (0.1, 1e4)),
        ParamSpec("beta", "1/m²", "Bouc–Wen β", 3.63e6, PER_X2, (0.1, 1e4)),
        ParamSpec("A", "-", "Bouc–Wen A (held fixed: one scale of α, A, β, γ is redundant)", 301.0, ONE, (10.0, 3000.0)),
        ParamSpec("n", "-", "Bouc–Wen exponent", 2.0, ONE, (1.0, 4.0)),
        ParamSpec("eta", "1/s", "current-driver lag 1/time constant", 190.0, (0, -1, 1, 0), (0.01, 100.0)),
    ),
    states=("y", "z", "u"),
    frame_in_form=False,
    fixed=("A",),
    # its force runs through a stiff two-state block (y, z: the series dashpot c0 + c1 against αz), where the
    # Rosenbrock step's state-wise error test does not bound the force's error: against solve_ivp, RK4 7e-6
    # (structure test, 1 kHz) and 5e-7 (device, 3 kHz) of the SD, the adaptive step 1.8e-3 and 7e-5; and on the
    # packaged damper at its least-squares optimum the test kept ROS2 in 12 % of the intervals, a net loss
    ros2=False,
    derived=(Ratio("x0", "m", "accumulator initial displacement F_pre/k1", "F_pre", "k1"),),
)

FORMS: dict[str, Form] = {f.name: f for f in (NORMALIZED_BOUC_WEN, DAHL, LUGRE, BOUC_WEN, SPENCER)}
