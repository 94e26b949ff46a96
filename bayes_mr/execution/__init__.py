"""How work runs: grids of independent fits on threads, a process pool or a Dask cluster, and
progress on a terminal.

* :mod:`.executor` — :func:`~.executor.run_jobs`, :func:`~.executor.side_by_side`,
  :func:`~.executor.open_executor`;
* :mod:`.progress` — one-line messages and progress bars on stderr.
"""
