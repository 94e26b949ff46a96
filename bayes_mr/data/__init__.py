"""Measured and simulated records: one validated xarray schema (see schema.py).

The public entry points: :func:`load` (read a CSV, CSV.gz or netCDF record
and prepare it: units, derived velocity, quality control, optional noise
floor and trimming; each step is a function of its own module),
:func:`write_record`, :func:`load_packaged` (the measured NEES MR-damper
record), :func:`apply_quality` (mask clipping, spikes, jumps, dropouts,
end-of-test disturbances), :func:`noise_floor` and :func:`trim_excited`.
"""

from .load import load
from .nees import load_packaged
from .noise_floor import noise_floor
from .quality import QualityConfig, apply_quality
from .read_csv import read_inputs
from .schema import DEVICE, STRUCTURE, RecordError, make_record
from .trim import trim_excited
from .write import write_record

__all__ = [
    "DEVICE", "QualityConfig", "RecordError", "STRUCTURE", "apply_quality", "load", "load_packaged",
    "make_record", "noise_floor", "read_inputs", "trim_excited", "write_record",
]
