"""Least squares: the output-error optimum, its Laplace covariance and evidence.

* :mod:`.least_squares` — :func:`~.least_squares.fit_lsq` (multi-start trust-region search from
  convex sub-fit starts) and :func:`~.least_squares.laplace`;
* :mod:`.refine` — the inner loop: standardised residuals, their Jacobian, one refinement;
* :mod:`.subfit` — starting values from the convex sub-fit of the parameters that enter linearly;
* :mod:`.evidence_scale` — the magnitude-adjusted Laplace evidence behind Bayes factors under model error.
"""

from bayes_mr.inference.lsq.least_squares import LSQResult, LSQSettings, fit_lsq, laplace

__all__ = ["LSQResult", "LSQSettings", "fit_lsq", "laplace"]
