"""How bayes_mr compiles its hot loops: the bottom layer, imported by the models and the UKF.

* :mod:`.jit` — the two numba decorators (:func:`~.jit.hot` for kernels, :func:`~.jit.driver` for
  parallel loops) and the on-disk cache they share;
* :mod:`.specialise` — kernels generated and compiled per model layout, cached on disk;
* :mod:`.worker` — the child process that compiles a specialised kernel in the background;
* :mod:`.threads` — BLAS and OpenMP thread settings, so the parallel work is numba's own.

Nothing here knows a model or a record.
"""
