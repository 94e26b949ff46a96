"""How results look: Markdown tables, figures and the diagnosis's report.

The package imports nothing else of bayes_mr: it formats what the layers above computed and never
computes a result, so any layer may draw with it. Figures use matplotlib's object API on an Agg
canvas, so importing the package changes no global matplotlib state.

* :mod:`.markdown` — number formatting and Markdown tables;
* :mod:`.figures` — the helpers every figure uses, and the thesis's plots;
* :mod:`.diagnose` — the figures and ``diagnose.md`` of a diagnosis.

The main job's report is :mod:`bayes_mr.run.report`.
"""
