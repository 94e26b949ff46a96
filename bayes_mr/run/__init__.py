"""The main job (``bayes-mr run``, ``make run``): the packaged measured MR damper through the whole procedure.

* :mod:`.plan` — :class:`~.plan.Budget`, how much of the record and of each estimator a run uses
  (:data:`~.plan.FULL` for ``make run``, :data:`~.plan.QUICK` for ``--quick``);
* :mod:`.records` — the measured record prepared and split into part A (training) and part B (held out);
* :mod:`.job` — :func:`~.job.run`: first pass, posteriors, stages, report;
* :mod:`.posteriors` — the emcee posteriors from one pool of work (integrator steps) under a wall-time cap;
* :mod:`.stages` — the stages that need only the first pass (diagnosis, virtual shake table);
* :mod:`.aside` — those stages in a child process beside the posteriors, where cores allow;
* :mod:`.context` — a paper's parameters and the other residual model, for the headline;
* :mod:`.warmup` — the UKF's filter compiled in a child process while the first fits run.
"""

from bayes_mr.run.job import run
from bayes_mr.run.plan import FULL, QUICK, Budget

__all__ = ["FULL", "QUICK", "Budget", "run"]
