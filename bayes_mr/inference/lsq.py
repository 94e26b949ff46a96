"""Least-squares baseline: output-error fit, Laplace covariance and evidence.

1. **Starting values by a convex sub-fit.** Given the *nonlinear* parameters
   (σ of Dahl, ρ and n of Bouc–Wen, α of LuGre, effect shapes, …) the force
   is linear in the others (c, k, F_d / k_z / β, ε, f0, k3, c_v): driving the
   hysteresis with the measured motion gives regressors Φ(t), and
   min ‖Φ θ_lin − f‖² over the plausible box is a small bounded convex
   problem, solved with cvxpy (CLARABEL). The force target is the measured
   force (device test) or −m·(absolute acceleration) (structure test).
   Latin-hypercube candidates of the nonlinear parameters are screened this
   way and the best become starts.
2. **Output-error least squares** (``scipy.optimize.least_squares``, trust
   region reflective, bounded by the plausible box) on the simulation
   residuals in the estimation coordinates φ, from each start; residuals are
   weighted by the noise SD of each channel, then re-weighted once by the
   residual RMS (the maximum-likelihood σ_c when σ is unknown).
3. **Laplace approximation** at the optimum: Cov(φ) = (JᵀJ)⁻¹ with J the
   Jacobian of the σ̂-standardised residuals (central differences on a
   replayed sub-step schedule). Residuals of a dynamic model are
   autocorrelated (process noise, model error), and (JᵀJ)⁻¹ then understates
   the uncertainty many times over; the reported covariance is the
   heteroskedasticity-and-autocorrelation-consistent sandwich
   (JᵀJ)⁻¹ Ω (JᵀJ)⁻¹ with a Bartlett-weighted Ω (Newey & West 1987) whose
   bandwidth is where the residual autocorrelation dies out. The evidence is
   ln Z ≈ ln p(y|φ̂,σ̂) + ln p(φ̂) + ln p(σ̂) + ½(d+c) ln 2π + ½ ln|Σ_φ| − ½ Σ_c ln(2 N_c),
   with the same priors as :class:`~bayes_mr.likelihood.OutputError`.
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize
from scipy.stats import qmc

from ..likelihood import OutputError
from ..simulate import Inputs, simulate
from ..stats import hac_bandwidth

#: Parameters in which the restoring force is linear, given the hysteretic state.
LINEAR_FORM = {
    "normalized-bouc-wen": ("c", "k", "k_z"),
    "dahl": ("c", "k", "F_d"),
    "lugre": ("c", "k", "beta", "epsilon"),
    "bouc-wen": ("c", "k"),
    "spencer": (),
}
LINEAR_EFFECT = ("f0", "k3", "c_v")
#: The form coefficient that scales the hysteretic force (not linear with a series dashpot).
HYSTERETIC_COEF = {"normalized-bouc-wen": "k_z", "dahl": "F_d", "lugre": "beta"}


@dataclass(frozen=True)
class LSQSettings:
    """Least-squares settings.

    Attributes
    ----------
    n_candidates : int
        Latin-hypercube candidates of the nonlinear parameters screened by the
        convex sub-fit.
    n_starts : int
        Best candidates refined by nonlinear least squares.
    max_nfev : int
        Most residual evaluations per start.
    seed : int
        Seed of the candidates.
    reweight : bool
        Re-weight channels by their residual RMS after the first fit.
    """

    n_candidates: int = 48
    n_starts: int = 4
    max_nfev: int = 200
    seed: int = 0
    reweight: bool = True


@dataclass
class LSQResult:
    """Outcome of :func:`fit_lsq`.

    Attributes
    ----------
    phi : ndarray (p,)
        Optimum in estimation coordinates.
    theta : dict
        Optimum, name → value [SI] (free parameters).
    cov_phi : ndarray (p, p)
        Covariance of φ (autocorrelation-consistent sandwich).
    cov_phi_iid : ndarray (p, p)
        (JᵀJ)⁻¹: the covariance if residuals were independent.
    sd_theta : dict
        Delta-method standard deviations [SI].
    sigma : ndarray (n_channels,)
        Residual RMS per measured channel (ML noise SD).
    log_likelihood, log_evidence : float
        At the optimum, and the Laplace evidence.
    starts : list of dict
        Each start: initial φ, final φ, cost, nfev, status.
    """

    phi: np.ndarray
    theta: dict[str, float]
    cov_phi: np.ndarray
    cov_phi_iid: np.ndarray
    sd_theta: dict[str, float]
    sigma: np.ndarray
    log_likelihood: float
    log_evidence: float
    starts: list[dict] = field(default_factory=list)
    wall_s: float = 0.0
    hac_lag: int = 0


# --- convex sub-fit ----------------------------------------------------------------

def linear_names(lik: OutputError) -> tuple[str, ...]:
    """Free parameters the force is linear in (given the others)."""
    model = lik.model
    if lik.kind == "forced" or (lik.kind == "structure" and len(lik.channels) < 2):
        return ()  # the sub-fit's force target needs the measured motion and acceleration of a full record
    lin = list(LINEAR_FORM[model.form.name])
    if lik.kind == "structure" and not model.form.frame_in_form:
        lin = ["c", "k"]
    if model.effect("low_velocity_rolloff") and HYSTERETIC_COEF.get(model.form.name) in lin:
        lin.remove(HYSTERETIC_COEF[model.form.name])  # the series dashpot makes z depend on it
    lin += [n for n in LINEAR_EFFECT if n in model.param_names(lik.kind)]
    return tuple(n for n in lin if n in lik.par.names)


def _motion(lik: OutputError) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Measured x, ẋ, voltage and the force target of the sub-fit."""
    rec = lik.record
    x = rec["displacement"].values
    v = rec["voltage"].values if "voltage" in rec else np.zeros_like(x)
    if lik.kind == "device":
        return x, rec["velocity"].values, v, rec["force"].values
    from ..data.derive import smooth_velocity

    xd = smooth_velocity(x, float(rec.attrs["dt"]))
    return x, xd, v, -float(rec.attrs["mass"]) * rec["acceleration"].values


class LinearSubfit:
    """Bounded convex fit of the linear parameters for given nonlinear ones."""

    def __init__(self, lik: OutputError, stride: int | None = None):
        import cvxpy as cp

        self.lik = lik
        self.lin = linear_names(lik)
        names = lik.par.names
        self.j_lin = np.array([names.index(n) for n in self.lin], int)
        self.j_non = np.array([j for j in range(len(names)) if names[j] not in self.lin], int)
        x, xd, v, f = _motion(lik)
        # Enough samples for a well-posed regression, few enough to be quick.
        self.stride = stride or max(1, lik.inputs.n // 20000)
        self.valid = lik.valid
        self.target = f
        self.inputs = Inputs.device(x, xd, lik.inputs.dt, v)
        self.frame = lik.kind == "structure" and not lik.model.form.frame_in_form
        self.x, self.xd = x, xd
        coords = lik.par.coords
        self.lo = coords.lower[self.j_lin]
        self.hi = coords.upper[self.j_lin]
        self.ref = np.maximum(np.abs(self.lo), np.abs(self.hi))
        p = len(self.lin)
        self._R = cp.Parameter((p, p))
        self._b = cp.Parameter(p)
        self._u = cp.Variable(p)
        self._prob = cp.Problem(
            cp.Minimize(cp.sum_squares(self._R @ self._u - self._b)),
            [self._u >= self.lo / self.ref, self._u <= self.hi / self.ref],
        )

    def _device_theta(self, theta_full: np.ndarray) -> np.ndarray:
        """Device-test parameter vector of the same law (drops a structure frame)."""
        return theta_full[2:] if self.frame else theta_full

    def regressors(self, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(Φ (n, p_lin), offset force f_rest (n,)) at the nonlinear values in ``phi``."""
        names = self.lik.model.param_names(self.lik.kind)
        full = self.lik.par.full(phi)
        lin_full = [names.index(n) for n in self.lin]
        base = full.copy()
        base[lin_full] = 0.0
        batch = [base]
        for j in lin_full:
            e = base.copy()
            e[j] = 1.0
            batch.append(e)
        batch = np.array(batch)
        frame_cols = []
        if self.frame:
            # frame c, k of a structure test enter as c ẋ + k x outside the device law
            frame_cols = [n for n in ("c", "k") if n in self.lin]
            keep = [i for i, n in enumerate(self.lin) if n not in ("c", "k")]
            batch = np.array([self._device_theta(b) for b in batch[[0] + [1 + i for i in keep]]])
        dev_model = self.lik.model
        sim = simulate(dev_model, self.inputs, batch)
        f = sim["force"]
        cols = [f[i] - f[0] for i in range(1, f.shape[0])]
        if self.frame:
            extra = {"c": self.xd, "k": self.x}
            order = [n for n in self.lin if n not in ("c", "k")]
            lookup = dict(zip(order, cols))
            lookup.update({n: extra[n] for n in frame_cols})
            cols = [lookup[n] for n in self.lin]
        return np.column_stack(cols), f[0]

    def solve(self, phi: np.ndarray) -> tuple[np.ndarray, float]:
        """φ with its linear parameters replaced by the bounded LS optimum, and the cost.

        The cost is the mean squared force residual over valid samples [N²].
        """
        Phi, rest = self.regressors(phi)
        sel = self.valid & (np.arange(self.valid.size) % self.stride == 0)
        A = Phi[sel] * self.ref  # columns scaled so that the unknowns u = θ/ref are O(1)
        b = self.target[sel] - rest[sel]
        if not (np.all(np.isfinite(A)) and np.all(np.isfinite(b))):
            return phi, np.inf
        Q, R = np.linalg.qr(A)
        self._R.value = R
        self._b.value = Q.T @ b
        try:
            self._prob.solve(solver="CLARABEL")
        except Exception:  # a failed convex solve only drops this candidate
            return phi, np.inf
        if self._u.value is None:
            return phi, np.inf
        theta_lin = np.clip(self._u.value * self.ref, self.lo, self.hi)
        out = np.array(phi, float)
        coords = self.lik.par.coords
        for k, j in enumerate(self.j_lin):
            th = theta_lin[k]
            if coords.log[j]:
                th = max(th, coords.lower[j])
                out[j] = math.log(coords.scale[j] * th)
            else:
                out[j] = coords.scale[j] * th
        cost = float(np.mean((A @ (theta_lin / self.ref) - b) ** 2))
        return out, cost


def candidates(lik: OutputError, n: int, seed: int) -> np.ndarray:
    """Candidate starts φ, shape (n + 1, p): the model's published/thesis
    defaults (clipped into the box) and ``n`` Latin-hypercube samples of it."""
    sampler = qmc.LatinHypercube(d=lik.n_params, seed=np.random.default_rng(seed))
    u = sampler.random(n)
    specs = {s.name: s for s in lik.model.free_specs(lik.kind)}
    default = np.array([specs[name].default for name in lik.par.names])
    coords = lik.par.coords
    default = np.clip(default, coords.lower, coords.upper)
    return np.vstack([coords.to_phi(default), lik.phi_lo + u * (lik.phi_hi - lik.phi_lo)])


# --- covariance -------------------------------------------------------------------------

def hac_covariance(J: np.ndarray, r: np.ndarray, n_t: int) -> tuple[np.ndarray, int]:
    """Sandwich covariance (JᵀJ)⁻¹ Ω (JᵀJ)⁻¹ with a Bartlett-weighted Ω.

    Parameters
    ----------
    J : ndarray, shape (n_t · c, p)
        Jacobian of the standardised residuals, rows ordered (time, channel).
    r : ndarray, shape (n_t · c,)
        Standardised residuals, same order.
    n_t : int
        Number of time samples.

    Returns
    -------
    cov : ndarray (p, p)
    lag : int
        Bandwidth used [samples].
    """
    p = J.shape[1]
    c = r.size // n_t
    g = (J * r[:, None]).reshape(n_t, c, p).sum(axis=1)  # score contribution of each sample
    lag = hac_bandwidth(r.reshape(n_t, c), max_lag=min(n_t // 4, 5000))
    m = 2 * n_t
    G = np.fft.rfft(g, m, axis=0)
    omega = np.zeros((p, p))
    for a in range(p):
        for b in range(a, p):
            cc = np.fft.irfft(G[:, a] * np.conj(G[:, b]), m)  # cc[l] = Σ_t g_a[t] g_b[t−l]
            w = 1.0 - np.arange(lag + 1) / (lag + 1)
            val = cc[0] + np.sum(w[1:] * (cc[1: lag + 1] + cc[m - lag:][::-1]))
            omega[a, b] = omega[b, a] = val
    bread = np.linalg.pinv(J.T @ J)
    return bread @ omega @ bread, lag


# --- nonlinear least squares -----------------------------------------------------------

class _Residuals:
    """Standardised residual vector and its finite-difference Jacobian."""

    def __init__(self, lik: OutputError, sd: np.ndarray):
        self.lik = lik
        self.sd = np.asarray(sd, float)
        self.schedule = None

    def __call__(self, phi):
        yhat, sim = self.lik.predict(phi)
        self.schedule = sim.schedule[0]
        r = (self.lik.y[self.lik.valid] - yhat[0][self.lik.valid]) / self.sd
        if not sim.ok[0] or not np.all(np.isfinite(r)):
            # a diverged simulation is a very bad fit (worse than predicting zero), not a crash
            worst = 1e3 * np.max(np.abs(self.lik.y[self.lik.valid]) / self.sd)
            return np.full(r.size, worst)
        return r.ravel()

    def jacobian(self, phi, central: bool = False):
        p = phi.size
        h = 1e-6 * np.maximum(1.0, np.abs(phi))
        batch = [phi]
        for j in range(p):
            e = np.zeros(p)
            e[j] = h[j]
            batch.append(phi + e)
            if central:
                batch.append(phi - e)
        if self.schedule is None:
            self(phi)
        yhat, _ = self.lik.predict(np.array(batch), schedule=self.schedule)
        v = self.lik.valid
        r = [((self.lik.y[v] - yh[v]) / self.sd).ravel() for yh in yhat]
        # a perturbed simulation that diverges says nothing about the slope: treat it as flat
        r = [ri if np.all(np.isfinite(ri)) else r[0] for ri in r]
        if not np.all(np.isfinite(r[0])):
            return np.zeros((r[0].size, p))
        J = np.empty((r[0].size, p))
        for j in range(p):
            if central:
                J[:, j] = (r[1 + 2 * j] - r[2 + 2 * j]) / (2 * h[j])
            else:
                J[:, j] = (r[1 + j] - r[0]) / h[j]
        return J


def _refine(lik: OutputError, phi0: np.ndarray, sd: np.ndarray, max_nfev: int) -> optimize.OptimizeResult:
    res_fn = _Residuals(lik, sd)
    lo, hi = lik.phi_lo, lik.phi_hi
    x0 = np.clip(phi0, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
    return optimize.least_squares(
        res_fn, x0, jac=res_fn.jacobian, bounds=(lo, hi), method="trf",
        x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=max_nfev,
    )


def fit_lsq(lik: OutputError, settings: LSQSettings = LSQSettings(), *, progress=None) -> LSQResult:
    """Least-squares fit of ``lik``'s model to its record (see module docstring).

    Parameters
    ----------
    lik : OutputError
        Model and record (its ``noise_sd`` weights the first pass).
    settings : LSQSettings
    progress : callable, optional
        Called with a short text after each stage.

    Returns
    -------
    LSQResult
    """
    t0 = _time.perf_counter()
    say = progress or (lambda msg: None)
    cands = candidates(lik, settings.n_candidates, settings.seed)
    sub = LinearSubfit(lik) if linear_names(lik) else None
    scored = []
    for c in cands:
        if sub is not None:
            c, cost = sub.solve(c)
        else:
            yhat, sim = lik.predict(c)
            cost = float(np.mean(((lik.y - yhat[0])[lik.valid] / lik.noise_sd) ** 2)) if sim.ok[0] else np.inf
        scored.append((cost, c))
    scored.sort(key=lambda t: t[0])
    say(f"screened {len(cands)} candidates")
    starts = [c for cost, c in scored[: settings.n_starts] if np.isfinite(cost)] or [cands[0]]
    sd = lik.noise_sd.copy()
    runs = []
    for i, phi0 in enumerate(starts):
        res = _refine(lik, phi0, sd, settings.max_nfev)
        runs.append({"phi0": phi0, "phi": res.x, "cost": float(res.cost), "nfev": int(res.nfev),
                     "status": int(res.status), "message": str(res.message)})
        say(f"start {i + 1}/{len(starts)}: cost {res.cost:.4g}")
    best = min(runs, key=lambda r: r["cost"])
    phi = best["phi"]
    if settings.reweight:
        yhat, _ = lik.predict(phi)
        resid = (lik.y - yhat[0])[lik.valid]
        sd = np.maximum(np.sqrt(np.mean(resid**2, axis=0)), 1e-12 * np.std(lik.y[lik.valid], axis=0))
        res = _refine(lik, phi, sd, settings.max_nfev)
        phi = res.x
    return laplace(lik, phi, starts=runs, wall_s=_time.perf_counter() - t0)


def laplace(lik: OutputError, phi: np.ndarray, *, starts=None, wall_s: float = 0.0) -> LSQResult:
    """Laplace covariance and evidence of ``lik`` at φ (an optimum)."""
    yhat, _ = lik.predict(phi)
    resid = (lik.y - yhat[0])[lik.valid]
    n_c = resid.shape[0]
    sampled = lik.noise == "sampled"
    if sampled:
        # σ_c at its maximum-likelihood value, the residual RMS
        floor = 1e-12 * np.std(lik.y[lik.valid], axis=0)
        sigma = np.maximum(np.sqrt(np.mean(resid**2, axis=0)), floor)
    else:
        sigma = np.asarray(lik.noise_sd, float)
    rf = _Residuals(lik, sigma)
    r = rf(phi)
    J = rf.jacobian(phi, central=True)
    JtJ = J.T @ J
    cov_iid = np.linalg.pinv(JtJ)
    eig = np.linalg.eigvalsh(JtJ)
    logdet = -float(np.sum(np.log(np.clip(eig, 1e-300, None))))
    cov, lag = hac_covariance(J, r, n_c)
    loglik = float(np.sum(-0.5 * (resid / sigma) ** 2 - np.log(sigma) - 0.5 * math.log(2 * math.pi)))
    d = phi.size
    log_prior = -float(np.sum(np.log(lik.phi_hi - lik.phi_lo)))
    log_z = loglik + log_prior + 0.5 * d * math.log(2 * math.pi) + 0.5 * logdet
    if sampled:
        # log-uniform σ prior, and the Gaussian integral over ln σ_c (curvature 2 N_c at the optimum)
        c = sigma.size
        log_z += -float(np.sum(lik.log_sigma_hi - lik.log_sigma_lo)) + 0.5 * c * math.log(2 * math.pi)
        log_z -= 0.5 * c * math.log(2.0 * n_c)
    coords = lik.par.coords
    theta = coords.to_theta(phi)
    sd_phi = np.sqrt(np.clip(np.diag(cov), 0, None))
    sd_theta = np.where(coords.log, theta * sd_phi, sd_phi / coords.scale)
    return LSQResult(
        phi=phi,
        theta=dict(zip(coords.names, theta)),
        cov_phi=cov,
        cov_phi_iid=cov_iid,
        sd_theta=dict(zip(coords.names, sd_theta)),
        sigma=sigma,
        log_likelihood=loglik,
        log_evidence=float(log_z),
        starts=list(starts or []),
        wall_s=wall_s,
        hac_lag=lag,
    )
