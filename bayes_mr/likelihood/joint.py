"""One likelihood over several records: shared physical parameters, the log-likelihood summed.

A test matrix (sine tests at several amplitudes, frequencies and currents)
identifies what no single record does — the current dependence of
``spencer``'s ``alpha``, ``c0``, ``c1`` from constant-current tests, say. The
records are independent tests of one device, so

    ln p(y_1, …, y_R | θ, σ) = Σ_r ln p(y_r | θ, σ_r),

each term the output-error likelihood of one record
(:class:`~bayes_mr.likelihood.output_error.OutputError`) with its own initial
state (every simulation starts from rest at the record's first sample), its
own noise SDs σ_r (a noise floor per record: a test at 1 A has another force
level than one at 0 A), quality mask, residual model (iid, or AR orders chosen
on that record's residual) and input and command interpolation. The physical
parameters θ are shared; the prior box is placed from the largest amplitude
and longest duration of any record (:func:`joint_scales`), so it holds each record's.

The parameter vector is x = [φ, ln σ_1, …, ln σ_R] (the noise part only when
sampled), σ_r one SD per measured channel of record r; with one record it is
that record's x, and every number is that record's.

Per-record force offsets (``record_offsets=True``): a test's load cell is zeroed
before each test, and an accumulator's preload moves with the rig's set-up, so a
constant force offset is a property of the test, not of the device. Each record r
then gets its own additive offset ``f0[r]`` [N] (the ``force_offset`` effect's
``f0``, one per record; the label is the record's index, as ``sigma_<channel>[r]``'s),
a nuisance estimated with the shared parameters: x = [φ, f0[0], …, f0[R−1], ln σ…]
(one record's is labelled ``f0``, as its noise SD is ``sigma_<channel>``).
Each record's likelihood is that of ``MODEL+force_offset`` with its f0 taken from
x; its prior is flat over ±1 × that record's own force scale (the 99th-percentile
|F − median F| of :func:`~bayes_mr.likelihood.output_error.record_scales`: the
``force_offset`` effect's plausible range on that record alone). With one record
this is exactly that record's ``MODEL+force_offset`` likelihood.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import xarray as xr

from dataclasses import dataclass

from bayes_mr.likelihood.noise_model import ResidualModel
from bayes_mr.likelihood.output_error import OutputError, Parameterisation, record_scales
from bayes_mr.models import FORCE_OFFSET, Model, Scales, get_model
from bayes_mr.models.params import Coordinates

#: The force offset's parameter (``force_offset``'s ``f0``); record r's is labelled ``f0[r]``.
OFFSET = FORCE_OFFSET.params[0].name


def offset_label(r: int) -> str:
    """The label of record r's force offset in a joint fit's parameters: ``f0[r]``."""
    return f"{OFFSET}[{r}]"


def joint_scales(records: Sequence[xr.Dataset]) -> Scales:
    """Prior scales of a set of records: the largest force, displacement and velocity, the longest duration.

    The plausible ranges are wide multiples of these (:mod:`bayes_mr.models.params`); the largest
    amplitudes keep every record's parameters inside, and one record's scales are its own.
    """
    each = [record_scales(r) for r in records]
    if len(each) == 1:
        return each[0]
    return Scales(force=max(s.force for s in each), displacement=max(s.displacement for s in each),
                  velocity=max(s.velocity for s in each), duration=max(s.duration for s in each))


@dataclass(frozen=True)
class OffsetParameterisation:
    """The joint coordinates of shared parameters and per-record offsets, φ = [φ_shared, f0[0] …].

    Reads as a :class:`~bayes_mr.likelihood.output_error.Parameterisation` where the engines and results read
    one (``names``, ``coords``, ``model``, ``kind``); :meth:`full` and :meth:`full_theta` give the *shared*
    model's full θ (the offsets dropped: each record's own θ is
    :meth:`JointLikelihood.record_theta`).
    """

    shared: Parameterisation
    coords: Coordinates

    @property
    def model(self) -> Model:
        return self.shared.model

    @property
    def kind(self) -> str:
        return self.shared.kind

    @property
    def names(self) -> tuple[str, ...]:
        return self.coords.names

    @property
    def template(self) -> np.ndarray:
        return self.shared.template

    @property
    def free_idx(self) -> np.ndarray:
        return self.shared.free_idx

    def full(self, phi: np.ndarray) -> np.ndarray:
        """The shared model's full θ (..., n_full) from the joint φ (..., p + R) [SI]."""
        return self.shared.full(np.asarray(phi, float)[..., : len(self.shared.names)])

    def full_theta(self, theta: np.ndarray) -> np.ndarray:
        """The shared model's full θ (..., n_full) from the joint free θ (..., p + R) [SI]."""
        return self.shared.full_theta(np.asarray(theta, float)[..., : len(self.shared.names)])


def offset_labels(n: int) -> tuple[str, ...]:
    """The offsets' labels of a set of n records: ``f0[r]``, or ``f0`` for one (as the noise SDs are labelled)."""
    return (OFFSET,) if n == 1 else tuple(offset_label(r) for r in range(n))


def _joined_coords(shared: Coordinates, parts: list[OutputError]) -> Coordinates:
    """The shared coordinates followed by each record's offset coordinate (its own range and scale)."""
    j = [p.par.names.index(OFFSET) for p in parts]
    cat = lambda a, attr: np.concatenate([a] + [getattr(p.par.coords, attr)[[k]] for p, k in zip(parts, j)])
    return Coordinates(names=shared.names + offset_labels(len(parts)),
                       scale=cat(shared.scale, "scale"), log=cat(shared.log, "log"),
                       lower=cat(shared.lower, "lower"), upper=cat(shared.upper, "upper"),
                       units=tuple(shared.units) + tuple(p.par.coords.units[k] for p, k in zip(parts, j)),
                       asinh=cat(shared.asinh, "asinh"))


class JointLikelihood:
    """Output-error log-posterior of a model over several records, batched over x (module docstring).

    Parameters
    ----------
    model : Model or str
    records : sequence of xarray.Dataset
        Records of one kind measuring the same output channels (a
        :class:`~bayes_mr.data.records.RecordSet` is one; its files, roles and
        conditions are then kept in :attr:`about`).
    ranges, fixed, noise, residual, input_interp, command_interp
        As :class:`~bayes_mr.likelihood.output_error.OutputError`, the same for every record
        (``ranges`` may also hold ``f0[r]``: record r's offset range [N]).
    record_offsets : bool, optional
        A force offset ``f0[r]`` per record (module docstring); default: the set's
        :attr:`~bayes_mr.data.records.RecordSet.record_offsets` (off for a list of records).

    Attributes
    ----------
    parts : list of OutputError
        One likelihood per record, sharing the parameterisation.
    about : list of dict
        Per record: ``file``, ``role`` and ``conditions`` (what the results report of each record).
    index : list of ndarray of int
        Per record: the positions in the joint φ of its likelihood's φ (the identity without offsets).
    """

    def __init__(self, model: Model | str, records: Sequence[xr.Dataset], *, ranges: dict | None = None,
                 fixed: dict | None = None, noise: str = "sampled", residual: str | ResidualModel = "iid",
                 input_interp: str = "auto", command_interp: str = "auto", record_offsets: bool | None = None):
        about = records.describe() if hasattr(records, "describe") else None
        if record_offsets is None:
            record_offsets = bool(getattr(records, "record_offsets", False))
        records = list(records)
        self.about = about or [{"file": str(r.attrs.get("source", "")), "role": "train", "conditions": {}}
                               for r in records]
        if not records:
            raise ValueError("a joint likelihood needs at least one record")
        model = get_model(model)
        scales = joint_scales(records)
        self.record_offsets = bool(record_offsets)
        shared_ranges = {k: v for k, v in (ranges or {}).items() if not k.startswith(f"{OFFSET}[")}
        if self.record_offsets:
            if model.effect("force_offset") is not None:
                raise ValueError(f"{model.name} with per-record offsets: each record's f0[r] is its force offset — "
                                 "drop +force_offset from the model or the record offsets")
            if any(r.attrs["kind"] != "device" for r in records):
                raise ValueError("per-record force offsets are for device tests (the force is what is measured)")
            part_model = model + FORCE_OFFSET
            own = [{**shared_ranges, OFFSET: (ranges or {}).get(
                offset_label(r), FORCE_OFFSET.params[0].plausible(record_scales(rec)))} for r, rec in enumerate(records)]
        else:
            part_model, own = model, [ranges] * len(records)
        self.parts = [OutputError(part_model, r, ranges=rng, fixed=fixed, noise=noise, scales=scales,
                                  residual=residual, input_interp=input_interp, command_interp=command_interp)
                      for r, rng in zip(records, own)]
        first = self.parts[0]
        for part in self.parts[1:]:
            src = part.record.attrs.get("source", "record")
            if part.kind != first.kind or part.channels != first.channels:
                raise ValueError(f"{src}: a {part.kind} test measuring {', '.join(part.channels)}; the first record is a "
                                 f"{first.kind} test measuring {', '.join(first.channels)} — a joint fit needs records "
                                 "of one kind with the same output channels")
            if part.par.names != first.par.names or part.fixed != first.fixed:
                raise ValueError(f"{src}: other free or fixed parameters than the first record's "
                                 f"({', '.join(part.par.names)}) — give every record the same mass")
        self.kind, self.channels, self.fixed, self.scales = first.kind, first.channels, first.fixed, scales
        self.noise = noise
        if self.record_offsets:
            shared = Parameterisation.build(model, self.kind, scales, ranges=shared_ranges, fixed=first.fixed)
            self.model, self.ranges = model, {k: v for k, v in first.ranges.items() if k != OFFSET}
            self.par = OffsetParameterisation(shared, _joined_coords(shared.coords, self.parts))
            p = len(shared.names)
            self.index = [np.array([p + r if n == OFFSET else shared.names.index(n) for n in part.par.names])
                          for r, part in enumerate(self.parts)]
            self.phi_lo, self.phi_hi = self.par.coords.phi_lower, self.par.coords.phi_upper
        else:
            self.model, self.par, self.ranges = first.model, first.par, first.ranges
            self.index = [np.arange(len(first.par.names))] * len(self.parts)
            self.phi_lo, self.phi_hi = first.phi_lo, first.phi_hi
        # the same floating-point steps as OutputError's constant, so one record's prior is its own to the bit
        const = -float(np.sum(np.log(self.phi_hi - self.phi_lo)))
        if noise == "sampled":
            for part in self.parts:
                const -= float(np.sum(part.log_sigma_hi - part.log_sigma_lo))
        self._log_prior_const = const

    # --- dimensions and names ---------------------------------------------------------
    @property
    def records(self) -> list[xr.Dataset]:
        return [p.record for p in self.parts]

    @property
    def n_params(self) -> int:
        return len(self.par.names)

    @property
    def offset_names(self) -> tuple[str, ...]:
        """The per-record offsets' labels ``f0[r]`` in φ's order (``f0`` for one record, whose offset is its
        ``MODEL+force_offset``'s; empty without record offsets)."""
        return offset_labels(len(self.parts)) if self.record_offsets else ()

    def part_phi(self, phi: np.ndarray, r: int) -> np.ndarray:
        """Record r's φ (..., p_r) from the joint φ (..., p): the shared parameters and its own offset."""
        phi = np.asarray(phi, float)
        return phi[..., self.index[r]] if self.record_offsets else phi

    def scatter(self, J: np.ndarray, r: int) -> np.ndarray:
        """Record r's Jacobian (n, p_r) by its φ as one by the joint φ (n, p): zeros at the other offsets."""
        if not self.record_offsets:
            return J
        out = np.zeros((J.shape[0], self.n_params))
        out[:, self.index[r]] = J
        return out

    def record_model(self, r: int) -> Model:
        """The model record r is simulated with (``MODEL+force_offset`` with record offsets)."""
        return self.parts[r].model

    def record_theta(self, phi: np.ndarray, r: int) -> np.ndarray:
        """Record r's full θ [SI] of :meth:`record_model` from the joint φ."""
        return self.parts[r].par.full(self.part_phi(phi, r))

    def offsets(self, phi: np.ndarray) -> np.ndarray:
        """The records' force offsets f0[r] [N] at the joint φ (..., R) (empty without record offsets)."""
        if not self.record_offsets:
            return np.zeros(np.shape(phi)[:-1] + (0,))
        return self.par.coords.to_theta(np.asarray(phi, float))[..., -len(self.parts):]

    @property
    def n_sigma(self) -> int:
        """Sampled noise SDs: one per channel and record (0 when the noise is fixed)."""
        return len(self.channels) * len(self.parts) if self.noise == "sampled" else 0

    @property
    def ndim(self) -> int:
        return self.n_params + self.n_sigma

    @property
    def noise_labels(self) -> tuple[str, ...]:
        """The noise SDs' labels in x's order: ``channel`` for one record, ``channel[r]`` for several."""
        if len(self.parts) == 1:
            return tuple(self.channels)
        return tuple(f"{c}[{r}]" for r in range(len(self.parts)) for c in self.channels)

    @property
    def names(self) -> tuple[str, ...]:
        extra = tuple(f"sigma_{c}" for c in self.noise_labels) if self.noise == "sampled" else ()
        return self.par.names + extra

    @property
    def n_valid(self) -> int:
        return int(sum(p.n_valid for p in self.parts))

    @property
    def noise_sd(self) -> np.ndarray:
        """Every record's noise floor σ_r, concatenated in x's order [channel units]."""
        return np.concatenate([p.noise_sd for p in self.parts])

    @property
    def log_sigma_lo(self) -> np.ndarray:
        return np.concatenate([p.log_sigma_lo for p in self.parts])

    @property
    def log_sigma_hi(self) -> np.ndarray:
        return np.concatenate([p.log_sigma_hi for p in self.parts])

    @property
    def lower(self) -> np.ndarray:
        return np.concatenate([self.phi_lo, self.log_sigma_lo]) if self.noise == "sampled" else self.phi_lo

    @property
    def upper(self) -> np.ndarray:
        return np.concatenate([self.phi_hi, self.log_sigma_hi]) if self.noise == "sampled" else self.phi_hi

    def part_x(self, x: np.ndarray, r: int) -> np.ndarray:
        """Record r's parameter vector [φ, ln σ_r] (B, p + C) from the joint x (B, ndim)."""
        x = np.atleast_2d(np.asarray(x, float))
        phi = self.part_phi(x[:, : self.n_params], r)
        if self.noise != "sampled":
            return phi
        c = len(self.channels)
        lo = self.n_params + r * c
        return np.concatenate([phi, x[:, lo: lo + c]], axis=1)

    def joint_x(self, phi: np.ndarray, sigma: np.ndarray) -> np.ndarray:
        """The joint x from φ (p,) and every record's σ (R·C,) [channel units]."""
        phi = np.asarray(phi, float)
        return np.concatenate([phi, np.log(sigma)]) if self.noise == "sampled" else phi

    # --- densities ----------------------------------------------------------------------
    def log_prior(self, x: np.ndarray) -> np.ndarray:
        """ln p(x): uniform in φ over the plausible box, log-uniform σ_r per record, −inf outside."""
        x = np.atleast_2d(np.asarray(x, float))
        inside = np.all((x >= self.lower) & (x <= self.upper), axis=1)
        return np.where(inside, self._log_prior_const, -np.inf)

    def log_likelihood(self, x: np.ndarray, *, pointwise: bool = False):
        """Σ_r ln p(y_r | x) for each row of x (B,); with ``pointwise`` also each record's terms (a list)."""
        x = np.atleast_2d(np.asarray(x, float))
        if pointwise:
            each = [p.log_likelihood(self.part_x(x, r), pointwise=True) for r, p in enumerate(self.parts)]
            return self._sum([t for t, _ in each]), [terms for _, terms in each]
        return self._sum([p.log_likelihood(self.part_x(x, r)) for r, p in enumerate(self.parts)])

    def per_record(self, x: np.ndarray) -> np.ndarray:
        """ln p(y_r | x) of each record, shape (B, R): what leaving one record out removes."""
        x = np.atleast_2d(np.asarray(x, float))
        return np.stack([p.log_likelihood(self.part_x(x, r)) for r, p in enumerate(self.parts)], axis=1)

    @staticmethod
    def _sum(terms: list[np.ndarray]) -> np.ndarray:
        total = terms[0]  # one record: its own array, not a sum with zero
        for t in terms[1:]:
            total = total + t
        return total

    #: ln posterior (unnormalised) of each row of x, vectorised for emcee: one record's rule, on the sum
    __call__ = OutputError.__call__

    def residuals(self, phi: np.ndarray, sd: np.ndarray | None = None) -> np.ndarray:
        """Every record's standardised residuals (:meth:`OutputError.residuals`), stacked record by record.

        ``sd`` (R·C,) weights record r's channels by ``sd[r·C:(r+1)·C]``; default each record's noise floor.
        """
        c = len(self.channels)
        return np.concatenate([p.residuals(self.part_phi(phi, r),
                                           None if sd is None else np.asarray(sd, float)[r * c:(r + 1) * c])
                               for r, p in enumerate(self.parts)])
