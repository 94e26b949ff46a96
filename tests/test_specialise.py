"""Kernels specialised per model layout give the generic kernel's numbers, and cache on disk.

The generic kernel is the reference: the specialised one is the same code
with the layout a compile-time constant, so outputs agree to 1e-12 (they are
in fact identical where LLVM keeps the operation order). Each specialisation
compiles for tens of seconds, so all but one case are ``slow``.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from records import device_inputs, structure_inputs

from bayes_mr._compile import specialise as S
from bayes_mr.inference.mcmc.settings import MCMCSettings
from bayes_mr.models import get_model
from bayes_mr.models.drivers import run_batch, run_one
from bayes_mr.simulation.simulate import Inputs

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """A private kernel cache, so tests never write generated modules outside tmp."""
    monkeypatch.setenv(S.CACHE_ENV, str(tmp_path / "cache"))
    return tmp_path / "cache"


def _forced_inputs(n: int = 1500, fs: float = 1000.0) -> Inputs:
    t = np.arange(n) / fs
    return Inputs.forced(40.0 * np.sin(2 * np.pi * 2.0 * t) * np.clip(t / 0.2, 0, 1), 1 / fs,
                         command=np.where(np.sin(2 * np.pi * 0.7 * t) > 0, 2.25, 0.0))


def _inputs(kind: str) -> Inputs:
    if kind == "structure":
        return structure_inputs(3.0, 50.0)
    if kind == "device":
        return device_inputs(0.01)
    return _forced_inputs()


def _both(name: str, kind: str, inline=None, driver=run_batch, any_layout: bool = False):
    """Outputs and schedules of the generic and of the specialised (``any_layout``: the inlined) kernel on the
    same inputs."""
    m = get_model(name)
    inp = _inputs(kind)
    lay, cst = m.layout(kind), m.constants(inp.mass)
    P = np.atleast_2d(m.theta(kind, {}))
    n_out = 4 if kind != "device" else 2
    res = []
    for fn in (driver, S.specialised(driver, None if any_layout else lay, inline)):
        out = np.empty((1, inp.n, n_out))
        sched = np.zeros((1, inp.n - 1), np.int64)
        if driver is run_batch:
            failed = np.empty(1, np.int64)
            fn(lay, cst, P, inp.dt, inp.rows, out, sched, False, failed)
        else:
            fn(lay, cst, P[0], inp.dt, inp.rows, out[0], sched[0], False)
        res.append((out, sched))
    return res


def _assert_same(res):
    (out_g, sch_g), (out_s, sch_s) = res
    assert np.isfinite(out_g).all()
    np.testing.assert_array_equal(sch_s, sch_g)
    np.testing.assert_allclose(out_s, out_g, rtol=1e-12, atol=1e-12 * np.abs(out_g).max())


def test_specialised_matches_generic_and_caches_outside_the_repo(cache):
    """dahl, structure test, nothing inlined (the cheapest specialisation): same numbers; files only in the cache."""
    before = set(REPO.rglob("k_*.py"))
    _assert_same(_both("dahl", "structure", inline=(), driver=run_one))
    generated = list((cache / "kernels").glob("k_run_one_*.py"))
    assert len(generated) == 1
    assert "LAY = (" in generated[0].read_text()
    assert set(REPO.rglob("k_*.py")) == before
    assert not list((cache / "kernels").glob("*.tmp"))


def _inlined_kernels(inline) -> list[str]:
    """Texts of the generated any-layout kernels, after two models of two kinds ran on the one ``inline`` asks for
    and gave the generic kernel's numbers."""
    _assert_same(_both("dahl", "structure", inline=inline, driver=run_one, any_layout=True))
    _assert_same(_both("lugre+force_offset+voltage_dependence", "device", inline=inline, driver=run_one,
                       any_layout=True))
    return [p.read_text() for p in S.cache_dir().glob("k_run_one_any_*.py")]


def test_an_inlined_kernel_matches_generic_for_every_layout(cache):
    """A kernel with the force law (``forces``) inlined and the layout read at run time gives the generic kernel's
    numbers, and the one compiled kernel serves two models. The tier's own inline set compiles for minutes: the
    slow test below checks that one."""
    generated = _inlined_kernels(("forces",))
    assert len(generated) == 1 and "LAY" not in generated[0]


@pytest.mark.slow
def test_the_inlined_tier_matches_generic_for_every_layout(cache):
    """The inlined tier as ``auto`` compiles it (:data:`~bayes_mr._compile.specialise.INLINE`): the same numbers."""
    generated = _inlined_kernels(None)
    assert len(generated) == 1 and "LAY" not in generated[0]


def test_kernel_switch(monkeypatch, cache):
    lay = get_model("dahl").layout("structure")
    monkeypatch.setenv(S.KERNELS_ENV, "generic")
    assert S.kernel(run_batch, lay) is run_batch
    monkeypatch.setenv(S.KERNELS_ENV, "fast")
    with pytest.raises(ValueError, match="specialised"):
        S.kernel(run_batch, lay)


def test_auto_compiles_in_the_background_only_when_it_pays(monkeypatch, cache):
    """``auto`` runs the generic kernel and asks for one background compile once the work pays for it."""
    from bayes_mr.models.kernel import mass

    monkeypatch.setenv(S.KERNELS_ENV, "auto")
    monkeypatch.setattr(S, "_work", {})
    monkeypatch.setattr(S, "INLINED_TIER", ("mass",))
    started = []
    monkeypatch.setattr(S, "_start_background",
                        lambda d, l, t, inline=None, nice=0: started.append((l, t, inline, nice)))
    args = _mass_args("lugre+force_offset", "device")
    assert S.kernel(mass, args[0], work=S.INLINED_WORK / 2)(*args) == mass(*args)
    assert started == []
    # another layout's work counts towards the inlined kernel (one for all layouts), not towards this one's
    other = _mass_args("dahl", "device")
    assert S.kernel(mass, other[0], work=S.INLINED_WORK / 2)(*other) == mass(*other)
    assert len(started) == 1 and started[0][0] is None and len(started[0][1]) == 3  # the argument types
    k = S.kernel(mass, args[0], work=S.AUTO_WORK)
    assert k(*args) == mass(*args) and k.dispatcher is mass  # the generic kernel ran this call
    # then the layout's full specialised kernel at the lowest priority, and its quick one (nothing inlined) at ours
    lay = tuple(int(v) for v in args[0])
    assert started[1:] == [(lay, started[1][1], None, S.BACKGROUND_NICE), (lay, started[1][1], S.QUICK_INLINE, 0)]
    assert len(started) == 3


def test_declared_work_starts_the_compiles_at_the_first_call(monkeypatch, cache):
    """Work declared ahead (:func:`~bayes_mr._compile.specialise.expect_work`, the main job's posteriors) counts as work
    asked: the next call for that layout, however small, starts the layout's compiles; another layout's does not."""
    from bayes_mr.models.kernel import mass
    from bayes_mr.run.warmup import expect_posteriors

    monkeypatch.setenv(S.KERNELS_ENV, "auto")
    monkeypatch.setattr(S, "_work", {})
    started = []
    monkeypatch.setattr(S, "_start_background",
                        lambda d, l, t, inline=None, nice=0: started.append((l, inline, nice)))
    args, other = _mass_args("lugre", "device"), _mass_args("dahl", "device")
    S.expect_work(mass, args[0], S.AUTO_WORK)
    assert S.kernel(mass, other[0], work=1.0)(*other) == mass(*other) and started == []
    assert S.kernel(mass, args[0], work=1.0)(*args) == mass(*args)
    lay = tuple(int(v) for v in args[0])
    assert started == [(lay, None, S.BACKGROUND_NICE), (lay, S.QUICK_INLINE, 0)]
    # the main job declares each form's pilot: samples x walkers x pilot steps, on the simulator's layout
    settings = MCMCSettings()
    rec = xr.Dataset(coords={"time": np.arange(1000) * 1e-3}, attrs={"kind": "device"})
    monkeypatch.setattr(S, "_work", {})
    expect_posteriors(rec, ["spencer"], settings)
    model = get_model("spencer")
    d = len(model.param_names("device"))
    assert S._work == {(id(run_batch), S._lay_tuple(model.layout("device"))):
                       1000.0 * settings.walkers(d) * settings.pilot_length}


def test_processes_sharing_a_cache_start_one_compile_per_kernel(monkeypatch, cache):
    """The first process to ask claims a kernel's compile; another process (here: the per-process memory cleared)
    starts no second child while the claim's child lives, and takes over a claim whose process has ended (killed
    before it released it) or that is older than ``CLAIM_STALE_S``. The child releases the claim when done."""
    from bayes_mr._compile import worker as W
    from bayes_mr.models.kernel import mass

    ended = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    spawned = []

    class Child:
        def __init__(self, argv, **_):
            spawned.append(argv)
            self.pid = os.getpid()  # a live process

    monkeypatch.setattr(S.subprocess, "Popen", Child)
    args = _mass_args("dahl", "device")
    types = tuple(S.typeof(a, S.Purpose.argument) for a in args)
    lay = S._lay_tuple(args[0])
    S._start_background(mass, lay, types, inline=S.QUICK_INLINE)
    marker = Path(spawned[0][-2])
    assert W.claim_path(marker).read_text().split()[1] == str(os.getpid())
    monkeypatch.setattr(S, "_started", set())  # another process
    S._start_background(mass, lay, types, inline=S.QUICK_INLINE)
    assert len(spawned) == 1
    W.hand_over(marker, int(ended.stdout))  # the child was killed without releasing its claim
    monkeypatch.setattr(S, "_started", set())
    S._start_background(mass, lay, types, inline=S.QUICK_INLINE)
    assert len(spawned) == 2
    assert not W.claim(marker)  # held by the new (live) child
    monkeypatch.setattr(W, "CLAIM_STALE_S", 0.0)
    assert W.claim(marker)  # too old: taken over
    # the child releases the claim when it is done, compiled or not (here: its module is missing)
    with pytest.raises(FileNotFoundError):
        W.main([str(marker.parent / "missing.py"), "mass", str(marker.with_suffix(".types")), str(marker)])
    assert not W.claim_path(marker).exists()


def _mass_args(name: str, kind: str) -> tuple:
    """Arguments of the (small, quick to compile) kernel :func:`~bayes_mr.models.kernel.mass`."""
    model = get_model(name)
    return model.layout(kind), model.constants(3.0), np.ones(len(model.param_names(kind)))


def test_background_compile_is_used_once_ready(monkeypatch, cache):
    """A real child process compiles a (small) kernel into the cache; the next call loads it without compiling."""
    from bayes_mr.models.kernel import mass

    monkeypatch.setenv(S.KERNELS_ENV, "auto")
    args = _mass_args("dahl", "structure")
    lay = args[0]
    assert S.kernel(mass, lay, work=2 * S.AUTO_WORK)(*args) == mass(*args)
    markers = [m for m in S._started if str(cache) in str(m)]
    assert len(markers) == 2  # the full kernel (at low priority) and the quick one
    for marker in markers:
        for _ in range(300):
            if marker.exists():
                break
            time.sleep(0.5)
        assert marker.exists(), marker.with_name(marker.name.split(".")[0] + ".log").read_text()
    assert S.kernel(mass, lay)(*args) == mass(*args)
    fn = S.specialised(mass, lay)
    assert sum(fn.stats.cache_hits.values()) == 1 and not fn.stats.cache_misses


def test_ready_marker_follows_numbas_cache(monkeypatch, cache):
    """A marker says the machine code is in numba's cache: another cache directory (an edited package) has
    none, so the old marker must not count there."""
    import numba

    path = S.module_path(run_batch, get_model("dahl").layout("structure"))
    types = ("int64",)
    a = S.ready_path(path, types)
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(cache / "another"))
    assert S.ready_path(path, types) != a


def test_module_name_follows_the_physics(cache, tmp_path):
    """The generated module's name hashes the layout and the kernel's sources: another layout, another module."""
    a = S.module_path(run_batch, get_model("dahl").layout("structure"))
    b = S.module_path(run_batch, get_model("dahl+force_offset").layout("structure"))
    c = S.module_path(run_batch, get_model("dahl").layout("structure"), inline=())
    assert len({a, b, c}) == 3
    files = S._reached_files(run_batch)
    assert any(f.endswith("kernel.py") for f in files) and any(f.endswith("drivers.py") for f in files)


def test_generated_kernels_pass_the_command_hold_on():
    """Every tier's wrapper is generated from the generic kernel's signature: it takes the ``hold`` flag (the
    command held between samples) and hands it to the generic code, so no tier reads a held command as linear."""
    from bayes_mr.inference.ukf import kernel as K

    lay = get_model("spencer").layout("device")
    for dispatcher in (run_batch, run_one, K.ukf_batch, K.ukf_run):
        for layout, inline in ((lay, S.INLINE), (lay, ()), (None, S.INLINE)):
            text = S._source(dispatcher, layout, inline)
            signature, call = text.split(f"def {dispatcher.py_func.__name__}(")[1].split("return _generic(")
            assert "hold" in signature and "hold" in call, text


@pytest.mark.slow
def test_specialised_and_inlined_kernels_hold_the_command(cache):
    """spencer's device test under a switching command, held: the specialised and the inlined kernels give the
    generic kernel's numbers, and those are not the linear reading's."""
    m = get_model("spencer")
    inp = device_inputs(0.01)
    lay, cst = m.layout("device"), m.constants()
    p = m.theta("device", {})
    out = {}
    for label, fn, hold in (("generic", run_one, True), ("linear", run_one, False),
                            ("specialised", S.specialised(run_one, lay, ()), True),
                            ("inlined", S.inlined(run_one), True)):
        y = np.empty((inp.n, 2))
        fn(lay, cst, p, inp.dt, inp.rows, y, np.zeros(inp.n - 1, np.int64), False, 1, hold)
        out[label] = y
    for label in ("specialised", "inlined"):
        np.testing.assert_allclose(out[label], out["generic"], rtol=1e-12, atol=1e-12 * np.abs(out["generic"]).max())
    assert np.abs(out["linear"] - out["generic"]).max() > 1e-3 * np.abs(out["generic"]).max()


FORMS = ["normalized-bouc-wen", "dahl", "lugre", "bouc-wen", "spencer"]


@pytest.mark.slow
@pytest.mark.parametrize("form", FORMS)
def test_every_form_structure(cache, form):
    _assert_same(_both(form, "structure"))


@pytest.mark.slow
@pytest.mark.parametrize("name,kind", [
    ("dahl+force_offset+voltage_dependence", "device"),
    ("lugre+stiffness_drift+asymmetry", "structure"),
    ("bouc-wen+small_amplitude_regime+low_velocity_rolloff", "device"),
    ("dahl+cubic_stiffness", "forced"),
])
def test_effects_and_kinds(cache, name, kind):
    _assert_same(_both(name, kind))


def _sensitivities(name: str, kind: str):
    from bayes_mr.simulation.sensitivity import output_sensitivities
    from bayes_mr.simulation.simulate import simulate

    m = get_model(name)
    inp = _inputs(kind)
    theta = m.theta(kind, {})
    sched = simulate(m, inp, theta, ros2=False).schedule[0]
    return output_sensitivities(m, inp, theta, sched)


def test_sensitivities_run_the_kernel_the_choice_gives(monkeypatch):
    """The sensitivity kernel is chosen like the simulator's (:func:`~bayes_mr._compile.specialise.kernel`), with
    no work counted: ``auto`` never starts its minutes-long compile (:mod:`bayes_mr.models.sensitivity`)."""
    from bayes_mr.models.sensitivity import run_sensitivities
    from bayes_mr.simulation import sensitivity

    asked = []

    def choose(dispatcher, lay, work=0.0):
        asked.append((dispatcher, work))
        return dispatcher

    monkeypatch.setattr(sensitivity, "kernel", choose)
    _sensitivities("dahl+force_offset", "structure")
    assert asked == [(run_sensitivities, 0.0)]


@pytest.mark.slow
@pytest.mark.parametrize("name,kind", [("spencer+command_saturation", "device"), ("dahl+force_offset", "structure")])
def test_specialised_sensitivities_match_generic(cache, monkeypatch, name, kind):
    monkeypatch.setenv(S.KERNELS_ENV, "generic")
    y_g, dy_g, failed = _sensitivities(name, kind)
    monkeypatch.setenv(S.KERNELS_ENV, "specialised")
    y_s, dy_s, _ = _sensitivities(name, kind)
    assert failed == -1 and np.isfinite(dy_g).all()
    np.testing.assert_allclose(y_s, y_g, rtol=1e-12, atol=1e-12 * np.abs(y_g).max())
    np.testing.assert_allclose(dy_s, dy_g, rtol=1e-12, atol=1e-12 * np.abs(dy_g).max())


@pytest.mark.slow
def test_ukf_outputs_match(cache, monkeypatch):
    from bayes_mr.inference.ukf import filter as ukf
    from bayes_mr.likelihood.output_error import OutputError
    from records import structure_record

    rec, _ = structure_record("dahl", {}, n=1500)
    problem = ukf.make_problem(OutputError("dahl", rec))
    priors = ukf.lhs_priors(problem.coords, seed=0)[:4]
    out = {}
    for mode in ("generic", "specialised"):
        monkeypatch.setenv(S.KERNELS_ENV, mode)
        out[mode] = ukf.run_priors(problem, priors)
    for key in ("mean", "cov", "info", "hist_mean", "hist_sd"):
        a, b = out["generic"][key], out["specialised"][key]
        np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12 * np.nanmax(np.abs(a)), equal_nan=True)


@pytest.mark.slow
def test_second_process_loads_from_disk(cache):
    """A fresh process finds the machine code the first one compiled (warm start well under the cold one)."""
    code = (
        "import time, numpy as np; t0 = time.perf_counter()\n"
        "from bayes_mr import _specialise as S\nfrom bayes_mr.models import get_model\n"
        "from bayes_mr.models.drivers import run_one\n"
        "m = get_model('lugre'); lay = m.layout('device')\n"
        "fn = S.specialised(run_one, lay, inline=())\n"
        "x = np.linspace(0, 1, 50); rows = np.stack([0.01 * np.sin(6 * x), 0.06 * np.cos(6 * x), 0 * x], 1)\n"
        "out = np.empty((50, 2)); fn(lay, m.constants(), m.theta('device', {}), 0.02, rows, out,"
        " np.zeros(49, np.int64), False)\n"
        "print(time.perf_counter() - t0, len(fn.stats.cache_hits))\n"
    )
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    cold = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    warm = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    t_cold, hits_cold = cold.stdout.split()
    t_warm, hits_warm = warm.stdout.split()
    assert int(hits_cold) == 0 and int(hits_warm) == 1
    assert float(t_warm) < float(t_cold)


def test_specialised_choice_compiles_here_and_marks_it_ready_for_auto(monkeypatch, cache):
    """``specialised`` compiles in the calling process (the bench's warm-up); ``auto`` then runs that kernel."""
    from bayes_mr.models.kernel import mass

    args = _mass_args("lugre", "forced")
    monkeypatch.setenv(S.KERNELS_ENV, "specialised")
    assert S.kernel(mass, args[0])(*args) == mass(*args)
    monkeypatch.setenv(S.KERNELS_ENV, "auto")
    monkeypatch.setattr(S, "_start_background", lambda *a: pytest.fail("no compile needed: it is ready"))
    monkeypatch.setattr(S, "specialised", lambda d, l, inline=None: (lambda *a: "specialised ran"))
    assert S.kernel(mass, args[0], work=2 * S.AUTO_WORK)(*args) == "specialised ran"


def test_a_background_compile_runs_in_the_idle_class_where_the_os_has_one():
    probe = ("import os\nfrom bayes_mr._compile.worker import idle_class\n"
             "moved = idle_class()\nprint(moved, moved == (os.sched_getscheduler(0) == os.SCHED_IDLE))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout.split()
    assert out[1] == "True"
    if hasattr(os, "SCHED_IDLE"):
        assert out[0] == "True"
