"""Propose library terms by sparse regression of a fitted model's residual.

The candidates are every library term (:mod:`bayes_mr.models.terms`) of one
or two factors, in the force map (``term``) and in the hysteretic law
(``zterm``). What each would change in the measured channels is its *output
sensitivity* along the fitted model's simulation: the model with the term
switched on at a small θ = ε, simulated at the fitted parameters, minus the
fit, over ε (forward finite difference). A force-map term on a device test
gives back its basis b(t) exactly; a term in the law, or any term on a
structure test, is seen through the dynamics that carry it to the outputs —
the linearised response of the output to the added term, which is what a
refit of that term can move.

Every sensitivity is projected off the span of the model's own parameter
sensitivities (a term the refit would absorb into c, k, … explains nothing
new) and the weighted residual (each channel over its noise SD) is regressed
on the projected, unit-normalised columns by the lasso (cvxpy) along a path of
penalties. Each support on the path (at most :data:`MAX_TERMS` terms) is
refitted by ordinary least squares and scored by BIC with an effective sample
size n/τ, τ the integrated autocorrelation time of the residual (correlated
samples inform less); the support of least BIC is the proposal, best first by
|t|.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.models import Model, terms
from bayes_mr.simulation.simulate import simulate
from bayes_mr.diagnosis.residuals import varying_voltage

#: Most terms one proposal holds (and the kernel's slots allow).
MAX_TERMS = 3
#: Penalties on the lasso path, log-spaced from the largest useful one down by PATH_DEPTH.
N_PATH, PATH_DEPTH = 30, 1e-3
#: A candidate whose sensitivity keeps less than this share of its norm once projected
#: off the model's parameter sensitivities is what the model already has.
MIN_NEW = 1e-3
#: The factors of one variable (a pair of them with a sign repeats a single factor).
_SAME = {"x": ("x", "abs(x)", "sgn(x)"), "xdot": ("xdot", "abs(xdot)", "sgn(xdot)"),
         "z": ("z", "abs(z)", "sgn(z)")}


@dataclass
class Proposal:
    """A library term the sparse regression picked, with its regression estimate."""

    name: str
    theta: float
    t_stat: float

    def to_dict(self) -> dict:
        return {"term": self.name, "theta_regression": float(self.theta), "t": float(self.t_stat)}


def _redundant(pair: tuple[str, str]) -> bool:
    """A pair of one variable's factors with a sign in it repeats one factor (sgn v·v = |v|, sgn v·|v| = v)."""
    return any(pair[0] in g and pair[1] in g for g in _SAME.values()) and "sgn(" in pair[0] + pair[1]


def library(model: Model, record) -> list[str]:
    """Names of the candidate terms for ``model`` on ``record`` (not already in the model).

    Products of one or two factors; the command ``u`` only with a varying
    command, its lag only when the model has one; force-map ``x`` and ``ẋ`` are
    the model's own stiffness and damping and left out.
    """
    factors = [f for f in terms.FACTORS if f not in ("u", "ulag")]
    if varying_voltage(record):
        factors.append("u")
        if "u" in model.state_names(record.attrs["kind"]):
            factors.append("ulag")
    bases = [(f,) for f in factors] + [p for p in itertools.combinations(factors, 2) if not _redundant(p)]
    have = {e.name for e in model.effects}
    out = []
    for target in terms.TARGETS:
        for b in bases:
            if target == "term" and b in (("x",), ("xdot",)):
                continue
            name = f"{target}({'*'.join(b)})"
            canon = terms.make(name, model.form.name).name
            if canon not in have and canon not in out:
                out.append(canon)
    return out


def _weighted(lik: OutputError, yhat: np.ndarray, sd: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Channels at ``rows`` over their noise SDs, stacked into one vector."""
    return (yhat[rows] / sd).ravel()


def sensitivities(lik: OutputError, theta: dict[str, float], names: list[str], sd: np.ndarray,
                  rows: np.ndarray) -> tuple[np.ndarray, list[str], np.ndarray]:
    """Output sensitivity (weighted, at ``rows``) of each candidate term at the fitted θ.

    Returns
    -------
    S : ndarray (n·channels, m)
        Columns ∂ŷ/∂θ_term of the terms kept (finite, non-zero).
    kept : list of str
    eps : ndarray (m,)
        The step of each.
    """
    base_model = lik.model
    y0 = None
    cols, kept, steps = [], [], []
    scales = lik.scales
    for name in names:
        effect = terms.make(name, base_model.form.name)
        model = base_model + effect
        spec = effect.params[0]
        eps = 1e-3 * spec.plausible(scales)[1] / terms.SPAN
        vals = {**theta, spec.name: eps}
        try:
            th = model.theta(lik.kind, vals)
            sim = simulate(model, lik.inputs, th)
        except ValueError:
            continue
        y1 = np.column_stack([np.asarray(sim.outputs[c]) for c in lik.channels])
        if y0 is None:
            sim0 = simulate(model, lik.inputs, model.theta(lik.kind, {**theta, spec.name: 0.0}))
            y0 = np.column_stack([np.asarray(sim0.outputs[c]) for c in lik.channels])
        col = _weighted(lik, (y1 - y0) / eps, sd, rows)
        if not (sim.ok.all() and np.all(np.isfinite(col)) and np.any(col != 0)):
            continue
        cols.append(col)
        kept.append(name)
        steps.append(eps)
    if not cols:
        return np.zeros((rows.sum() * len(lik.channels), 0)), [], np.zeros(0)
    return np.column_stack(cols), kept, np.array(steps)


def model_jacobian(lik: OutputError, phi: np.ndarray, sd: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Weighted output sensitivities to the model's own free parameters (forward differences in φ)."""
    h = 1e-5 * np.maximum(1.0, np.abs(phi))
    batch = np.vstack([phi, phi + np.diag(h)])
    yhat, sim = lik.predict(batch)
    y0 = _weighted(lik, yhat[0], sd, rows)
    cols = [(_weighted(lik, yhat[j + 1], sd, rows) - y0) / h[j] for j in range(phi.size)]
    J = np.column_stack(cols)
    return J[:, np.all(np.isfinite(J), axis=0)]


def autocorrelation_time(r: np.ndarray) -> float:
    """Integrated autocorrelation time τ = 1 + 2 Σ ρ_k of ``r``, summed until ρ first drops below 0."""
    r = r - r.mean()
    n = r.size
    f = np.fft.rfft(r, 2 * n)
    acf = np.fft.irfft(f * np.conj(f))[:n]
    acf = acf / acf[0] if acf[0] > 0 else np.zeros(n)
    neg = np.flatnonzero(acf[1:] <= 0)
    k = int(neg[0]) + 1 if neg.size else n
    return float(max(1.0, 1.0 + 2.0 * np.sum(acf[1:k])))


def _ols(S: np.ndarray, r: np.ndarray, support: tuple[int, ...]) -> tuple[np.ndarray, float, np.ndarray]:
    """Least squares of r on the columns ``support``: coefficients, RSS, standard errors (iid)."""
    if not support:
        return np.zeros(0), float(r @ r), np.zeros(0)
    A = S[:, list(support)]
    beta, *_ = np.linalg.lstsq(A, r, rcond=None)
    rss = float(np.sum((r - A @ beta) ** 2))
    cov = np.linalg.pinv(A.T @ A) * rss / max(1, r.size - len(support))
    return beta, rss, np.sqrt(np.clip(np.diag(cov), 0, None))


def lasso_path(S: np.ndarray, r: np.ndarray) -> list[tuple[int, ...]]:
    """Distinct supports (≤ :data:`MAX_TERMS` columns, largest coefficients first) along the lasso path of r on
    unit-norm S."""
    import cvxpy as cp

    m = S.shape[1]
    beta = cp.Variable(m)
    lam = cp.Parameter(nonneg=True)
    prob = cp.Problem(cp.Minimize(0.5 * cp.sum_squares(S @ beta - r) + lam * cp.norm1(beta)))
    lam_max = float(np.max(np.abs(S.T @ r)))
    supports: list[tuple[int, ...]] = [()]
    for value in lam_max * np.logspace(0, math.log10(PATH_DEPTH), N_PATH):
        lam.value = value
        prob.solve()
        if beta.value is None:
            continue
        b = np.asarray(beta.value)
        # the solver leaves ~1e-8 on inactive columns: active is above 1e-3 of the largest
        sup = tuple(int(j) for j in np.argsort(-np.abs(b)) if abs(b[j]) > 1e-3 * max(1e-300, np.abs(b).max()))
        # correlated columns enter together: the largest MAX_TERMS of a wider support are candidates too
        for k in range(1, min(len(sup), MAX_TERMS) + 1):
            if tuple(sorted(sup[:k])) not in [tuple(sorted(s)) for s in supports]:
                supports.append(sup[:k])
        if len(sup) > 3 * MAX_TERMS:
            break
    return supports


def propose(lik: OutputError, phi: np.ndarray, sd: np.ndarray, rows: np.ndarray,
            names: list[str]) -> tuple[list[Proposal], dict]:
    """Sparse regression of the fit's residual (at ``rows``) on the candidates ``names``.

    Returns
    -------
    list of Proposal, dict
        The proposed terms, best first, and what the search saw (candidates,
        τ, the BIC of each support on the path).
    """
    theta = dict(zip(lik.model.param_names(lik.kind), lik.par.full(phi)))
    yhat, _ = lik.predict(phi)
    r = _weighted(lik, lik.y - yhat[0], sd, rows)
    S, kept, _ = sensitivities(lik, theta, names, sd, rows)
    J = model_jacobian(lik, phi, sd, rows)
    qj, _ = np.linalg.qr(J)
    raw = np.linalg.norm(S, axis=0)
    S = S - qj @ (qj.T @ S)  # what the model's own parameters cannot do
    norm = np.linalg.norm(S, axis=0)
    new = norm > MIN_NEW * np.maximum(raw, 1e-300)
    S, kept, norm = S[:, new] / norm[new], [k for k, n in zip(kept, new) if n], norm[new]
    r = r - qj @ (qj.T @ r)
    tau = autocorrelation_time(r.reshape(-1, len(lik.channels))[:, 0]) if r.size else 1.0
    n_eff = r.size / tau
    seen = {"candidates": len(names), "independent": len(kept), "autocorrelation_time": tau, "path": []}
    if not kept:
        return [], seen
    best, best_bic = (), math.inf
    for sup in lasso_path(S, r):
        _, rss, _ = _ols(S, r, sup)
        bic = n_eff * math.log(max(rss, 1e-300) / r.size) + len(sup) * math.log(n_eff)
        seen["path"].append({"terms": [kept[j] for j in sup], "bic": bic})
        if bic < best_bic:
            best, best_bic = sup, bic
    beta, _, se = _ols(S, r, best)
    out = [Proposal(kept[j], float(b / norm[j]), float(b / s) if s > 0 else math.inf)
           for j, b, s in zip(best, beta, se)]
    return sorted(out, key=lambda p: -abs(p.t_stat)), seen
