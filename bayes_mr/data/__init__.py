"""Measured and simulated records: one validated xarray schema (see schema.py).

The public entry points: :func:`load` (read a CSV, CSV.gz or netCDF record
and prepare it: units, derived velocity, quality control, optional noise
floor and trimming; each step is a function of its own module),
:func:`write_record`, :func:`load_packaged` (the measured NEES MR-damper
record), :func:`apply_quality` (mask clipping, spikes, jumps, dropouts,
end-of-test disturbances), :func:`noise_floor` and :func:`trim_excited`;
:func:`load_records` reads several records (files or a manifest CSV) into a :class:`RecordSet`.
"""

from bayes_mr.data.load import load
from bayes_mr.data.nees import load_packaged
from bayes_mr.data.noise_floor import noise_floor
from bayes_mr.data.quality import QualityConfig, apply_quality
from bayes_mr.data.read_csv import read_inputs
from bayes_mr.data.records import RecordSet, load_records
from bayes_mr.data.schema import DEVICE, STRUCTURE, RecordError, make_record
from bayes_mr.data.trim import trim_excited
from bayes_mr.data.write import write_record

__all__ = [
    "DEVICE", "QualityConfig", "RecordError", "STRUCTURE", "apply_quality", "load", "load_packaged",
    "RecordSet", "load_records", "make_record", "noise_floor", "read_inputs", "trim_excited", "write_record",
]
