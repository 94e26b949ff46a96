"""The UKF over several records in turn: the parameter part of the state carried, the motion states reset.

Several records of one device are filtered as one run over the records one
after another (:func:`~bayes_mr.inference.ukf.training.concat_records`, thesis
method 3): at the first sample of each record the model's states restart from
rest with their initial covariance, while the parameters' mean and covariance
carry over, so each record updates the estimate the previous ones left. The
filter has one measurement-noise covariance: the records share their pooled
noise variances (exact for one rig's sensors; least squares and emcee keep
each record's own σ_r). A run is chosen by its MSE pooled over the records
(:func:`~bayes_mr.inference.ukf.validation.combine`), each simulated from rest.

Per-record force offsets (``JointLikelihood(record_offsets=True)``) are refused: the filter's augmented
state carries one parameter vector through every record, so an offset there would be one offset of the
whole set (``MODEL+force_offset``), not one per test. A per-record nuisance needs its own state, reset to
its prior at each record's first sample, and its estimate read at each record's last; the filter does not
have that, so least squares and emcee estimate the offsets.
"""

from __future__ import annotations

import xarray as xr

from bayes_mr.inference.ukf.training import concat_records
from bayes_mr.inference.ukf.validation import combine, validate_runs
from bayes_mr.likelihood.joint import JointLikelihood
from bayes_mr.likelihood.output_error import OutputError


def filtered(lik: OutputError | JointLikelihood) -> tuple[OutputError, object, list[xr.Dataset]]:
    """What the filter runs on: (one record's likelihood, reset mask or None, the records it scores runs on).

    A joint likelihood of several records gives the likelihood of the records joined one after another,
    with the joint's coordinates (prior scales, ranges, fixed parameters), and the samples where each
    record after the first starts (module docstring); one record's likelihood is returned as it is.

    Raises
    ------
    ValueError
        The records differ in sampling interval, storey mass or command interpolation (one filter run
        reads one grid): the message names the record and what to do.
    """
    if not isinstance(lik, JointLikelihood):
        return lik, None, [lik.record]
    if len(lik.parts) == 1:
        return lik.parts[0], None, [lik.parts[0].record]  # with record offsets: its MODEL+force_offset
    if lik.record_offsets:
        raise ValueError("the UKF does not estimate per-record force offsets (its parameter state is carried "
                         "across the records): fit them by least squares or emcee (--engine lsq|mcmc), or drop "
                         "--record-offsets")
    joined, reset = concat_records(lik.records)
    one = OutputError(lik.model, joined, ranges=lik.ranges, fixed=lik.fixed, noise=lik.noise, scales=lik.scales)
    return one, reset, lik.records


def validate_on_records(training: xr.Dataset, records: list[xr.Dataset]) -> xr.Dataset:
    """Every trained run scored on each record (simulated from rest) and pooled over them."""
    return combine([validate_runs(training, r) for r in records])
