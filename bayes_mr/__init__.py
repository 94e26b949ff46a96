"""bayes_mr: Bayesian identification, selection and diagnosis of MR-damper models.

Everything a notebook needs is one import away::

    import bayes_mr as bm

    record = bm.load("test.csv", mass=50.0)               # read, check, mask faults
    matrix = bm.load("tests.csv")                         # a manifest (or a list of files): a RecordSet
    joint = bm.Identify("spencer", bm.LeastSquares()).fit(matrix)  # one likelihood summed over them
    idata = bm.Identify("dahl", bm.Emcee()).fit(record)   # any engine, one result schema
    cmp = bm.compare(record, ["dahl", "lugre"], engines=("lsq",))
    cmp.selected, cmp.table(), cmp.plot()                 # a Comparison
    report = bm.diagnose(record, "dahl")                  # residual → cause → extension → gain
    report.cause, report.table(), report.plot()           # a Diagnosis
    bm.save(cmp, "compare.json"); bm.load("compare.json") # one pair for records, fits and results

``bm.FORMS`` and ``bm.EFFECTS`` name the vocabulary a model is built from
(``"FORM+EFFECT+…"``, :func:`get_model`).

Names are resolved on first use (PEP 562), so ``import bayes_mr`` stays cheap
and has no side effects; the contract (columns, model and effect names, CLI
verbs, JSON keys) is in ``docs/CONTRACT.md``.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

#: Public name → (module, attribute).
_PUBLIC = {
    # records
    "load": ("bayes_mr.storage", "load"),
    "load_packaged": ("bayes_mr.data", "load_packaged"),
    "write_record": ("bayes_mr.data", "write_record"),
    "make_record": ("bayes_mr.data", "make_record"),
    "RecordError": ("bayes_mr.data", "RecordError"),
    "RecordSet": ("bayes_mr.data.records", "RecordSet"),
    "load_records": ("bayes_mr.data.records", "load_records"),
    # models and simulation
    "FORMS": ("bayes_mr.models", "FORMS"),
    "EFFECTS": ("bayes_mr.models", "EFFECTS"),
    "get_model": ("bayes_mr.models", "get_model"),
    "Model": ("bayes_mr.models", "Model"),
    "simulate": ("bayes_mr.simulation.simulate", "simulate"),
    "synthesize": ("bayes_mr.simulation.simulate", "synthesize"),
    "Inputs": ("bayes_mr.simulation.simulate", "Inputs"),
    "make_signal": ("bayes_mr.signals", "make_signal"),
    # one likelihood, three engines, one result schema
    "OutputError": ("bayes_mr.likelihood.output_error", "OutputError"),
    "JointLikelihood": ("bayes_mr.likelihood.joint", "JointLikelihood"),
    "Identify": ("bayes_mr.inference.identify", "Identify"),
    "validate": ("bayes_mr.inference.identify", "validate"),
    "validate_records": ("bayes_mr.inference.identify", "validate_records"),
    "LeastSquares": ("bayes_mr.inference.estimators", "LeastSquares"),
    "Emcee": ("bayes_mr.inference.estimators", "Emcee"),
    "UKF": ("bayes_mr.inference.estimators", "UKF"),
    "engine": ("bayes_mr.inference.estimators", "engine"),
    "Posterior": ("bayes_mr.inference.base", "Posterior"),
    "LSQSettings": ("bayes_mr.inference.lsq.least_squares", "LSQSettings"),
    "MCMCSettings": ("bayes_mr.inference.mcmc.settings", "MCMCSettings"),
    "UKFSettings": ("bayes_mr.inference.ukf.filter", "UKFSettings"),
    "summary_of": ("bayes_mr.inference.results", "summary_of"),
    "point_of": ("bayes_mr.inference.results", "point_of"),
    "save": ("bayes_mr.storage", "save"),
    "load_result": ("bayes_mr.inference.results", "load_result"),
    "score": ("bayes_mr.scores", "score"),
    # comparison and diagnosis
    "compare": ("bayes_mr.selection.comparison", "compare"),
    "Comparison": ("bayes_mr.selection.result", "Comparison"),
    "crosscheck": ("bayes_mr.selection.comparison", "crosscheck"),
    "leave_one_out": ("bayes_mr.selection.loco", "leave_one_out"),
    "diagnose": ("bayes_mr.diagnosis.diagnose", "diagnose"),
    "Diagnosis": ("bayes_mr.diagnosis.result", "Diagnosis"),
}

__all__ = sorted(_PUBLIC)


def __getattr__(name: str):
    if name not in _PUBLIC:
        raise AttributeError(f"module 'bayes_mr' has no attribute {name!r}")
    module, attr = _PUBLIC[name]
    value = getattr(importlib.import_module(module), attr)
    globals()[name] = value  # resolve once
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_PUBLIC))
