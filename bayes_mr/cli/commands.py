"""The ``bayes-mr`` command (verbs and flags fixed by ``docs/CONTRACT.md``).

Bad input ends with one line on stderr naming file, column, row and what to
do, exit status 2, and nothing written. Ctrl-C ends with status 130.
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np

from bayes_mr.cli.parser import build_parser
from bayes_mr.execution.progress import on_terminal
from bayes_mr.execution.progress import say as progress_say


class CLIError(Exception):
    """A user error the command reports in one line."""


# --- small parsers ---------------------------------------------------------------------

def _pairs(items: list[str] | None, flag: str) -> dict[str, str]:
    out = {}
    for item in items or []:
        if "=" not in item:
            raise CLIError(f"{flag} {item!r}: expected NAME=VALUE")
        k, v = item.split("=", 1)
        out[k.strip()] = v.strip()
    return out


def _floats(items: list[str] | None, flag: str) -> dict[str, float]:
    out = {}
    for k, v in _pairs(items, flag).items():
        try:
            out[k] = float(v)
        except ValueError:
            raise CLIError(f"{flag} {k}={v}: not a number") from None
    return out


def _ranges(items: list[str] | None) -> dict[str, tuple[float, float]]:
    out = {}
    for k, v in _pairs(items, "--prior").items():
        try:
            lo, hi = (float(p) for p in v.split(":"))
        except ValueError:
            raise CLIError(f"--prior {k}={v}: expected LO:HI in SI units") from None
        out[k] = (lo, hi)
    return out


def _read(path: str, args, *, what: str = "record"):
    from bayes_mr.data import load

    rec = load(
        path, mass=getattr(args, "mass", None), units=getattr(args, "units", None),
        columns=getattr(args, "columns", None),
        quality=not getattr(args, "no_quality", False), trim=getattr(args, "trim", False),
    )
    for name in ("input_interp", "command_interp"):
        value = getattr(args, name, "auto")
        if value != "auto":  # the record attribute every simulation of it reads (bayes_mr.simulation.input_grid)
            rec.attrs[name] = value
    return rec


def _conditions(args) -> dict:
    """``--set NAME=VALUE`` as conditions: numbers where they read as one; a command must be one [A or V]."""
    out = {}
    for name, value in _pairs(getattr(args, "set", None), "--set").items():
        try:
            out[name] = float(value)
        except ValueError:
            if name in ("current", "voltage"):
                raise CLIError(f"--set {name}={value}: not a number (the constant {name} in "
                               f"{'A' if name == 'current' else 'V'})") from None
            out[name] = value
    if "current" in out and "voltage" in out:
        raise CLIError("--set current and --set voltage: a test runs at a constant current or voltage, not both")
    return out


def _read_records(paths: list[str], args):
    """The verb's DATA: one record (a file, read as :func:`_read` reads it), or a RecordSet of several
    (files or one manifest CSV, :func:`bayes_mr.data.records.load_records`), ``--set`` conditions applied."""
    from dataclasses import replace

    from bayes_mr.data.records import RecordSet, is_manifest, load_records, with_constant_command

    constants = _conditions(args)
    offsets = bool(getattr(args, "record_offsets", False))
    if len(paths) == 1 and not is_manifest(paths[0]):
        one = with_constant_command(_read(paths[0], args), constants)
        return RecordSet((one,), record_offsets=True) if offsets else one  # its own offset: MODEL+force_offset
    records = load_records(
        paths, constants=constants, mass=getattr(args, "mass", None), units=getattr(args, "units", None),
        columns=getattr(args, "columns", None), quality=not getattr(args, "no_quality", False),
        trim=getattr(args, "trim", False))
    for rec in records:
        for name in ("input_interp", "command_interp"):
            value = getattr(args, name, "auto")
            if value != "auto":
                rec.attrs[name] = value
    return replace(records, record_offsets=True) if offsets else records


def _n_records(rec) -> int:
    """How many records a RecordSet of :func:`_read_records` holds; 0 for one record read alone."""
    from bayes_mr.data.records import RecordSet

    return len(rec) if isinstance(rec, RecordSet) else 0


def _train_test(rec):
    """(what a fit fits, what it predicts): a RecordSet's ``train`` and ``test`` rows (None: no test row)."""
    if not _n_records(rec):
        return rec, None
    return rec.split()


def _executor(args):
    """The executor of ``--scheduler`` / ``--workers`` (a context: a local cluster is closed after)."""
    from bayes_mr.execution.executor import open_executor

    return open_executor(scheduler=args.scheduler, workers=args.workers)


def _write_json(data: dict, path: str | None) -> None:
    import json

    from bayes_mr.inference.results import _jsonable, write_json

    if path:
        write_json(data, path)
    else:
        print(json.dumps(_jsonable(data), indent=2))


# --- verbs -----------------------------------------------------------------------------

def cmd_simulate(args) -> int:
    from bayes_mr.data import read_inputs, write_record
    from bayes_mr.models import EFFECTS, get_model
    from bayes_mr.simulation.simulate import synthesize

    model = get_model(args.model)
    effect_values = _floats(args.effect, "--effect")
    for name in effect_values:
        if name not in EFFECTS:
            raise CLIError(f"--effect {name}: unknown effect; valid: {', '.join(EFFECTS)}")
        if model.effect(name) is None:
            model = model + EFFECTS[name]
    params = _floats(args.param, "--param")
    for name, value in effect_values.items():
        params.setdefault(EFFECTS[name].primary, value)
    if args.input:
        kind, time, inputs = read_inputs(args.input, units=args.units)
        if kind == "device" and "velocity" not in inputs:
            from bayes_mr.data.derive import smooth_velocity

            inputs["velocity"] = smooth_velocity(inputs["displacement"], float(time[1] - time[0]))
        source = f"simulate {model.name} --input {args.input}"
    elif args.signal:
        kind = args.kind or ("structure" if args.mass else "device")
        time, inputs = _signal_inputs(args, kind, params)
        source = f"simulate {model.name} --signal {args.signal}"
    else:
        raise CLIError("give the input: --input CSV or --signal NAME (see --help)")
    _simulate_checks(args, kind, params)
    for name, value in (("voltage", args.voltage), ("current", args.current)):
        if value is not None and not any(c in inputs for c in ("voltage", "current")):
            inputs[name] = np.full(time.size, value)
    theta = model.theta(kind, params)
    outputs = tuple(c.strip() for c in args.outputs.split(",") if c.strip()) if args.outputs else None
    rec = synthesize(model, theta, time, inputs, mass=args.mass if kind != "device" else None,
                     noise=args.noise, seed=args.seed, source=source, outputs=outputs, input_interp=args.input_interp,
                     command_interp=args.command_interp)
    path = write_record(rec, args.output)
    print(f"wrote {path}: {kind} test, {rec.sizes['time']} samples at {rec.attrs['fs']:.6g} Hz, model {model.name}, "
          f"input {rec.attrs['input_interp']}, command {rec.attrs['command_interp']}", file=sys.stderr)
    return 0


def _signal_inputs(args, kind: str, params: dict) -> tuple[np.ndarray, dict]:
    """Time and input channels of ``--signal``: a forced test is pushed by m × the signal's acceleration."""
    from bayes_mr.signals import make_signal

    opts = {k: getattr(args, k) for k in ("duration", "fs", "amplitude", "fmax", "scale") if getattr(args, k) is not None}
    sig = make_signal(args.signal, seed=args.seed, **opts)
    if kind == "forced":
        m = args.mass or params.get("m", 1.0)
        return sig.time, {"applied_force": float(m) * sig.acceleration}
    return sig.time, sig.as_input(kind)


def _simulate_checks(args, kind: str, params: dict) -> None:
    """The mass and command options make sense for ``kind`` (a forced test's --mass sets its parameter m)."""
    if kind == "structure" and not args.mass:
        raise CLIError("a structure test needs the storey mass: pass --mass KG")
    if args.mass is not None and not args.mass > 0:
        raise CLIError(f"--mass {args.mass}: the mass must be positive [kg]")
    if kind == "forced" and args.mass is not None:
        if "m" in params and params["m"] != args.mass:
            raise CLIError("give the mass once: --mass KG or --param m=KG")
        params["m"] = args.mass
    if args.voltage is not None and args.current is not None:
        raise CLIError("the damper command is --voltage or --current, not both")


def cmd_fit(args) -> int:
    from bayes_mr.inference import results
    from bayes_mr.inference.identify import Emcee, Identify, engine, validate_records

    rec, held_out = _train_test(_read_records(args.data, args))
    options = {}
    if getattr(args, "validate", None):
        if args.engine != "ukf":
            raise CLIError("--validate chooses among trained UKF runs (thesis method 2): use it with --engine ukf, "
                           "or score a fit on another record with `bayes-mr validate RESULT.nc DATA2`")
        options["validate_on"] = _read(args.validate, args)
    if args.evidence is not None:
        if args.engine != "mcmc":
            raise CLIError(f"--evidence {args.evidence} is the route of the mcmc engine's evidence: use it with "
                           "--engine mcmc (least squares' evidence is Laplace, the UKF's is not an evidence)")
        options["evidence"] = args.evidence
    if (args.scheduler or args.workers is not None) and args.engine != "ukf":
        raise CLIError("--scheduler/--workers spread UKF training runs: use them with --engine ukf (or compare)")
    if args.engine == "lsq":  # the starts from --seed, as an mcmc fit's least squares (Emcee.lsq_settings)
        options["settings"] = Emcee.lsq_settings(args.seed)
    with _executor(args) as ex:
        options.update({"executor": ex} if ex is not None else {})
        job = Identify(args.model, engine(args.engine, **options), ranges=_ranges(args.prior),
                       fixed=_floats(args.fix, "--fix"), noise=args.noise)
        idata = job.fit(rec, seed=args.seed, progress=not args.quiet)
    summary = results.summary_of(idata).to_dict()
    if _n_records(rec) and "records" not in summary:  # one record from a manifest: still say its conditions
        summary["records"] = rec.describe()
    if held_out is not None:  # the manifest's test rows: predicted, not fitted
        summary["test"] = validate_records(idata, held_out)
    if args.output:
        results.save(idata, args.output)
    _write_json(summary, args.json)
    return 0


def cmd_validate(args) -> int:
    from bayes_mr.inference import results
    from bayes_mr.inference.identify import validate, validate_records

    if args.loco:
        return _loco(args)
    if args.model is not None or args.fix or args.prior:
        raise CLIError("--model, --fix and --prior set --loco's fits; without --loco the model is RESULT.nc's")
    if args.result is None or not args.data:
        raise CLIError("validate takes RESULT.nc and the record(s) to predict (or --loco and the records)")
    idata = results.load_result(args.result)
    rec = _read_records(args.data, args)
    if _n_records(rec) and "test" in rec.roles:
        rec = rec.role("test")  # a manifest's test rows are what a fit on its train rows predicts
    if _n_records(rec) == 0:
        out = validate(idata, rec, warmup=args.warmup)
    else:
        out = validate_records(idata, rec, warmup=args.warmup)
    _condition_figure(out.get("by_condition"), args, f"force NRMSE by condition: {out['model']} fitted on "
                                                      f"{Path(str(out.get('trained_on') or '')).name or 'its records'}")
    _write_json(out, args.json)
    return 0


def _loco(args) -> int:
    """``validate --loco``: leave-one-condition-out over the records (every role), the held-out table."""
    from bayes_mr.data.records import RecordSet
    from bayes_mr.selection.loco import leave_one_out

    if args.model is None:
        raise CLIError("--loco fits a model in each fold: name it with --model FORM[+EFFECT...]")
    paths = ([args.result] if args.result else []) + list(args.data)
    if not paths:
        raise CLIError("--loco takes the records: several files or a manifest CSV")
    rec = _read_records(paths, args)
    if not _n_records(rec):
        rec = RecordSet((rec,))
    out = leave_one_out(rec, args.model, seed=args.seed, noise=args.noise, warmup=args.warmup,
                        fixed=_floats(args.fix, "--fix"), ranges=_ranges(args.prior),
                        progress=progress_say(on_terminal(not args.quiet)))
    _condition_figure(out["table"], args, f"held-out force NRMSE by condition: {args.model}, "
                                          "fitted on the other tests (least squares)")
    _write_json(out, args.json)
    return 0


def _condition_figure(rows: list[dict] | None, args, title: str) -> None:
    """``--figure``: the heat map of the rows' force NRMSE (:func:`bayes_mr.report.figures.condition_map`)."""
    if not args.figure:
        return
    if not rows:
        raise CLIError("--figure maps the scores of several records by condition: give several records, each "
                       "with displacement and force (or --loco)")
    from bayes_mr.report.figures import condition_map, save

    save(condition_map(rows, title=title), args.figure)


def cmd_compare(args) -> int:
    from bayes_mr.selection.comparison import compare
    from bayes_mr.inference.identify import UKF, Emcee
    from bayes_mr.report.markdown import markdown_table

    rec, held_out = _train_test(_read_records(args.data, args))
    if held_out is not None and args.validate:
        raise CLIError("a manifest with test rows and --validate: give the records to predict one way")
    other = _read(args.validate, args) if args.validate else held_out
    models = [m.strip() for m in args.models.split(",") if m.strip()]
    engines = [e.strip() for e in args.engines.split(",") if e.strip()]
    estimators = {"ukf": UKF(n_lhs=args.ukf_lhs)} if args.ukf_lhs else {}
    if args.evidence is not None:
        if "mcmc" not in engines:
            raise CLIError(f"--evidence {args.evidence} is the route of the mcmc rows' evidence: add mcmc to --engines")
        estimators["mcmc"] = Emcee(evidence=args.evidence)
    with _executor(args) as ex:
        result = compare(rec, models, engines=engines, validate=other, seed=args.seed,
                         progress=progress_say(on_terminal(not args.quiet)), out_dir=args.out,
                         estimators=estimators, executor=ex, noise=args.noise, force=args.force)
    print(markdown_table(result.table()), file=sys.stderr)
    out = result.to_dict()
    if out["selected"]:
        print(f"selected by {out['selected_by']}: {out['selected']}" + (" (forced)" if out.get("forced") else ""),
              file=sys.stderr)
    elif out.get("refused"):
        print(f"no model selected: {out['refused']}", file=sys.stderr)
    if out.get("bayes_factors_calibrated"):
        print(f"calibrated laplace evidence (k = {out['evidence_scale']:.3g}) selects {out['selected_calibrated']}; "
              f"selected on the {out['selected_on']} evidence", file=sys.stderr)
    _write_json(out, args.json)
    return 0


def cmd_diagnose(args) -> int:
    from bayes_mr.diagnosis.diagnose import diagnose

    rec = _read_records(args.data, args)
    if _n_records(rec) and len(rec) == 1:
        if args.record_offsets:
            raise CLIError("--record-offsets gives each of several tests its own force offset; on one record the "
                           "offset is the model's: --model FORM+force_offset")
        rec = rec[0]
    other = _read(args.validate, args) if args.validate else None
    with _executor(args) as ex:
        out = diagnose(rec, args.model, validate=other, out_dir=args.out, seed=args.seed,
                       progress=progress_say(on_terminal(not args.quiet)), executor=ex, noise=args.noise,
                       terms=args.terms, search=args.search).to_dict()
    print(f"baseline {out['baseline']['model']}: cause {out['cause']}; extended {out['extended']['model']}, "
          f"MSE ratio {out['gain']['mse_ratio']:.4g}, Δ ln Z {out['gain']['delta_log_evidence']:.4g}; {out['verdict']}",
          file=sys.stderr)
    _write_json(out, args.json)
    return 0


def cmd_run(args) -> int:
    from bayes_mr.run.job import run

    record = _read(args.record, args) if args.record else None
    other = _read(args.validate, args) if args.validate else None
    budget = None
    if args.mcmc_pool is not None or args.mcmc_cap is not None:
        from dataclasses import replace

        from bayes_mr.run.plan import FULL, QUICK

        budget = QUICK if args.quick else FULL
        budget = replace(budget, mcmc_pool=budget.mcmc_pool if args.mcmc_pool is None else args.mcmc_pool,
                         mcmc_pool_cap_s=budget.mcmc_pool_cap_s if args.mcmc_cap is None else args.mcmc_cap)
    summary = run(args.out, quick=args.quick, seed=args.seed, progress=not args.quiet, noise=args.noise,
                  record=record, validate=other, budget=budget)
    print(f"report: {Path(args.out) / 'report.md'}", file=sys.stderr)
    if args.json:
        _write_json(summary, args.json)
    return 0


def studies_dir() -> Path:
    """The ``studies/`` folder of the source tree this package runs from."""
    return Path(__file__).resolve().parents[2] / "studies"


def study_names() -> list[str]:
    d = studies_dir()
    return sorted(p.stem.replace("_", "-") for p in d.glob("*.py") if not p.stem.startswith("_")) if d.is_dir() else []


def cmd_study(args) -> int:
    import importlib.util
    import inspect

    names = study_names()
    if args.name in (None, "list"):
        print("\n".join(names) if names else f"no studies found in {studies_dir()}")
        return 0
    if args.name not in names:
        raise CLIError(f"unknown study '{args.name}'; valid: {', '.join(names) or 'none (studies/ not found)'}")
    path = studies_dir() / (args.name.replace("-", "_") + ".py")
    spec = importlib.util.spec_from_file_location(f"bayes_mr_study_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    out = args.out or str(Path("results") / "studies" / args.name)
    takes = "executor" in inspect.signature(module.main).parameters
    if (args.scheduler or args.workers is not None) and not takes:
        raise CLIError(f"study {args.name} runs in one process: it takes no --scheduler/--workers")
    with _executor(args) as ex:
        summary = module.main(out_dir=out, quick=args.quick, seed=args.seed, **({"executor": ex} if takes else {}))
    _write_json(summary, args.json)
    return 0


def cmd_bench(args) -> int:
    from bayes_mr.bench.benchmark import run_bench

    say = progress_say(on_terminal(True))
    result = run_bench(seed=args.seed, progress=say, boucwen=args.boucwen, compare=args.compare,
                       spencer=args.spencer)
    _write_json(result, args.json)
    return 0


VERBS = {
    "simulate": cmd_simulate,
    "fit": cmd_fit,
    "validate": cmd_validate,
    "compare": cmd_compare,
    "diagnose": cmd_diagnose,
    "run": cmd_run,
    "study": cmd_study,
    "bench": cmd_bench,
}


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``bayes-mr``."""
    from bayes_mr.data.schema import RecordError

    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)
            return VERBS[args.verb](args)
    except (CLIError, RecordError, ValueError, FileNotFoundError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        print(f"bayes-mr {args.verb}: error: {msg}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"bayes-mr {args.verb}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
