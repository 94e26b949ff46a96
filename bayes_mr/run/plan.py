"""The main job's plan: how much of the record and of each estimator ``bayes-mr run`` uses."""

from __future__ import annotations

from dataclasses import dataclass, field

from bayes_mr.inference.mcmc.settings import MCMCSettings
from bayes_mr.inference.ukf.filter import TAUS
from bayes_mr.models import FORMS

__all__ = ["FULL", "QUICK", "Budget"]


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
        not converged, not hidden). With ``max_evaluations`` a posterior that
        cannot hold its pilot and shortest chain in it is not started, and the
        report says which and why (:mod:`bayes_mr.inference.mcmc.budget`).
    mcmc_pool : float or None
        The work all posteriors share [integrator steps]: each log-density evaluation is charged the integrator
        steps (RK4 sub-steps and Rosenbrock steps) of one simulation of part A at the least-squares optimum its
        chain starts from, a price fixed by the record and that fit, never by the machine
        (:func:`bayes_mr.run.posteriors.evaluation_price`). None: each posterior has ``mcmc.max_evaluations``
        alone. They run after every form's least squares and UKF, the selected form first, then by evidence,
        each with what the earlier ones left (:mod:`bayes_mr.run.posteriors`).
    mcmc_pool_cap_s : float or None
        Wall-time cap of all posteriors together [s]: a safety net for a machine far slower than the pool was
        set for, deciding nothing on a machine that meets it. A posterior it stops, or does not start, is
        reported as a machine limit, not a result. None: no cap.
    evidence : str
        ``"ti"`` or ``"laplace"`` for the MCMC rows.
    ukf_lhs : int
        Latin-hypercube priors per index of dispersion.
    ukf_taus : tuple of float
        Indices of dispersion (thesis: ten).
    input_interp : {"linear", "bandlimited"} or None
        Inputs between samples (None: ``auto``). ``make run`` keeps linear: ``auto`` reads
        its record at 250 Hz band-limited (S = 11), which costs several times the run's budget.
    noise : {"iid", "ar"}
        Residual model of the comparison's likelihood (``Identify.noise``).
        The other one is also fitted by least squares, so the report says how
        the model choice and the Bayes factors move between them.
    diagnose_s : float or None
        Diagnose the selected model on the first this-many seconds of part A
        (None: all of A; 0: no diagnosis).
    diagnose_fs : float or None
        Sampling rate of the diagnosis [Hz] (None: :attr:`fs`). The
        record's own rate or ≥ 1 kHz — a command switch and the field's
        sub-millisecond lag are below a 4-ms sample.
    shake_table_engines : tuple of str
        Engines of the virtual shake table (``ukf``, ``lsq``).
    terms : bool
        After the named effects, search the term library for what the extended model still leaves
        (:mod:`bayes_mr.diagnosis.term_search`; a term is kept only if the evidence and the error on a held-out
        end of A both improve, and again with the start of A held out), whatever the verdict: on the measured
        damper the named effects leave ~80× the noise floor, and that is what the diagnosis must speak to.
    aside : bool
        Run the stages that need only the first pass (noise sensitivity, diagnosis, virtual shake table) in a
        child process at the lowest priority beside the posteriors (:mod:`bayes_mr.run.aside`; same results),
        else after them here. Off by default: on 2 cores the posteriors hold both and the child gets ~5 % of one
        (that module); for a machine with cores the job's threads leave idle.
    """

    fs: float
    duration_s: float | None
    train_fraction: float = 0.6
    forms: tuple[str, ...] = tuple(FORMS)
    mcmc: MCMCSettings = field(default_factory=lambda: MCMCSettings(max_steps=3000))
    mcmc_pool: float | None = None
    mcmc_pool_cap_s: float | None = None
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
        if self.mcmc_pool is not None and not self.mcmc_pool > 0:
            raise ValueError(f"mcmc_pool must be a positive number of integrator steps or None, not "
                             f"{self.mcmc_pool!r}")
        if self.mcmc_pool_cap_s is not None and not self.mcmc_pool_cap_s > 0:
            raise ValueError(f"mcmc_pool_cap_s must be positive seconds or None, not {self.mcmc_pool_cap_s!r}")


#: ``make run``: the whole trimmed record at ~1 kHz (the record's 3 kHz decimated by 3; the RK4 sub-steps are
#: set by the model's stiffness, not the rate, so 1 kHz costs about what 250 Hz does). The emcee posteriors
#: share one pool of work (``mcmc_pool``, integrator steps), the selected form's first
#: (:mod:`bayes_mr.run.posteriors`); a posterior that cannot hold its pilot and shortest chain in what the pool
#: has left is not started, and the report says which and why (:mod:`bayes_mr.inference.mcmc.budget`).
#: The pool is what the five forms' posteriors spend unbudgeted on that record, each to its own rule, and a
#: quarter more: normalized-bouc-wen 10 400 log-density evaluations × 60 700 integrator steps, dahl
#: 8 000 × 19 400, lugre 10 400 × 18 900, bouc-wen 25 200 × 28 400 (seven adaptation rounds), spencer
#: 38 400 × 66 100, 4.24e9 in all (``scripts/measure_posterior_work.py``, seed 0; the same counts on any machine).
#: The quarter (1.06e9) covers every posterior taking one adaptation round and two convergence checks more than
#: there (0.85e9), so another seed's chains also get all five. The wall-time cap (1800 s) is a safety net only:
#: that script reports the posteriors' wall times beside their work (1110 s in all on two cores shared with
#: another job's test run).
#: Selection is by the Laplace evidence every form has (a thermodynamic-integration ladder per form takes
#: minutes each: ``bayes-mr compare --engines mcmc`` runs it). The virtual shake table runs the UKF only; the
#: diagnosis runs on all of part A at 1 kHz.
FULL = Budget(fs=1000.0, duration_s=None, mcmc=MCMCSettings(max_steps=8000), mcmc_pool=5.3e9,
              mcmc_pool_cap_s=1800.0, evidence="laplace", ukf_lhs=2, shake_table_engines=("ukf",))
#: ``bayes-mr run --quick``: a minute-long pass (a 4-s window at ~250 Hz, two forms, short chains; the
#: diagnosis on that window's part A at 1 kHz, ~15 s).
QUICK = Budget(fs=250.0, duration_s=4.0, forms=("dahl", "lugre"),
               mcmc=MCMCSettings(max_steps=500, min_tau_multiple=20.0, rhat_max=1.05),
               evidence="laplace", ukf_lhs=1, ukf_taus=(0.01, 0.1))
