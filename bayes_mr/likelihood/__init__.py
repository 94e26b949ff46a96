"""The one likelihood every estimator reads: a model, a record and a residual model → ln p(y | θ).

* :mod:`.output_error` — :class:`~.output_error.OutputError`, the output-error log-density of θ in
  the thesis's log-scaled coordinates, with its prior box and noise floors;
* :mod:`.noise_model` — the residual models (independent or AR(p) errors) it whitens with.
"""

from bayes_mr.likelihood.noise_model import ResidualModel
from bayes_mr.likelihood.output_error import OutputError, Parameterisation, channel_noise

__all__ = ["OutputError", "Parameterisation", "ResidualModel", "channel_noise"]
