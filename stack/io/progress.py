"""A simulation run in slices of simulated time, with a progress bar on a terminal and Ctrl-C
that stops it between slices (the summary so far stays consistent), and a wall-clock time limit
per run: what the commands, the experiment pipeline and the sweeps share to run long simulations
(`run_sliced`, `show_progress`, `time_limit`, `stop_when`).
"""

from __future__ import annotations

import _thread
import contextlib
import contextvars
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

__all__ = ["run_sliced", "show_progress", "TimeLimitExceeded", "GRACE_S", "time_limit", "stop_when"]


def show_progress(requested: bool | None) -> bool:
    """Whether to draw a progress bar: when asked (``--progress``), else when stderr is a
    terminal (a pipe or a log file gets no bar)."""
    if requested is not None:
        return requested
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False


class TimeLimitExceeded(RuntimeError):
    """A run went past its wall-clock time limit (`run_sliced`'s ``time_limit``)."""


_TIME_LIMIT: contextvars.ContextVar[float | None] = contextvars.ContextVar("run_time_limit", default=None)
_STOP_WHEN: contextvars.ContextVar[Callable[[], bool] | None] = contextvars.ContextVar("run_stop_when", default=None)


@contextlib.contextmanager
def time_limit(seconds: float | None) -> Iterator[None]:
    """Inside the block, every `run_sliced` that is given no ``time_limit`` of its own takes
    ``seconds`` (the sweeps' per-run limit, set around each run in the worker)."""
    token = _TIME_LIMIT.set(seconds)
    try:
        yield
    finally:
        _TIME_LIMIT.reset(token)


#: Seconds a run may take to reach the end of its slice after Ctrl-C (or SIGTERM) before it is
#: stopped where it is: a slice holds at most 100 ms of bus time, but one event that never ends
#: (a timer re-armed at the same instant) would keep it from ever ending.
GRACE_S = 1.0


class _Interrupt:
    """Ctrl-C as a flag, checked between slices, so that the simulation is never left in the
    middle of an event (the summary so far stays consistent). A second Ctrl-C — or the first
    when the slice has not ended within `GRACE_S` — stops it where it is (KeyboardInterrupt in
    the loop); so does a wall-clock ``limit`` (`TimeLimitExceeded`)."""

    def __init__(self, limit: float | None = None) -> None:
        self.requested = False
        self.timed_out = False
        self._old: Any = None
        self._installed = False
        self._timers: list[threading.Timer] = []
        self._limit = limit

    def __enter__(self) -> _Interrupt:
        if threading.current_thread() is threading.main_thread():
            self._old = signal.signal(signal.SIGINT, self._handle)
            self._installed = True
            if self._limit is not None:
                self._later(self._limit + GRACE_S, self._time_up)
        return self

    def _later(self, seconds: float, action: Callable[[], None]) -> None:
        t = threading.Timer(seconds, action)
        t.daemon = True
        t.start()
        self._timers.append(t)

    def _time_up(self) -> None:
        if self._installed:
            self.timed_out = True
            _thread.interrupt_main(signal.SIGINT)

    def _escalate(self) -> None:
        if self._installed:
            _thread.interrupt_main(signal.SIGINT)

    def _handle(self, signum: int, frame: Any) -> None:
        if self.timed_out:
            raise TimeLimitExceeded
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True
        # a slice that does not end in time is stopped where it is
        self._later(GRACE_S, self._escalate)

    def __exit__(self, *exc: Any) -> None:
        installed, self._installed = self._installed, False  # a timer firing now does nothing
        for t in self._timers:
            t.cancel()
        if installed:
            signal.signal(signal.SIGINT, self._old)


@contextlib.contextmanager
def stop_when(requested: Callable[[], bool]) -> Iterator[None]:
    """Inside the block, every `run_sliced` also stops at the end of a slice once ``requested()``
    is true, as it does on Ctrl-C. A sweep's pool worker passes the sweep's stop flag: the SIGINT
    it is sent to stop its run is lost when it comes before the run has installed its handler
    (while the scenario is being built, the worker ignores SIGINT), the flag is not."""
    token = _STOP_WHEN.set(requested)
    try:
        yield
    finally:
        _STOP_WHEN.reset(token)


def _slices(start: int, until: int, step: int) -> Iterator[int]:
    t = start
    while t < until:
        t = min(until, t + step)
        yield t


def run_sliced(
    bus: Any,
    until_ns: int,
    *,
    progress: bool | None = None,
    desc: str = "simulating",
    time_limit: float | None = None,
) -> bool:
    """Run a `SimBus` to ``until_ns`` in slices of simulated time (the same result as one
    ``bus.run(until=until_ns)``: the run stops at each slice's end and goes on from there).

    A progress bar (tqdm, in simulated seconds, with the time left) is drawn on stderr when
    `show_progress` says so; on a terminal it appears only for runs longer than 2 s of wall
    clock. Ctrl-C (and SIGTERM, which `stack.cli.main` turns into it) stops the run at the end of
    the current slice, or where it is when that does not come within `GRACE_S`, and so does the
    enclosing `stop_when` flag at the end of a slice: returns False then, True when the run reached ``until_ns``. ``time_limit`` (wall-clock seconds) raises
    `TimeLimitExceeded` when the run takes longer (default: the enclosing `time_limit` block's)."""
    if time_limit is None:
        time_limit = _TIME_LIMIT.get()
    external = _STOP_WHEN.get()
    show = show_progress(progress)
    step = max(1_000_000, min(100_000_000, (until_ns - bus.now()) // 200 or 1))
    bar = None
    if show:
        from tqdm import tqdm

        bar = tqdm(
            total=round(until_ns / 1e9, 3),
            unit="s",
            desc=desc,
            file=sys.stderr,
            leave=False,
            delay=0 if progress else 2.0,
            bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.3f}/{total:.3f} s simulated [{elapsed}<{remaining}]",
        )
    done = 0.0
    deadline = None if time_limit is None else time.monotonic() + time_limit
    try:
        with _Interrupt(time_limit) as stop:
            try:
                for t in _slices(bus.now(), until_ns, step):
                    bus.run(until=t)
                    if bar is not None:
                        now = round(t / 1e9, 3)
                        bar.update(now - done)
                        done = now
                    if stop.requested or (external is not None and external()):
                        return False
                    if deadline is not None and time.monotonic() > deadline:
                        raise TimeLimitExceeded
            except KeyboardInterrupt:
                return False  # stopped inside a slice: what was simulated so far
    except TimeLimitExceeded:
        raise TimeLimitExceeded(
            f"stopped after the time limit of {time_limit:g} s (wall clock) at {bus.now() / 1e9:.6g} s simulated"
        ) from None
    finally:
        if bar is not None:
            bar.close()
    return True
