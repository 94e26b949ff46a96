"""Reporting: Markdown, figures and README sections, one module per concern.

A layer above the library: these modules read what :mod:`bayes_mr.diagnosis`,
:mod:`bayes_mr.comparison` and :mod:`bayes_mr.results` computed and never
compute a result themselves. Only the top level (the CLI, the main job, the
benchmark, the studies and ``scripts/``) imports them — and
``diagnose(out_dir=...)``, which writes its report through
:mod:`.diagnose` on request, lazily.

* :mod:`.markdown` — number formatting and Markdown tables.
* :mod:`.figures` — the figure helpers every figure uses (object API on an
  Agg canvas: importing the package changes no global matplotlib state) and
  the thesis's plots.
* :mod:`.diagnose` — the figures and ``diagnose.md`` of a diagnosis.
* :mod:`.run` — the figures, headline and ``report.md`` of the main job.
* :mod:`.readme` — the README's run and bench sections, as text, from the
  JSON those commands wrote (``scripts/update_readme.py`` writes them).
"""
