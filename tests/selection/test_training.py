"""Training and validation (thesis §3.6): the run Dataset, executors, interruption, methods 1–3, scores."""

from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import json
import math
import signal

import numpy as np
import pytest
import xarray as xr

from bayes_mr.inference import results
from bayes_mr.data.schema import make_record
from bayes_mr.inference.ukf import filter as ukf
from bayes_mr.likelihood.output_error import OutputError
from bayes_mr.inference.ukf import kernel as K
from bayes_mr import scores as scores_mod
from bayes_mr.inference.ukf import training as training_mod
from bayes_mr.inference.identify import UKF, Identify
from bayes_mr.inference.ukf.training import concat_records, train
from bayes_mr.inference.ukf.validation import validate_runs
from bayes_mr.scores import score
from bayes_mr.selection import Trial, best_trial, method1, method2, method3
from records import signal_record, structure_record

# few priors (3 LHS × 3 τ) on short records keep the file fast; the τ are thesis values
SMALL = dict(n_lhs=3, taus=(0.01, 0.1, 0.5), progress=False)
RUN_VARS = ("lhs", "tau", "prior_mean", "prior_sd_phi", "final_mean", "final_sd", "final_phi", "final_cov_phi",
            "log_evidence", "status", "reason", "fail_step", "n_jitter", "n_clip", "max_substeps",
            "history_mean", "history_sd_phi")


@pytest.fixture(scope="module")
def dahl_a():
    """Signal A: band-limited ground noise, 8 s at 1 kHz (thesis-like frame, 1 % noise)."""
    return structure_record("dahl", {}, n=8000, seed=3, rms=0.6)


@pytest.fixture(scope="module")
def dahl_b():
    """Signal B: another realisation of the noise, stronger."""
    return structure_record("dahl", {}, n=8000, seed=4, rms=0.8)


@pytest.fixture(scope="module")
def trained_a(dahl_a):
    return train(OutputError("dahl", dahl_a[0]), seed=0, **SMALL)


# --- the training Dataset ------------------------------------------------------------

def test_training_returns_every_run_labelled_and_serialisable(trained_a, dahl_a, tmp_path):
    ds = trained_a
    rec, theta = dahl_a
    assert dict(ds.sizes) == {"run": 9, "param": 4, "param_": 4, "hist": ds.sizes["hist"]}
    assert list(ds["param"].values) == ["c", "k", "F_d", "sigma"]
    for v in RUN_VARS:
        assert v in ds, v
    assert ds["final_cov_phi"].dims == ("run", "param", "param_")
    assert ds["history_mean"].dims == ("run", "hist", "param")
    # the thesis's grid: every LHS mean with every τ, σ_j = τ·|μ_j| on φ
    assert list(ds["lhs"].values) == [0, 0, 0, 1, 1, 1, 2, 2, 2]
    assert list(ds["tau"].values) == [0.01, 0.1, 0.5] * 3
    phi0 = np.log(ds["phi_scale"].values * ds["prior_mean"].values)
    np.testing.assert_allclose(ds["prior_sd_phi"].values, ds["tau"].values[:, None] * np.abs(phi0), rtol=1e-12)
    # counts
    ok = ds["status"].values == K.OK
    assert ds.attrs["trained"] == ok.sum() == 9 and ds.attrs["diverged"] == 0
    assert ds.attrs["interrupted"] == 0 and ds.attrs["n_priors"] == 9
    assert list(ds["reason"].values) == ["ok"] * 9 and np.all(ds["fail_step"].values == -1)
    assert np.all(np.isfinite(ds["log_evidence"].values))
    # delta method for log-scaled parameters: sd_θ = θ · sd_φ
    sd_phi = np.sqrt(np.diagonal(ds["final_cov_phi"].values, axis1=1, axis2=2))
    np.testing.assert_allclose(ds["final_sd"].values, ds["final_mean"].values * sd_phi, rtol=1e-12)
    np.testing.assert_allclose(ds["final_mean"].values, training_mod.to_theta(ds, ds["final_phi"].values), rtol=1e-12)
    # histories start at the prior and end near the final estimate
    np.testing.assert_allclose(ds["history_mean"].values[:, 0], ds["prior_mean"].values, rtol=1e-12)
    assert ds["hist_time"].values[0] == 0 and ds["hist_time"].values[-1] <= rec["time"].values[-1]
    # attrs: settings round-trip, seed entropy, nothing netCDF cannot hold
    assert training_mod.settings_from_json(ds.attrs["settings"]) == ukf.UKFSettings()
    assert ds.attrs["seed_entropy"] == "0" and ds.attrs["taus"] == [0.01, 0.1, 0.5]
    path = tmp_path / "training.nc"
    ds.to_netcdf(path)
    back = xr.load_dataset(path)
    xr.testing.assert_equal(back, ds)
    assert back.attrs["trained"] == 9
    # the estimate of the best-evidence run is the truth to 1 % on this clean record
    best = int(np.nanargmax(ds["log_evidence"].values))
    assert np.max(np.abs(ds["final_mean"].values[best] / theta - 1)) < 0.01


def test_same_seed_same_priors_other_seed_other_priors(dahl_a):
    rec = dahl_a[0].isel(time=slice(0, 1500))
    a = train(OutputError("dahl", rec), seed=5, n_lhs=2, taus=(0.1,), progress=False)
    b = train(OutputError("dahl", rec), seed=5, n_lhs=2, taus=(0.1,), progress=False)
    c = train(OutputError("dahl", rec), seed=6, n_lhs=2, taus=(0.1,), progress=False)
    xr.testing.assert_equal(a, b)
    assert not np.allclose(a["prior_mean"].values, c["prior_mean"].values)


def test_default_training_is_the_thesis_100_priors(dahl_a):
    """10 Latin-hypercube means × the 10 indices of dispersion of eq. 3-43 (1 s of record)."""
    ds = train(OutputError("dahl", dahl_a[0].isel(time=slice(0, 1000))), seed=0, progress=False)
    assert ds.sizes["run"] == ds.attrs["n_priors"] == 100 and ds.attrs["n_lhs"] == 10
    assert ds.attrs["taus"] == list(ukf.TAUS) == [0.001, 0.01, 0.1, 0.25, 0.5, 0.75, 1.0, 2.0, 3.0, 6.0]
    assert sorted(set(ds["lhs"].values)) == list(range(10))
    assert all(sorted(ds["tau"].values[ds["lhs"].values == i]) == list(ukf.TAUS) for i in range(10))
    assert ds.attrs["trained"] + ds.attrs["diverged"] == 100
    assert ds.attrs["trained"] == int(np.sum(ds["status"].values == K.OK)) >= 50


def test_a_diverged_run_is_a_row_with_reason_and_step():
    """σ of the Dahl law up to 1e8 with at most 2 RK4 sub-steps: the stiff priors blow up."""
    rec, _ = structure_record("dahl", {}, n=3000, seed=1)
    settings = ukf.UKFSettings(box_decades=40.0, n_max=2)
    ds = train(OutputError("dahl", rec, ranges={"sigma": (1e3, 1e8)}), n_lhs=3, taus=(0.01, 0.1), settings=settings,
               seed=0, progress=False)
    status = ds["status"].values
    bad = status != K.OK
    assert 0 < bad.sum() < status.size  # some diverge, the others finish
    assert ds.attrs["trained"] == (~bad).sum() and ds.attrs["diverged"] == bad.sum()
    for r in np.flatnonzero(bad):
        assert ds["reason"].values[r] == K.NAMES[int(status[r])]
        assert 0 < ds["fail_step"].values[r] < rec.sizes["time"]
        assert np.isnan(ds["log_evidence"].values[r])
    # every run from the stiffest prior mean diverges, every run from the least stiff one trains
    sig = ds["prior_mean"].sel(param="sigma").values
    assert bad[sig == sig.max()].all() and not bad[sig == sig.min()].any()
    val = validate_runs(ds, rec)
    assert np.all(np.isnan(val["mse"].values[bad])) and np.all(np.isfinite(val["mse"].values[~bad]))
    assert all(r.startswith("not trained: ") for r in val["reason"].values[bad])
    assert val.attrs["best"] in ds["run"].values[~bad]


# --- executors and interruption ---------------------------------------------------------

def test_thread_pool_and_dask_give_the_in_process_result_bit_for_bit(trained_a, dahl_a):
    rec = dahl_a[0]
    with cf.ThreadPoolExecutor(max_workers=2) as pool:
        pooled = train(OutputError("dahl", rec), seed=0, executor=pool, chunk_size=2, **SMALL)
    xr.testing.assert_equal(pooled, trained_a)  # values, NaNs and coordinates alike
    assert pooled.attrs["executor"] == "ThreadPoolExecutor" and pooled.attrs["interrupted"] == 0

    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        dasked = train(OutputError("dahl", rec), seed=0, executor=client, chunk_size=4, **SMALL)
    xr.testing.assert_equal(dasked, trained_a)
    assert dasked.attrs["executor"] == "Client"


class _SyncFuture:
    def __init__(self, fn, args, interrupt):
        self._interrupt = interrupt
        self._value = None if interrupt else fn(*args)

    def result(self):
        if self._interrupt:
            raise KeyboardInterrupt
        return self._value

    def done(self):
        return True


class _CtrlCOnSecondChunk:
    """Runs chunks at once; the second one's result is a Ctrl-C, as if pressed while waiting for it."""

    def __init__(self):
        self.calls = 0

    def submit(self, fn, *args):
        self.calls += 1
        return _SyncFuture(fn, args, interrupt=self.calls == 2)


def test_ctrl_c_while_waiting_on_an_executor_keeps_the_finished_chunks(trained_a, dahl_a):
    ds = train(OutputError("dahl", dahl_a[0]), seed=0, executor=_CtrlCOnSecondChunk(), chunk_size=2, **SMALL)
    assert ds.attrs["interrupted"] == 1
    # chunks 0-1, [2-3 lost], 4-5, 6-7, 8 — the ones that finished are kept, unchanged
    assert list(ds["run"].values) == [0, 1, 4, 5, 6, 7, 8]
    xr.testing.assert_equal(ds, trained_a.sel(run=ds["run"].values))
    assert ds.attrs["trained"] == 7


def test_ctrl_c_in_process_stops_after_the_running_chunk(trained_a, dahl_a, monkeypatch):
    real = training_mod.train_chunk
    calls = []

    def chunk_then_ctrl_c(*args):
        out = real(*args)
        calls.append(1)
        if len(calls) == 2:
            signal.raise_signal(signal.SIGINT)  # what a Ctrl-C during the second chunk delivers
        return out

    monkeypatch.setattr(training_mod, "train_chunk", chunk_then_ctrl_c)
    before = signal.getsignal(signal.SIGINT)
    ds = train(OutputError("dahl", dahl_a[0]), seed=0, chunk_size=2, **SMALL)
    assert signal.getsignal(signal.SIGINT) is before  # the handler is given back
    assert len(calls) == 2 and ds.attrs["interrupted"] == 1
    assert list(ds["run"].values) == [0, 1, 2, 3]
    xr.testing.assert_equal(ds, trained_a.sel(run=[0, 1, 2, 3]))


# --- method 3's reset ---------------------------------------------------------------------

def test_reset_restarts_the_states_from_rest():
    """With every parameter fixed the filter is a function of the data and its start: after the
    reset, the record filtered again must give its first pass's state means exactly, and the log
    evidence twice; without the reset the second pass starts from the end of the first and differs."""
    rec, theta = structure_record("dahl", {}, n=2000, seed=2)
    values = dict(zip(("c", "k", "F_d", "sigma"), theta))
    p1 = ukf.make_problem(OutputError("dahl", rec, fixed=values))
    # the same problem (same noise, same state scales) on the record twice over: only the reset differs
    p2 = dataclasses.replace(
        p1, inputs=dataclasses.replace(p1.inputs, rows=np.concatenate([p1.inputs.rows] * 2)),
        yobs=np.concatenate([p1.yobs] * 2), valid=np.concatenate([p1.valid] * 2))
    reset = np.zeros(4000, bool)
    reset[2000] = True
    prior = ukf.Prior(np.zeros(0), np.zeros(0))
    one = ukf.filter_states(p1, prior)
    two = ukf.filter_states(p2, prior, reset=reset)
    plain = ukf.filter_states(p2, prior)
    assert one["info"][K.I_STATUS] == two["info"][K.I_STATUS] == K.OK
    np.testing.assert_array_equal(two["states"][2000:], one["states"])
    np.testing.assert_array_equal(two["states"][:2000], one["states"])
    np.testing.assert_array_equal(two["cov"], one["cov"])
    assert two["info"][K.I_LOGLIK] == pytest.approx(2 * one["info"][K.I_LOGLIK], rel=1e-12)
    assert two["info"][K.I_NUPD] == 2 * one["info"][K.I_NUPD]
    assert np.max(np.abs(plain["states"][2000:2100, 0] - one["states"][:100, 0])) > 1e-4  # x at rest vs moving


def test_reset_zeroes_state_parameter_covariance_and_keeps_phi():
    """A reset on the last sample: the states are back at their prior (mean 0, covariance P0,
    no cross-covariance) and φ is exactly the posterior after the sample before."""
    rec, theta = structure_record("dahl", {}, n=1500, seed=2)
    problem = ukf.make_problem(OutputError("dahl", rec))
    shorter = dataclasses.replace(  # the same problem without its last sample
        problem, inputs=problem.inputs.slice(0, 1499), yobs=problem.yobs[:1499], valid=problem.valid[:1499])
    prior = ukf.Prior(problem.coords.to_phi(theta) + 0.05, np.full(4, 0.05))
    reset = np.zeros(1500, bool)
    reset[-1] = True
    out = ukf.filter_states(problem, prior, reset=reset)
    ref = ukf.filter_states(shorter, prior)
    ns = len(problem.p0_states)
    assert np.all(out["mean"][:ns] == 0)
    np.testing.assert_array_equal(out["cov"][:ns, :ns], np.diag(problem.p0_states))
    assert np.all(out["cov"][:ns, ns:] == 0) and np.all(out["cov"][ns:, :ns] == 0)
    np.testing.assert_array_equal(out["mean"][ns:], ref["mean"][ns:])
    np.testing.assert_array_equal(out["cov"][ns:, ns:], ref["cov"][ns:, ns:])
    assert ref["cov"][0, ns] != 0  # an ordinary step does correlate states and parameters


def test_concat_records_pools_noise_and_refuses_mismatches(dahl_a, dahl_b):
    a, b = dahl_a[0], dahl_b[0]
    both, reset = concat_records([a, b])
    n_a, n_b = a.sizes["time"], b.sizes["time"]
    assert list(np.flatnonzero(reset)) == [n_a] and both.sizes["time"] == n_a + n_b
    for c in ("displacement", "acceleration", "ground_acceleration"):
        pooled = math.sqrt((n_a * a.attrs[f"noise_sd_{c}"] ** 2 + n_b * b.attrs[f"noise_sd_{c}"] ** 2) / (n_a + n_b))
        assert both.attrs[f"noise_sd_{c}"] == pytest.approx(pooled, rel=1e-12)
    np.testing.assert_array_equal(both["displacement"].values[n_a:], b["displacement"].values)
    assert both.attrs["source"] == "test + test"
    with pytest.raises(ValueError, match="sampled every"):
        concat_records([a, b.assign_attrs(dt=2 * b.attrs["dt"])])
    with pytest.raises(ValueError, match="storey mass"):
        concat_records([a, b.assign_attrs(mass=60.0)])


# --- methods 1, 2, 3 and selection -----------------------------------------------------

def _rel(trial: Trial, theta: np.ndarray) -> np.ndarray:
    return np.array([trial.theta[n] for n in ("c", "k", "F_d", "sigma")]) / theta - 1


def test_method1_picks_a_run_within_5_percent(dahl_a):
    rec, theta = dahl_a
    trial = method1("dahl", rec, seed=0, **SMALL)
    assert trial.method == 1 and len(trial.validation) == 1
    val = trial.validation[0]
    assert trial.best == val.attrs["best"] == int(val["run"][np.nanargmin(val["mse"].values)])
    assert np.max(np.abs(_rel(trial, theta))) < 0.05
    # a model right to the noise scores ≈ 200 (100 per channel) on its own record
    assert 190 < trial.scores["mse"] < 230
    assert set(trial.scores["force_errors"]) == {"E_t", "E_x", "E_xdot"}
    assert trial.scores["n"] == rec.sizes["time"]


def test_method2_cross_validates_on_the_other_signal(dahl_a, dahl_b):
    (a, theta), (b, _) = dahl_a, dahl_b
    trial = method2("dahl", a, b, seed=0, **SMALL)
    assert trial.method == 2
    assert trial.training.attrs["source"] == a.attrs["source"]
    assert trial.validation[0].attrs["sigma"] == json.dumps(
        {"displacement": b.attrs["noise_sd_displacement"], "acceleration": b.attrs["noise_sd_acceleration"]})
    assert np.max(np.abs(_rel(trial, theta))) < 0.05
    assert trial.scores["mse"] < 230


def test_method3_trains_on_both_and_validates_on_both(dahl_a, dahl_b):
    (a, theta), (b, _) = dahl_a, dahl_b
    trial = method3("dahl", a, b, seed=0, **SMALL)
    assert trial.method == 3 and len(trial.validation) == 2
    assert json.loads(trial.training.attrs["record_starts"]) == [0, a.sizes["time"]]
    assert trial.training["hist_time"].values[-1] > a["time"].values[-1]  # the history runs through both
    va, vb = trial.validation
    n_a, n_b = va["n"].sel(run=trial.best), vb["n"].sel(run=trial.best)
    by_hand = (n_a * va["mse"].sel(run=trial.best) + n_b * vb["mse"].sel(run=trial.best)) / (n_a + n_b)
    assert trial.scores["mse"] == pytest.approx(float(by_hand), rel=1e-12)
    comb = trial.combined["mse"].values
    assert trial.scores["mse"] == np.nanmin(comb)
    assert np.max(np.abs(_rel(trial, theta))) < 0.05

    trials = {"dahl/1": method1("dahl", b, seed=0, **SMALL), "dahl/3": trial}
    name, chosen = best_trial(trials)
    assert name == min(trials, key=lambda k: trials[k].scores["mse"]) and chosen is trials[name]


def test_method1_on_a_device_test():
    """The damper alone under band-limited motion: force is the measured channel."""
    from bayes_mr.models import get_model

    model = get_model("dahl")
    theta = model.theta("device", {})
    rec = signal_record(model, "device", duration=6.0, fs=1000.0, amplitude=3e-3, fmax=10.0, signal_seed=1,
                        noise=0.01, seed=1, source="device")
    trial = method1(model, rec, seed=0, **SMALL)
    assert trial.training.attrs["kind"] == "device"
    assert np.max(np.abs(_rel(trial, theta))) < 0.05
    # one channel: a model right to the noise scores ≈ 100 (the noisy imposed motion adds a little)
    assert 95 < trial.scores["mse"] < 130
    assert trial.scores["force_nrmse"] == trial.scores["force_errors"]["E_t"] < 0.02


def test_select_refuses_when_nothing_was_validated(trained_a):
    empty = Trial(1, "dahl", trained_a, (), -1, {}, {"mse": float("nan")})
    with pytest.raises(ValueError, match="every UKF run diverged"):
        best_trial({"dahl/1": empty})


# --- scores ---------------------------------------------------------------------------------

def _sine_structure(n=4000, fs=1000.0, with_force=True):
    """x = A sin ωt, ground still, a = −Aω² sin ωt, and a force F = 30 cos ωt [N]."""
    t = np.arange(n) / fs
    A, w = 2e-3, 2 * np.pi * 2.0
    ch = dict(ground_acceleration=np.zeros(n), displacement=A * np.sin(w * t), acceleration=-A * w * w * np.sin(w * t))
    if with_force:
        ch["force"] = 30.0 * np.cos(w * t)
    valid = np.ones(n, bool)
    valid[100] = False
    rec = make_record(t, ch, mass=50.0, valid=valid, attrs=dict(noise_sd_displacement=1e-5, noise_sd_acceleration=0.02))
    return rec, A, w


def test_structure_scores_by_hand():
    rec, A, w = _sine_structure()
    valid = rec["valid"].values
    pred = {c: rec[c].values.copy() for c in ("displacement", "acceleration", "force")}
    pred["displacement"] += 2e-5  # 2 σ_d
    pred["acceleration"] += 0.02  # 1 σ_a
    pred["force"] += 3.0
    for c in pred:
        pred[c][100] = 1e9  # a masked sample is never scored
    s = score(rec, pred)
    assert s["n"] == 3999
    assert s["mse"] == pytest.approx(100 * (4 + 1), rel=1e-9)
    sigma_f = 30 / math.sqrt(2)  # SD of a cosine over whole periods
    f = rec["force"].values[valid]
    assert np.std(f) == pytest.approx(sigma_f, rel=1e-3)
    e = s["force_errors"]
    assert e["E_t"] == pytest.approx(3.0 / np.std(f), rel=1e-12)
    assert s["force_nrmse"] == pytest.approx(3.0 / np.std(f), rel=1e-12)
    # ẋ from the smoothed displacement ≈ Aω cos ωt, ẍ = a − a_g exactly
    assert e["E_x"] == pytest.approx(3.0 * math.sqrt(2 * A * w / math.pi) / np.std(f), rel=5e-3)
    xddot = np.abs(rec["acceleration"].values[valid])
    assert e["E_xdot"] == pytest.approx(3.0 * math.sqrt(xddot.mean()) / np.std(f), rel=1e-12)
    # another noise SD, another MSE; no measured force, no force errors
    assert score(rec, pred, noise_sd={"acceleration": 0.04})["mse"] == pytest.approx(100 * (4 + 0.25), rel=1e-9)
    bare, _, _ = _sine_structure(with_force=False)
    s2 = score(bare, pred)
    assert s2["force_errors"] is None and s2["force_nrmse"] is None


def test_device_scores_by_hand():
    n, fs = 4000, 1000.0
    t = np.arange(n) / fs
    A, w = 5e-3, 2 * np.pi
    v = A * w * np.cos(w * t)
    f = 200.0 * np.sin(w * t) + 50.0 * np.cos(w * t)
    rec = make_record(t, dict(displacement=A * np.sin(w * t), velocity=v, force=f), source="device",
                      attrs=dict(noise_sd_force=2.0))
    s = score(rec, {"force": f - 4.0})
    assert s["mse"] == pytest.approx(100 * 4.0**2 / 2.0**2, rel=1e-12)  # 100/N Σ (F−F̂)²/σ_F²
    sd = np.std(f)
    assert s["force_nrmse"] == pytest.approx(4.0 / sd, rel=1e-12)
    assert s["force_errors"]["E_x"] == pytest.approx(4.0 * math.sqrt(np.abs(v).mean()) / sd, rel=1e-12)
    # ẍ is the gradient of the velocity channel ≈ Aω² |sin|, mean 2Aω²/π
    assert s["force_errors"]["E_xdot"] == pytest.approx(4.0 * math.sqrt(2 * A * w * w / math.pi) / sd, rel=1e-3)


def test_scorer_refuses_a_prediction_without_the_measured_channels():
    rec, _, _ = _sine_structure()
    with pytest.raises(ValueError, match="lacks channel"):
        scores_mod.Scorer(rec)({"displacement": rec["displacement"].values})


# --- the ukf engine of `bayes-mr fit` ----------------------------------------------------

CONTRACT_FIT_KEYS = {"model", "engine", "params", "params_sd", "log_evidence", "mse", "force_errors", "force_nrmse",
                 "masked", "trained", "diverged", "wall_s"}


def test_ukf_fit_round_trips_with_the_spec_summary(dahl_a, dahl_b, tmp_path):
    (a, theta), (b, _) = dahl_a, dahl_b
    idata = Identify("dahl", UKF(validate_on=b, n_draws=300, n_lhs=3, taus=(0.01, 0.1, 0.5))).fit(a, seed=0, progress=False)
    path = results.save(idata, tmp_path / "fit.nc")
    back = results.load_result(path)
    summary = results.summary_of(back).to_dict()
    assert CONTRACT_FIT_KEYS <= set(summary)
    assert summary["engine"] == "ukf" and summary["model"] == "dahl" and summary["method"] == 2
    assert summary["trained"] + summary["diverged"] == 9 and summary["masked"] == 0
    assert set(summary["force_errors"]) == {"E_t", "E_x", "E_xdot"}
    training = back["ukf_training"]
    sel = summary["selected_run"]
    assert summary["log_evidence"] == pytest.approx(float(training["log_evidence"].sel(run=sel)), rel=1e-12)
    assert sel == int(back["ukf_validation"].attrs["best"])
    # posterior: draws of the selected run's Gaussian on φ = ln(sθ) after the refinement passes
    # (UKFSettings.refine_passes), so θ is log-normal with mean θ̂·exp(σ_φ²/2); the draws' mean must
    # match it within 4 Monte Carlo standard errors
    post = back.posterior
    assert post.sizes["chain"] == 1 and post.sizes["draw"] == 300
    lik = OutputError("dahl", a)
    run = training.sel(run=sel)
    ref = ukf.refine(ukf.make_problem(lik, ukf.UKFSettings()), run["final_phi"].values, run["final_cov_phi"].values,
                     ukf.UKFSettings())
    assert ref["passes"] == summary["refine_passes"] == 2
    refined = dict(zip(lik.par.names, lik.par.coords.to_theta(ref["phi"])))
    point = results.point_of(back)
    for j, (name, value) in enumerate(point.items()):
        assert value == pytest.approx(refined[name], rel=1e-12)
        var_phi = float(ref["cov"][j, j])
        mcse = float(post[name].std()) / math.sqrt(300)
        assert abs(summary["params"][name] - value * math.exp(var_phi / 2)) < 4 * mcse
        assert abs(value / theta[j] - 1) < 0.05
    np.testing.assert_array_equal(back.sample_stats["lp"].values, summary["log_evidence"])
    ll = back.log_likelihood
    assert set(ll.data_vars) == {"displacement", "acceleration"}
    assert ll.sizes["draw"] == 100 and ll.sizes["obs"] == 2000 and np.all(np.isfinite(ll["displacement"].values))
    pp = back.posterior_predictive
    assert set(pp.data_vars) == {"displacement", "acceleration", "force"} and pp.sizes["draw"] == 20
    xr.testing.assert_equal(training, idata["ukf_training"])
