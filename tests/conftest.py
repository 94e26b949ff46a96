"""Fixtures shared by every test folder.

The record recipes live in ``tests/records.py`` (plain functions, importable
from any folder because ``pyproject.toml`` puts ``tests/`` on the path); the
fixtures below hand the same builders to tests that prefer fixtures, and
build the small records several files use.
"""

from __future__ import annotations

import os

import pytest
import records

# The suite simulates dozens of models once each: the generic kernel (compiled once, cached in the
# package) suits that; the specialised kernels compile per model and are tested in test_specialise.py.
os.environ.setdefault("BAYES_MR_KERNELS", "generic")  # no per-model compiles in the suite (auto would specialise long fits)


@pytest.fixture(scope="session")
def structure_record():
    """The builder :func:`records.structure_record` (band-limited ground motion, noisy outputs)."""
    return records.structure_record


@pytest.fixture(scope="session")
def signal_record():
    """The builder :func:`records.signal_record` (a named signal through ``synthesize``)."""
    return records.signal_record


@pytest.fixture(scope="session")
def device_inputs():
    """The builder :func:`records.device_inputs` (imposed damper motion and voltage)."""
    return records.device_inputs


@pytest.fixture(scope="session")
def offset_device_record():
    """The builder :func:`records.offset_device_record` (Dahl device test with a hidden force offset)."""
    return records.offset_device_record
