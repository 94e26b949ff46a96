"""The ``bayes-mr`` argument parser: one sub-parser per verb, the flags of ``docs/CONTRACT.md``.

:func:`build_parser` is all :mod:`bayes_mr.cli.commands` needs; every flag's help text
says what it does and its unit.
"""

from __future__ import annotations

import argparse


def _common_data_flags(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mass", type=float, help="storey mass [kg] (structure tests; or a netCDF 'mass' attribute); "
                                              "a forced test's known mass (else its parameter m is estimated)")
    _reading_flags(p)
    p.add_argument("--trim", action="store_true", help="trim the record to its excited part (thesis practice)")
    _input_interp_flag(p)


#: Help of a verb's DATA: one or more records, or a manifest.
DATA_HELP = ("record(s): one or more files (.csv, .csv.gz, .nc, .mat, .h5), fitted by one likelihood summed over "
             "them, or a manifest CSV (a 'file' column, paths relative to it; per-file conditions such as "
             "'current [A]'; optional 'role' train/test)")


def _records_flags(p: argparse.ArgumentParser) -> None:
    """``--set NAME=VALUE``: a condition of every record (a constant command where a file has none)."""
    p.add_argument("--set", action="append", metavar="NAME=VALUE",
                   help="a condition of every record, e.g. current=0.5 [A] or voltage=2 [V]: a constant command "
                        "becomes the record's command channel where the file has none (a manifest's cell wins)")
    p.add_argument("--record-offsets", action="store_true",
                   help="each device test has its own constant force offset f0[r] [N] (a load cell zeroed per test, "
                        "a preload set per test): estimated per record with the shared parameters (lsq, mcmc; the "
                        "UKF refuses it), profiled on each record a fit predicts; diagnose then does not name a "
                        "force offset as an effect")


def _reading_flags(p: argparse.ArgumentParser) -> None:
    """How a record's file is read: units, column names, quality control."""
    p.add_argument("--units", action="append", metavar="COLUMN=UNIT",
                   help="unit of a column whose header has none, e.g. displacement=cm (cm, mm, g, kN, …)")
    p.add_argument("--columns", action="append", metavar="CHANNEL=NAME,...",
                   help="which file column (CSV header, MATLAB/HDF5 variable) holds which channel, "
                        "e.g. time=t,displacement=D,force=F")
    p.add_argument("--no-quality", action="store_true",
                   help="do not mask clipped, spiky or disturbed samples (quality control is on by default)")


def _input_interp_flag(p: argparse.ArgumentParser) -> None:
    """``--input-interp`` and ``--command-interp``: how the drive and the command read between samples."""
    p.add_argument("--input-interp", choices=("auto", "linear", "bandlimited"), default="auto",
                   help="the input between samples: linear, or the drive reconstructed band-limited (polyphase, "
                        "S× finer grid; never the command); auto (default): the record's input_interp "
                        "attribute, else band-limited when the drive has content near the Nyquist rate")
    p.add_argument("--command-interp", choices=("auto", "hold", "linear"), default="auto",
                   help="the command (voltage/current) between samples: held from each sample to the next, as a "
                        "DAC holds it (hold), or linear; auto (default): the record's command_interp attribute, "
                        "else linear")


def _job_flags(p: argparse.ArgumentParser, *, out: str | None, json: tuple[str, str]) -> None:
    """The flags the fitting verbs end with: seed, output folder (help ``out``; None: none), ``--json``
    (metavar, help), quiet, and the record's data flags."""
    p.add_argument("--seed", type=int, default=0, help="random seed")
    p.add_argument("--noise", choices=("iid", "ar"), default="iid",
                   help="residual model of the likelihood: independent errors (iid, default) or an AR(p) process "
                        "per channel, p by BIC on a first iid fit (ar); the UKF keeps its own iid model")
    if out:
        p.add_argument("--out", metavar="DIR", help=out)
    p.add_argument("--json", metavar=json[0], help=json[1])
    p.add_argument("--quiet", action="store_true", help="no progress display")
    _common_data_flags(p)


def _executor_flags(p: argparse.ArgumentParser, what: str) -> None:
    """``--scheduler ADDRESS`` / ``--workers N``: where the command's grid of jobs (``what``) runs."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--scheduler", metavar="ADDRESS", help=f"run {what} on this Dask scheduler's cluster (tcp://HOST:8786)")
    g.add_argument("--workers", type=int, metavar="N", help=f"run {what} on a local cluster of N processes, closed after")


def _evidence_flag(p: argparse.ArgumentParser, where: str) -> None:
    """``--evidence ti|laplace|tmcmc``: the evidence route of the mcmc engine (``where``: which fits)."""
    p.add_argument("--evidence", choices=("ti", "laplace", "tmcmc"), default=None,
                   help=f"evidence route of {where}: thermodynamic integration with stepping-stone and Laplace "
                        "beside it (ti, default), Laplace alone (laplace, no ladder: fast), or transitional MCMC "
                        "from the posterior's reference (tmcmc, Laplace beside it; see bayes_mr/inference/tmcmc.py)")


def _no_readme_flag(p: argparse.ArgumentParser) -> None:
    # kept so scripts and Makefiles written for earlier versions still run: the command never writes docs
    p.add_argument("--no-readme", action="store_true",
                   help="accepted and ignored: docs/ is written by scripts/update_readme.py, not by this command")


def _simulate_parser(sub, forms: str, effects: str) -> None:
    p = sub.add_parser("simulate", help="simulate a test record of a model (with noise)",
                       description=f"Simulate a structure or device test. Forms: {forms}. Effects: {effects}.")
    p.add_argument("--model", required=True, help="FORM[+EFFECT...], e.g. dahl or dahl+force_offset")
    p.add_argument("--param", action="append", metavar="NAME=VALUE",
                   help="parameter value in SI (repeat); unset ones take the thesis/published defaults")
    p.add_argument("--effect", action="append", metavar="NAME=VALUE",
                   help="switch an effect on and set its main parameter, e.g. force_offset=20 (repeat)")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--input", metavar="CSV", help="CSV with time and ground_acceleration (or displacement)")
    src.add_argument("--signal", metavar="NAME", help="a thesis signal: blwn, amp-sweep-up-down, amp-sweep-up, "
                                                     "freq-sweep-up, freq-sweep-up-down, step, elcentro, loma-prieta")
    p.add_argument("--kind", choices=("structure", "device", "forced"),
                   help="with --signal: drive a frame (needs --mass), the damper alone, or a mass by a force "
                        "(forced: applied_force = m × the signal's acceleration) (default: structure if --mass)")
    p.add_argument("--duration", type=float, help="signal length [s]")
    p.add_argument("--fs", type=float, help="sampling rate [Hz]")
    p.add_argument("--amplitude", type=float, help="signal amplitude [m]")
    p.add_argument("--fmax", type=float, help="signal frequency limit [Hz]")
    p.add_argument("--scale", type=float, help="earthquake scale factor")
    p.add_argument("--voltage", type=float, help="constant command voltage [V]")
    p.add_argument("--current", type=float, help="constant command current [A] (instead of --voltage)")
    p.add_argument("--mass", type=float, help="storey mass [kg] (structure tests); a forced test's known mass "
                                              "(written to the record; else its parameter m is left to fit)")
    p.add_argument("--outputs", metavar="A,B", help="structure/forced tests: the outputs to write (default all)")
    p.add_argument("--units", action="append", metavar="COLUMN=UNIT", help="units of --input columns")
    p.add_argument("--noise", type=float, default=0.0,
                   help="noise as a fraction of each channel's RMS on input and outputs (0.01 = 1 %%)")
    p.add_argument("--seed", type=int, default=0, help="random seed (noise and random signals)")
    _input_interp_flag(p)
    p.add_argument("-o", "--output", required=True, metavar="OUT", help="output record (.csv, .csv.gz or .nc)")


def _fit_parsers(sub, forms: str) -> None:
    p = sub.add_parser("fit", help="fit one model with one estimator",
                       description="Fit a model to a record. Writes the fit JSON (docs/CONTRACT.md) and, with -o, "
                                   "the full result (ArviZ InferenceData, netCDF).")
    p.add_argument("data", nargs="+", help=DATA_HELP)
    p.add_argument("--model", required=True, help=f"FORM[+EFFECT...]; forms: {forms}")
    p.add_argument("--engine", choices=("ukf", "mcmc", "lsq"), default="lsq", help="estimator (default lsq)")
    p.add_argument("--validate", metavar="DATA2",
                   help="(ukf) choose the trained run by its MSE on this other record (thesis method 2)")
    p.add_argument("--prior", action="append", metavar="NAME=LO:HI", help="plausible range of a parameter [SI]")
    p.add_argument("--fix", action="append", metavar="NAME=VALUE", help="hold a parameter fixed [SI]")
    p.add_argument("-o", "--output", metavar="RESULT.nc", help="write the full result")
    _evidence_flag(p, "--engine mcmc")
    _executor_flags(p, "the UKF's training runs (--engine ukf)")
    _job_flags(p, out=None, json=("SUMMARY.json", "write the summary here (default: stdout)"))
    _records_flags(p)

    p = sub.add_parser("validate", help="predict another record with a fitted model (thesis method 2)",
                       description="Simulate the fitted point estimate on another record and score it; "
                                   "same JSON keys as fit.")
    p.add_argument("result", nargs="?", help="RESULT.nc written by fit -o (with --loco: the first record)")
    p.add_argument("data", nargs="*", help="the other record(s), or a manifest CSV: each is predicted, the scores "
                                           "also pooled over them and, for several, tabled by condition")
    p.add_argument("--json", metavar="OUT.json", help="write here (default: stdout)")
    p.add_argument("--warmup", type=float, default=0.0, metavar="SECONDS",
                   help="simulate the first SECONDS but do not score them (transients, steady-state multisines)")
    p.add_argument("--loco", action="store_true",
                   help="leave-one-condition-out: no RESULT; for each of the records (files or a manifest) fit "
                        "--model by least squares on all the others and predict it; the JSON is the table of "
                        "the held-out scores by condition")
    p.add_argument("--model", help="(with --loco) the model fitted in each fold, FORM[+EFFECT...]")
    p.add_argument("--seed", type=int, default=0, help="(with --loco) seed of the least-squares starts")
    p.add_argument("--noise", choices=("iid", "ar"), default="iid", help="(with --loco) the fits' residual model")
    p.add_argument("--fix", action="append", metavar="NAME=VALUE", help="(with --loco) hold a parameter fixed [SI]")
    p.add_argument("--prior", action="append", metavar="NAME=LO:HI",
                   help="(with --loco) plausible range of a parameter [SI]")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    p.add_argument("--figure", metavar="MAP.png",
                   help="a heat map of the force NRMSE by amplitude × frequency, one panel per current or voltage "
                        "(several records or --loco)")
    _common_data_flags(p)
    _records_flags(p)


def _compare_parsers(sub, forms: str, effects: str) -> None:
    p = sub.add_parser("compare", help="fit several models with several engines and compare them",
                       description="Models × engines on one record: parameters with uncertainty, MSE, force "
                                   "errors, log evidence and Bayes factors; the model is selected by evidence "
                                   "(TI with mcmc, else Laplace with lsq; the UKF's innovation likelihood is "
                                   "not an evidence: UKF-only comparisons select the lowest MSE).")
    p.add_argument("data", nargs="+", help=DATA_HELP)
    p.add_argument("--models", required=True, help=f"comma-separated FORM[+EFFECT...]; forms: {forms}")
    p.add_argument("--engines", default="lsq,mcmc,ukf", help="comma-separated subset of ukf,mcmc,lsq")
    p.add_argument("--validate", metavar="DATA2", help="every fit also predicts this record (thesis method 2)")
    p.add_argument("--ukf-lhs", type=int, metavar="N",
                   help="Latin-hypercube priors per index of dispersion for the UKF (default 10: 100 priors)")
    p.add_argument("--force", action="store_true",
                   help="select even if the evidence's chains (a TI rung, the posterior) did not converge; "
                        "the JSON then says forced (default: refuse and name the failed rungs)")
    _evidence_flag(p, "the mcmc rows")
    _executor_flags(p, "the models × engines fits")
    _job_flags(p, out="also write every fit as netCDF and the table as CSV here",
               json=("OUT.json", "write the comparison here (default: stdout)"))
    _records_flags(p)

    p = sub.add_parser("diagnose", help="what the model gets wrong, why, and what extending it gains",
                       description=f"Fit the baseline, look at its residuals, score every effect ({effects}) "
                                   "as an extension, refit the named one(s) and report the gain.")
    p.add_argument("data", nargs="+", help="record(s) (.csv, .csv.gz, .nc) or a manifest CSV; on several device tests "
                   "the baseline is fitted by one likelihood and an effect is kept only if it predicts "
                   "the conditions it was not fitted on")
    p.add_argument("--model", help="baseline FORM[+EFFECT...] (default: the form with the highest evidence)")
    p.add_argument("--validate", metavar="DATA2", help="error ratio of extended/baseline on this record (method 2)")
    p.add_argument("--terms", action=argparse.BooleanOptionalAction, default=None,
                   help="search the library of terms (products of x, xdot, z, u, |.|, sgn) for what the model "
                        "leaves (default: where the model stays above its noise floor, with no effect named or "
                        "after the named ones)")
    p.add_argument("--search", choices=("forward", "ranked"), default="forward",
                   help="forward (default): re-screen every remaining effect after each one added; ranked: rank "
                        "them once against the baseline and add the passing ones best first, each refitted and "
                        "kept only if it still passes (one fit per effect: a stiff model on a long record)")
    _executor_flags(p, "the candidate effects' fits")
    _job_flags(p, out="write the Markdown report, figures, baseline.nc and extended.nc here",
               json=("REPORT.json", "write the report here (default: stdout)"))
    _records_flags(p)


def _job_parsers(sub) -> None:
    p = sub.add_parser("run", help="the main job on the packaged measured MR damper record (make run)",
                       description="Every form × estimator on part A of the measured damper record, validated on "
                                   "part B; Spencer (1997)'s published parameters beside; diagnosis of the selected "
                                   "model; the virtual shake table. Writes OUT/report.md, OUT/summary.json, CSV "
                                   "tables, netCDF fits and figures under OUT, nothing else.")
    p.add_argument("--out", default="results", metavar="DIR", help="output folder (default results)")
    p.add_argument("--quick", action="store_true", help="a minute-long pass on a short window")
    p.add_argument("--record", metavar="DATA",
                   help="another device test of an MR damper instead of the packaged record (.csv, .csv.gz, .nc)")
    p.add_argument("--validate", metavar="DATA2",
                   help="a second test of the same damper, held out whole: every fit and the diagnosis's baseline "
                        "and extended model predict it (trimmed and decimated as the record is)")
    _reading_flags(p)
    p.add_argument("--seed", type=int, default=0, help="random seed")
    p.add_argument("--json", metavar="OUT.json", help="also write the summary here")
    p.add_argument("--noise", choices=("iid", "ar"), default=None,
                   help="residual model of the comparison (default iid); the other one is refitted by least "
                        "squares beside it and the report says how the model choice and ln BF move")
    p.add_argument("--mcmc-pool", type=float, default=None, metavar="STEPS",
                   help="work the emcee posteriors share, the selected form's first, in integrator steps: each "
                        "log-density evaluation (one walker, one step) is charged the RK4 and Rosenbrock steps of "
                        "one simulation of part A at its least-squares optimum, so the same posteriors run on any "
                        "machine (default: Budget.mcmc_pool of bayes_mr/run/plan.py, what the five forms' posteriors "
                        "need on the packaged record and a quarter more; --quick: none, each posterior runs to its "
                        "step limit)")
    p.add_argument("--mcmc-cap", type=float, default=None, metavar="SECONDS",
                   help="wall-time cap of all the posteriors together: a safety net for a slow machine, reported "
                        "as a machine limit where it stops or skips a posterior (default: Budget.mcmc_pool_cap_s, 1800; "
                        "--quick: none)")
    _no_readme_flag(p)
    p.add_argument("--quiet", action="store_true", help="no progress display")

    p = sub.add_parser("study", help="run one study of studies/ (thesis reproductions and extensions)",
                       description="Run a study script of the studies/ folder; `bayes-mr study list` lists them.")
    p.add_argument("name", nargs="?", help="study name (e.g. table-3-2), or 'list'")
    p.add_argument("--quick", action="store_true", help="small inputs (what CI runs)")
    p.add_argument("--out", metavar="DIR", help="output folder (default results/studies/NAME)")
    p.add_argument("--seed", type=int, default=0, help="random seed")
    p.add_argument("--json", metavar="OUT.json", help="write the study's summary here (default: stdout)")
    _executor_flags(p, "the study's grid (studies whose main takes an executor)")

    p = sub.add_parser("bench", help="the performance benchmark (UKF vs filterpy, training, MCMC, LSQ)",
                       description="Measure the UKF per step against filterpy on the same model and data, a "
                                   "100-prior training at the thesis's size, and MCMC/least-squares wall times; "
                                   "writes the figures to --json only (make bench then writes docs/performance.md "
                                   "with scripts/update_readme.py).")
    p.add_argument("--json", metavar="OUT.json", help="write the figures here (default: stdout)")
    p.add_argument("--seed", type=int, default=0, help="random seed")
    p.add_argument("--boucwen", action="store_true",
                   help="also time bouc-wen lsq and MCMC on the packaged Bouc–Wen benchmark record (40 960 samples, "
                        "band-limited inputs; long: not part of make bench)")
    p.add_argument("--compare", action="store_true",
                   help="also time compare of dahl, normalized-bouc-wen and lugre × lsq, mcmc, ukf on a 30 s, "
                        "1 kHz structure test, TI evidence (compare_s; long: not part of make bench)")
    p.add_argument("--spencer", action="store_true",
                   help="also time spencer least squares (exact Jacobians and finite differences), diagnose and "
                        "a five-form compare × lsq on simulated device tests: 20 s at 1 kHz under random motion "
                        "and a switching command, and a 4 s, 5 mm / 3 Hz sine test (spencer_*; long: not part of "
                        "make bench)")
    _no_readme_flag(p)


def build_parser() -> argparse.ArgumentParser:
    """The ``bayes-mr`` argument parser: one sub-parser per verb (docs/CONTRACT.md)."""
    from bayes_mr.models import EFFECTS, FORMS

    forms = ", ".join(FORMS)
    effects = ", ".join(EFFECTS)
    parser = argparse.ArgumentParser(
        prog="bayes-mr",
        description="Bayesian identification, model selection and diagnosis of MR dampers "
                    "(UKF, emcee and least squares on one likelihood).",
    )
    sub = parser.add_subparsers(dest="verb", required=True, metavar="VERB")
    _simulate_parser(sub, forms, effects)
    _fit_parsers(sub, forms)
    _compare_parsers(sub, forms, effects)
    _job_parsers(sub)
    return parser
