"""The main job's stages that need only the first pass, run in a child process beside the posteriors.

After the first pass (every form's least squares and UKF,
:func:`bayes_mr.run.job.first_pass`) the selected form is known, and three
stages need nothing more: the model choice under the other residual model,
the diagnosis of the selected form and the virtual shake table
(:mod:`bayes_mr.run.context`, :mod:`bayes_mr.run.stages`).
:func:`start` runs them, in order, in a spawned child at the lowest CPU
priority (``nice`` :data:`NICE`, one numba thread): it takes only cycles the
job's own threads leave, and yields a core the moment one of them wakes, so
the posteriors' budget of wall seconds is not spent on it.
:meth:`Aside.collect` waits for the stages after the posteriors.

It is off in ``make run`` (:attr:`bayes_mr.run.plan.Budget.aside`): on 2
cores the posteriors leave almost nothing. The posteriors keep their time,
but the child gets about 4 % of a core (its least squares of
normalized-bouc-wen under the AR residual takes minutes instead of seconds),
so its stages end up running after the posteriors on one thread and the job
takes longer than with the stages in process. It is for a machine whose
cores the job's threads do not fill.

Nothing depends on which process ran a stage: each is deterministic in its
arguments (seeded; a compiled batch computes its members independently of
the thread count), so the results are those of the stages run in process —
tested. A child that cannot start or dies (killed, out of memory) costs time
only: its stages then run in this process and the job says why. A stage that
raises in the child raises here, as it would have in process. With progress on
stderr the child prints beside the job, its lines marked ``(beside)``; with a
progress callable its lines are passed on when it is collected.
"""

from __future__ import annotations

import multiprocessing
import os
import sys
import time as _time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field

#: ``nice`` increment of the child (the lowest priority: the job's own threads take a core first).
NICE = 19


@dataclass(frozen=True)
class Stage:
    """One stage: ``fn(*args, say=say, **kwargs)``, its wall seconds recorded under ``name``.

    ``fn`` is a module-level function and its arguments picklable: the stage is
    shipped to the child.
    """

    name: str
    fn: Callable
    args: tuple = ()
    kwargs: dict = field(default_factory=dict)

    def __call__(self, say: Callable[[str], None]):
        return self.fn(*self.args, say=say, **self.kwargs)


def run_stages(stages: list[Stage], say: Callable[[str], None]) -> dict[str, tuple[object, float]]:
    """Run ``stages`` in order in this process: name → (value, wall seconds)."""
    out = {}
    for st in stages:
        t = _time.perf_counter()
        out[st.name] = (st(say), _time.perf_counter() - t)
    return out


class _Log:
    """The child's progress: kept, and printed to stderr on the job's clock when ``live`` (picklable)."""

    def __init__(self, t0: float, live: bool):
        self.t0, self.live, self.lines = t0, live, []

    def __call__(self, msg: str) -> None:
        self.lines.append(msg)
        if self.live:
            print(f"[{_time.time() - self.t0:6.0f} s] (beside) {msg}", file=sys.stderr, flush=True)


def _child(conn, stages: list[Stage], t0: float, live: bool) -> None:
    """The child's body: lowest priority, one numba thread, the stages in order; sends (results, log, error)."""
    import numba

    os.nice(NICE)
    numba.set_num_threads(1)
    log, out, error = _Log(t0, live), {}, None
    for st in stages:
        t = _time.perf_counter()
        try:
            out[st.name] = (st(log), _time.perf_counter() - t)
        except Exception as exc:  # noqa: BLE001 — raised again in the job's process (Aside.collect)
            error = (st.name, f"{type(exc).__name__}: {exc}", traceback.format_exc())
            break
    conn.send((out, log.lines, error))
    conn.close()


class Aside:
    """Stages running in a child process (:func:`start`); :meth:`collect` their results."""

    def __init__(self, stages: list[Stage], t0: float, live: bool):
        self.stages = stages
        self.failed: str | None = None
        ctx = multiprocessing.get_context("spawn")
        self._conn, send = ctx.Pipe(duplex=False)
        self._process = ctx.Process(target=_child, args=(send, stages, t0, live), daemon=True,
                                    name="bayes_mr-beside-posteriors")
        try:
            self._process.start()
        except Exception as exc:  # noqa: BLE001 — e.g. an argument that cannot be pickled: run them here later
            self.failed = f"could not start ({type(exc).__name__}: {exc})"
        finally:
            send.close()
        self.live = live

    def cancel(self) -> None:
        """Stop the child (the job was interrupted or failed)."""
        if self._process.is_alive():
            self._process.terminate()
            self._process.join(5)

    def collect(self, say: Callable[[str], None]) -> tuple[dict[str, tuple[object, float]], float, str]:
        """Wait for the stages; run them here if the child could not.

        Returns
        -------
        results : dict
            Stage name → (value, wall seconds).
        waited : float
            Seconds this process waited for the child.
        where : str
            Where the stages ran (and why here, if the child failed).

        Raises
        ------
        RuntimeError
            A stage raised in the child (its traceback in the message).
        """
        t = _time.perf_counter()
        names = ", ".join(st.name for st in self.stages)
        if self.failed is None:
            say(f"waiting for the stages beside the posteriors ({names})")
            try:
                out, lines, error = self._conn.recv()
            except KeyboardInterrupt:
                self.cancel()
                raise
            except (EOFError, OSError):
                self._process.join(5)
                self.failed = f"its process ended (exit code {self._process.exitcode}) before sending them"
            else:
                self._process.join(5)
                if not self.live:
                    for line in lines:
                        say(f"(beside) {line}")
                if error is not None:
                    name, message, tb = error
                    raise RuntimeError(f"stage {name}, run beside the posteriors, failed: {message}\n{tb}")
                return out, _time.perf_counter() - t, "a child process beside the posteriors"
        say(f"the stages beside the posteriors ({names}) {self.failed}: running them here")
        return run_stages(self.stages, say), _time.perf_counter() - t, f"this process: the child {self.failed}"


def start(stages: list[Stage], *, t0: float, live: bool) -> Aside:
    """Start ``stages`` in a child process.

    Parameters
    ----------
    stages : list of Stage
    t0 : float
        The job's start, as :func:`time.time` [s] (the child's progress clock).
    live : bool
        Print the child's progress to stderr as it goes (else it is passed on by :meth:`Aside.collect`).
    """
    return Aside(stages, t0, live)
