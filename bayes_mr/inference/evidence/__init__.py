"""Model evidence ln p(y | model) by sampling: thermodynamic integration, stepping stone and
transitional MCMC, beside the Laplace evidence of least squares.

* :mod:`.routes` — :func:`~.routes.evidence_routes` and the rule that picks one;
* :mod:`.ladder` — the temperature ladder the first two share;
* :mod:`.tmcmc` — transitional MCMC (opt-in).
"""

from bayes_mr.inference.evidence.routes import Evidence, evidence_routes, select_route

__all__ = ["Evidence", "evidence_routes", "select_route"]
