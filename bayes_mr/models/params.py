"""Parameter specifications, record scales and the thesis's log-scaled coordinates.

Every parameter of every model is described by a frozen :class:`ParamSpec`:
its name (the thesis's symbol), unit, sign constraint, a published or thesis
default value, and a *plausible range* expressed relative to the scales of the
record being fitted (:class:`Scales`). Expressing priors relative to the
record is what lets one package meet a 25 N laboratory damper and a 2 kN
prototype without retuning: a Coulomb force is "between 0.1 % and 100 % of
the record's force amplitude", not "between 1 and 100 N".

Estimation coordinates (thesis eqs. 3-37/3-38): a positive parameter θ is
carried as φ = ln(s·θ), where the power of ten ``s`` puts the lower end of its
plausible range in [1, 10) — so φ > 0 across the range, which the thesis's
index of dispersion σ_j = τ·μ_j (3-42) needs. A signed parameter (a force
offset, a drift rate) is carried linearly, φ = s·θ.

A *sign-free* parameter (a positive-looking parameter whose physics allows
either sign, the classic Bouc–Wen γ) over a range that reaches zero or below
is carried on the signed-log coordinate φ = asinh(s·θ): ≈ ±ln(2s|θ|) for
|θ| ≫ 1/s, so both signs get the log scale's resolution over decades (a
linear coordinate over ±100 X⁻² cannot resolve γ = −1100 /m against a range
of 10⁸, nor start least squares on the right side), and linear through zero
within the floor 1/s. The floor is the range's magnitude times the ratio of
the spec's span ends (by default the lower end of the positive span: the
value below which the sign no longer matters), rounded down to a power of
ten like ``s`` of a log parameter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

# Exponents (force, displacement, velocity, duration) of the record scale a
# plausible range is relative to (ParamSpec.dims), named by the unit they give.
F_V = (1, 0, -1, 0)  # N·s/m
F_X = (1, -1, 0, 0)  # N/m
F_ = (1, 0, 0, 0)  # N
PER_X = (0, -1, 0, 0)  # 1/m
PER_X2 = (0, -2, 0, 0)  # 1/m²
ONE = (0, 0, 0, 0)


@dataclass(frozen=True)
class Scales:
    """Characteristic magnitudes of a record, used to place default priors.

    Attributes
    ----------
    force : float
        Force amplitude [N] (device: robust peak of the force about its median;
        structure: storey mass × robust peak absolute acceleration).
    displacement : float
        Displacement amplitude [m] (robust peak).
    velocity : float
        Velocity amplitude [m/s] (robust peak).
    duration : float
        Record length [s].
    """

    force: float
    displacement: float
    velocity: float
    duration: float = 1.0

    def reference(self, dims: tuple[int, int, int, int]) -> float:
        """Reference magnitude F^a · X^b · V^c · T^d for exponents ``dims``."""
        a, b, c, d = dims
        return self.force**a * self.displacement**b * self.velocity**c * self.duration**d


@dataclass(frozen=True)
class ParamSpec:
    """One model parameter.

    Attributes
    ----------
    name : str
        Identifier used on the command line and in results (thesis symbol).
    unit : str
        SI unit.
    description : str
        One line for ``--help`` and reports.
    default : float
        Thesis or published value (used by ``simulate`` when not given).
    dims : tuple of int
        Exponents (force, displacement, velocity, duration) of the record
        scale the plausible range is relative to; zeros for an absolute range.
    span : tuple of float
        Plausible range as multiples of the reference magnitude.
    positive : bool
        Positive parameters are estimated on a log scale; others linearly.
    sign_free : bool
        A parameter whose physics allows either sign though its published
        values are mostly positive: its default range is ±(upper span end),
        carried on the signed-log coordinate asinh(s·θ); a range given with
        lo > 0 keeps it positive on the log scale (see :meth:`Coordinates.build`).
    """

    name: str
    unit: str
    description: str
    default: float
    dims: tuple[int, int, int, int] = (0, 0, 0, 0)
    span: tuple[float, float] = (0.1, 10.0)
    positive: bool = True
    sign_free: bool = False

    def log_scaled(self, lo: float) -> bool:
        """Whether the parameter is estimated on a log scale for a range starting at ``lo``."""
        return self.positive and not (self.sign_free and lo <= 0)

    def signed_log(self, lo: float) -> bool:
        """Whether the parameter is carried as asinh(s·θ) for a range starting at ``lo`` (sign-free, lo ≤ 0)."""
        return self.sign_free and lo <= 0

    def plausible(self, scales: Scales | None) -> tuple[float, float]:
        """Plausible range [lo, hi] in SI units for a record with ``scales``.

        For a signed or sign-free parameter the range is symmetric,
        ±hi·reference. Without scales the range is placed around :attr:`default`.
        """
        lo, hi = self.span
        if scales is None:
            ref = abs(self.default) if self.default != 0 else 1.0
            if self.positive:
                mid = math.sqrt(lo * hi)
                lo, hi = lo / mid, hi / mid
        else:
            ref = scales.reference(self.dims)
        if self.positive and not self.sign_free:
            return lo * ref, hi * ref
        return -hi * ref, hi * ref


@dataclass(frozen=True)
class Ratio:
    """A reported parameter that is the ratio of two estimated ones, ``name = numerator / denominator``.

    A model whose data determine a product better than its factors carries
    the product as the estimated parameter and reports the factor it
    replaced as this ratio, with its spread taken from the draws (Spencer's
    accumulator: the preload ``F_pre = k1·x0`` is estimated, ``x0 = F_pre/k1``
    reported). The ratio is also accepted as an input name wherever the
    denominator is given with it (:meth:`~bayes_mr.models.model.Model.canonical`).

    Attributes
    ----------
    name, unit, description : str
        The reported parameter (its contract name, SI unit, one line).
    numerator, denominator : str
        Names of the estimated parameters it is computed from.
    """

    name: str
    unit: str
    description: str
    numerator: str
    denominator: str


@dataclass(frozen=True)
class Coordinates:
    """Map between natural parameters θ (SI) and estimation coordinates φ.

    Attributes
    ----------
    names : tuple of str
        Free parameter names, in order.
    scale : ndarray, shape (p,)
        The thesis's power-of-ten factors s_j.
    log : ndarray of bool, shape (p,)
        True where φ_j = ln(s_j θ_j), False where φ_j = s_j θ_j (or asinh).
    lower, upper : ndarray, shape (p,)
        Plausible range of θ [SI] (used for LHS priors and sanity bounds).
    units : tuple of str
    asinh : ndarray of bool, shape (p,), optional
        True where φ_j = asinh(s_j θ_j) (sign-free parameters over a range
        reaching zero or below); all False when not given.
    """

    names: tuple[str, ...]
    scale: np.ndarray
    log: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    units: tuple[str, ...] = field(default=())
    asinh: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.asinh is None:  # frozen: the default is set once, here
            object.__setattr__(self, "asinh", np.zeros(len(self.names), bool))

    @classmethod
    def build(cls, specs: tuple[ParamSpec, ...], ranges: dict[str, tuple[float, float]]) -> "Coordinates":
        """Coordinates for ``specs`` with plausible ``ranges`` (name → (lo, hi))."""
        scale, lower, upper = [], [], []
        for spec in specs:
            lo, hi = ranges[spec.name]
            if spec.log_scaled(lo):
                if not (0 < lo < hi):
                    raise ValueError(f"parameter '{spec.name}': range must satisfy 0 < lo < hi, got {lo}, {hi}")
                floor = lo
            else:
                if not lo < hi:
                    raise ValueError(f"parameter '{spec.name}': range must satisfy lo < hi, got {lo}, {hi}")
                floor = max(abs(lo), abs(hi))
                if spec.signed_log(lo):  # the resolution floor of asinh: the span's ratio below the magnitude
                    floor *= spec.span[0] / spec.span[1]
            scale.append(10.0 ** (-math.floor(math.log10(floor))))
            lower.append(lo)
            upper.append(hi)
        return cls(
            names=tuple(s.name for s in specs),
            scale=np.array(scale, float),
            log=np.array([s.log_scaled(ranges[s.name][0]) for s in specs], bool),
            lower=np.array(lower, float),
            upper=np.array(upper, float),
            units=tuple(s.unit for s in specs),
            asinh=np.array([s.signed_log(ranges[s.name][0]) for s in specs], bool),
        )

    @property
    def code(self) -> np.ndarray:
        """Coordinate of each parameter for compiled kernels: 0 linear, 1 log, 2 asinh (int8, shape (p,))."""
        return np.where(self.asinh, 2, np.where(self.log, 1, 0)).astype(np.int8)

    @property
    def log_like(self) -> np.ndarray:
        """True where φ is log-like (log or asinh): box margins in decades apply there."""
        return self.log | self.asinh

    def to_phi(self, theta: np.ndarray) -> np.ndarray:
        """θ (..., p) in SI → φ (..., p). Non-positive θ of a log parameter gives NaN."""
        theta = np.asarray(theta, float)
        with np.errstate(divide="ignore", invalid="ignore"):
            logged = np.log(self.scale * np.where(theta > 0, theta, np.nan))
        st = self.scale * theta
        return np.where(self.log, logged, np.where(self.asinh, np.arcsinh(st), st))

    def to_theta(self, phi: np.ndarray) -> np.ndarray:
        """φ (..., p) → θ (..., p) in SI."""
        phi = np.asarray(phi, float)
        with np.errstate(over="ignore"):
            return np.where(self.log, np.exp(phi), np.where(self.asinh, np.sinh(phi), phi)) / self.scale

    def dtheta_dphi(self, phi: np.ndarray) -> np.ndarray:
        """dθ/dφ per coordinate (..., p) [SI per unit φ]: e^φ/s, cosh(φ)/s or 1/s (delta-method SDs)."""
        phi = np.asarray(phi, float)
        with np.errstate(over="ignore"):
            return np.where(self.log, np.exp(phi), np.where(self.asinh, np.cosh(phi), 1.0)) / self.scale

    def jacobian_log_det(self, phi: np.ndarray) -> np.ndarray:
        """ln |dθ/dφ| (for densities moved between coordinates)."""
        phi = np.asarray(phi, float)
        # ln cosh φ = |φ| + ln(1 + e^{−2|φ|}) − ln 2, stable for large |φ|
        ln_cosh = np.abs(phi) + np.log1p(np.exp(-2.0 * np.abs(phi))) - math.log(2.0)
        return np.sum(np.where(self.log, phi, np.where(self.asinh, ln_cosh, 0.0)) - np.log(self.scale), axis=-1)

    @property
    def phi_lower(self) -> np.ndarray:
        return self.to_phi(self.lower)

    @property
    def phi_upper(self) -> np.ndarray:
        return self.to_phi(self.upper)
