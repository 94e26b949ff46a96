"""Measured and simulated records: one validated xarray schema (see schema.py).

The public entry points: :func:`read_record` / :func:`write_record` (CSV,
CSV.gz, netCDF), :func:`load_packaged` (the measured NEES MR-damper record),
:func:`apply_quality` (mask clipping, spikes, jumps, dropouts, end-of-test
disturbances), :func:`noise_floor` and :func:`trim_excited`.
"""

from .io import read_record, write_record
from .nees import load_packaged
from .noise import noise_floor, trim_excited
from .quality import QualityConfig, apply_quality
from .schema import DEVICE, STRUCTURE, RecordError, make_record

__all__ = [
    "DEVICE", "QualityConfig", "RecordError", "STRUCTURE", "apply_quality", "load_packaged",
    "make_record", "noise_floor", "read_record", "trim_excited", "write_record",
]
