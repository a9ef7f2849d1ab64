"""Where the runs of a sweep or a study go: this process, a process pool, or a Dask cluster —
with the same rows in the same order whichever it is.

A run is ``fn(task)``: a top-level function (so that it pickles by reference) and a task with an
``index`` (its place in the canonical order) and ``head()`` (the columns that identify it). Its
row is what ``fn`` returns; an exception inside a run becomes that run's row with an ``error``
column (one line), and the other runs go on. Rows are returned sorted by index, whatever order
the workers finished in.

Engines (DESIGN.md: Dask ``distributed`` as an optional extra, the standard library's process
pool as the default; no home-made pool or RPC):

- ``sequential`` — one run after the other in this process (``workers=1``);
- ``processes`` — `concurrent.futures.ProcessPoolExecutor` with ``workers`` processes;
- ``dask`` — a `distributed.Client`: on a `distributed.LocalCluster` of ``workers`` processes (one
  thread each: a run is pure Python and holds the GIL), or on a running scheduler
  (``scheduler="tcp://HOST:8786"``) whose workers have canstack installed.

``auto`` picks: a scheduler → dask; one worker → sequential; more → processes (DESIGN.md: the
process pool is the default). On one machine the pool is the faster of the two: a LocalCluster
starts fresh interpreters and shares the cores with its scheduler (`python -m stack.bench`; the
figures are on the benchmarks page); ``dask`` gives a LocalCluster on request, with its dashboard.

Ctrl-C keeps what is done: the runs finished so far are returned with ``interrupted``; runs
under way are abandoned (a run stopped half-way raises KeyboardInterrupt in its worker and is
not recorded), and runs not started are cancelled. Pool workers ignore SIGINT between runs (the
terminal sends it to every process of the foreground group) and skip the runs queued to them
once the sweep has stopped.
"""

from __future__ import annotations

import functools
import importlib.util
import logging
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures import as_completed as futures_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any, Protocol

from profiles.schema import ScenarioError
from stack.io.progress import stop_when

__all__ = [
    "Execution",
    "ExecuteError",
    "execute",
    "choose_engine",
    "dask_available",
    "error_text",
    "ENGINES",
    "Task",
    "chunks",
]

ENGINES = ("auto", "sequential", "processes", "dask")
DASK_EXTRA = "pip install 'canstack[dask]'"


class ExecuteError(ValueError):
    """Runs cannot be sent where they were asked to go (no dask, no scheduler): one line."""


class Task(Protocol):
    """What the executor needs of a task: its canonical index and its identifying columns."""

    @property
    def index(self) -> int:
        """The task's place in the canonical order."""
        ...

    def head(self) -> dict[str, Any]:
        """The columns that identify the run (index, parameters, seed)."""
        ...


@dataclass
class Execution:
    """The rows done (canonical order), whether Ctrl-C stopped the runs, the engine used, the wall
    time in seconds and, of it, the time spent starting the pool or cluster."""

    rows: list[dict[str, Any]]
    interrupted: bool
    engine: str
    wall_s: float
    startup_s: float = 0.0


def dask_available() -> bool:
    """True when `distributed` (the ``dask`` extra) is installed."""
    return importlib.util.find_spec("distributed") is not None


def choose_engine(workers: int, scheduler: str | None, engine: str = "auto") -> str:
    """The engine the runs will use (see the module docstring), or `ExecuteError` saying in one
    line why the request cannot be met (no dask for --scheduler, a bad worker count)."""
    if engine not in ENGINES:
        raise ExecuteError(f"--engine {engine!r}: one of {', '.join(ENGINES)}")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ExecuteError(f"--workers {workers!r}: at least 1")
    if scheduler is not None:
        if engine not in ("auto", "dask"):
            raise ExecuteError(f"--scheduler runs on a Dask cluster; --engine {engine} cannot use it")
        if not dask_available():
            raise ExecuteError(f"--scheduler needs Dask's distributed, which is not installed: {DASK_EXTRA}")
        if not scheduler.strip():
            raise ExecuteError("--scheduler needs an address (tcp://HOST:8786)")
        return "dask"
    if engine == "dask":
        if not dask_available():
            raise ExecuteError(f"--engine dask needs Dask's distributed, which is not installed: {DASK_EXTRA}")
        return "dask"
    if engine == "sequential" and workers > 1:
        raise ExecuteError(f"--engine sequential runs in this process: --workers {workers} needs processes or dask")
    if engine == "auto":
        return "sequential" if workers == 1 else "processes"
    return engine


def error_text(exc: BaseException) -> str:
    """A failed run's error on one line: a scenario's own message (it names the file, table and
    key), else the exception's type and message."""
    text = str(exc) if isinstance(exc, ScenarioError) else f"{type(exc).__name__}: {exc}".rstrip(": ")
    text = " ".join(text.split())
    return text if len(text) <= 500 else text[:497] + "..."


def _within(fn: Callable[[Any], dict[str, Any]], limit: float, task: Task) -> dict[str, Any]:
    """``fn(task)`` with a wall-clock limit on each simulation it runs (`stack.io.progress.time_limit`:
    past it the run raises, and its row records the error)."""
    from stack.io.progress import time_limit

    with time_limit(limit):
        return fn(task)


def _guarded(fn: Callable[[Any], dict[str, Any]], task: Task) -> dict[str, Any]:
    """Run ``fn(task)``; an exception becomes the task's row with ``error`` (KeyboardInterrupt
    is not caught: a stopped run is no result)."""
    try:
        return fn(task)
    except Exception as exc:
        row = task.head()
        row["error"] = error_text(exc)
        return row


# --- the process pool: its workers' side ------------------------------------------------------

_STOP: Any = None
_STATE: Any = None

#: a run's state in the pool's shared array: not started, running, done
_WAITING, _RUNNING, _DONE = 0, 1, 2

#: how often a run may lose its worker when it runs alone (killed, out of memory) before it is
#: recorded as failed: the other runs of a broken pool are rerun on a new one
WORKER_LOSSES = 2


def _pool_init(stop: Any, state: Any) -> None:
    """In each pool worker: remember the sweep's stop flag and the runs' shared state array, and
    ignore Ctrl-C between runs (the parent decides what an interrupt means; a run in progress
    still stops through the runner's own handler, which the parent's SIGINT reaches)."""
    global _STOP, _STATE
    _STOP = stop
    _STATE = state
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _pool_call(fn: Callable[[Any], dict[str, Any]], task: Task) -> dict[str, Any] | None:
    if _STOP is not None and _STOP.is_set():
        return None  # the sweep was stopped while this run waited in the queue
    if _STATE is not None:
        _STATE[task.index] = _RUNNING
    try:
        if _STOP is None:
            return _guarded(fn, task)
        with stop_when(_STOP.is_set):  # a stop that comes before the run takes SIGINT
            return _guarded(fn, task)
    finally:
        if _STATE is not None:
            _STATE[task.index] = _DONE


# --- the three engines ---------------------------------------------------------------------------


class _Rows:
    """Rows by index, and the progress bar they advance."""

    def __init__(self, total: int, progress: bool | None, desc: str) -> None:
        from stack.io.progress import show_progress

        self.rows: dict[int, dict[str, Any]] = {}
        self.failed = 0
        self.bar = None
        if show_progress(progress):
            from tqdm import tqdm

            self.bar = tqdm(total=total, unit="run", desc=desc, file=sys.stderr, dynamic_ncols=True, leave=True)

    def add(self, index: int, row: dict[str, Any]) -> None:
        """Keep the row of run ``index`` and advance the bar (failures counted beside it)."""
        self.rows[index] = row
        if row.get("error"):
            self.failed += 1
        if self.bar is not None:
            self.bar.update(1)
            if self.failed:
                self.bar.set_postfix(failed=self.failed, refresh=False)

    def close(self) -> list[dict[str, Any]]:
        """Close the bar; the rows in canonical (index) order."""
        if self.bar is not None:
            self.bar.close()
        return [self.rows[i] for i in sorted(self.rows)]


def _sequential(fn: Callable[[Any], dict[str, Any]], tasks: Sequence[Task], out: _Rows) -> bool:
    try:
        for t in tasks:
            out.add(t.index, _guarded(fn, t))
    except KeyboardInterrupt:
        return True
    return False


def _stop_workers() -> None:
    """Ask the pool's workers to stop the runs they are in (SIGINT: the runner's handler stops
    at the end of its slice); idle workers ignore it."""
    for child in multiprocessing.active_children():
        try:
            os.kill(child.pid, signal.SIGINT)  # type: ignore[arg-type]
        except (OSError, TypeError):
            pass


def _processes(fn: Callable[[Any], dict[str, Any]], tasks: Sequence[Task], workers: int, out: _Rows) -> bool:
    """Run on a process pool. A worker that dies (killed, out of memory) breaks the pool: the
    runs it left without a row go to a new pool, except those under way when it broke — one of
    them took its worker down, and any may have been killed with it — which run again each in a
    pool of its own, where a loss is its own; a run that loses its worker `WORKER_LOSSES` times
    alone is recorded as failed."""
    ctx = multiprocessing.get_context()
    stop = ctx.Event()
    state = ctx.Array("b", max(1, max((t.index for t in tasks), default=0) + 1), lock=False)
    losses: dict[int, int] = {}
    todo, alone = list(tasks), list[Task]()
    while todo or alone:
        if alone:
            t = alone.pop(0)
            broken, interrupted = _pool_round(fn, [t], 1, out, ctx, stop, state)
            if interrupted:
                return True
            if broken:
                losses[t.index] = losses.get(t.index, 0) + 1
                if losses[t.index] >= WORKER_LOSSES:
                    row = t.head()
                    row["error"] = (
                        f"the worker process running it died {WORKER_LOSSES} times (killed, or out of memory); "
                        "the other runs went on"
                    )
                    out.add(t.index, row)
                else:
                    state[t.index] = _WAITING
                    alone.insert(0, t)
            continue
        broken, interrupted = _pool_round(fn, todo, workers, out, ctx, stop, state)
        if interrupted:
            return True
        todo = []
        for t in broken:
            (alone if state[t.index] == _RUNNING else todo).append(t)
            state[t.index] = _WAITING
    return False


def _pool_round(
    fn: Callable[[Any], dict[str, Any]],
    tasks: Sequence[Task],
    workers: int,
    out: _Rows,
    ctx: Any,
    stop: Any,
    state: Any,
) -> tuple[list[Task], bool]:
    """One pool over ``tasks``: (the tasks a broken pool left without a row, interrupted)."""
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_pool_init, initargs=(stop, state))
    broken: list[Task] = []
    interrupted = False
    futs: dict[Any, Task] = {}
    seen: set[Any] = set()
    try:
        futs = {pool.submit(_pool_call, fn, t): t for t in tasks}
        for fut in futures_completed(futs):
            seen.add(fut)
            t = futs[fut]
            exc = fut.exception()
            if isinstance(exc, KeyboardInterrupt):
                raise KeyboardInterrupt
            if isinstance(exc, BrokenProcessPool):
                broken.append(t)
                continue
            if exc is not None:  # the task did not pickle
                row = t.head()
                row["error"] = error_text(exc)
                out.add(t.index, row)
                continue
            done = fut.result()
            if done is not None:
                out.add(t.index, done)
    except KeyboardInterrupt:
        interrupted = True
        stop.set()
        _stop_workers()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
    if interrupted:
        # a run that ended before the stop reached it is done, though the loop above had not
        # taken its row yet when the interrupt came (a stopped run raised KeyboardInterrupt)
        for fut, t in futs.items():
            if fut not in seen and fut.done() and not fut.cancelled() and fut.exception() is None:
                done = fut.result()
                if done is not None:
                    out.add(t.index, done)
    return sorted(broken, key=lambda t: t.index), interrupted


def _dask_client(workers: int, scheduler: str | None) -> tuple[Any, Any]:
    from distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            return Client(scheduler, timeout="10s"), None
        except (OSError, TimeoutError, ValueError) as exc:
            raise ExecuteError(f"--scheduler {scheduler}: cannot connect ({' '.join(str(exc).split())})") from None
    import dask

    # one single-threaded process per worker: a run holds the GIL; a random dashboard port so
    # that two sweeps (or a user's own cluster on 8787) do not collide; no statistical profiler
    # in the workers (it samples the run's deep stack every 10 ms)
    # The worker processes are started with Ctrl-C ignored (a disposition a child inherits, and
    # Python and asyncio leave in place): the terminal sends SIGINT to the whole foreground group,
    # and a LocalCluster worker that gets it dies with a traceback; the sweep stops them instead.
    old = (
        signal.signal(signal.SIGINT, signal.SIG_IGN) if threading.current_thread() is threading.main_thread() else None
    )
    try:
        with dask.config.set({"distributed.worker.profile.enabled": False}):
            cluster = LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=True,
                dashboard_address=":0",
                silence_logs=logging.ERROR,
            )
    finally:
        if old is not None:
            signal.signal(signal.SIGINT, old)
    return Client(cluster), cluster


def _warm(module: str) -> None:
    """On a worker: import the module of the runs (returns nothing: a module does not pickle)."""
    importlib.import_module(module)


def _guarded_chunk(fn: Callable[[Any], dict[str, Any]], tasks: Sequence[Task]) -> list[dict[str, Any]]:
    return [_guarded(fn, t) for t in tasks]


def chunks(tasks: Sequence[Task], slots: int) -> list[list[Task]]:
    """The tasks cut into consecutive chunks for ``slots`` worker threads: 4 chunks a slot (so
    the last chunk to finish is a small part of the work, and work stealing can even out runs of
    different lengths), and at most 50 runs a chunk (so the progress bar moves). A Dask task
    costs milliseconds of scheduling, a sizeable part of a short run, hence runs in chunks; 4 a
    slot did better than 16 in the benchmark's sweep (the benchmarks page has the figures)."""
    n = len(tasks)
    count = min(n, max(4 * max(1, slots), -(-n // 50)))
    size = -(-n // count) if count else 1
    return [list(tasks[i : i + size]) for i in range(0, n, size)]


def _dask(fn: Callable[[Any], dict[str, Any]], tasks: Sequence[Task], client: Any, out: _Rows) -> bool:
    from distributed import as_completed

    slots = sum(client.nthreads().values()) or 1
    parts = chunks(tasks, slots)
    futs = client.map(functools.partial(_guarded_chunk, fn), parts, pure=False)
    by_key = {f.key: part for f, part in zip(futs, parts)}
    try:
        for fut in as_completed(futs):
            part = by_key[fut.key]
            if fut.status == "finished":
                for t, row in zip(part, fut.result()):
                    out.add(t.index, row)
            else:
                exc = fut.exception() if fut.status == "error" else None
                if isinstance(exc, KeyboardInterrupt):
                    raise KeyboardInterrupt
                for t in part:  # the worker died or the chunk did not unpickle: every run of it failed
                    row = t.head()
                    row["error"] = error_text(exc) if exc is not None else f"run {fut.status} on the cluster"
                    out.add(t.index, row)
            fut.release()
    except KeyboardInterrupt:
        client.cancel(futs)
        return True
    return False


def execute(
    fn: Callable[[Any], dict[str, Any]],
    tasks: Sequence[Task],
    *,
    workers: int = 1,
    scheduler: str | None = None,
    engine: str = "auto",
    progress: bool | None = None,
    desc: str = "runs",
    time_limit: float | None = None,
) -> Execution:
    """Run ``fn`` on every task (see the module docstring) and return the rows in canonical order.

    ``progress`` draws a tqdm bar of runs done / total with the ETA on stderr (None: when stderr
    is a terminal); ``time_limit`` (wall-clock seconds) stops a simulation of a run that takes
    longer, and the run's row records it. Raises `ExecuteError` before any run when the engine
    cannot be had."""
    name = choose_engine(workers, scheduler, engine)
    module = fn.__module__
    if time_limit is not None:
        fn = functools.partial(_within, fn, time_limit)
    wall0 = time.perf_counter()
    startup = 0.0
    if name == "dask":
        client, cluster = _dask_client(workers, scheduler)
        try:
            # every worker imports the run's module now (LocalCluster workers are fresh interpreters:
            # half a second each), so that the start-up is counted as such, not in the first runs
            try:
                client.run(_warm, module)
            except Exception as exc:
                raise ExecuteError(
                    f"the Dask workers cannot import {module} ({error_text(exc)}): install "
                    "canstack (the same version) on every worker"
                ) from None
            startup = time.perf_counter() - wall0
            out = _Rows(len(tasks), progress, desc)
            if scheduler is not None and out.bar is not None:
                print(f"dask: {scheduler}, dashboard {client.dashboard_link}", file=sys.stderr)
            interrupted = _dask(fn, tasks, client, out)
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    else:
        out = _Rows(len(tasks), progress, desc)
        if name == "processes":
            interrupted = _processes(fn, tasks, workers, out)
        else:
            interrupted = _sequential(fn, tasks, out)
    rows = out.close()
    return Execution(
        rows=rows, interrupted=interrupted, engine=name, wall_s=time.perf_counter() - wall0, startup_s=startup
    )
