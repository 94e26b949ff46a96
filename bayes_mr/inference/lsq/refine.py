"""Output-error least squares' inner loop: the standardised residual vector, its Jacobian and one refinement.

:class:`Residuals` is the residual vector r(φ) = (y − ŷ(φ))/σ over the valid
samples (prewhitened under an AR residual model) and its Jacobian, on the base
point's sub-step schedule (one grid, so the derivatives see the parameters and
not the step control): exact, from the forward sensitivities integrated beside
the states in one run (:mod:`bayes_mr.simulation.sensitivity`), where the model
has them and the residual is not prewhitened (profiled AR coefficients make the
whitened residual nonlinear in ŷ); else by finite differences, the perturbed
simulations replaying that schedule. :func:`refine` runs scipy's bounded trust-region least squares on
it from one start; :mod:`bayes_mr.inference.lsq.least_squares` (the search, Laplace,
evidence) and :mod:`bayes_mr.diagnosis.diagnose` (candidate refits) call it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import optimize

from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.inference.lsq.memo import simulated, slopes
from bayes_mr.inference.lsq.subfit import stiff
from bayes_mr.simulation import sensitivity


def standardised(lik: OutputError, yhat: np.ndarray, sd: np.ndarray) -> np.ndarray:
    """(y − ŷ)/σ over valid samples (n_valid, C); prewhitened under a chosen AR model (GLS)."""
    if lik.residual.kind == "iid":  # with no masked sample, no boolean-indexed copies (0.7 ms at 30 s, 1 kHz)
        return (lik.y - yhat) / sd if lik.valid.all() else (lik.y[lik.valid] - yhat[lik.valid]) / sd
    return lik.whiten(np.where(lik.valid[:, None], lik.y - yhat, 0.0))[lik.valid] / sd


class Residuals:
    """Standardised (under AR: prewhitened) residual vector and its Jacobian (module docstring).

    ``cap``: most sub-steps per sample interval (the search's cost cap); a
    simulation saturating it too often counts as a diverged one. ``exact``:
    use the forward sensitivities where :meth:`has_exact` (False: finite
    differences always, the reference they are tested against).
    """

    def __init__(self, lik: OutputError, sd: np.ndarray, cap: int | None = None, exact: bool = True):
        self.lik = lik
        self.sd = np.asarray(sd, float)
        self.schedule = None
        self.options = {} if cap is None else {"n_max": int(cap)}
        self.cap = cap
        self.last = None  # (φ, residual) of the last evaluation that simulated: the Jacobian's base point
        self.at = None  # φ of the last evaluation (its schedule is ``schedule``), accepted or not
        self.exact = exact and self.has_exact(lik)

    @staticmethod
    def has_exact(lik: OutputError) -> bool:
        """Whether ``lik``'s Jacobian comes from sensitivities: a covered model, channels that have them
        (:data:`~bayes_mr.simulation.sensitivity.CHANNELS`: a device test's force, a structure or forced test's
        displacement, velocity and acceleration), and residuals that are not prewhitened (iid, or AR before
        its orders are chosen). Each evaluation also needs a schedule without ROS2 intervals
        (:func:`~bayes_mr.simulation.sensitivity.replayable`), else it takes finite differences."""
        return (sensitivity.covered(lik.model, lik.kind)
                and all(c in sensitivity.CHANNELS[lik.kind] for c in lik.channels)
                and (lik.residual.kind == "iid" or not lik.residual.resolved))

    def __call__(self, phi):
        yhat, sim = simulated(self.lik, phi, **self.options)
        self.schedule = sim.schedule[0]
        self.at = np.array(phi, float)
        r = standardised(self.lik, yhat[0], self.sd)
        self.last = None
        if not sim.ok[0] or not np.all(np.isfinite(r)) or stiff(sim.schedule[:1], self.cap)[0]:
            # a diverged (or, while searching, too stiff) simulation is a very bad fit, not a crash
            worst = 1e3 * np.max(np.abs(self.lik.y[self.lik.valid]) / self.sd)
            return np.full(r.size, worst)
        self.last = (np.array(phi, float), r.ravel())
        return r.ravel()

    def jacobian(self, phi, central: bool = False):
        """∂r/∂φ (n_valid·C, p) at φ: exact where :attr:`exact` (``central`` is then moot), else forward
        (``central``: central) differences of step 1e-6·max(1, |φ_j|)."""
        if self.exact:
            J = self._sensitivity_jacobian(phi)
            if J is not None:
                return J
        p = phi.size
        h = 1e-6 * np.maximum(1.0, np.abs(phi))
        # trust-region asks for J(φ) right after r(φ): the base point is not simulated again (same numbers)
        known = not central and self.last is not None and np.array_equal(self.last[0], phi)
        batch = [] if known else [phi]
        for j in range(p):
            e = np.zeros(p)
            e[j] = h[j]
            batch.append(phi + e)
            if central:
                batch.append(phi - e)
        if self.schedule is None:
            self(phi)
        yhat, _ = self.lik.predict(np.array(batch), schedule=self.schedule)
        r = ([self.last[1]] if known else []) + [standardised(self.lik, yh, self.sd).ravel() for yh in yhat]
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

    def _sensitivity_jacobian(self, phi):
        """−(∂ŷ/∂φ)/σ_c over the valid samples from one run with sensitivities, on φ's own schedule; zeros where
        φ's simulation diverged (as the differences give; a point only rejected as too stiff for the search
        keeps its slope, as there), None where the schedule holds a ROS2 interval (the sensitivities follow
        RK4 only: the caller takes finite differences)."""
        phi = np.asarray(phi, float)
        if self.at is None or not np.array_equal(self.at, phi):
            self(phi)  # the schedule at φ itself
        if not sensitivity.replayable(self.schedule):
            return None
        lik = self.lik
        n_res = lik.n_valid * len(lik.channels)
        dy = slopes(lik, phi, self.options, lambda: self._slopes(phi))  # kept beside φ's run (self(φ) above)
        if dy is None:
            return np.zeros((n_res, phi.size))
        # rows as standardised() ravels its (n_valid, C): sample by sample, the channels within a sample
        return -(dy / self.sd[None, :, None]).reshape(n_res, phi.size)

    def _slopes(self, phi):
        """∂ŷ/∂φ (n_valid, C, p) at φ on its schedule, or None where the run diverged."""
        lik = self.lik
        _, dy, failed = sensitivity.output_sensitivities(lik.model, lik.inputs, lik.par.full(phi), self.schedule,
                                                         lik.channels)
        dy = dy[:, :, lik.par.free_idx] * lik.par.coords.dtheta_dphi(phi)
        if failed >= 0 or not np.all(np.isfinite(dy)):
            return None
        return dy if lik.valid.all() else dy[lik.valid]


#: Relative cost tolerance of the trust-region refinement: it stops after an accepted step that lowers
#: ½Σr² by less than FTOL of itself. The cost of standardised residuals is about half their number, so this is
#: ~1.5e-6 in log-likelihood on a 30-s, 1-kHz, two-channel record (3e4) and 5e-5 on 1e6 residuals — far below
#: any difference the package reports or decides on. On the bench's diagnose (``bayes-mr bench``, 70
#: refinements) 1e-12 spent 36 % of the simulations after the cost was within 1e-10 of its final value (the last
#: accepted steps lower it by ~1e-9 relative, then the trust region shrinks to ``xtol``). At 1e-8 the
#: small-amplitude record's diagnosis names the wrong cause; at 1e-10 the hidden-effect tests of
#: ``tests/diagnosis/test_diagnose.py`` hold.
FTOL = 1e-10


#: scipy ``least_squares``' status when its callback raised StopIteration: a refinement :class:`Stall` stopped.
STALLED = -2


@dataclass(frozen=True)
class Stall:
    """Stop a refinement whose last ``steps`` accepted steps together lowered ½Σr² by less than ``nats``.

    With residuals standardised by the noise SDs, ½Σr² is −ln L up to a
    constant, so ``nats`` is a log-likelihood: a refinement crawling along a
    ridge at that rate is stopped where what it could still gain is far below
    what a caller decides on (diagnose's screen: a threshold of 8 on a score
    of Δℓ/κ). The point returned is the last accepted one; scipy's status is :data:`STALLED`.
    A caller that builds on the point (the next round's base) refines it again
    without a stall rule.
    """

    steps: int = 3
    nats: float = 0.05

    def callback(self):
        """A fresh ``least_squares`` callback applying the rule (it raises StopIteration)."""
        seen: list[float] = []

        def check(intermediate_result):
            seen.append(float(intermediate_result.cost))
            if len(seen) > self.steps and seen[-1 - self.steps] - seen[-1] < self.nats:
                raise StopIteration

        return check


def refine(lik: OutputError, phi0: np.ndarray, sd: np.ndarray, max_nfev: int,
           cap: int | None = None, stall: Stall | None = None, exact: bool = True,
           residuals=None) -> optimize.OptimizeResult:
    """Bounded trust-region least squares (scipy's ``trf``, ``x_scale="jac"``) of :class:`Residuals` from φ₀.

    Parameters
    ----------
    lik : OutputError
    phi0 : ndarray (p,)
        Start [φ]; moved inside the box by 1e-9 of its width if it sits on a bound.
    sd : ndarray (n_channels,)
        Channel weights σ_c [channel units].
    max_nfev : int
        Most residual evaluations.
    cap : int, optional
        Most sub-steps per sample interval (:class:`Residuals`).
    stall : Stall, optional
        Stop early on a crawl (:class:`Stall`); None: only scipy's tolerances and ``max_nfev`` stop it.
    exact : bool
        Exact Jacobians where the model has sensitivities (:class:`Residuals`); False: finite differences.
    residuals : object, optional
        The residual vector and its Jacobian (``__call__``, ``jacobian``) in place of
        :class:`Residuals` of ``lik`` (a joint fit's, over several records); ``sd``, ``cap`` and ``exact`` are
        then its own.

    Returns
    -------
    scipy.optimize.OptimizeResult
        ``x`` the refined φ, ``cost`` ½Σr² there, ``nfev``, ``status`` (:data:`STALLED`: stopped by ``stall``).
    """
    res_fn = residuals if residuals is not None else Residuals(lik, sd, cap, exact)
    lo, hi = lik.phi_lo, lik.phi_hi
    x0 = np.clip(phi0, lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
    return optimize.least_squares(
        res_fn, x0, jac=res_fn.jacobian, bounds=(lo, hi), method="trf",
        x_scale="jac", xtol=1e-12, ftol=FTOL, gtol=1e-12, max_nfev=max_nfev,
        callback=None if stall is None else stall.callback(),
    )
