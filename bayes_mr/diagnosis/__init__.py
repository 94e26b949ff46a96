"""Diagnosis: what a model gets wrong on measured data, its cause, the extended model and the gain.

* :mod:`.diagnose` — :func:`~.diagnose.diagnose`, the whole route: baseline, residual, cause, extension, gain;
* :mod:`.result` — :class:`~.result.Diagnosis`, what it returns (JSON keys, table, figure, fits);
* :mod:`.residuals` — where the simulation departs from the record (time, displacement, velocity, command);
* :mod:`.screen`, :mod:`.inflation` — every named effect scored as an extension, corrected for correlated
  residuals; :mod:`.search` — how effects are added and ranked;
* :mod:`.extend`, :mod:`.fits` — the extended model fitted and measured on a part it never saw;
* :mod:`.term_search`, :mod:`.library` — open-ended terms for what no named effect explains;
* :mod:`.unexplained` — what remains against the record's noise floor;
* :mod:`.ranking` — of the effects that pass, which explains the record, and which the record cannot tell apart;
* :mod:`.report` — the figures and ``diagnose.md`` of a diagnosis;
* :mod:`.measurement_chain` — a decimated record's anti-alias chain, applied to the prediction too.
"""

from bayes_mr.diagnosis.diagnose import diagnose, select_baseline
from bayes_mr.diagnosis.result import Diagnosis

__all__ = ["Diagnosis", "diagnose", "select_baseline"]
