"""Scores of a prediction against a record (thesis eqs. 3-44 … 3-49).

* :mod:`.metrics` — the formulas on plain arrays: :func:`mse` (3-44),
  :func:`force_errors` (E_t, E_x, E_ẋ, 3-45 … 3-49), :func:`force_nrmse`;
* :mod:`.scorer` — :class:`Scorer` binds them to a record (its valid mask,
  noise SDs and derived velocity), and :func:`score` scores one prediction.
"""

from bayes_mr.scores.metrics import force_errors, force_nrmse, mse
from bayes_mr.scores.scorer import Scorer, score

__all__ = ["Scorer", "force_errors", "force_nrmse", "mse", "score"]
