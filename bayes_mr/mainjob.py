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
   evidence) from one pool of seconds, the selected form's first
   (:mod:`bayes_mr.mainjob_posteriors`); selection by evidence, MSE and force
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
   beside the posteriors (:mod:`bayes_mr.mainjob_aside`, the same numbers).
6. **A second record** of the same damper (``run --validate DATA2``), when
   given: prepared as part B was (:mod:`bayes_mr.mainjob_records`), held
   out whole, predicted by every fit and by the diagnosis's baseline and
   extended model.

Everything is written to ``out_dir``: ``report.md`` with figures
(:mod:`bayes_mr.report.run`), tables as CSV, every fit as netCDF and
``summary.json``, which holds every number the README's run section shows
(``scripts/update_readme.py`` writes that section; this module never
touches the README).
"""

from __future__ import annotations

import time as _time
from dataclasses import asdict, dataclass, field, replace
from functools import partial
from pathlib import Path

import xarray as xr

from . import results
from .comparison import choose, compare, table
from .identify import UKF
from .mainjob_aside import Stage, run_stages, start
from .mainjob_context import noise_sensitivity, published_spencer
from .mainjob_posteriors import least_squares_pass, posterior_order, run_posteriors
from .mainjob_records import prepare, prepare_other, second_record
from .mainjob_stages import THESIS_FORMS, best_thesis_form, diagnose_selected, shake_table
from .warmup import compile_filter_aside, expect_posteriors, wait
from .inference.mcmc import MCMCSettings
from .inference.ukf import TAUS
from .models import FORMS, get_model
from .progress import say as progress_say
from .report.run import report_markdown, run_figures, spencer_table

__all__ = ["FULL", "QUICK", "THESIS_FORMS", "Budget", "diagnose_selected", "prepare", "run", "shake_table"]

@dataclass(frozen=True)
class Budget:
    """How much of the record and of each estimator the job uses.

    Attributes
    ----------
    fs : float
        Target sampling rate after decimation [Hz] (an integer factor of the record's).
    duration_s : float or None
        Length of the trimmed record used [s] (None: all of it).
    train_fraction : float
        Share of the record in part A (training); the rest is part B.
    forms : tuple of str
        Models compared.
    mcmc : MCMCSettings
        Settings of each posterior (a run that hits ``max_steps`` is flagged
        not converged, not hidden). With ``max_seconds`` a posterior whose
        measured step cost projects past it is not started, and the report
        says which and why (:mod:`bayes_mr.inference.budget`).
    mcmc_pool_s : float or None
        Wall seconds all posteriors share (None: each has ``mcmc.max_seconds`` alone). They run after every
        form's least squares and UKF, the selected form first, then by evidence, each with what the earlier
        ones left (:mod:`bayes_mr.mainjob_posteriors`).
    evidence : str
        ``"ti"`` or ``"laplace"`` for the MCMC rows.
    ukf_lhs : int
        Latin-hypercube priors per index of dispersion.
    ukf_taus : tuple of float
        Indices of dispersion (thesis: ten).
    input_interp : {"linear", "bandlimited"} or None
        Inputs between samples (None: ``auto``). ``make run`` keeps linear, as every earlier run: ``auto`` read
        its record at 250 Hz band-limited (S = 11, measured), several times the run's budget.
    noise : {"iid", "ar"}
        Residual model of the comparison's likelihood (``Identify.noise``).
        The other one is also fitted by least squares, so the report says how
        the model choice and the Bayes factors move between them.
    diagnose_s : float or None
        Diagnose the selected model on the first this-many seconds of part A
        (None: all of A; 0: no diagnosis).
    diagnose_fs : float or None
        Sampling rate of the diagnosis [Hz] (None: :attr:`fs`). Issue 15: the
        record's own rate or ≥ 1 kHz — a command switch and the field's
        sub-millisecond lag are below a 4-ms sample.
    shake_table_engines : tuple of str
        Engines of the virtual shake table (``ukf``, ``lsq``).
    terms : bool
        After the named effects, search the term library for what the extended model still leaves
        (:mod:`bayes_mr.diagnosis.terms`; a term is kept only if the evidence and the error on a held-out
        end of A both improve, and again with the start of A held out), whatever the verdict: on the measured
        damper the named effects leave ~80× the noise floor, and that is what the diagnosis must speak to.
    aside : bool
        Run the stages that need only the first pass (noise sensitivity, diagnosis, virtual shake table) in a
        child process at the lowest priority beside the posteriors (:mod:`bayes_mr.mainjob_aside`; same results),
        else after them here. Off by default: on 2 cores the posteriors hold both and the child got ~5 % of one
        (measured, that module); for a machine with cores the job's threads leave idle.
    """

    fs: float
    duration_s: float | None
    train_fraction: float = 0.6
    forms: tuple[str, ...] = tuple(FORMS)
    mcmc: MCMCSettings = field(default_factory=lambda: MCMCSettings(max_steps=3000))
    mcmc_pool_s: float | None = None
    evidence: str = "ti"
    ukf_lhs: int = 3
    ukf_taus: tuple[float, ...] = TAUS
    diagnose_s: float | None = None
    diagnose_fs: float | None = 1000.0
    noise: str = "iid"
    input_interp: str | None = "linear"
    shake_table_engines: tuple[str, ...] = ("ukf", "lsq")
    terms: bool = True
    aside: bool = False

    def __post_init__(self):
        unknown = set(self.shake_table_engines) - {"ukf", "lsq"}
        if unknown:
            raise ValueError(f"shake_table_engines: {sorted(unknown)} unknown; use 'ukf' and/or 'lsq'")
        if self.mcmc_pool_s is not None and not self.mcmc_pool_s > 0:
            raise ValueError(f"mcmc_pool_s must be positive seconds or None, not {self.mcmc_pool_s!r}")


#: ``make run``: the whole trimmed record at ~1 kHz (the record's 3 kHz decimated by 3). The simulator's RK4
#: sub-steps are set by the model's stiffness, not by the sampling rate, so 1 kHz costs about what 250 Hz did
#: (a 24-walker evaluation at the least-squares optima: dahl 65 against 62 ms, bouc-wen 663 against 757 ms).
#: The emcee posteriors share one 720-s pool (``mcmc_pool_s``), the selected form's first, then by evidence
#: (:mod:`bayes_mr.mainjob_posteriors`); each runs until the package's rule holds (≥ 50 τ, R-hat < 1.01) or what
#: the pool has left runs out. One whose measured step cost at its least-squares optimum projects the pilot and a
#: minimal chain past that is not started, and a chain whose own integrated time projects the rule past it stops
#: there (``stopped`` "projected"); the headline names either, with the numbers (:mod:`bayes_mr.inference.budget`).
#: Measured (2 cores, warm kernels; each chain proper the independence move alone on 8 walkers,
#: ``MCMCSettings.moves``, ``chain_walkers``): all five converge in 531 s of the pool — the selected spencer in
#: 241 s with its least squares (a 200-step pilot and three adaptation rounds of 56 walkers, acceptance
#: 0.13 → 0.34, then 850 steps of 8, τ 7.5), normalized-bouc-wen 105 s, lugre 23 s, dahl 25 s and bouc-wen 122 s
#: (six rounds of 24 walkers, then 650 steps of 8, τ 5.7); on the next machine of the same kind the same steps
#: took 401 s (spencer 216 s) and the whole ``make run`` 13.9 min against 17.6. The pool's 720 s leave a margin
#: for a slower machine (unbudgeted on part A the five took ~625 s in separate processes). With 2·d + 2 walkers
#: and differential evolution in the chain (stop 50) spencer took 436 s and bouc-wen (~4100 steps of 14, ~7 min) did not fit in
#: 600 s; with 180 s per posterior (until stop 48) spencer never started. A fresh clone's first run at stop 53 (empty
#: kernel cache, each chain from the first pass's fit): 542 s of the pool (spencer 279 s, bouc-wen 153 s), 17.3 min.
#: Selection is by the Laplace evidence every form has; a thermodynamic-integration ladder per form (several
#: minutes each on this record) does not fit — ``bayes-mr compare --engines mcmc`` runs it. The virtual shake
#: table runs the UKF only (its least squares took 165 s of the stage's 232 s; the README reports the UKF).
#: The diagnosis of the selected model runs on all of part A at 1 kHz (:attr:`Budget.diagnose_fs`; for
#: spencer 5-6 min, the extension study's procedure from the comparison's optimum).
FULL = Budget(fs=1000.0, duration_s=None, mcmc=MCMCSettings(max_steps=8000), mcmc_pool_s=720.0,
              evidence="laplace", ukf_lhs=2, shake_table_engines=("ukf",))
#: ``bayes-mr run --quick``: a minute-long pass (a 4-s window at ~250 Hz, two forms, short chains; the
#: diagnosis on that window's part A at 1 kHz, ~15 s).
QUICK = Budget(fs=250.0, duration_s=4.0, forms=("dahl", "lugre"),
               mcmc=MCMCSettings(max_steps=500, min_tau_multiple=20.0, rhat_max=1.05),
               evidence="laplace", ukf_lhs=1, ukf_taus=(0.01, 0.1))


def first_pass(part_a, part_b, budget: Budget, *, seed: int, say) -> dict:
    """Least squares of every form, then the UKF of every form (its filter compiled meanwhile in a child process,
    :mod:`bayes_mr.warmup`), on A and validated on B; the selection on them (:func:`~bayes_mr.comparison.choose`).

    Returns
    -------
    dict
        ``rows``, ``idata`` ((form, engine) → InferenceData), ``fitted`` (form → the least-squares fit each chain
        starts from, :func:`~bayes_mr.mainjob_posteriors.least_squares_pass`) and the selection's keys.
    """
    forms = [get_model(m).name for m in budget.forms]  # as compare names its rows
    child = compile_filter_aside(part_a, forms[0], budget.ukf_lhs, budget.ukf_taus)
    expect_posteriors(part_a, forms, budget.mcmc)
    lsq_rows, lsq_idata, fitted = least_squares_pass(part_a, part_b, forms, seed=seed, noise=budget.noise, say=say)
    wait(child, say)
    ukf = compare(part_a, forms, engines=("ukf",), validate=part_b, seed=seed, progress=say,
                  estimators={"ukf": UKF(n_lhs=budget.ukf_lhs, taus=budget.ukf_taus)}, noise=budget.noise)
    by_pair = {(r["model"], r["engine"]): r for r in lsq_rows + ukf["rows"]}
    rows = [by_pair[(m, e)] for m in forms for e in ("lsq", "ukf")]
    return {"rows": rows, **choose(rows, forms), "idata": {**lsq_idata, **ukf["idata"]}, "fitted": fitted}


def with_posteriors(first: dict, part_a, part_b, budget: Budget, *, seed: int, out_dir: Path, say) -> dict:
    """The comparison: the first pass (:func:`first_pass`) and the emcee posteriors from one pool of seconds, the
    selected form's first, each chain from its form's least-squares fit of the first pass
    (:mod:`bayes_mr.mainjob_posteriors`); every fit saved under ``out_dir/fits``; the selection on all rows."""
    order = posterior_order(budget.forms, first["selected"], first["bayes_factors"])
    if budget.mcmc_pool_s is not None:
        say(f"emcee posteriors from a pool of {budget.mcmc_pool_s:g} s, in this order: {', '.join(order)}")
    chains, skipped = run_posteriors(part_a, part_b, order, budget, seed=seed, fitted=first["fitted"], say=say)
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
            "mcmc_skipped": skipped, "posterior_order": order, "idata": fits}


#: Keys of :func:`bayes_mr.comparison.choose` that ``summary.json`` carries besides ``selected`` and ``bayes_factors``.
SELECTION_KEYS = ("evidence_engine", "selected_by", "selected_on", "unconverged", "evidence_scale",
                  "log_evidence_calibrated", "bayes_factors_calibrated", "selected_calibrated")


def _best_by_validation(rows: list[dict]) -> dict | None:
    ok = [r for r in rows if r.get("validation", {}).get("force_nrmse") is not None]
    return min(ok, key=lambda r: r["validation"]["force_nrmse"]) if ok else None


def _posteriors_beside(first: dict, plan, part_a, part_b, budget: Budget, *, seed: int, out_dir: Path,
                       say, clock: tuple[float, float], live: bool, timing: dict) -> tuple[dict, dict, str, dict]:
    """The posteriors (:func:`with_posteriors`) with the stages ``plan(first)`` beside them in a child process
    (:mod:`bayes_mr.mainjob_aside`); without :attr:`Budget.aside`, the stages ``plan(comparison)`` after them here
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
    """The stages that need only the first pass (:mod:`bayes_mr.mainjob_aside`): the model choice under the other
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
        :func:`~bayes_mr.mainjob_context.published_spencer`.
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
        "posterior_order": comp["posterior_order"],
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
        A second test of the same damper (issue 15 item 4). It is trimmed and decimated as the record is and
        held out whole: every fit of the comparison predicts it, and so do the diagnosis's baseline and
        extended model at the diagnosis's rate (``summary.json``'s ``second_record``). Checked before the
        comparison starts: a record of another kind or without the channels the fits read stops the job
        at once.
    noise : {"iid", "ar"}, optional
        Residual model of the comparison (default: the budget's, ``iid``);
        the other one is fitted by least squares beside it
        (:func:`~bayes_mr.mainjob_context.noise_sensitivity`).
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
