"""How results look: Markdown tables and figures.

The package imports nothing else of bayes_mr: it formats what the layers above computed and never
computes a result, so any layer may draw with it. Figures use matplotlib's object API on an Agg
canvas, so importing the package changes no global matplotlib state.

* :mod:`.markdown` — number formatting and Markdown tables;
* :mod:`.figures` — the helpers every figure uses, and the thesis's plots.

The reports built with them live beside what they report: a diagnosis's in
:mod:`bayes_mr.diagnosis.report`, the main job's in :mod:`bayes_mr.run.report`.
"""
