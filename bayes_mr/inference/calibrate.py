"""Honest parameter covariance under noise on the measured input (errors in variables), for every engine.

The output-error likelihood (:class:`~bayes_mr.likelihood.output_error.OutputError`)
compares the measured outputs with the model driven by the *recorded* input.
When the input itself is measured with noise w (a structure's ground
acceleration, a forced test's applied force, a device test's imposed motion),
the residual at the true θ is not the measurement noise v alone but

    r = G(θ) w + v,

the model's response to the input noise — smooth, correlated and
concentrated in the band the parameters are identified from — plus v. An iid
(or AR by BIC) likelihood sees mostly v: on simulated structure tests with
2 % input and output noise the least-squares estimates scatter 2–3× wider than
(JᵀJ)⁻¹ says and ~2× wider than the Bartlett HAC sandwich (bandwidth-limited)
says; the MCMC posterior, sampling the same likelihood, is as narrow as (JᵀJ)⁻¹.

The cure used here is the sandwich with a *model-based* middle:

    Cov(φ̂) = B⁻¹ Ω B⁻¹,  B = JᵀJ,  Ω = E[(Jᵀ r)(Jᵀ r)ᵀ],

with J the Jacobian of the standardised (under AR: prewhitened) residual and
Ω estimated by Monte Carlo from :data:`N_DRAWS` replicas r_k = W(G w_k + v_k)/σ̂:
the model at the estimate driven by the recorded input plus a fresh draw w_k
of the input noise (its SD from the record, as the UKF's process noise reads
it: :func:`~bayes_mr.likelihood.output_error.channel_noise`), minus the model on the recorded
input, plus white measurement noise v_k of the variance the residual has left
over, passed through the same AR prewhitening W as the residual. This is the
linearised parametric bootstrap of the estimator: no refits, K simulations.
Where model error makes the empirical HAC middle larger in some direction,
that direction keeps the larger one (:func:`loewner_max`), so the correction
never narrows what the data's own residual says.

Every engine reads it: least squares reports it as ``cov_phi``; the MCMC
draws are adjusted to it (:func:`adjust_draws`: an affine map about the
posterior mode whose image has this covariance, the curvature adjustment of
Ribatet, Cooley & Davison 2012 and Shaby 2014) and kept inside the prior's box
(:func:`truncate_to_box`). The UKF does not use it: its
filter carries the input noise as process noise, and it reports its own
covariance plus its offset from the likelihood's peak (``UKF.peak_nfev`` in
``inference/estimators.py``). Measured by ``studies/coverage.py``.
"""

from __future__ import annotations


import numpy as np

from bayes_mr.likelihood.output_error import OutputError, channel_noise
from bayes_mr.models.integrate import steps
from bayes_mr.simulation.simulate import DRIVE, simulate
from bayes_mr.numerics.stats import hac_bandwidth

#: Monte Carlo replicas of the input-noise response (Ω's relative SD error ≈ √(2/K) per element).
N_DRAWS = 200
#: Fewest replicas (Ω's elements to ≈ 25 %), and the most RK4 sub-steps all replicas together may take:
#: the count is cut to fit (deterministically, from the simulation's own sub-step schedule) on long or stiff records.
MIN_DRAWS = 30
REPLICA_SUBSTEPS = 5.0e7


def input_noise_sd(lik: OutputError) -> dict[int, float]:
    """SD of the noise on each measured input column of the kernel rows [input units].

    Structure and forced tests: the drive (column 0); device tests: the
    imposed displacement (0) and velocity (1). Read from the record's
    ``noise_sd_<channel>`` attribute, else the noise-floor estimate; an input
    with no such attribute on a record simulated without noise gets 0.
    """
    kind = lik.kind
    names = (DRIVE[kind],) if kind != "device" else ("displacement", "velocity")
    if not all(n in lik.record for n in names):
        return {}
    if lik.record.attrs.get("noise_fraction", None) == 0.0:
        return {}
    sd = channel_noise(lik.record, names)
    return {col: float(s) for col, s in enumerate(sd) if np.isfinite(s) and s > 0}


def response_replicas(lik: OutputError, phi: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Responses of the model at φ to ``n`` fresh draws of the input noise, shape (n, N, C) [channel units].

    ŷ(φ; u + w_k) − ŷ(φ; u) on the record's sample grid, the simulation's
    grid and sub-steps replayed (:meth:`~bayes_mr.simulation.inputs.Inputs.with_rows`:
    noise widens a band-limited drive's bandwidth, which would otherwise pick
    a finer grid) so the difference is the input's effect alone. Zeros when
    the record's input has no noise.
    """
    sds = input_noise_sd(lik)
    base, sim = lik.predict(np.atleast_2d(phi))
    if sim.schedule is not None:
        # Ω's precision is not worth minutes: at most REPLICA_SUBSTEPS RK4 sub-steps of replicas in all
        # (a stiff point on a long record needs hundreds per sample; an interval ROS2 took counts its steps,
        # each ns + 2 right-hand sides against a sub-step's 4 for a device test's few states), never fewer
        # than MIN_DRAWS
        n = min(n, max(MIN_DRAWS, int(REPLICA_SUBSTEPS // max(int(np.sum(steps(sim.schedule))), 1))))
    out = np.zeros((n,) + base.shape[1:])
    if not sds:
        return out
    theta = lik.par.full(np.atleast_2d(phi))
    for k in range(n):
        rows = lik.inputs.rows.copy()
        for col, sd in sds.items():
            rows[:, col] += rng.normal(0.0, sd, rows.shape[0])
        s = simulate(lik.model, lik.inputs.with_rows(rows), theta, schedule=sim.schedule)
        if not s.ok[0]:
            continue  # a replica that diverges says nothing about small perturbations
        out[k] = np.stack([s[c][0] for c in lik.channels], axis=-1) - base[0]
    return out


def replica_middle(lik: OutputError, phi: np.ndarray, J: np.ndarray, sigma: np.ndarray, *,
                   n: int = N_DRAWS, seed: int = 0) -> tuple[np.ndarray, dict]:
    """Ω = E[(Jᵀ r)(Jᵀ r)ᵀ] over replicas r of the standardised residual (module docstring).

    Parameters
    ----------
    J : ndarray, shape (n_valid · C, p)
        Jacobian of the standardised (prewhitened) residual, rows (time, channel).
    sigma : ndarray (C,)
        The σ_c the residual is standardised by [channel units].

    Returns
    -------
    omega : ndarray (p, p)
    info : dict
        ``input_share``: per channel, the fraction of the residual variance
        the input noise explains; ``n_replicas``.
    """
    rng = np.random.default_rng(seed)
    yhat, _ = lik.predict(np.atleast_2d(phi))
    resid = np.where(lik.valid[:, None], lik.y - yhat[0], 0.0)
    e = response_replicas(lik, phi, n, rng)
    n = e.shape[0]  # fewer on a long or stiff record (REPLICA_SUBSTEPS)
    v = lik.valid
    var_r = np.mean(resid[v] ** 2, axis=0)
    var_e = np.mean(e[:, v] ** 2, axis=(0, 1))
    sd_v = np.sqrt(np.maximum(var_r - var_e, 0.0))
    e = e + rng.normal(size=e.shape) * sd_v
    if lik.residual.kind == "ar" and lik.residual.resolved:
        from bayes_mr.likelihood.noise_model import apply_filter, whiten

        _, coefs = whiten(resid[None], v, lik.residual.orders)
        e = apply_filter(e, v, lik.residual.orders, [a[0] for a in coefs])
    r = (e[:, v] / sigma).reshape(n, -1)
    s = r @ J  # (n, p) score of each replica
    omega = s.T @ s / n
    return omega, {"input_share": (var_e / np.maximum(var_r, 1e-300)).tolist(), "n_replicas": n}


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
    omega, lag = hac_middle(J, r, n_t)
    bread = np.linalg.pinv(J.T @ J)
    return bread @ omega @ bread, lag


def hac_middle(J: np.ndarray, r: np.ndarray, n_t: int) -> tuple[np.ndarray, int]:
    """The Bartlett-weighted middle Ω of :func:`hac_covariance` and its bandwidth [samples].

    Independent records add their middles: the joint sandwich of several
    records is (Σ JᵣᵀJᵣ)⁻¹ (Σ Ωᵣ) (Σ JᵣᵀJᵣ)⁻¹.
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
    return omega, lag


def loewner_max(a: np.ndarray, b: np.ndarray, rtol: float = 1e-12) -> np.ndarray:
    """The smallest symmetric matrix ≥ both ``a`` and ``b`` in their common eigen-frame, direction by direction.

    With S = a + b, the matrices S^{-1/2} a S^{-1/2} = Q diag(μ) Qᵀ and
    S^{-1/2} b S^{-1/2} = Q diag(1 − μ) Qᵀ share Q, so X = S^{1/2} Q
    diagonalises both and the result is X diag(max(μ, 1 − μ)) Xᵀ — for a
    positive definite ``a`` the same matrix as a^{1/2} max(I, a^{-1/2} b a^{-1/2}) a^{1/2}.
    Working through S rather than a^{-1/2} keeps it exact when ``a`` is
    singular: the input-noise replicas' middle is zero for a forced test whose
    force noise moves no output, and a^{-1/2} with a clipped to 1e-300 made a
    spencer covariance of 1e240 (the Bouc–Wen benchmark record). Directions
    where S is below ``rtol`` of its largest eigenvalue are zero in both.
    """
    a, b = 0.5 * (a + a.T), 0.5 * (b + b.T)
    w, u = np.linalg.eigh(a + b)
    keep = w > rtol * max(float(w.max()), 0.0)
    half, inv_half = u[:, keep] * np.sqrt(w[keep]), u[:, keep] / np.sqrt(w[keep])
    mu, q = np.linalg.eigh(inv_half.T @ a @ inv_half)
    x = half @ q
    return (x * np.maximum(mu, 1.0 - mu)) @ x.T


#: A direction of the prior-scaled information whose eigenvalue is below this fraction of the largest is
#: one the record does not see (the pseudo-inverses above give it zero variance); comfortably above
#: ``numpy.linalg.pinv``'s own cut (1e-15), far below any direction a record determines.
UNSEEN_RTOL = 1e-12


def prior_on_unseen(cov: np.ndarray, info: np.ndarray, widths: np.ndarray) -> np.ndarray:
    """``cov`` [φ²] with the uniform prior's variance in the directions the information ``info`` does not see.

    Every covariance here is built on a pseudo-inverse of the information
    JᵀJ, which gives a direction with no information (a voltage parameter on
    a record without a command, a law a saturated state switches off) zero
    variance: the parameter would be reported as known to the last digit.
    The posterior there is the prior, uniform on the box. In the box's scaled
    frame (φ / width, the prior the unit cube, variance 1/12 along any unit
    direction) the null space of D JᵀJ D, D = diag(widths), is found by
    :data:`UNSEEN_RTOL` and given that variance; it is orthogonal to the range
    of the pseudo-inverse, so every seen direction keeps its covariance
    exactly. Draws are then truncated to the box (:func:`~.base.laplace_draws`).

    Parameters
    ----------
    cov : ndarray (p, p)
        Covariance of φ built on ``pinv(info)``.
    info : ndarray (p, p)
        JᵀJ (or any information with the same null space).
    widths : ndarray (p,)
        Prior box widths hi − lo in φ.
    """
    d = np.asarray(widths, float)
    scaled = d[:, None] * info * d[None, :]
    w, u = np.linalg.eigh(0.5 * (scaled + scaled.T))
    null = u[:, w <= UNSEEN_RTOL * max(float(w.max()), 0.0)]
    if null.shape[1] == 0:
        return cov
    v = d[:, None] * null  # the null directions in φ, each of prior variance 1/12 in the scaled frame
    return cov + (v @ v.T) / 12.0


def within_prior(cov: np.ndarray, widths: np.ndarray) -> np.ndarray:
    """``cov`` [φ²] with no direction wider than the prior's box: SD at most one box width.

    A direction the record barely sees (a stiffness pinned at its lower bound,
    where it moves the output by nothing) has a tiny but nonzero information, so
    :func:`prior_on_unseen` keeps it and its pseudo-inverse variance can be
    10⁶ box widths squared. The posterior there is the prior (uniform on the
    box); a Gaussian of that variance truncated to the box draws almost nothing
    inside it. In the box's scaled frame (φ / width) every eigenvalue of the
    covariance is capped at 1 — an SD of one box width, whose Gaussian
    truncated to the box is within a factor e^-½ of uniform across it — and every
    direction the record determines (variance far below the box) is untouched.
    """
    d = np.asarray(widths, float)
    scaled = cov / d[:, None] / d[None, :]
    w, u = np.linalg.eigh(0.5 * (scaled + scaled.T))
    if w.max() <= 1.0:
        return cov
    capped = (u * np.minimum(w, 1.0)) @ u.T
    return d[:, None] * capped * d[None, :]


def sandwich(J: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """B⁻¹ Ω B⁻¹ with B = JᵀJ (pseudo-inverse) [φ²]."""
    bread = np.linalg.pinv(J.T @ J)
    return bread @ omega @ bread


def _sqrt_pair(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Symmetric square root of a covariance and of its (pseudo-)inverse."""
    w, u = np.linalg.eigh(0.5 * (cov + cov.T))
    w = np.clip(w, 1e-12 * max(float(w.max()), 1e-300), None)
    return (u * np.sqrt(w)) @ u.T, (u / np.sqrt(w)) @ u.T


def adjust_draws(phi: np.ndarray, center: np.ndarray, cov_model: np.ndarray, cov_target: np.ndarray) -> np.ndarray:
    """Posterior draws of φ (..., p) mapped affinely about ``center`` from the model's to the target covariance.

    φ' = c + A (φ − c), A = Σ_t^{1/2} Σ_m^{-1/2}: a posterior sampled from a
    likelihood whose curvature is Σ_m⁻¹ (the iid or AR Gauss–Newton
    information) gets the calibrated covariance Σ_t (least squares'
    sandwich) while keeping its shape — the curvature adjustment of Ribatet,
    Cooley & Davison (2012) and Shaby (2014). With Σ_t = Σ_m it is the identity.
    """
    half_t, _ = _sqrt_pair(cov_target)
    _, inv_half_m = _sqrt_pair(cov_model)
    A = half_t @ inv_half_m
    c = np.asarray(center, float)
    return c + (np.asarray(phi, float) - c) @ A.T


def truncate_to_box(phi: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                    rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """Adjusted draws (W, n, p) restricted to the prior's box, and the fraction that fell outside.

    The calibrated posterior is the adjusted likelihood times the prior; with
    the uniform box prior of :meth:`~bayes_mr.likelihood.output_error.OutputError.log_prior`
    that is the adjusted draws truncated to the box. A draw the map carried out
    of it (a direction the data barely constrain, whose calibrated variance
    exceeds the box) is replaced by one drawn at random from the draws inside,
    so the array keeps its (walker, draw) shape. With no draw inside (a map
    that moved everything out) the draws are returned as they are with
    fraction 1.0, for the caller to report.
    """
    phi = np.asarray(phi, float)
    flat = phi.reshape(-1, phi.shape[-1])
    inside = np.all((flat >= lower) & (flat <= upper), axis=1)
    n_out = int(np.count_nonzero(~inside))
    if n_out == 0 or n_out == inside.size:
        return phi, n_out / inside.size
    out = flat.copy()
    out[~inside] = flat[inside][rng.integers(0, inside.sum(), size=n_out)]
    return out.reshape(phi.shape), n_out / inside.size


def describe(res, channels: tuple[str, ...]) -> dict:
    """The fit JSON's ``uncertainty``: how a least-squares result's covariance was made.

    ``covariance``: ``gls`` ((JᵀJ)⁻¹ of whitened residuals found white),
    ``hac`` (the Bartlett sandwich) or ``hac+input_noise`` (its middle
    widened by the input-noise replicas); with the replicas, ``input_share``
    (channel → fraction of the residual variance the input noise explains)
    and ``n_replicas``.
    """
    kind = "gls" if res.hac_lag == 0 and res.whiteness_p is not None else "hac"
    if res.input_noise is None:
        return {"covariance": kind}
    return {"covariance": kind + "+input_noise", "n_replicas": res.input_noise["n_replicas"],
            "input_share": dict(zip(channels, res.input_noise["input_share"]))}

