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
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import xarray as xr

from bayes_mr.likelihood.noise_model import ResidualModel
from bayes_mr.likelihood.output_error import OutputError, record_scales
from bayes_mr.models import Model, Scales, get_model


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
        As :class:`~bayes_mr.likelihood.output_error.OutputError`, the same for every record.

    Attributes
    ----------
    parts : list of OutputError
        One likelihood per record, sharing the parameterisation.
    about : list of dict
        Per record: ``file``, ``role`` and ``conditions`` (what the results report of each record).
    """

    def __init__(self, model: Model | str, records: Sequence[xr.Dataset], *, ranges: dict | None = None,
                 fixed: dict | None = None, noise: str = "sampled", residual: str | ResidualModel = "iid",
                 input_interp: str = "auto", command_interp: str = "auto"):
        about = records.describe() if hasattr(records, "describe") else None
        records = list(records)
        self.about = about or [{"file": str(r.attrs.get("source", "")), "role": "train", "conditions": {}}
                               for r in records]
        if not records:
            raise ValueError("a joint likelihood needs at least one record")
        model = get_model(model)
        scales = joint_scales(records)
        self.parts = [OutputError(model, r, ranges=ranges, fixed=fixed, noise=noise, scales=scales,
                                  residual=residual, input_interp=input_interp, command_interp=command_interp)
                      for r in records]
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
        self.model, self.kind, self.par = first.model, first.kind, first.par
        self.channels, self.fixed, self.ranges, self.scales = first.channels, first.fixed, first.ranges, scales
        self.noise = noise
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
        if self.noise != "sampled":
            return x[:, : self.n_params]
        c = len(self.channels)
        lo = self.n_params + r * c
        return np.concatenate([x[:, : self.n_params], x[:, lo: lo + c]], axis=1)

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
        return np.concatenate([p.residuals(phi, None if sd is None else np.asarray(sd, float)[r * c:(r + 1) * c])
                               for r, p in enumerate(self.parts)])
