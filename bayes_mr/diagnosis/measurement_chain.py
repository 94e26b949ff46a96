"""The measurement chain of a decimated record, applied to the model's prediction too.

:func:`bayes_mr.data.derive.decimate_record` low-pass filters every channel
before it keeps every ``factor``-th sample (:func:`scipy.signal.decimate`:
Chebyshev I, order 8, 0.05 dB ripple, cut-off 0.8 × the new Nyquist
frequency, forwards and backwards). The measured force of a decimated record
has therefore lost its content above ~0.8 × Nyquist; a model's simulated force
at the same sample instants has not. Compared as they are, a model is charged
for force content the preparation took out of the data (and on the NEES
damper, whose force has sharp transitions at every 10-ms command or motion
update, that is a third of the part-B residual's power, measured): the
comparison is only fair when the prediction passes through the same filter.

:class:`ChainOutputError` is :class:`~bayes_mr.likelihood.output_error.OutputError` with
that filter applied to every predicted channel; :func:`through_chain` applies
it to one prediction. On a record that was not decimated both are the
identity. This is the observation operator, not damper physics: the report
gives part-B errors with and without it.
"""

from __future__ import annotations

import numpy as np
import xarray as xr
from scipy import signal

from bayes_mr.likelihood.output_error import OutputError

#: scipy.signal.decimate's IIR anti-alias filter: order, pass-band ripple [dB], cut-off (share of Nyquist).
ORDER, RIPPLE_DB, CUTOFF = 8, 0.05, 0.8


def decimated(record: xr.Dataset) -> bool:
    """Whether ``record`` went through :func:`~bayes_mr.data.derive.decimate_record` (attribute ``decimated`` > 1)."""
    return int(record.attrs.get("decimated", 1)) > 1


def filter_coefficients() -> tuple[np.ndarray, np.ndarray]:
    """(b, a) of the last decimation stage's low-pass, at the decimated record's own rate."""
    return signal.cheby1(ORDER, RIPPLE_DB, CUTOFF)


def through_chain(record: xr.Dataset, y: np.ndarray, axis: int = -1) -> np.ndarray:
    """``y`` (samples along ``axis``) through ``record``'s anti-alias filter, zero phase; unchanged if not decimated."""
    y = np.asarray(y, float)
    if not decimated(record):
        return y
    b, a = filter_coefficients()
    return signal.filtfilt(b, a, y, axis=axis)


class ChainOutputError(OutputError):
    """:class:`~bayes_mr.likelihood.output_error.OutputError` whose predictions pass through the record's decimation filter.

    Same arguments; every estimator and refit that reads ``predict`` sees the
    filtered channels, so a fit on a decimated record is scored against what
    the preparation left in the data.
    """

    def predict(self, phi: np.ndarray, schedule: np.ndarray | None = None, **options):
        yhat, sim = super().predict(phi, schedule, **options)
        if decimated(self.record):
            yhat = through_chain(self.record, yhat, axis=-2)
        return yhat, sim
