"""One place that turns (model, record) into a log-density of θ.

The output-error likelihood: the model is simulated from rest under the
record's inputs and compared with the measured channels (``channels``: those
the record has of structure test: displacement and absolute acceleration;
forced test: displacement, velocity, acceleration; device test: force), with
independent Gaussian errors of standard deviation σ_c per channel, over the
samples quality control left valid:

    ln p(y | θ, σ) = Σ_c Σ_{i valid} ln N(y_{c,i}; ŷ_{c,i}(θ), σ_c²)

Priors: uniform on the estimation coordinates φ over each parameter's
plausible range (log-uniform in θ for positive parameters, thesis 3-37), and
log-uniform σ_c on [1e-4, 1] × SD(y_c) when the noise is sampled. Both are
proper, so the evidence ∫ p(y|θ,σ) p(θ) p(σ) dθ dσ is defined; the σ prior
is the same for every model fitted to the same record.

Residuals of a measured record are autocorrelated (model error and the
response to input noise are smooth in time); with independent errors and
thousands of samples the posterior is narrower than the model error
justifies. ``residual="ar"`` replaces the independent errors of each channel
by an AR(p_c) process with profiled coefficients and σ_c its innovation SD
(:mod:`bayes_mr.likelihood.noise_model`: conditional likelihood, restarted after masked
gaps; p_c chosen by BIC on the residual of a first iid fit). The default,
``"iid"``, is the density above.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr

from bayes_mr.data.schema import outputs_of
from bayes_mr.models import Model, Scales, get_model
from bayes_mr.models.params import Coordinates
from bayes_mr.likelihood.noise_model import ResidualModel, select_orders
from bayes_mr.likelihood.noise_model import log_density as ar_log_density
from bayes_mr.likelihood.noise_model import whiten as ar_whiten
from bayes_mr.simulation.simulate import Inputs, Simulation, simulate

LOG_2PI = float(np.log(2 * np.pi))
#: Sampled noise SD prior: log-uniform on these multiples of each channel's SD.
SIGMA_SPAN = (1e-4, 1.0)

#: Largest batch of :meth:`OutputError.log_likelihood` simulated at once [rows × samples]. Measured: 4000
#: dahl draws, 30 s at 1 kHz, took 16.8 s in one batch (~2 GB of trajectories), 4.1 s in batches of ≤ 1000.
CHUNK_SAMPLES = 2_000_000


def record_scales(record: xr.Dataset) -> Scales:
    """Force, displacement and velocity amplitudes of a record (robust peaks), from what it measures.

    A channel the record lacks is reached from the nearest one it has: by
    differentiation (displacement → velocity → acceleration), or by dividing
    by the acceleration's (velocity's) dominant angular frequency ω_c (the
    amplitude-weighted median of its spectrum) — so an accelerometer-only
    record gets X ≈ A/ω_c², V ≈ A/ω_c. The force scale is the damper force
    (device), m × peak absolute acceleration (structure), or the peak applied
    force (forced). These are prior scales: a factor of two does not matter.
    """
    valid = record["valid"].values.astype(bool) if "valid" in record else np.ones(record.sizes["time"], bool)

    def peak(values):
        v = np.asarray(values)[valid]
        return float(np.percentile(np.abs(v - np.median(v)), 99))

    dt = float(record.attrs["dt"])
    kind = record.attrs["kind"]
    if kind == "device":
        x = peak(record["displacement"].values)
        f = peak(record["force"].values)
        v = peak(record["velocity"].values) if "velocity" in record else peak(
            np.gradient(record["displacement"].values, dt))
    else:
        x, v, acc = _motion_peaks(record, peak, dt)
        if kind == "structure":
            f = float(record.attrs["mass"]) * acc
        else:
            f = peak(record["applied_force"].values)
    duration = dt * record.sizes["time"]
    for name, value in (("force", f), ("displacement", x), ("velocity", v)):
        if not value > 0:
            raise ValueError(f"{record.attrs.get('source', 'record')}: {name} amplitude is zero — nothing to identify")
    return Scales(force=f, displacement=x, velocity=v, duration=duration)


def _motion_peaks(record: xr.Dataset, peak, dt: float) -> tuple[float, float, float]:
    """Peaks of displacement, velocity and absolute acceleration of a structure or forced test."""
    x = record["displacement"].values if "displacement" in record else None
    v = record["velocity"].values if "velocity" in record else None
    if "acceleration" in record:
        a = record["acceleration"].values
        # a structure test's motion is relative: the accelerometer reads ẍ + ẍ_g
        rel = a - record["ground_acceleration"].values if record.attrs["kind"] == "structure" else a
    else:
        rel = None
    if x is None and v is None:
        w = _dominant_omega(rel, dt)
        return peak(rel) / w**2, peak(rel) / w, peak(a)
    if x is None:
        w = _dominant_omega(v, dt)
        x_pk, v_pk = peak(v) / w, peak(v)
    else:
        v_pk = peak(v) if v is not None else peak(np.gradient(x, dt))
        x_pk = peak(x)
    if rel is not None:
        return x_pk, v_pk, peak(a)
    base = record["ground_acceleration"].values if record.attrs["kind"] == "structure" else 0.0
    xdd = np.gradient(v, dt) if v is not None else np.gradient(np.gradient(x, dt), dt)
    return x_pk, v_pk, peak(xdd + base)


def _dominant_omega(y: np.ndarray, dt: float) -> float:
    """Amplitude-weighted median angular frequency [rad/s] of ``y``'s spectrum (the mean removed)."""
    amp = np.abs(np.fft.rfft(y - np.mean(y)))
    f = np.fft.rfftfreq(y.size, dt)
    amp[0] = 0.0
    c = np.cumsum(amp)
    if not c[-1] > 0:
        return 2 * np.pi * f[1]
    return 2 * np.pi * max(float(f[np.searchsorted(c, 0.5 * c[-1])]), f[1])


def channel_noise(record: xr.Dataset, channels: tuple[str, ...]) -> np.ndarray:
    """Measurement-noise standard deviation of each channel [channel units].

    From the record's ``noise_sd_<channel>`` attribute (simulated records; a
    measured record after a noise-floor estimate), else estimated by
    :func:`bayes_mr.data.noise_floor.noise_floor` (quiet segment, else differencing).
    """
    out = []
    missing = [c for c in channels if f"noise_sd_{c}" not in record.attrs]
    floor = {}
    if missing:
        from bayes_mr.data.noise_floor import noise_floor

        floor = noise_floor(record, channels=missing)
    for c in channels:
        sd = record.attrs.get(f"noise_sd_{c}", floor.get(c))
        if sd is None or not np.isfinite(sd) or sd <= 0:
            sd = 1e-3 * float(np.std(record[c].values))
        out.append(float(sd))
    return np.array(out)


@dataclass(frozen=True)
class Parameterisation:
    """Free parameters of (model, kind) and their estimation coordinates.

    Attributes
    ----------
    model : Model
    kind : str
    coords : Coordinates
        Free parameters (fixed ones excluded) and their plausible ranges.
    template : ndarray
        Full θ with fixed parameters at their values.
    free_idx : ndarray of int
        Positions of the free parameters in the full θ.
    """

    model: Model
    kind: str
    coords: Coordinates
    template: np.ndarray
    free_idx: np.ndarray

    @classmethod
    def build(
        cls,
        model: Model | str,
        kind: str,
        scales: Scales,
        *,
        ranges: dict[str, tuple[float, float]] | None = None,
        fixed: dict[str, float] | None = None,
    ) -> "Parameterisation":
        model = get_model(model)
        fixed = model.canonical(fixed)  # a derived name (spencer's x0, with k1) fixes what it stands for
        template = model.theta(kind, fixed)
        names = model.param_names(kind)
        free = [i for i in model.free_index(kind) if names[i] not in fixed]
        specs = [s for s in model.free_specs(kind) if s.name not in fixed]
        all_ranges = {s.name: s.plausible(scales) for s in specs}
        for name, rng in (ranges or {}).items():
            if name not in all_ranges:
                raise ValueError(f"prior range for '{name}', which is not a free parameter of {model.name}; "
                                 f"free: {', '.join(all_ranges)}")
            all_ranges[name] = (float(rng[0]), float(rng[1]))
        coords = Coordinates.build(tuple(specs), all_ranges)
        return cls(model, kind, coords, template, np.array(free, np.int64))

    @property
    def names(self) -> tuple[str, ...]:
        return self.coords.names

    def full(self, phi: np.ndarray) -> np.ndarray:
        """Full θ (..., n_full) from free φ (..., p)."""
        return self.full_theta(self.coords.to_theta(np.asarray(phi, float)))

    def full_theta(self, theta: np.ndarray) -> np.ndarray:
        """Full θ (..., n_full) from the free parameters θ (..., p) [SI]."""
        theta = np.asarray(theta, float)
        out = np.broadcast_to(self.template, theta.shape[:-1] + self.template.shape).copy()
        out[..., self.free_idx] = theta
        return out


class OutputError:
    """Gaussian output-error log-posterior of (model, record), batched over θ.

    Parameters
    ----------
    model : Model or str
    record : xarray.Dataset
        Record in the package schema (quality mask in ``valid``).
    ranges, fixed : dict, optional
        Plausible-range overrides and fixed parameters (SI).
    noise : {"sampled", "fixed"}
        Sample ln σ_c with the parameters, or hold σ_c at ``noise_sd``.
    noise_sd : array, optional
        σ_c per channel for ``noise="fixed"`` (default: the record's noise floor).
    residual : {"iid", "ar"} or ResidualModel
        Residual model: independent Gaussian errors, or an AR(p_c) process per
        channel (σ_c then is the innovation SD; see :mod:`bayes_mr.likelihood.noise_model`).
    input_interp : {"auto", "linear", "bandlimited"}
        The input between samples (:mod:`bayes_mr.simulation.input_grid`); "auto": the
        record's ``input_interp`` attribute, else from the drive's bandwidth.
    command_interp : {"auto", "linear", "hold"}
        The command between samples; "auto": the record's ``command_interp``
        attribute, else linear. A choice other than the record's is written
        into :attr:`record`'s attributes, so every later reading of it reads
        the command the same way.

    Notes
    -----
    The parameter vector ``x`` is φ (free parameters, estimation coordinates)
    followed, when the noise is sampled, by ln σ_c for each channel.
    """

    def __init__(
        self,
        model: Model | str,
        record: xr.Dataset,
        *,
        ranges: dict | None = None,
        fixed: dict | None = None,
        noise: str = "sampled",
        noise_sd: np.ndarray | None = None,
        scales: Scales | None = None,
        residual: str | ResidualModel = "iid",
        input_interp: str = "auto",
        command_interp: str = "auto",
    ):
        if noise not in ("sampled", "fixed"):
            raise ValueError(f"noise must be 'sampled' or 'fixed', got {noise!r}")
        self.inputs = Inputs.from_record(record, input_interp, command_interp)
        if self.inputs.command_interp != record.attrs.get("command_interp", "linear"):
            # a head race, a refit or the UKF's validation re-reads lik.record: it must read the command as here
            record = record.assign_attrs(command_interp=self.inputs.command_interp)
        self.record = record
        self.kind = record.attrs["kind"]
        fixed = dict(fixed or {})
        if self.kind == "forced" and "mass" in record.attrs:
            fixed.setdefault("m", float(record.attrs["mass"]))  # a known mass (--mass) is not estimated
        self.fixed = {k: float(v) for k, v in fixed.items()}
        self.ranges = {k: (float(v[0]), float(v[1])) for k, v in (ranges or {}).items()}
        self.scales = scales or record_scales(record)
        self.par = Parameterisation.build(model, self.kind, self.scales, ranges=ranges, fixed=fixed)
        self.model = self.par.model
        self.channels = outputs_of(record)
        y = np.column_stack([record[c].values for c in self.channels])
        self.valid = record["valid"].values.astype(bool) if "valid" in record else np.ones(y.shape[0], bool)
        bad = ~np.isfinite(y[self.valid])
        if bad.any():
            raise ValueError(f"{record.attrs.get('source', 'record')}: non-finite measured values in valid samples")
        self.y = y
        self.n_valid = int(self.valid.sum())
        self.noise = noise
        self.residual = residual if isinstance(residual, ResidualModel) else ResidualModel(residual)
        self.noise_sd = np.asarray(noise_sd, float) if noise_sd is not None else channel_noise(record, self.channels)
        sd_y = np.array([np.std(y[self.valid, j]) for j in range(len(self.channels))])
        self.log_sigma_lo = np.log(SIGMA_SPAN[0] * sd_y)
        self.log_sigma_hi = np.log(SIGMA_SPAN[1] * sd_y)
        self.phi_lo = self.par.coords.phi_lower
        self.phi_hi = self.par.coords.phi_upper
        self._log_prior_const = -float(np.sum(np.log(self.phi_hi - self.phi_lo)))
        if noise == "sampled":
            self._log_prior_const -= float(np.sum(self.log_sigma_hi - self.log_sigma_lo))

    # --- dimensions and names ---------------------------------------------------
    @property
    def n_params(self) -> int:
        return len(self.par.names)

    @property
    def ndim(self) -> int:
        return self.n_params + (len(self.channels) if self.noise == "sampled" else 0)

    @property
    def noise_labels(self) -> tuple[str, ...]:
        """The noise SDs' labels in x's order: the measured channels."""
        return tuple(self.channels)

    @property
    def names(self) -> tuple[str, ...]:
        extra = tuple(f"sigma_{c}" for c in self.channels) if self.noise == "sampled" else ()
        return self.par.names + extra

    @property
    def lower(self) -> np.ndarray:
        lo = self.phi_lo
        return np.concatenate([lo, self.log_sigma_lo]) if self.noise == "sampled" else lo

    @property
    def upper(self) -> np.ndarray:
        hi = self.phi_hi
        return np.concatenate([hi, self.log_sigma_hi]) if self.noise == "sampled" else hi

    def split(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(φ (B, p), σ (B, n_channels)) from x (B, ndim)."""
        x = np.atleast_2d(np.asarray(x, float))
        phi = x[:, : self.n_params]
        if self.noise == "sampled":
            sigma = np.exp(x[:, self.n_params:])
        else:
            sigma = np.broadcast_to(self.noise_sd, (x.shape[0], len(self.channels)))
        return phi, sigma

    # --- model evaluation ------------------------------------------------------------
    def simulate(self, phi: np.ndarray, schedule: np.ndarray | None = None, **options) -> Simulation:
        """Simulate the model for φ of shape (B, p) (or (p,)).

        ``options`` go to :func:`bayes_mr.simulation.simulate.simulate` (sub-step control).
        """
        return simulate(self.model, self.inputs, self.par.full(phi), schedule=schedule, **options)

    def predict(self, phi: np.ndarray, schedule: np.ndarray | None = None,
                **options) -> tuple[np.ndarray, Simulation]:
        """Predicted measured channels, shape (B, N, n_channels), and the simulation."""
        sim = self.simulate(np.atleast_2d(phi), schedule, **options)
        yhat = np.stack([sim[c] for c in self.channels], axis=-1)
        return yhat, sim

    # --- densities ---------------------------------------------------------------------
    def log_prior(self, x: np.ndarray) -> np.ndarray:
        """ln p(x): uniform in φ over the plausible box (and log-uniform σ), −inf outside."""
        x = np.atleast_2d(np.asarray(x, float))
        inside = np.all((x >= self.lower) & (x <= self.upper), axis=1)
        return np.where(inside, self._log_prior_const, -np.inf)

    def log_likelihood(self, x: np.ndarray, *, pointwise: bool = False):
        """ln p(y | x) for each row of x (B,); −inf where the simulation failed.

        With ``pointwise`` also returns the per-sample terms (B, N, n_channels)
        (zero at invalid samples).
        """
        x = np.atleast_2d(np.asarray(x, float))
        rows = max(1, CHUNK_SAMPLES // max(1, self.y.shape[0]))
        if not pointwise and x.shape[0] > rows:  # rows are independent: the same numbers, bounded memory
            return np.concatenate([self.log_likelihood(x[i:i + rows]) for i in range(0, x.shape[0], rows)])
        phi, sigma = self.split(x)
        if not pointwise and self.residual.kind != "ar":
            # the channels straight from the simulation: no (B, N, n_channels) stack (a sixth of an emcee step)
            sim = self.simulate(phi)
            return self._iid_total([sim[c] for c in self.channels], sigma, sim.ok)
        yhat, sim = self.predict(phi)
        return self.log_density(yhat, sigma, sim.ok, pointwise=pointwise)

    def log_density(self, yhat: np.ndarray, sigma: np.ndarray, ok: np.ndarray, *, pointwise: bool = False):
        """ln p(y | ŷ, σ) of predictions ``yhat`` (B, N, n_channels) with noise SDs ``sigma`` (B, n_channels).

        ``ok`` (B,) marks simulations that completed; the others get −inf.
        With ``pointwise`` also returns the per-sample terms (B, N,
        n_channels) (zero at invalid samples, and under the AR model at the
        samples it conditions on).
        """
        if self.residual.kind == "ar":
            return self._ar_log_density(yhat, sigma, ok, pointwise)
        if not pointwise:
            return self._iid_total([yhat[..., j] for j in range(yhat.shape[2])], sigma, ok)
        with np.errstate(over="ignore", invalid="ignore"):  # a simulation that blew up overflows here: −inf below
            r = (self.y[None] - yhat) / sigma[:, None, :]
            terms = -0.5 * r * r - np.log(sigma)[:, None, :] - 0.5 * LOG_2PI
            terms[:, ~self.valid, :] = 0.0
            total = terms.sum(axis=(1, 2))
        return np.where(ok & np.isfinite(total), total, -np.inf), terms

    def _iid_total(self, yhat: list[np.ndarray], sigma: np.ndarray, ok: np.ndarray) -> np.ndarray:
        """The iid ln p(y | ŷ, σ) (B,) from each channel's prediction (B, N), through per-channel sums of squares.

        One temporary per channel instead of four per sample, a third of an emcee step's time on a
        25 s record at 1 kHz; einsum's two-index reduction is twice as fast as "bnc,bnc->bc" (measured).
        """
        with np.errstate(over="ignore", invalid="ignore"):  # a simulation that blew up overflows here: −inf below
            ssr = np.empty(sigma.shape)
            for j, yj in enumerate(yhat):
                d = yj - self.y[None, :, j]
                if self.n_valid < d.shape[1]:
                    d[:, ~self.valid] = 0.0
                ssr[:, j] = np.einsum("bn,bn->b", d, d)
            total = -0.5 * np.sum(ssr / sigma**2, axis=1) - self.n_valid * (
                np.sum(np.log(sigma), axis=1) + 0.5 * len(self.channels) * LOG_2PI)
        return np.where(ok & np.isfinite(total), total, -np.inf)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """ln posterior (unnormalised) of each row of x; vectorised for emcee."""
        x = np.atleast_2d(np.asarray(x, float))
        if not np.all(np.isfinite(x)):
            raise ValueError("log-posterior asked at a non-finite parameter vector")
        lp = self.log_prior(x)
        out = np.full(x.shape[0], -np.inf)
        inside = np.isfinite(lp)
        if inside.any():
            out[inside] = lp[inside] + self.log_likelihood(x[inside])
        return out

    def _ar_log_density(self, yhat, sigma, ok, pointwise):
        """:meth:`log_density` under the AR residual model (orders must have been chosen)."""
        if not self.residual.resolved:
            raise ValueError("the AR orders are not chosen yet: fit least squares first "
                             "(or call choose_residual_orders at a parameter vector)")
        with np.errstate(over="ignore", invalid="ignore"):
            total, terms = ar_log_density(self.y[None] - yhat, np.asarray(sigma, float), self.valid,
                                          self.residual.orders, pointwise=True)
        total = np.where(ok & np.isfinite(total), total, -np.inf)
        return (total, terms) if pointwise else total

    def choose_residual_orders(self, phi: np.ndarray) -> tuple[int, ...]:
        """Choose the AR order of each channel by BIC on the residual at φ (a first iid fit's optimum).

        Sets and returns ``residual.orders``; a no-op for the iid model or when already chosen.
        """
        if self.residual.resolved:
            return self.residual.order_of(len(self.channels))
        yhat, _ = self.predict(np.atleast_2d(phi))
        orders = select_orders(np.where(self.valid[:, None], self.y - yhat[0], 0.0), self.valid,
                               self.residual.max_order)
        self.residual = ResidualModel("ar", orders, self.residual.max_order)
        return orders

    def whiten(self, resid: np.ndarray) -> np.ndarray:
        """Prewhitened residuals (..., N, n_channels) under the chosen residual model [channel units].

        Identity for the iid model and for AR before its orders are chosen (a
        first iid fit); otherwise zero at the samples the AR model conditions on.
        """
        if self.residual.kind == "iid" or not self.residual.resolved:
            return resid
        r = np.asarray(resid, float)
        w, _ = ar_whiten(r.reshape((-1,) + r.shape[-2:]), self.valid, self.residual.orders)
        return w.reshape(r.shape)

    def residuals(self, phi: np.ndarray, sd: np.ndarray | None = None) -> np.ndarray:
        """Standardised residuals over valid samples, flattened (time, channel) (for least squares).

        (y − ŷ)/σ, prewhitened first under the AR model (:meth:`whiten`): the
        generalised-least-squares residual whose sum of squares is −2 ln p(y|θ, σ) + const.
        """
        sd = self.noise_sd if sd is None else np.asarray(sd, float)
        yhat, _ = self.predict(np.atleast_2d(phi))
        return (self.whiten(np.where(self.valid[:, None], self.y - yhat[0], 0.0))[self.valid] / sd).ravel()
