"""The bayes-mr command: verbs, JSON keys, one-line errors, nothing written on error."""

import json

import numpy as np
import pytest

from bayes_mr.cli.commands import main
from bayes_mr.data import load

FIT_KEYS = {"model", "engine", "params", "params_sd", "log_evidence", "mse", "force_errors", "force_nrmse",
            "masked", "trained", "diverged", "wall_s"}


@pytest.fixture(scope="module")
def structure_csv(tmp_path_factory):
    path = tmp_path_factory.mktemp("cli") / "sig.csv"
    rc = main(["simulate", "--model", "dahl", "--signal", "blwn", "--amplitude", "0.004", "--fmax", "20",
               "--duration", "6", "--fs", "1000", "--mass", "50", "--noise", "0.01", "--seed", "2",
               "-o", str(path)])
    assert rc == 0
    return path


@pytest.fixture(scope="module")
def device_csv(tmp_path_factory):
    path = tmp_path_factory.mktemp("cli") / "dev.csv.gz"
    rc = main(["simulate", "--model", "dahl", "--effect", "force_offset=-100", "--signal", "blwn",
               "--kind", "device", "--amplitude", "0.05", "--fmax", "10", "--duration", "5", "--fs", "1000",
               "--param", "c=800", "--param", "k=300", "--param", "F_d=200", "--param", "sigma=3000",
               "--noise", "0.01", "-o", str(path)])
    assert rc == 0
    return path


def test_simulate_writes_a_valid_record(structure_csv, device_csv):
    rec = load(structure_csv, mass=50)
    assert rec.attrs["kind"] == "structure" and rec.sizes["time"] == 6000
    dev = load(device_csv)
    assert dev.attrs["kind"] == "device"
    assert dev["force"].values.mean() < -50  # the force offset is in the data


def test_simulate_from_an_input_csv(tmp_path, structure_csv):
    rec = load(structure_csv, mass=50)
    inp = tmp_path / "in.csv"
    inp.write_text("time,ground_acceleration [g]\n" + "\n".join(
        f"{t},{a / 9.80665}" for t, a in zip(rec["time"].values, rec["ground_acceleration"].values)))
    out = tmp_path / "out.nc"
    assert main(["simulate", "--model", "lugre", "--input", str(inp), "--mass", "50", "-o", str(out)]) == 0
    sim = load(out)
    np.testing.assert_allclose(sim["ground_acceleration"].values, rec["ground_acceleration"].values, rtol=1e-9)


def test_fit_and_validate_with_least_squares(tmp_path, structure_csv, capsys):
    res = tmp_path / "fit.nc"
    summary = tmp_path / "fit.json"
    assert main(["fit", str(structure_csv), "--mass", "50", "--model", "dahl", "--engine", "lsq",
                 "-o", str(res), "--json", str(summary), "--quiet"]) == 0
    fit = json.loads(summary.read_text())
    assert FIT_KEYS <= set(fit)
    assert fit["engine"] == "lsq" and fit["model"] == "dahl"
    assert abs(fit["params"]["F_d"] / 25.0 - 1) < 0.05
    val = tmp_path / "val.json"
    assert main(["validate", str(res), str(structure_csv), "--mass", "50", "--json", str(val)]) == 0
    v = json.loads(val.read_text())
    assert FIT_KEYS <= set(v)
    assert v["mse"] == pytest.approx(fit["mse"], rel=1e-6)


def test_device_fit_reports_force_nrmse(tmp_path, device_csv):
    out = tmp_path / "dev.json"
    assert main(["fit", str(device_csv), "--model", "dahl+force_offset", "--engine", "lsq",
                 "--json", str(out), "--quiet"]) == 0
    fit = json.loads(out.read_text())
    assert fit["force_nrmse"] < 0.05
    assert fit["params"]["f0"] == pytest.approx(-100, rel=0.05)


def test_fit_with_least_squares_searches_from_the_seed_given(tmp_path, monkeypatch):
    """``fit --engine lsq --seed 3``: the starts come from seed 3, as an mcmc fit's least squares do."""
    from bayes_mr.inference import identify

    seeds = []

    def recorded(self, record, *, seed=0, progress=True):
        seeds.append((self.estimator.settings.seed, seed))
        raise ValueError("stopped after the estimator was built")

    monkeypatch.setattr(identify.Identify, "fit", recorded)
    path = tmp_path / "short.csv"
    assert main(["simulate", "--model", "dahl", "--signal", "blwn", "--amplitude", "0.004", "--fmax", "10",
                 "--duration", "2", "--fs", "250", "--mass", "50", "-o", str(path)]) == 0
    for seed in ("0", "3"):
        main(["fit", str(path), "--mass", "50", "--model", "dahl", "--engine", "lsq", "--seed", seed, "--quiet"])
    assert seeds == [(0, 0), (3, 3)]


def test_fit_takes_the_mcmc_evidence_route_from_the_command_line(tmp_path, monkeypatch):
    """``--evidence laplace``: the chain's fit reports the Laplace route and no ladder ran (its rungs would be in
    ``evidence_routes`` as ti/ss). The chain is cut at 250 steps: the route is the point, not the posterior
    (measured: its 8 independent walkers met the rule after 200, τ 1.8)."""
    from functools import partial

    from bayes_mr.inference.mcmc import settings

    # the estimator reads MCMCSettings from its defining module when it runs
    monkeypatch.setattr(settings, "MCMCSettings", partial(settings.MCMCSettings, max_steps=250))
    path = tmp_path / "short.csv"
    assert main(["simulate", "--model", "dahl", "--signal", "blwn", "--amplitude", "0.004", "--fmax", "10",
                 "--duration", "3", "--fs", "250", "--mass", "50", "--noise", "0.01", "--seed", "4",
                 "-o", str(path)]) == 0
    out = tmp_path / "mcmc.json"
    assert main(["fit", str(path), "--mass", "50", "--model", "dahl", "--engine", "mcmc", "--evidence", "laplace",
                 "--json", str(out), "--quiet"]) == 0
    fit = json.loads(out.read_text())
    assert fit["engine"] == "mcmc" and fit["evidence_route"] == "laplace"
    assert set(fit["evidence_routes"]) == {"laplace"} and fit["n_steps"] <= 250


@pytest.mark.parametrize("argv,needle", [
    (["fit", "{missing}", "--model", "dahl"], "file not found"),
    (["fit", "{structure}", "--model", "dahl"], "mass"),
    (["fit", "{structure}", "--mass", "50", "--model", "dahl+nonsense"], "unknown effect"),
    (["fit", "{structure}", "--mass", "50", "--model", "dahl", "--prior", "sigma=1"], "LO:HI"),
    (["simulate", "--model", "dahl", "--param", "Fd=3", "--signal", "blwn", "--kind", "device"], "unknown parameter"),
    (["simulate", "--model", "dahl", "--signal", "blwn", "--mass", "50", "--duration", "0.05"], "samples"),
    (["fit", "{structure}", "--mass", "50", "--model", "dahl", "--engine", "lsq", "--evidence", "tmcmc"], "mcmc"),
])
def test_bad_input_is_one_line_and_writes_nothing(tmp_path, structure_csv, capsys, argv, needle):
    out = tmp_path / "out.json"
    argv = [a.format(missing=tmp_path / "nope.csv", structure=structure_csv) for a in argv]
    if argv[0] == "simulate":
        argv += ["-o", str(tmp_path / "sim.csv")]
    else:
        argv += ["--json", str(out), "-o", str(tmp_path / "res.nc")]
    rc = main(argv)
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert needle in err and len(err.splitlines()) == 1
    assert "Traceback" not in err
    assert not out.exists() and not (tmp_path / "res.nc").exists() and not (tmp_path / "sim.csv").exists()


@pytest.mark.parametrize("argv", [["run", "--quick", "--no-readme"], ["bench", "--no-readme", "--json", "b.json"]])
def test_no_readme_is_still_accepted(argv):
    """--no-readme is kept as a no-op: run and bench never write README.md (scripts/update_readme.py does)."""
    from bayes_mr.cli.commands import build_parser

    assert build_parser().parse_args(argv).no_readme
