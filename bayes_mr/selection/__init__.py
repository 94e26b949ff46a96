"""Training, validation and selection of models (thesis §3.6).

* :mod:`.scores` — MSE (3-44) and force errors (3-45..3-49) of a prediction;
* :mod:`.training` — the UKF from the thesis's LHS × τ priors, as one Dataset;
* :mod:`.validation` — every trained run scored on a record; methods 1, 2, 3
  and the selection of the lowest MSE;
* :mod:`.ukf_fit` — the ``ukf`` engine of ``bayes-mr fit`` (InferenceData).
"""

from ..scores import Scorer, score
from .training import concat_records, train
from .validation import Trial, method1, method2, method3, select, validate_runs

__all__ = [
    "Scorer", "Trial", "concat_records", "method1", "method2", "method3", "score", "select", "train",
    "validate_runs",
]
