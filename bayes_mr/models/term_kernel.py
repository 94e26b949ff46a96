"""Compiled basis functions of the library terms (:mod:`bayes_mr.models.terms`), read by the kernel.

A term's integer code packs up to three factor codes (``TF_*``, base 16) and
its target (``TERM_*``, × 4096); :func:`term_basis` multiplies the factors at
the current state, and :func:`bayes_mr.models.kernel.deriv` adds θ·b to the
damper force or to the hysteretic-state rate.
"""

from __future__ import annotations

from bayes_mr._compile.jit import hot

# --- library-term codes: code = f1 + 16·f2 + 256·f3 + 4096·target ------------------
# factor codes (0 = absent, i.e. 1): the states and inputs the basis multiplies
TF_X, TF_XD, TF_Z, TF_U, TF_UL, TF_AX, TF_AXD, TF_AZ, TF_SX, TF_SXD, TF_SZ = range(1, 12)
TERM_FORCE, TERM_LAW = 0, 1  # target: added to the damper force, or to the hysteretic-state rate ż


@hot(inline="always")
def _factor(c, x, xd, z, u, ul):
    """Factor code ``c`` (TF_*) of a library term at (x, ẋ, z, command u, lagged command)."""
    if c == 0:
        return 1.0
    if c == TF_X:
        return x
    if c == TF_XD:
        return xd
    if c == TF_Z:
        return z
    if c == TF_U:
        return u
    if c == TF_UL:
        return ul
    if c == TF_AX:
        return abs(x)
    if c == TF_AXD:
        return abs(xd)
    if c == TF_AZ:
        return abs(z)
    if c == TF_SX:
        return 1.0 if x > 0.0 else (-1.0 if x < 0.0 else 0.0)
    if c == TF_SXD:
        return 1.0 if xd > 0.0 else (-1.0 if xd < 0.0 else 0.0)
    return 1.0 if z > 0.0 else (-1.0 if z < 0.0 else 0.0)


@hot(inline="always")
def term_basis(code, x, xd, z, u, ul):
    """Basis value b of a library-term ``code`` (its three factors' product; the target bits ignored)."""
    return (_factor(code % 16, x, xd, z, u, ul) * _factor((code // 16) % 16, x, xd, z, u, ul)
            * _factor((code // 256) % 16, x, xd, z, u, ul))
