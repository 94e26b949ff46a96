"""Quality control of measured records: detect, mask, repair inputs, report.

Lab records carry faults that are not errors: a channel clipped at a rail
value, isolated spikes, implausible jumps, dropouts and flat-lines, and a
disturbance at the end of a test. :func:`assess` finds them with thresholds
that are robust statistics of the record itself (see :class:`QualityConfig`),
:func:`apply_quality` writes the mask into the record's ``valid`` variable.
Masked samples are never deleted — time stays uniform — and every
likelihood, filter update and metric skips them. Input channels (what drives
a simulation) are additionally repaired by linear interpolation across their
own faults so that a simulator driven by them is not corrupted.

All thresholds were calibrated on families of clean simulated records
(band-limited random, frequency and amplitude sweeps; device tests with a
tanh-plus-Dahl force that has sharp velocity-reversal corners; structure
tests of the thesis's Dahl frame; several seeds, amplitudes, force scales and
sampling rates, 1 % noise) so that nothing is masked on clean data with a
margin, and on the NEES MR-damper record, where nothing is masked either.
"""

from bayes_mr.data.quality.assessment import INPUTS, POLARITY, apply_quality, assess, default_channels, report_of
from bayes_mr.data.quality.config import QualityConfig
from bayes_mr.data.quality.report import FAULT_KINDS, Fault, QualityReport, Repair

__all__ = [
    "FAULT_KINDS", "Fault", "INPUTS", "POLARITY", "QualityConfig", "QualityReport", "Repair",
    "apply_quality", "assess", "default_channels", "report_of",
]
