"""BLAS limited to one thread by the compute layer (bayes_mr._compile.threads), with an override."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from bayes_mr._compile.threads import ENV, blas_threads

_PROBE = ("import scipy.linalg\nimport bayes_mr.simulation.simulate\n"
          "from threadpoolctl import threadpool_info\n"
          "print(sorted({i['num_threads'] for i in threadpool_info() if i['user_api'] == 'blas'}))")


def _blas_threads_after_import(value: str | None, probe: str = _PROBE) -> list[int]:
    env = {k: v for k, v in os.environ.items() if k not in (ENV, "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    if value is not None:
        env[ENV] = value
    out = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


def test_importing_the_compute_layer_limits_every_blas_library_to_one_thread():
    assert _blas_threads_after_import(None) == [1]


def test_the_override_is_applied_and_zero_leaves_blas_alone():
    assert _blas_threads_after_import("1") == [1]
    # "0": what the same libraries run with when bayes_mr is not imported at all
    untouched = _blas_threads_after_import(None, _PROBE.replace("import bayes_mr.simulation.simulate\n", ""))
    assert _blas_threads_after_import("0") == untouched


def test_a_bad_override_names_the_variable_and_what_to_give(monkeypatch):
    monkeypatch.setenv(ENV, "two")
    with pytest.raises(ValueError, match=f"{ENV}.*non-negative integer"):
        blas_threads()
    monkeypatch.setenv(ENV, "-1")
    with pytest.raises(ValueError, match="non-negative"):
        blas_threads()
    monkeypatch.setenv(ENV, " 3 ")
    assert blas_threads() == 3
    monkeypatch.delenv(ENV)
    assert blas_threads() == 1


def _omp_wait_after_import(value: str | None) -> str:
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    if value is not None:
        env["OMP_WAIT_POLICY"] = value
    probe = "import os, bayes_mr.simulation.simulate\nprint(os.environ.get('OMP_WAIT_POLICY'))"
    return subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True,
                          check=True).stdout.strip()


def test_numba_threads_sleep_between_batches_unless_the_environment_says_otherwise():
    assert _omp_wait_after_import(None) == "PASSIVE"
    assert _omp_wait_after_import("ACTIVE") == "ACTIVE"
