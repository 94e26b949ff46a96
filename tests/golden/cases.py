"""The golden cases: small records, every estimator, fixed seeds (see capture.py)."""

from __future__ import annotations

KEYS = ("params", "params_sd", "log_evidence", "mse", "force_errors", "force_nrmse", "masked",
        "trained", "diverged")


def _structure():
    from bayes_mr.models import get_model
    from bayes_mr.signals import make_signal
    from bayes_mr.simulation.simulate import synthesize

    model = get_model("dahl")
    sig = make_signal("blwn", duration=2.0, fs=500.0, amplitude=1.0, fmax=8.0, seed=11)
    theta = model.theta("structure", {"c": 100.0, "k": 2.0e4, "F_d": 25.0, "sigma": 2500.0})
    return synthesize(model, theta, sig.time, sig.as_input("structure"), mass=50.0, noise=0.01, seed=12,
                      source="golden-structure")


def _device():
    from bayes_mr.models import get_model
    from bayes_mr.signals import make_signal
    from bayes_mr.simulation.simulate import synthesize

    model = get_model("dahl+force_offset")
    sig = make_signal("blwn", duration=2.0, fs=500.0, amplitude=0.01, fmax=5.0, seed=3)
    theta = model.theta("device", {"c": 800.0, "k": 300.0, "F_d": 200.0, "sigma": 3000.0, "f0": -60.0})
    return synthesize(model, theta, sig.time, sig.as_input("device"), noise=0.01, seed=4, source="golden-device")


CASES = {
    "structure-dahl-lsq": (_structure, "dahl", "lsq"),
    "structure-dahl-mcmc": (_structure, "dahl", "mcmc"),
    "structure-dahl-ukf": (_structure, "dahl", "ukf"),
    "device-dahl+force_offset-lsq": (_device, "dahl+force_offset", "lsq"),
    "device-dahl+force_offset-mcmc": (_device, "dahl+force_offset", "mcmc"),
    "device-dahl+force_offset-ukf": (_device, "dahl+force_offset", "ukf"),
}


def estimator(engine: str):
    import bayes_mr.inference.identify as ident
    from bayes_mr.inference.mcmc.settings import MCMCSettings

    if engine == "lsq":
        return ident.LeastSquares()
    if engine == "ukf":
        return ident.UKF(n_lhs=2, taus=(0.01, 0.1))
    settings = MCMCSettings(seed=0, progress=False, min_tau_multiple=10.0, rhat_max=1.2, check_every=100,
                            max_steps=600)
    return ident.Emcee(settings=settings, evidence="laplace")


def fit_case(name: str) -> dict:
    """Summary keys of one golden case (JSON-ready)."""
    from bayes_mr.inference.identify import Identify
    from bayes_mr.inference.results import summary_of

    make, model, engine = CASES[name]
    idata = Identify(model, estimator(engine)).fit(make(), seed=0, progress=False)
    d = summary_of(idata).to_dict()
    return {k: d.get(k) for k in KEYS}
