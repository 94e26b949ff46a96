"""Training, validation and selection of models (thesis §3.6).

* :mod:`.validation` — the thesis's identification methods 1, 2, 3 (train
  the UKF, score every run on a record, keep the lowest MSE) as
  :class:`Trial` objects, and :func:`best_trial` across models (Fig. 3.16).

The UKF training itself and the scoring of its runs live in
:mod:`bayes_mr.inference.ukf.training` and
:mod:`bayes_mr.inference.ukf.validation`; the scores in :mod:`bayes_mr.scores`.
"""

from bayes_mr.selection.thesis_methods import Trial, best_trial, method1, method2, method3

__all__ = ["Trial", "best_trial", "method1", "method2", "method3"]
