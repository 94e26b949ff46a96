"""Starting values of least squares: the convex sub-fit of the linear parameters.

Given the *nonlinear* parameters (σ of Dahl, ρ and n of Bouc–Wen, α of
LuGre, effect shapes, …) the force is linear in the others (c, k, F_d / k_z /
β, ε, f0, k3, c_v): driving the hysteresis with the measured motion gives
regressors Φ(t), and min ‖Φ θ_lin − f‖² over the plausible box is a small
bounded convex problem, solved with cvxpy (CLARABEL). The force target is the
measured force (device test) or −m·(absolute acceleration) (structure test).
:func:`candidates` gives the Latin-hypercube candidates it screens
(:func:`bayes_mr.inference.lsq.least_squares.fit_lsq`), and :func:`screen` ranks them into
starts, with a sub-step cost cap (:func:`stiff`) where simulating is expensive.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import qmc

from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.models.integrate import steps
from bayes_mr.simulation.simulate import Inputs, simulate

#: Parameters in which the restoring force is linear, given the hysteretic state.
LINEAR_FORM = {
    "normalized-bouc-wen": ("c", "k", "k_z"),
    "dahl": ("c", "k", "F_d"),
    "lugre": ("c", "k", "beta", "epsilon"),
    "bouc-wen": ("c", "k"),
    "spencer": (),
}
LINEAR_EFFECT = ("f0", "k3", "c_v")
#: Share of sample intervals at a search's sub-step cap above which a parameter set is too stiff to start from.
STIFF_FRACTION = 0.1
#: The form coefficient that scales the hysteretic force (not linear with a series dashpot).
HYSTERETIC_COEF = {"normalized-bouc-wen": "k_z", "dahl": "F_d", "lugre": "beta"}


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
    """Measured x, ẋ, command (voltage or current, whichever the record has) and the force target of the sub-fit."""
    rec = lik.record
    x = rec["displacement"].values
    v = lik.inputs.rows[:, 2]  # the command column Inputs.from_record filled from either channel
    if lik.kind == "device":
        return x, rec["velocity"].values, v, rec["force"].values
    from bayes_mr.data.derive import smooth_velocity

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
        self.inputs = Inputs.device(x, xd, lik.inputs.dt, v, command_interp=lik.inputs.command_interp)
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
            elif coords.asinh[j]:
                out[j] = math.asinh(coords.scale[j] * th)
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


def stiff(schedule: np.ndarray, cap: int | None) -> np.ndarray:
    """Whether each simulation (rows of ``schedule``) saturates the sub-step ``cap`` too often to start from.

    An interval the Rosenbrock step took (a negative count, :mod:`bayes_mr.models.integrate`) passed its
    error test, so the cap did not limit it: it does not count as saturated.
    """
    if cap is None:
        return np.zeros(schedule.shape[0], bool)
    return np.mean(steps(schedule) >= cap, axis=1) > STIFF_FRACTION


def screen(lik: OutputError, n_candidates: int, n_starts: int, seed: int, cap: int | None) -> list[np.ndarray]:
    """The ``n_starts`` best of :func:`candidates` (``n_candidates``, ``seed``) as starts φ.

    Ranked by the convex sub-fit's force misfit where the force is linear in
    some parameters, else by the simulated output misfit (one parallel batch,
    at most ``cap`` sub-steps per interval; candidates that :func:`stiff`
    rejects are dropped unless all are). Diverged candidates are dropped.
    """
    cands = candidates(lik, n_candidates, seed)
    sub = LinearSubfit(lik) if linear_names(lik) else None
    if sub is not None:
        scored = [sub.solve(c)[::-1] for c in cands]
    else:
        yhat, sim = lik.predict(cands, **({} if cap is None else {"n_max": int(cap)}))
        err = np.where(lik.valid[None, :, None], (lik.y[None] - yhat) / lik.noise_sd, 0.0)
        cost = np.sum(err**2, axis=(1, 2)) / max(int(lik.valid.sum()), 1)
        ok = sim.ok & np.isfinite(cost)
        too_stiff = stiff(sim.schedule, cap)
        cost = np.where(ok & ~too_stiff, cost, np.inf) if np.any(ok & ~too_stiff) else np.where(ok, cost, np.inf)
        scored = list(zip(cost, cands))
    order = sorted(range(len(scored)), key=lambda i: scored[i][0])
    starts = [scored[i][1] for i in order[: n_starts] if np.isfinite(scored[i][0])]
    return starts or [cands[0]]
