"""Grids of fits on an executor: a Dask LocalCluster and a process pool give the in-process result.

One LocalCluster (2 worker processes, one thread each) serves the module; the
CLI reaches it with ``--scheduler ADDRESS`` as a user reaches a running
cluster. Process pools use the ``spawn`` start method: the compiled kernels'
OpenMP runtime does not survive ``fork``.
"""

import json
import multiprocessing
import threading
import time
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor

import pytest

from bayes_mr.cli.commands import main
from bayes_mr.selection.comparison import compare
from bayes_mr.diagnosis.diagnose import diagnose
from bayes_mr.execution.executor import call_single_threaded, local_threads, open_executor, run_jobs, side_by_side
from bayes_mr.inference.results import _jsonable
from records import offset_device_record

MODELS = ["dahl", "dahl+force_offset"]


def comparable(out) -> str:
    """The JSON of a comparison (a Comparison, or the CLI's JSON) that must not depend on where it ran (wall times
    left out)."""
    out = out if isinstance(out, dict) else out.to_dict()
    rows = [{k: v for k, v in r.items() if k != "wall_s"} for r in out["rows"]]
    return json.dumps(_jsonable({"rows": rows, "selected": out["selected"], "bayes_factors": out["bayes_factors"]}),
                      sort_keys=True)


@pytest.fixture(scope="module")
def record():
    return offset_device_record(2.0, fs=250.0)


@pytest.fixture(scope="module")
def cluster():
    from distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as c:
        yield c


@pytest.fixture(scope="module")
def pool():
    with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as ex:
        yield ex


def test_compare_on_a_dask_cluster_gives_the_in_process_json(tmp_path, record, cluster):
    """``bayes-mr compare … --scheduler ADDRESS``: the same rows, selection and Bayes factors as in process."""
    from bayes_mr.data import write_record

    path = write_record(record, tmp_path / "dev.nc")
    here, there = tmp_path / "here.json", tmp_path / "there.json"
    common = ["compare", str(path), "--models", ",".join(MODELS), "--engines", "lsq", "--quiet"]
    assert main(common + ["--json", str(here)]) == 0
    assert main(common + ["--json", str(there), "--scheduler", cluster.scheduler_address,
                          "--out", str(tmp_path / "fits")]) == 0
    a, b = json.loads(here.read_text()), json.loads(there.read_text())
    assert comparable(a) == comparable(b)
    assert b["selected"] == "dahl+force_offset" and b["evidence_route"] == "laplace"
    # fits come back from the workers whole: written here as they finish
    assert (tmp_path / "fits" / "dahl_force_offset__lsq.nc").exists()


def _no_walls(obj):
    """``obj`` without any ``wall_s`` at any depth (wall times depend on where a job ran)."""
    if isinstance(obj, dict):
        return {k: _no_walls(v) for k, v in obj.items() if k != "wall_s"}
    if isinstance(obj, list):
        return [_no_walls(v) for v in obj]
    return obj


@pytest.mark.slow  # an emcee posterior and its evidence ladder, twice: ~1 min on 2 cores
def test_compare_with_ti_evidence_on_a_dask_cluster_sends_the_rungs_there_and_gives_the_in_process_json(
        record, cluster):
    from distributed import Client, get_task_stream

    a = compare(record, ["dahl"], engines=("mcmc",), progress=False)
    with Client(cluster) as client, get_task_stream(client) as stream:
        b = compare(record, ["dahl"], engines=("mcmc",), progress=False, executor=client)
    assert len(stream.data) == 1 + 7  # the fit, and the reference ladder's 7 rungs between β = 0 and 1
    assert a.evidence_route == b.evidence_route == "ti"
    assert json.dumps(_jsonable(_no_walls(a.rows)), sort_keys=True) == \
        json.dumps(_jsonable(_no_walls(b.rows)), sort_keys=True)


def test_compare_on_a_process_pool_gives_the_in_process_json_and_reports_each_fit(record, pool):
    messages = []
    a = compare(record, MODELS, engines=("lsq",), progress=False)
    b = compare(record, MODELS, engines=("lsq",), progress=messages.append, executor=pool)
    assert comparable(a) == comparable(b)
    assert set(b.idata) == {(m, "lsq") for m in MODELS}
    done = sorted(m for m in messages if "ln Z" in m)
    assert len(done) == 2 and all(m.endswith(("[1/2]", "[2/2]")) for m in done)


def test_a_failing_job_is_a_row_with_its_error(record, pool):
    """An estimator that cannot be shipped (or fails on the worker) gives a row with ``error``; the rest stand."""

    class Unpicklable:
        name = "lsq"
        lock = threading.Lock()  # pickling fails on the way to the worker

        def fit(self, likelihood, *, seed=0, progress=True):
            raise AssertionError("never runs")

    out = compare(record, MODELS, engines=("lsq",), progress=False, executor=pool,
                  estimators={"lsq": Unpicklable()})
    assert len(out.rows) == 2 and all("error" in r for r in out.rows)
    assert out.selected is None and out.idata == {}


def test_diagnose_candidates_on_a_dask_cluster_give_the_same_cause_and_scores(record, cluster):
    from distributed import Client

    a = diagnose(record, "dahl", progress=False)
    with Client(cluster) as client:
        b = diagnose(record, "dahl", progress=False, executor=client)
    assert a.cause == b.cause == "force_offset"
    assert a.causes == b.causes and a.selection == b.selection
    assert a.extended == b.extended


def _spy_threads(monkeypatch, module, name: str) -> set:
    """Replace ``module.name`` by a wrapper that records the threads it runs on; returns their names."""
    seen, fn = set(), getattr(module, name)

    def spied(*args, **kwargs):
        seen.add(threading.current_thread().name)
        return fn(*args, **kwargs)

    monkeypatch.setattr(module, name, spied)
    return seen


def test_diagnose_on_this_process_threads_gives_the_result_in_turn(record, monkeypatch):
    """By default the candidates are fitted on threads of this process (one per numba thread), with the
    same cause, scores and extended model as one after another (one numba thread: no pool)."""
    import numba

    from bayes_mr.diagnosis import screen

    seen = _spy_threads(monkeypatch, screen, "screen_job")
    a = diagnose(record, "dahl", progress=False)
    on_threads = {n for n in seen if n.startswith("bayes_mr")}
    seen.clear()
    b = call_single_threaded(lambda: diagnose(record, "dahl", progress=False))
    assert not any(n.startswith("bayes_mr") for n in seen)
    if numba.get_num_threads() >= 2 and numba.threading_layer() in ("omp", "tbb"):
        assert on_threads
    assert a.cause == b.cause == "force_offset"
    assert a.causes == b.causes and a.selection == b.selection and a.extended == b.extended


def test_least_squares_starts_side_by_side_give_the_fit_in_turn(record, monkeypatch):
    import bayes_mr.inference.lsq.least_squares as lsq
    from bayes_mr.likelihood.output_error import OutputError

    seen = _spy_threads(monkeypatch, lsq, "refine")
    lik = OutputError("dahl", record)
    a = lsq.fit_lsq(lik, lsq.LSQSettings(n_starts=3, head_samples=400))
    b = call_single_threaded(lsq.fit_lsq, lik, lsq.LSQSettings(n_starts=3, head_samples=400))
    assert len(a.starts) == len(b.starts) == 3
    assert [r["cost"] for r in a.starts] == [r["cost"] for r in b.starts]
    assert a.log_evidence == b.log_evidence and list(a.phi) == list(b.phi)
    assert seen  # the refinements ran (on the pool's threads where there is one)


def test_local_threads_is_a_pool_only_where_jobs_can_run_side_by_side():
    import numba

    given = object()
    with local_threads(given) as ex:
        assert ex is given
    with local_threads() as ex:
        side_by_side = numba.get_num_threads() >= 2 and numba.threading_layer() in ("omp", "tbb")
        assert (ex is not None) == side_by_side
        if ex is not None:
            assert ex.submit(threading.current_thread).result().name.startswith("bayes_mr")

    def inside():
        with local_threads() as inner:
            return inner

    assert call_single_threaded(inside) is None  # a job on an executor runs its own grids in turn


def test_side_by_side_keeps_the_order_of_the_calls_and_raises_what_one_raised():
    assert side_by_side(_sleep_then, [(1, 0.2), (2, 0.0), (3, 0.1)]) == [1, 2, 3]
    with pytest.raises(ValueError, match="negative -2"):
        side_by_side(_sleep_then, [(1, 0.0), (-2, 0.0)])
    names = side_by_side(lambda: threading.current_thread().name, [(), ()])
    assert all(n.startswith("bayes_mr") for n in names) or names == [threading.current_thread().name] * 2


# --- the runner itself -------------------------------------------------------------------

def _sleep_then(value, seconds):
    time.sleep(seconds)
    if value < 0:
        raise ValueError(f"negative {value}")
    return value


def test_results_keep_the_order_of_the_jobs_not_of_completion():
    order = []
    with ThreadPoolExecutor(3) as ex:
        out = run_jobs(_sleep_then, [(1, 0.3), (-2, 0.0), (3, 0.1)], executor=ex,
                       on_done=lambda o: order.append(o.index))
    assert [o.value for o in out] == [1, None, 3]
    assert out[1].error == "ValueError: negative -2" and out[0].ok
    assert order == [1, 2, 0]  # reported as they finished
    same = run_jobs(_sleep_then, [(1, 0.0), (-2, 0.0), (3, 0.0)])
    assert [(o.value, o.error) for o in same] == [(o.value, o.error) for o in out]


def test_the_costliest_jobs_are_submitted_first_and_results_keep_the_order_of_the_jobs():
    submitted = []
    with ThreadPoolExecutor(1) as ex:
        out = run_jobs(_sleep_then, [(1, 0.0), (2, 0.0), (3, 0.0), (4, 0.0)], executor=ex,
                       on_start=submitted.append, cost=[1, 3, 2, 3])
    assert submitted == [1, 3, 2, 0]  # ties in the order given
    assert [o.value for o in out] == [1, 2, 3, 4] and [o.index for o in out] == [0, 1, 2, 3]
    turn = []
    run_jobs(_sleep_then, [(1, 0.0), (2, 0.0)], on_start=turn.append, cost=[1, 3])
    assert turn == [0, 1]  # in process: in the order given


def test_ctrl_c_cancels_the_jobs_that_have_not_started():
    """A KeyboardInterrupt while collecting cancels pending jobs and is raised again."""
    futures = []

    class Recording(ThreadPoolExecutor):
        def submit(self, fn, *args):
            futures.append(super().submit(fn, *args))
            return futures[-1]

    def interrupt(outcome):
        raise KeyboardInterrupt

    with Recording(1) as ex, pytest.raises(KeyboardInterrupt):
        run_jobs(_sleep_then, [(i, 0.05) for i in range(6)], executor=ex, on_done=interrupt)
    assert sum(f.cancelled() for f in futures) >= 4


def test_open_executor_needs_one_of_scheduler_or_workers():
    with open_executor() as ex:
        assert ex is None
    with pytest.raises(ValueError, match="not both"), open_executor("tcp://127.0.0.1:1", 2):
        pass
    with pytest.raises(ValueError, match="≥ 1"), open_executor(workers=0):
        pass


def test_fit_flags_only_with_the_ukf(tmp_path, record, capsys):
    from bayes_mr.data import write_record

    path = write_record(record, tmp_path / "dev.nc")
    assert main(["fit", str(path), "--model", "dahl", "--engine", "lsq", "--workers", "2", "--quiet"]) == 2
    assert "--engine ukf" in capsys.readouterr().err

