"""An emcee chain as the engines' common :class:`~bayes_mr.inference.base.Posterior`."""

from __future__ import annotations

import numpy as np
import xarray as xr

from bayes_mr.inference.base import Posterior, even_indices
from bayes_mr.inference.calibrate import adjust_draws, describe, loewner_max, truncate_to_box
from bayes_mr.inference.mcmc.start import seed_of
from bayes_mr.inference.evidence.routes import Evidence, select_route
from bayes_mr.inference.lsq.evidence_scale import calibration_info
from bayes_mr.inference.mcmc.geometry import chain_geometry
from bayes_mr.inference.mcmc.chain import MCMCResult


def mcmc_posterior(lik, result: MCMCResult, lsq=None, *, evidence=None, n_ll_draws: int = 200) -> Posterior:
    """The :class:`~bayes_mr.inference.base.Posterior` of an emcee chain.

    Parameters
    ----------
    lik : OutputError
        The posterior that was sampled.
    result : MCMCResult
        Its chain (coordinates x = [φ, ln σ_c]).
    lsq : LSQResult, optional
        The least-squares fit the walkers started from (reported beside).
    evidence : Evidence or dict of str → Evidence, optional
        Evidence routes; with a dict the selecting one is
        :func:`bayes_mr.inference.evidence.routes.select_route` of it and the others
        are reported beside it (``evidence_routes`` and the ``evidence`` group).
    n_ll_draws : int
        Pointwise log-likelihood on at most this many draws (all walkers ×
        evenly spaced draws).

    Returns
    -------
    Posterior
        Draws (chain = walker, draw) from the post-burn-in chain thinned by
        ``result.thin`` — with ``lsq``, mapped about its optimum from their own
        covariance to the larger (Loewner) of it and least squares' calibrated
        one (:func:`~bayes_mr.inference.calibrate.adjust_draws`; ``lp`` stays the sampled draws' log posterior) and
        truncated to the prior's box (:func:`~bayes_mr.inference.calibrate.truncate_to_box`; the fraction
        outside is ``uncertainty.draws_outside_prior``); the point is the maximum-posterior step after burn-in;
        ``sample_stats`` attributes ``rhat``, ``ess``, ``tau`` per coordinate; ``info["geometry"]`` what makes the
        chain slow (:func:`~bayes_mr.inference.mcmc.geometry.chain_geometry` of the chain after burn-in).
    """
    p = lik.n_params
    coords = lik.par.coords
    kept = result.chain[result.burn:: result.thin]  # (n_draw, W, d)
    x = np.moveaxis(kept, 1, 0)  # (W, n_draw, d)
    if lsq is not None:
        x, outside = _calibrated(lik, x, lsq, result.seed_entropy)
    # the point the engine stands behind: the highest posterior density visited after burn-in
    post_lp = result.log_prob[result.burn:]
    i, w = np.unravel_index(int(np.argmax(post_lp)), post_lp.shape)
    point = coords.to_theta(result.chain[result.burn + i, w][:p])
    W, n_draw = x.shape[0], x.shape[1]
    d_idx = even_indices(n_draw, max(1, n_ll_draws // W))
    flat = x.reshape(-1, x.shape[-1])
    routes, chosen = _routes(evidence)
    sigma = np.exp(flat[:, p:]).mean(axis=0) if lik.noise == "sampled" else np.asarray(lik.noise_sd, float)
    wall = result.wall_s + (lsq.wall_s if lsq is not None else 0.0) + max(
        [e.wall_s for e in routes.values() if e.route != "laplace"] or [0.0])
    info = {
        "evidence_route": chosen.route if chosen is not None else None,
        "evidence_routes": {k: e.to_dict() for k, e in routes.items()},
        "sigma": dict(zip(lik.noise_labels, sigma)), "map": dict(zip(coords.names, point)),
        "n_steps": result.n_steps, "n_walkers": result.n_walkers, "burn": result.burn, "thin": result.thin,
        "tau_max": float(np.max(result.tau)), "rhat_max": float(np.max(result.rhat)),
        "ess_min": float(np.min(result.ess)), "acceptance": float(np.mean(result.acceptance)),
        "pilot_steps": result.pilot_steps, "adapt_acceptance": [float(a) for a in result.adapt_acceptance],
        "converged": bool(result.converged), "stopped": result.stopped, "seed_entropy": result.seed_entropy,
        "projection": result.projection,
        # the work the posterior stands on and the limits it ran under (a cap that acted is a machine limit)
        "evaluations": int(result.evaluations), "max_evaluations": result.max_evaluations,
        "wall_cap_s": result.max_seconds,
        "pareto_k": float(result.pareto_k) if np.isfinite(result.pareto_k) else None,
        "geometry": chain_geometry(result.chain[result.burn:], lik.lower, lik.upper, result.names, result.tau),
    }
    if lsq is not None:
        info["lsq_optimum"] = dict(lsq.theta)
        info["uncertainty"] = {**describe(lsq, lik.noise_labels), "draws_outside_prior": outside,
                               "draws": "mapped to least squares' covariance" if outside < 1.0 else
                               "the chain's own (every mapped draw left the prior box)"}
        info.update(calibration_info(lsq.evidence_terms))  # the Laplace route's calibrated evidence (evidence_scale)
    names = list(lik.names)
    return Posterior(
        engine="mcmc", draws=coords.to_theta(x[:, :, :p]), point=point,
        x_draws=x[:, d_idx].reshape(-1, x.shape[-1]), x_chain=(W, d_idx.size), pp_draws=flat,
        log_evidence=None if chosen is None else float(chosen.log_z),
        lp=np.moveaxis(result.log_prob[result.burn:: result.thin], 1, 0), params_sd_ddof=1, info=info,
        sample_stats_attrs=dict(coordinates=",".join(names), rhat=np.asarray(result.rhat, float),
                                ess=np.asarray(result.ess, float), tau=np.asarray(result.tau, float),
                                burn=int(result.burn), thin=int(result.thin)),
        groups=_groups(result, names, routes, chosen), attrs={"seed_entropy": result.seed_entropy}, wall_s=wall,
    )


def _calibrated(lik, x: np.ndarray, lsq, seed_entropy: str) -> tuple[np.ndarray, float]:
    """Draws x (W, n, d) with φ mapped to least squares' calibrated covariance inside the prior's box, and the
    fraction the map carried outside (:func:`mcmc_posterior`).

    The chain samples the likelihood's own curvature; the map gives it least squares' calibrated covariance
    (input noise, autocorrelation) keeping its shape (calibrate.adjust_draws). It starts from the chain's own
    covariance, not (JᵀJ)⁻¹: where the sampled posterior is wider than its Gauss–Newton curvature (a curved
    ridge) that curvature's inverse would amplify the tail, and the chain is never narrowed. Times the prior:
    draws carried along a barely constrained direction out of the box are the truncated posterior's
    (calibrate.truncate_to_box); when every draw left it, the chain's own draws are kept.
    """
    p = lik.n_params
    cov_chain = np.atleast_2d(np.cov(x[..., :p].reshape(-1, p), rowvar=False))
    mapped = adjust_draws(x[..., :p], lsq.phi, cov_chain, loewner_max(cov_chain, lsq.cov_phi))
    rng = np.random.default_rng(seed_of(seed_entropy))  # the chain's own seed
    mapped, outside = truncate_to_box(mapped, lik.phi_lo, lik.phi_hi, rng)
    x = x.copy()
    if outside < 1.0:
        x[..., :p] = mapped
    return x, outside


def _routes(evidence) -> tuple[dict, object]:
    """(route name → Evidence, the selecting one) from one Evidence, a dict of them, or None."""
    if isinstance(evidence, Evidence):
        return {evidence.route: evidence}, evidence
    if evidence:
        return dict(evidence), select_route(dict(evidence))
    return {}, None


def _groups(result: MCMCResult, names: list[str], routes: dict, chosen) -> dict[str, xr.Dataset]:
    """``mcmc_diagnostics`` and (with evidence) ``evidence`` groups."""
    groups = {"mcmc_diagnostics": xr.Dataset(
        {"rhat": ("coordinate", result.rhat), "ess": ("coordinate", result.ess),
         "tau": ("coordinate", result.tau), "acceptance": ("walker", result.acceptance)},
        coords={"coordinate": names}, attrs={"burn": result.burn, "thin": result.thin,
                                             "n_steps": result.n_steps, "converged": int(result.converged)})}
    if routes:
        order = list(routes)
        groups["evidence"] = xr.Dataset(
            {k: ("route", np.array([getattr(routes[r], k) for r in order], float))
             for k in ("log_z", "mc_error", "ladder_error", "total_error", "wall_s")},
            coords={"route": order}, attrs={"selected": chosen.route})
    return groups
