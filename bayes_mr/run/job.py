"""The main job (``bayes-mr run``, ``make run``): the measured MR damper through the whole procedure.

On the packaged NEES record (a device test: imposed piston displacement,
command voltage, measured force):

1. **Prepare.** Quality control (nothing is masked on this record, and the
   report says so), trimming to the excited part, decimation to
   :attr:`Budget.fs` with an anti-alias filter, and a split into part A
   (training, the first :attr:`Budget.train_fraction`) and part B (never seen
   by any fit).
2. **Compare.** Every form with least squares (Laplace evidence) and the
   thesis's UKF (LHS × τ priors), then the emcee posteriors (TI or Laplace
   evidence) from one pool of work under a wall-time cap, the selected form's first
   (:mod:`bayes_mr.run.posteriors`); selection by evidence, MSE and force
   NRMSE beside it; thesis method 1 (scores on A) and method 2 (predicting B).
3. **A paper's table.** Spencer et al. (1997)'s published parameters (from a
   secondary source, converted to SI; :mod:`bayes_mr.models.forms`) predict B
   next to the identified models; the identified Spencer parameters stand
   next to the published ones.
4. **Diagnose** the selected model on all of A at 1 kHz (effects named,
   model extended, what remains against the noise floor; the extended model
   predicts B).
5. **Virtual shake table.** The thesis's frame built around the measured
   damper by inverse dynamics (:mod:`bayes_mr.data.virtual_table`); the UKF
   identifies the best of the thesis's four forms (by the same evidence) from
   displacement and acceleration only, and the damper force it implies is
   compared with the measured force.
   Steps 4 and 5 and the least squares under the other residual model need
   only the first pass (every form's least squares and UKF); with
   :attr:`Budget.aside` they run in a child process at the lowest priority
   beside the posteriors (:mod:`bayes_mr.run.aside`, the same numbers).
6. **A second record** of the same damper (``run --validate DATA2``), when
   given: prepared as part B was (:mod:`bayes_mr.run.records`), held
   out whole, predicted by every fit and by the diagnosis's baseline and
   extended model.

Everything is written to ``out_dir``: ``report.md`` with figures
(:mod:`bayes_mr.run.report`), tables as CSV, every fit as netCDF and
``summary.json``, which holds every number the README's run section shows
(``scripts/update_readme.py`` writes that section; this module never
touches the README).
"""

from __future__ import annotations

import time as _time
from dataclasses import asdict, replace
from functools import partial
from pathlib import Path

import xarray as xr

from bayes_mr.inference import results
from bayes_mr.selection.comparison import choose, compare, table
from bayes_mr.inference.identify import UKF
from bayes_mr.inference.mcmc.settings import MCMCSettings
from bayes_mr.run.aside import Stage, run_stages, start
from bayes_mr.run.context import noise_sensitivity, published_spencer
from bayes_mr.run.posteriors import least_squares_pass, posterior_order, run_posteriors
from bayes_mr.run.plan import FULL, QUICK, Budget
from bayes_mr.run.records import prepare, prepare_other, second_record
from bayes_mr.run.stages import THESIS_FORMS, best_thesis_form, diagnose_selected, shake_table
from bayes_mr.run.warmup import compile_filter_aside, expect_posteriors, wait
from bayes_mr.models import FORMS, get_model
from bayes_mr.execution.progress import say as progress_say
from bayes_mr.run.report import report_markdown, run_figures, spencer_table

__all__ = ["FULL", "QUICK", "THESIS_FORMS", "Budget", "diagnose_selected", "prepare", "run", "shake_table"]

def first_pass(part_a, part_b, budget: Budget, *, seed: int, say) -> dict:
    """Least squares of every form, then the UKF of every form (its filter compiled meanwhile in a child process,
    :mod:`bayes_mr.run.warmup`), on A and validated on B; the selection on them (:func:`~bayes_mr.selection.comparison.choose`).

    Returns
    -------
    dict
        ``rows``, ``idata`` ((form, engine) → InferenceData), ``fitted`` (form → the least-squares fit each chain
        starts from, :func:`~bayes_mr.run.posteriors.least_squares_pass`) and the selection's keys.
    """
    forms = [get_model(m).name for m in budget.forms]  # as compare names its rows
    child = compile_filter_aside(part_a, forms[0], budget.ukf_lhs, budget.ukf_taus)
    expect_posteriors(part_a, forms, budget.mcmc)
    lsq_rows, lsq_idata, fitted = least_squares_pass(part_a, part_b, forms, seed=seed, noise=budget.noise, say=say)
    wait(child, say)
    ukf = compare(part_a, forms, engines=("ukf",), validate=part_b, seed=seed, progress=say,
                  estimators={"ukf": UKF(n_lhs=budget.ukf_lhs, taus=budget.ukf_taus)}, noise=budget.noise)
    by_pair = {(r["model"], r["engine"]): r for r in lsq_rows + ukf.rows}
    rows = [by_pair[(m, e)] for m in forms for e in ("lsq", "ukf")]
    return {"rows": rows, **choose(rows, forms), "idata": {**lsq_idata, **ukf.idata}, "fitted": fitted}


def with_posteriors(first: dict, part_a, part_b, budget: Budget, *, seed: int, out_dir: Path, say) -> dict:
    """The comparison: the first pass (:func:`first_pass`) and the emcee posteriors from one pool of work, the
    selected form's first, each chain from its form's least-squares fit of the first pass
    (:mod:`bayes_mr.run.posteriors`); every fit saved under ``out_dir/fits``; the selection on all rows."""
    order = posterior_order(budget.forms, first["selected"], first["bayes_factors"])
    if budget.mcmc_pool is not None:
        cap = "" if budget.mcmc_pool_cap_s is None else f" (wall-time cap {budget.mcmc_pool_cap_s:g} s)"
        say(f"emcee posteriors from a pool of {budget.mcmc_pool:.3g} integrator steps{cap}, in this order: "
            f"{', '.join(order)}")
    chains, skipped, work = run_posteriors(part_a, part_b, order, budget, seed=seed, fitted=first["fitted"],
                                           say=say)
    fits = dict(first["idata"])
    fits.update({(m, "mcmc"): idata for m, (_, idata) in chains.items() if idata is not None})
    by_pair = {(r["model"], r["engine"]): r for r in first["rows"]}
    by_pair.update({(m, "mcmc"): row for m, (row, _) in chains.items()})
    rows = [by_pair[(m, e)] for m in budget.forms for e in ("lsq", "mcmc", "ukf") if (m, e) in by_pair]
    for (m, e), idata in fits.items():
        results.save(idata, out_dir / "fits" / f"{m.replace('+', '_')}__{e}.nc")
    # selection across forms as compare selects: the route every form has, on the calibrated evidence
    ok = [r for r in rows if "error" not in r]
    return {"rows": rows, **choose(ok, [f for f in budget.forms if any(r["model"] == f for r in ok)]),
            "mcmc_skipped": skipped, "posterior_order": order, "posterior_work": work, "idata": fits}


#: Keys of :func:`bayes_mr.selection.comparison.choose` that ``summary.json`` carries besides ``selected`` and ``bayes_factors``.
SELECTION_KEYS = ("evidence_engine", "selected_by", "selected_on", "unconverged", "evidence_scale",
                  "log_evidence_calibrated", "bayes_factors_calibrated", "selected_calibrated")


def _best_by_validation(rows: list[dict]) -> dict | None:
    ok = [r for r in rows if r.get("validation", {}).get("force_nrmse") is not None]
    return min(ok, key=lambda r: r["validation"]["force_nrmse"]) if ok else None


def _posteriors_beside(first: dict, plan, part_a, part_b, budget: Budget, *, seed: int, out_dir: Path,
                       say, clock: tuple[float, float], live: bool, timing: dict) -> tuple[dict, dict, str, dict]:
    """The posteriors (:func:`with_posteriors`) with the stages ``plan(first)`` beside them in a child process
    (:mod:`bayes_mr.run.aside`); without :attr:`Budget.aside`, the stages ``plan(comparison)`` after them here
    (planned for the final selection, so none has to run again).

    ``clock`` is (the comparison's start by :func:`time.perf_counter`, the job's by :func:`time.time`); ``timing``
    gets ``compare`` (first pass and posteriors) and ``beside_wait`` (the wait for the child after them).

    Returns
    -------
    comp : dict
    done : dict
        Stage name → (value, wall seconds).
    where : str
        Where the stages ran.
    planned : dict
        What the stages were planned from (``first`` or ``comp``: its ``selected`` and rows).
    """
    aside = start(plan(first), t0=clock[1], live=live) if budget.aside else None
    try:
        comp = with_posteriors(first, part_a, part_b, budget, seed=seed, out_dir=out_dir, say=say)
    except BaseException:
        if aside is not None:
            aside.cancel()
        raise
    timing["compare"] = _time.perf_counter() - clock[0]
    say(f"selected by {comp.get('selected_by') or comp['evidence_route']}: {comp['selected']}")
    if aside is None:
        return comp, run_stages(plan(comp), say), "this process, after the posteriors", comp
    done, timing["beside_wait"], where = aside.collect(say)
    return comp, done, where, first


def _context_stages(first: dict, *, record, part_a, part_b, budget: Budget, stages, seed: int,
                    out_dir: Path) -> list[Stage]:
    """The stages that need only the first pass (:mod:`bayes_mr.run.aside`): the model choice under the other
    residual model, the diagnosis of the form ``first`` selects and the virtual shake table of its best thesis
    form (as ``stages`` and the budget ask). ``first`` is the first pass, or the comparison with the posteriors
    (whose least-squares rows are the first pass's)."""
    todo = [Stage("noise_sensitivity", noise_sensitivity, (part_a, budget.forms, budget.noise, first["rows"]),
                  {"seed": seed})]
    if "diagnose" in stages and budget.diagnose_s != 0 and first["selected"] is not None:
        todo.append(Stage("diagnose", diagnose_selected, (record, first["selected"], budget),
                          {"rows": first["rows"], "seed": seed, "out_dir": out_dir}))
    thesis_form = best_thesis_form(first)
    if "shake_table" in stages and thesis_form is not None:
        todo.append(Stage("shake_table", shake_table, (part_a, part_b, thesis_form, budget),
                          {"seed": seed, "out_dir": out_dir}))
    return todo


def _redone(done: dict, name: str, wanted: bool, choice: tuple, timing: dict, tell, fn, *args, **kwargs):
    """Stage ``name``'s value (None when it does not run). ``choice`` is (planned, now): the form it was started
    for (the first pass's choice) and the one the comparison ends with; when the posteriors changed it, the stage
    runs again here for ``now`` (``tell``: the job's progress)."""
    planned, now = choice
    if not wanted or now is None:
        return None
    if planned == now:
        return done[name][0]
    tell(f"{name}: started for {planned} (the first pass's choice), the comparison chose {now}: run again")
    return _timed(timing, name, fn, *args, **kwargs)


def _strip(d):
    """Drop private (``_``-prefixed) entries: arrays kept for the figures."""
    if isinstance(d, dict):
        return {k: _strip(v) for k, v in d.items() if not str(k).startswith("_")}
    if isinstance(d, list):
        return [_strip(v) for v in d]
    return d


def _tables(comp: dict, part_a: xr.Dataset, part_b: xr.Dataset, out_dir: Path):
    """The comparison's table and Spencer (1997)'s published-against-identified table, both also as CSV.

    Returns
    -------
    tab : pandas.DataFrame
    spencer : dict
        :func:`~bayes_mr.run.context.published_spencer`.
    params : pandas.DataFrame
    """
    tab = table(comp)
    tab.to_csv(out_dir / "compare.csv", index=False)
    spencer = published_spencer(part_a, part_b, comp["rows"])
    params = spencer_table(spencer)
    params.to_csv(out_dir / "spencer_parameters.csv", index=False)
    return tab, spencer, params


def _comparison_summary(comp: dict, budget: Budget, info: dict, sensitivity: dict, best: dict | None) -> dict:
    """The keys of ``summary.json`` that the comparison fills (budget, record, rows, selection, noise models)."""
    return {
        "budget": {k: (v if not isinstance(v, MCMCSettings) else asdict(v)) for k, v in asdict(budget).items()},
        "record": info,
        "rows": comp["rows"], "selected": comp["selected"], "bayes_factors": comp["bayes_factors"],
        "evidence_route": comp["evidence_route"], "mcmc_skipped": comp["mcmc_skipped"],
        "posterior_order": comp["posterior_order"], "posterior_work": comp["posterior_work"],
        **{k: comp[k] for k in SELECTION_KEYS if k in comp},
        "noise": budget.noise, "noise_sensitivity": sensitivity,
        "best_on_part_b": None if best is None else {"model": best["model"], "engine": best["engine"],
                                                     "force_nrmse": best["validation"]["force_nrmse"]},
    }


def _write(summary: dict, out_dir: Path, tab, params, say) -> dict:
    """Write ``summary.json`` and ``report.md`` under ``out_dir``; return the summary."""
    results.write_json(summary, out_dir / "summary.json")
    (out_dir / "report.md").write_text(report_markdown(summary, tab, params))
    say(f"wrote {out_dir / 'report.md'} in {summary['wall_s']:.0f} s")
    return summary


def _timed(timing: dict[str, float], stage: str, fn, *args, **kwargs):
    """``fn(*args, **kwargs)``, its wall time [s] recorded as ``timing[stage]``."""
    t = _time.perf_counter()
    out = fn(*args, **kwargs)
    timing[stage] = _time.perf_counter() - t
    return out


def run(out_dir: str | Path = "results", *, quick: bool = False, seed: int = 0, progress=True,
        budget: Budget | None = None, record: xr.Dataset | None = None, noise: str | None = None,
        validate: xr.Dataset | None = None,
        stages: tuple[str, ...] = ("compare", "spencer", "diagnose", "shake_table")) -> dict:
    """The main job. Returns the summary written to ``out_dir/summary.json``.

    The summary's ``full_job`` is true for the full budget on the packaged
    record: the run whose numbers the README shows (``scripts/update_readme.py``).

    Parameters
    ----------
    out_dir : path
    quick : bool
        :data:`QUICK` instead of :data:`FULL`.
    seed : int
    progress : bool or callable
    budget : Budget, optional
        Overrides ``quick``.
    record : xarray.Dataset, optional
        A device test to use instead of the packaged NEES record.
    validate : xarray.Dataset, optional
        A second test of the same damper. It is trimmed and decimated as the record is and
        held out whole: every fit of the comparison predicts it, and so do the diagnosis's baseline and
        extended model at the diagnosis's rate (``summary.json``'s ``second_record``). Checked before the
        comparison starts: a record of another kind or without the channels the fits read stops the job
        at once.
    noise : {"iid", "ar"}, optional
        Residual model of the comparison (default: the budget's, ``iid``);
        the other one is fitted by least squares beside it
        (:func:`~bayes_mr.run.context.noise_sensitivity`).
    stages : tuple of str
        Stages after the comparison (which always runs): ``spencer``,
        ``diagnose``, ``shake_table``.
    """
    t0 = _time.perf_counter()
    say = progress_say(progress, clock=True)
    budget = budget or (QUICK if quick else FULL)
    full_job = record is None and budget == FULL and noise in (None, FULL.noise)
    if noise is not None:
        budget = replace(budget, noise=noise)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    timing: dict[str, float] = {}

    say("preparing the record (quality, trim, decimate, split)")
    whole, part_a, part_b, info = prepare(budget, record)
    say(f"{info['samples']} samples at {info['fs']:.1f} Hz; A {info['part_a_s']:.1f} s, B {info['part_b_s']:.1f} s")
    other = None if validate is None else prepare_other(budget, validate, part_a)
    timing["prepare"] = _time.perf_counter() - t0

    t = _time.perf_counter()
    first = first_pass(part_a, part_b, budget, seed=seed, say=say)
    plan = partial(_context_stages, record=record, part_a=part_a, part_b=part_b, budget=budget, stages=stages,
                   seed=seed, out_dir=out_dir)
    comp, done, where, src = _posteriors_beside(first, plan, part_a, part_b, budget, seed=seed, out_dir=out_dir,
                                                say=say, clock=(t, _time.time() - (_time.perf_counter() - t0)),
                                                live=progress is True, timing=timing)
    selected = comp["selected"]
    timing.update({name: wall for name, (_, wall) in done.items()})
    tab, spencer, params = _tables(comp, part_a, part_b, out_dir)
    sensitivity = done["noise_sensitivity"][0]
    diag = _redone(done, "diagnose", "diagnose" in stages and budget.diagnose_s != 0, (src["selected"], selected),
                   timing, say, diagnose_selected, record, selected, budget, rows=comp["rows"], seed=seed,
                   out_dir=out_dir, say=say) or {}
    second = None if other is None else _timed(timing, "second_record", second_record, validate, other, comp, diag,
                                               budget, like=part_a, out_dir=out_dir, say=say)
    thesis_form = best_thesis_form(comp)
    vst = _redone(done, "shake_table", "shake_table" in stages, (best_thesis_form(src), thesis_form), timing, say,
                  shake_table, part_a, part_b, thesis_form, budget, seed=seed, out_dir=out_dir, say=say)

    best = _best_by_validation(comp["rows"])
    figs = run_figures(out_dir, part_b, comp["rows"], selected, best, spencer, vst, diag)
    summary = {
        **_comparison_summary(comp, budget, info, sensitivity, best),
        "spencer_1997": spencer, "diagnose": diag, "second_record": second, "shake_table": vst, "figures": figs,
        "stages_s": timing, "stages_where": {"stages": list(done), "ran_in": where},
        "seed": seed, "full_job": full_job,
    }
    summary["wall_s"] = _time.perf_counter() - t0
    return _write(_strip(summary), out_dir, tab, params, say)
