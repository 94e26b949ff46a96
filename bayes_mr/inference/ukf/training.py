"""Model training (thesis §3.6.1): the UKF from every LHS × τ prior, as one labelled Dataset.

:func:`train` builds the filtering problem of a likelihood (model, record, noise), draws the
thesis's priors — ``n_lhs`` Latin-hypercube means × the indices of dispersion
τ (3-42, 3-43), 10 × 10 = 100 by default — and filters the record once per
prior. Runs go in chunks:

* in this process (default): each chunk is one call of the compiled batch
  filter, which spreads its runs over numba's threads (all cores);
* through an ``executor`` — anything with ``.submit(fn, *args)`` returning
  futures with ``.result()``, e.g. a :class:`concurrent.futures.Executor` or a
  ``dask.distributed.Client``: each chunk is a call of the module-level
  :func:`train_chunk` (picklable), filtering its runs one after another in
  one thread with the GIL released, so the executor's workers are the
  parallelism and do not oversubscribe the cores.

Every run is deterministic, so both routes give the same numbers bit for bit.

A run that fails numerically is a row with its status, reason and step, never
an exception. Ctrl-C stops after the running chunk (a second Ctrl-C at once)
and returns the finished runs with ``attrs["interrupted"] = 1``; with an
executor, chunks that have not started are cancelled and chunks that finished
meanwhile are kept.

Thesis method 3 (both signals at once) is training on several records in one
run: the records are concatenated (:func:`concat_records`) and the model
states restart from rest at the start of each (``reset``).

The training Dataset:

    Dims ``run`` (prior index; a subset when interrupted), ``param``,
    ``param_`` (second covariance axis), ``hist`` (history time points).

    * ``lhs``, ``tau`` (run): prior labels;
    * ``prior_mean`` (run, param): θ of the prior mean [SI];
      ``prior_sd_phi``: its SD in the log-scaled coordinates φ;
    * ``final_mean``, ``final_sd`` (run, param): filtered θ and its SD [SI]
      (delta method: θ·sd_φ for log-scaled parameters, sd_φ/s for signed);
      ``final_phi`` and ``final_cov_phi`` (run, param, param_): the
      filter's final Gaussian on φ. For a diverged run these hold the
      estimate when it stopped (possibly non-finite);
    * ``log_evidence`` (run): innovation log-likelihood Σ ln N(y_k; ŷ_k⁻, P_yy,k)
      (NaN for a diverged run, whose sum is partial);
    * ``status`` (int code of :mod:`~bayes_mr.inference.ukf.kernel`),
      ``reason`` (text), ``fail_step`` (sample, −1 when OK), ``n_jitter``,
      ``n_clip``, ``max_substeps``, ``n_updates`` (run);
    * ``history_mean`` (run, hist, param): θ [SI] along the record;
      ``history_sd_phi``: SD of φ; coordinate ``hist_time`` [s];
    * ``phi_scale``, ``phi_log``, ``lower``, ``upper`` (param): the
      coordinates φ = ln(s·θ), asinh(s·θ) or s·θ (``phi_log`` 1, 2, 0) and the plausible ranges [SI].

    Attributes: ``model``, ``kind``, ``source``, ``n_lhs``, ``taus``,
    ``n_priors``, ``settings`` (JSON), ``fixed`` and ``ranges`` (JSON),
    ``wall_s``, ``trained`` (OK runs), ``diverged``, ``interrupted``
    (0/1), ``seed_entropy``, ``seed_spawn_key``, ``record_starts`` (JSON;
    with ``reset``), ``chunk_size``, ``executor``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import signal
import sys
import threading
import time as _time

import numba
import numpy as np
import xarray as xr

from bayes_mr.execution.executor import cancel, is_done, share
from bayes_mr.likelihood.output_error import OutputError, channel_noise
from bayes_mr.execution.progress import bar as progress_bar
from bayes_mr.numerics.synthetic_noise import as_seed_sequence
from bayes_mr.inference.ukf import filter as ukf
from bayes_mr.inference.ukf import kernel as K
from bayes_mr.inference.ukf.filter import TAUS, Prior, Problem, UKFSettings

#: Channels whose noise SD the filter uses, by kind of test.
_NOISE_CHANNELS = {
    "structure": ("displacement", "acceleration", "ground_acceleration"),
    "device": ("force",),
    "forced": ("displacement", "velocity", "acceleration", "applied_force"),
}


# --- several records in one run (thesis method 3) -----------------------------------

def concat_records(records: list[xr.Dataset] | tuple[xr.Dataset, ...]) -> tuple[xr.Dataset, np.ndarray]:
    """Records one after another on one time axis, and where each one starts.

    Parameters
    ----------
    records : sequence of xarray.Dataset
        Records of the same kind, sampling interval and (structure tests)
        storey mass.

    Returns
    -------
    record : xarray.Dataset
        Channels common to all records, concatenated; time ``k·dt`` over the
        whole; ``valid`` concatenated; ``noise_sd_<channel>`` the pooled
        (sample-weighted mean-variance) noise of each channel; ``source`` the
        sources joined by ``" + "``.
    reset : ndarray of bool, shape (N,)
        True at the first sample of every record after the first.

    Notes
    -----
    The filter has one measurement-noise covariance, so the records share
    pooled noise variances. That is exact when the records come from the same
    sensors (the thesis's experiment); when their noise differs, the noisier
    record is trusted a little more than it should be and the quieter one a
    little less.
    """
    records = list(records)
    if not records:
        raise ValueError("concat_records: no records")
    first = records[0]
    kind = first.attrs["kind"]
    dt = float(first.attrs["dt"])
    for r in records[1:]:
        src = r.attrs.get("source", "record")
        if r.attrs["kind"] != kind:
            raise ValueError(f"{src}: a {r.attrs['kind']} test cannot be trained with a {kind} test")
        if not math.isclose(float(r.attrs["dt"]), dt, rel_tol=1e-9):
            raise ValueError(f"{src}: sampled every {float(r.attrs['dt']):.6g} s, the first record every {dt:.6g} s — "
                             "resample one (bayes_mr.data.derive.resample) so both share the sample interval")
        if kind == "structure" and not math.isclose(float(r.attrs["mass"]), float(first.attrs["mass"]), rel_tol=1e-12):
            raise ValueError(f"{src}: storey mass {r.attrs['mass']} kg differs from {first.attrs['mass']} kg")
        held = [str(x.attrs.get("command_interp", "linear")) for x in (first, r)]
        if held[0] != held[1]:  # one filter run reads one command: the joined record keeps the first's attribute
            raise ValueError(f"{src}: its command is read {held[1]} between samples, the first record's {held[0]} "
                             "— set both records' command_interp attribute alike")
    names = [v for v in first.data_vars if all(v in r for r in records) and first[v].dims == ("time",)]
    sizes = [r.sizes["time"] for r in records]
    n = sum(sizes)
    data = {v: ("time", np.concatenate([r[v].values for r in records]), dict(first[v].attrs)) for v in names}
    if "valid" not in data:
        data["valid"] = ("time", np.concatenate([
            r["valid"].values.astype(bool) if "valid" in r else np.ones(r.sizes["time"], bool) for r in records]))
    out = xr.Dataset(data, coords={"time": ("time", np.arange(n) * dt, {"units": "s"})})
    out.attrs.update({k: v for k, v in first.attrs.items() if not k.startswith("noise_sd_")})
    out.attrs.update(
        source=" + ".join(str(r.attrs.get("source", "record")) for r in records),
        masked=int((~out["valid"].values.astype(bool)).sum()),
    )
    for c in _NOISE_CHANNELS[kind]:
        if c not in out:
            continue
        var = sum(s * float(channel_noise(r, (c,))[0]) ** 2 for s, r in zip(sizes, records)) / n
        out.attrs[f"noise_sd_{c}"] = float(np.sqrt(var))
    reset = np.zeros(n, bool)
    reset[np.cumsum(sizes)[:-1]] = True
    return out, reset


# --- one chunk of runs (module level: picklable for any executor) ---------------------

def train_chunk(problem: Problem, priors: list[Prior], settings: UKFSettings, reset: np.ndarray | None,
                parallel: bool) -> dict:
    """Filter ``problem`` from each prior; :func:`bayes_mr.inference.ukf.filter.run_priors`'s raw arrays."""
    return ukf.run_priors(problem, priors, settings, reset=reset, parallel=parallel)


class _StopOnInterrupt:
    """Turn the first Ctrl-C into a request to stop after the running chunk.

    Only the main thread can own SIGINT; elsewhere Ctrl-C arrives as
    KeyboardInterrupt, which :func:`train` also handles.
    """

    def __init__(self, say):
        self.requested = False
        self._say = say
        self._old = None

    def _handler(self, signum, frame):
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True
        self._say("interrupted: finishing the running chunk (Ctrl-C again to stop at once)")

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            self._old = signal.signal(signal.SIGINT, self._handler)
        return self

    def __exit__(self, *exc):
        if self._old is not None:
            signal.signal(signal.SIGINT, self._old)
        return False


def _default_chunk(n_runs: int, executor) -> int:
    if executor is None:
        # whole multiples of the thread count keep every core busy; ~10 chunks give a useful progress bar
        threads = numba.get_num_threads()
        return threads * max(1, round(n_runs / (10 * threads)))
    return max(1, math.ceil(n_runs / 20))


def _settings_json(settings: UKFSettings) -> str:
    d = dataclasses.asdict(settings)
    d["points"]["name"] = type(settings.points).__name__
    return json.dumps(d, sort_keys=True)


def settings_from_json(text: str) -> UKFSettings:
    """The :class:`UKFSettings` stored in a training Dataset's ``settings`` attribute."""
    from bayes_mr.inference.ukf.sigma_points import MerweScaled

    d = json.loads(text)
    pts = dict(d.pop("points"))
    pts.pop("name", None)
    return UKFSettings(points=MerweScaled(**pts), **d)


def train(
    lik: OutputError,
    *,
    n_lhs: int = 10,
    taus: tuple[float, ...] = TAUS,
    settings: UKFSettings = UKFSettings(),
    seed: int | np.random.SeedSequence | None = 0,
    executor=None,
    chunk_size: int | None = None,
    progress: bool = True,
    reset: np.ndarray | None = None,
) -> xr.Dataset:
    """Train the likelihood's model on its record from the thesis's LHS × τ priors (§3.6.1).

    Parameters
    ----------
    lik : OutputError
        The binding of (model, record, noise) every engine shares: the
        filter's channels, valid mask, parameterisation (plausible ranges,
        fixed parameters) and measurement noise come from it.
    n_lhs : int
        Latin-hypercube samples of the prior means over the plausible ranges.
    taus : sequence of float
        Indices of dispersion τ as fractions (σ_j = τ·|μ_j| on the log-scaled
        coordinate, 3-42); the thesis's ten by default. Runs = n_lhs × len(taus).
    settings : UKFSettings
        Filter settings (sigma points, random walks, box, sub-steps).
    seed : int or SeedSequence or None
        Seed of the Latin hypercube; its entropy is stored in ``attrs``.
    executor : object, optional
        Runs chunks through ``executor.submit(train_chunk, ...)`` (see the
        module docstring); a dask Client gets the problem scattered once.
    chunk_size : int, optional
        Runs per chunk (default: ~10 chunks in process, ~20 with an executor).
    progress : bool
        Progress bar on stderr (only when stderr is a terminal).
    reset : ndarray of bool, shape (N,), optional
        Samples where the model states restart from rest (several records
        filtered in one run, thesis method 3: see :func:`concat_records`).

    Returns
    -------
    xarray.Dataset
        Every run, labelled (the module docstring lists its variables).
    """
    t_start = _time.perf_counter()
    problem = ukf.make_problem(lik, settings=settings)
    ss = as_seed_sequence(seed)
    priors = ukf.lhs_priors(problem.coords, n_lhs, taus, seed=np.random.default_rng(ss))
    n_runs = len(priors)
    chunk = int(chunk_size) if chunk_size is not None else _default_chunk(n_runs, executor)
    if chunk < 1:
        raise ValueError(f"chunk_size must be ≥ 1, got {chunk_size}")
    chunks = [list(range(i, min(i + chunk, n_runs))) for i in range(0, n_runs, chunk)]
    finished, interrupted = _run_chunks(problem, priors, settings, reset, chunks, executor=executor,
                                        progress=progress)
    ds = _assemble(problem, priors, finished, settings)
    status = ds["status"].values
    ds.attrs.update(
        model=lik.model.name,
        kind=problem.kind,
        source=str(lik.record.attrs.get("source", "")),
        n_lhs=int(n_lhs),
        taus=[float(t) for t in taus],
        n_priors=int(n_runs),
        settings=_settings_json(settings),
        fixed=json.dumps({k: float(v) for k, v in lik.fixed.items()}),
        ranges=json.dumps({k: [float(v[0]), float(v[1])] for k, v in lik.ranges.items()}),
        wall_s=float(_time.perf_counter() - t_start),
        trained=int(np.sum(status == K.OK)),
        diverged=int(np.sum(status != K.OK)),
        interrupted=int(interrupted),
        seed_entropy=str(ss.entropy),
        seed_spawn_key=json.dumps([int(k) for k in ss.spawn_key]),
        chunk_size=int(chunk),
        executor="" if executor is None else type(executor).__name__,
    )
    if reset is not None:
        ds.attrs["record_starts"] = json.dumps([0] + [int(i) for i in np.flatnonzero(reset)])
    return ds


def _run_chunks(problem: Problem, priors: list[Prior], settings: UKFSettings, reset, chunks, *, executor,
                progress: bool) -> tuple[list, bool]:
    """Filter every chunk (in process or on ``executor``); returns (finished chunks in order, interrupted)."""
    finished: list[tuple[list[int], dict]] = []
    interrupted = False
    bar = progress_bar(len(priors), f"UKF training {problem.model.name}", unit="run", enabled=bool(progress))
    with bar, _StopOnInterrupt(lambda msg: bar.write(msg, file=sys.stderr)) as stop:

        def collect(idx, out):
            finished.append((idx, out))
            n_ok = sum(int(np.sum(o["info"][:, K.I_STATUS] == K.OK)) for _, o in finished)
            n_done = sum(len(i) for i, _ in finished)
            bar.set_postfix(trained=n_ok, diverged=n_done - n_ok, refresh=False)
            bar.update(len(idx))

        try:
            if executor is None:
                for idx in chunks:
                    if stop.requested:
                        break
                    collect(idx, train_chunk(problem, [priors[i] for i in idx], settings, reset, True))
            else:
                interrupted = _run_on_executor(executor, problem, priors, settings, reset, chunks, stop, collect)
        except KeyboardInterrupt:
            interrupted = True
        interrupted = interrupted or stop.requested
    finished.sort(key=lambda item: item[0][0])
    return finished, interrupted


def _run_on_executor(executor, problem, priors, settings, reset, chunks, stop, collect) -> bool:
    """Submit every chunk and collect them in order; on Ctrl-C keep what finished. Returns ``interrupted``.

    Chunks not yet started are cancelled; a chunk already running on a
    worker cannot be stopped from here, and its result is dropped.
    """
    ref = share(executor, problem)  # dask: ship the (large) problem to the workers once
    pending: list = []
    interrupted = False
    try:
        for idx in chunks:
            pending.append((idx, executor.submit(train_chunk, ref, [priors[i] for i in idx], settings, reset, False)))
        while pending and not stop.requested:
            idx, fut = pending.pop(0)
            collect(idx, fut.result())
    except KeyboardInterrupt:  # the chunk being waited for did not deliver
        interrupted = True
    except BaseException:
        cancel(fut for _, fut in pending)
        raise
    # stopped early: keep the chunks that already finished, cancel the rest
    for idx, fut in pending:
        if is_done(fut):
            try:
                out = fut.result()
            except Exception:  # a chunk that failed or was cancelled has nothing to keep
                continue
            collect(idx, out)
        else:
            cancel([fut])
    return interrupted


def _assemble(problem: Problem, priors: list[Prior], finished, settings: UKFSettings) -> xr.Dataset:
    """The training Dataset from the finished chunks' raw arrays."""
    coords = problem.coords
    names = list(coords.names)
    p = len(names)
    ns = len(problem.p0_states)
    N = problem.inputs.n
    if finished:
        idx = np.concatenate([np.asarray(i, int) for i, _ in finished])
        cat = {k: np.concatenate([o[k] for _, o in finished]) for k in ("mean", "cov", "info", "hist_mean", "hist_sd")}
        hist_index = finished[0][1]["hist_index"]
    else:  # interrupted before the first chunk finished
        stride = max(1, int(math.ceil(N / settings.history_points)))
        hist_index = np.arange((N - 1) // stride + 1) * stride
        L = ns + p
        idx = np.zeros(0, int)
        cat = dict(mean=np.zeros((0, L)), cov=np.zeros((0, L, L)), info=np.zeros((0, K.INFO_SIZE)),
                   hist_mean=np.zeros((0, hist_index.size, L)), hist_sd=np.zeros((0, hist_index.size, L)))
    info = cat["info"]
    status = info[:, K.I_STATUS].astype(np.int32)
    ok = status == K.OK
    final_phi = cat["mean"][:, ns:]
    cov_phi = cat["cov"][:, ns:, ns:]
    sd_phi = np.sqrt(np.clip(np.diagonal(cov_phi, axis1=1, axis2=2), 0.0, None))
    final_theta = coords.to_theta(final_phi)
    # delta method: dθ/dφ = θ for φ = ln(sθ), 1/s for φ = sθ
    final_sd = coords.dtheta_dphi(final_phi) * sd_phi
    prior_mean = np.array([priors[i].mean for i in idx]).reshape(-1, p)
    prior_sd = np.array([priors[i].sd for i in idx]).reshape(-1, p)
    with np.errstate(invalid="ignore"):
        hist_theta = coords.to_theta(cat["hist_mean"][:, :, ns:])
    run_vars = {
        "lhs": ("run", np.array([priors[i].lhs for i in idx], np.int32)),
        "tau": ("run", np.array([priors[i].tau for i in idx], float), {"units": "1"}),
        "prior_mean": (("run", "param"), coords.to_theta(prior_mean), {"units": "SI"}),
        "prior_sd_phi": (("run", "param"), prior_sd),
        "final_mean": (("run", "param"), final_theta, {"units": "SI"}),
        "final_sd": (("run", "param"), final_sd, {"units": "SI"}),
        "final_phi": (("run", "param"), final_phi),
        "final_cov_phi": (("run", "param", "param_"), cov_phi),
        "log_evidence": ("run", np.where(ok, info[:, K.I_LOGLIK], np.nan)),
        "status": ("run", status),
        "reason": ("run", np.array([K.NAMES.get(int(s), f"status {int(s)}") for s in status], dtype=str)),
        "fail_step": ("run", np.where(ok, -1, info[:, K.I_STEP]).astype(np.int64)),
        "n_jitter": ("run", info[:, K.I_JITTER].astype(np.int64)),
        "n_clip": ("run", info[:, K.I_CLIP].astype(np.int64)),
        "max_substeps": ("run", info[:, K.I_NSUB].astype(np.int64)),
        "n_updates": ("run", info[:, K.I_NUPD].astype(np.int64)),
        "history_mean": (("run", "hist", "param"), hist_theta, {"units": "SI"}),
        "history_sd_phi": (("run", "hist", "param"), cat["hist_sd"][:, :, ns:]),
        "phi_scale": ("param", coords.scale),
        "phi_log": ("param", coords.code),
        "lower": ("param", coords.lower, {"units": "SI"}),
        "upper": ("param", coords.upper, {"units": "SI"}),
    }
    return xr.Dataset(
        run_vars,
        coords={
            "run": idx,
            "param": names,
            "param_": names,
            "unit": ("param", list(coords.units) if coords.units else [""] * p),
            "hist_time": ("hist", hist_index * problem.inputs.dt, {"units": "s"}),
        },
    )


def to_theta(training: xr.Dataset, phi: np.ndarray) -> np.ndarray:
    """θ [SI] from φ (..., p) in a training Dataset's coordinates."""
    scale = training["phi_scale"].values
    code = training["phi_log"].values  # Coordinates.code: 0 linear, 1 log, 2 asinh
    phi = np.asarray(phi, float)
    with np.errstate(over="ignore"):
        return np.where(code == 1, np.exp(phi), np.where(code == 2, np.sinh(phi), phi)) / scale
