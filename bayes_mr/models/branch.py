"""The hysteretic state on a loading branch: where each form's law holds it at its saturation at any velocity.

:func:`on_branch` tells the driver (:func:`bayes_mr.models.drivers._integrate`) that an interval may hold the
state there (:data:`bayes_mr.models.integrate.BRANCH` mode); :func:`saturation` is where, and
:func:`branch_state` which state.
"""

from __future__ import annotations

import math

from bayes_mr._compile.jit import hot
from bayes_mr.models.kernel import (
    BW, K_BRANCH, L_FORM, L_LVR, L_PFORM, L_SFORM, L_TP, LUGRE, N_TERMS, SPENCER,
)


#: How close to its saturation z_s the hysteretic state must be, relative, for :func:`on_branch`: the interval
#: ends with the state set to z_s, which moves the hysteretic force by at most this share, below the error of the
#: default step control (1e-5 to 1e-3 of the force's SD against the reference simulator).
BRANCH_TOL = 1e-5


@hot(inline="always")
def branch_state(lay):
    """Index in the states of the hysteretic state :func:`on_branch` looks at (spencer's z, the others' z or r)."""
    if lay[L_FORM] == SPENCER:
        return lay[L_SFORM] + 1
    return lay[L_SFORM]


@hot(inline="always")
def saturation(lay, p):
    """|z| where a form's loading branch (the state moving with its driving velocity) holds it at any velocity:
    spencer (A/(γ+β))^{1/n}, Bouc–Wen (β₁+γ)^{−1/n} (none, ∞, where β₁ + γ ≤ 0: a hardening loop grows without
    a bound), LuGre 1/α, Dahl and the normalized Bouc–Wen 1."""
    form = lay[L_FORM]
    o = lay[L_PFORM]
    if form == SPENCER:
        return math.pow(p[o + 11] / (p[o + 9] + p[o + 10]), 1.0 / p[o + 12])
    if form == BW:
        bg = p[o + 2] + p[o + 3]
        return math.pow(1.0 / bg, 1.0 / p[o + 4]) if bg > 0.0 else math.inf
    if form == LUGRE:
        return 1.0 / p[o + 4]
    return 1.0


@hot(inline="always")
def on_branch(lay, cst, p, s, ds, xd):
    """True when the hysteretic state sits on a loading branch at its saturation.

    On a loading branch (r·z > 0, r the velocity that drives the law: spencer's ẋ − ẏ, the others' ẋ) every
    form's law is r·g(|z|) with g(z_s) = 0 at the saturation :func:`saturation` (spencer's
    ż = r(A − (γ+β)|z|ⁿ), Bouc–Wen's ṙ = ẋ(1 − (β₁+γ)|r|ⁿ), LuGre's ż = ẋ(1 − α|z|), Dahl's ż = σẋ(1 − |z|),
    the normalized Bouc–Wen's ż = ρẋ(1 − |z|ⁿ)): a fixed point for every r, command and field, where the state
    stays exactly while the piston moves however fast. So an interval that starts and ends on the branch is
    integrated with z held at z_s (:mod:`bayes_mr.models.integrate`, mode ``BRANCH``) and the rest of the states
    at their own pace. ``ds`` holds the rates at ``s``, ``xd`` is ẋ there [m/s]. False when the simulation's
    constant ``K_BRANCH`` is 0, with ``low_velocity_rolloff`` (its series dashpot moves the driving velocity with
    the force) and when a library term changes ż (its fixed point is then elsewhere).
    """
    if cst[K_BRANCH] == 0.0 or lay[L_LVR] >= 0:
        return False
    for j in range(N_TERMS):
        if lay[L_TP + j] >= 0:
            return False
    z = s[branch_state(lay)]
    r = xd - ds[lay[L_SFORM]] if lay[L_FORM] == SPENCER else xd
    if r * z <= 0.0:
        return False
    return abs(z) >= (1.0 - BRANCH_TOL) * saturation(lay, p)
