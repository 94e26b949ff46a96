"""The augmented-state unscented Kalman filter (thesis §3.4–3.6): joint state and parameter estimation.

* :mod:`.filter` — :class:`~.filter.UKFSettings`, the priors and one batched filter run;
* :mod:`.kernel`, :mod:`.unscented`, :mod:`.sigma_points` — the compiled filter and its sigma points;
* :mod:`.training` — the thesis's 100-prior training as one labelled Dataset;
* :mod:`.validation` — every trained run scored on a record, the best one kept;
* :mod:`.crosscheck` — UKF estimates against the MCMC posterior of the same model and record.
"""

from bayes_mr.inference.ukf.filter import TAUS, UKFSettings
from bayes_mr.inference.ukf.training import train

__all__ = ["TAUS", "UKFSettings", "train"]
