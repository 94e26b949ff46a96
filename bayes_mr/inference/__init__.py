"""Inference: one likelihood, three estimators, one result schema.

* :mod:`.base` — the estimator protocol and :class:`~.base.Posterior`, what every engine returns;
* :mod:`.estimators` — the three engines :class:`~.estimators.LeastSquares`, :class:`~.estimators.Emcee`
  and :class:`~.estimators.UKF`;
* :mod:`.lsq`, :mod:`.mcmc`, :mod:`.ukf` — each engine's algorithm; :mod:`.evidence` — the sampling
  evidence routes; :mod:`.mcmc_posterior` — a chain and its evidence as a :class:`~.base.Posterior`;
* :mod:`.calibrate` — honest covariances under noise on the measured input, for every engine;
* :mod:`.results` — the one ArviZ InferenceData schema, saved and loaded;
* :mod:`.identify` — :class:`~.identify.Identify`: a model, a record, an engine → InferenceData.
"""

from bayes_mr.inference.base import Posterior
from bayes_mr.inference.estimators import UKF, Emcee, LeastSquares, engine
from bayes_mr.inference.identify import Identify, predict, validate
from bayes_mr.inference.results import load_result, point_of, save, summary_of

__all__ = ["UKF", "Emcee", "Identify", "LeastSquares", "Posterior", "engine", "load_result", "point_of",
           "predict", "save", "summary_of", "validate"]
