"""``bayes-mr bench``: the performance benchmark, every figure measured in one run.

* :mod:`.benchmark` — :func:`~.benchmark.run_bench`: the UKF against filterpy, the 100-prior training,
  least squares and emcee, the diagnosis and the comparison of the package's own jobs;
* :mod:`.kernels` — the compiled kernels: generic, inlined and specialised per model, and compile times.
"""

from bayes_mr.bench.benchmark import run_bench

__all__ = ["run_bench"]
