"""A simulation run in slices of simulated time, with a progress bar on a terminal and Ctrl-C
that stops it between slices (the summary so far stays consistent): what the commands and the
experiment pipeline share to run long simulations (`run_sliced`, `show_progress`).
"""

from __future__ import annotations

import signal
import sys
import threading
from collections.abc import Iterator
from typing import Any

__all__ = ["run_sliced", "show_progress"]


def show_progress(requested: bool | None) -> bool:
    """Whether to draw a progress bar: when asked (``--progress``), else when stderr is a
    terminal (a pipe or a log file gets no bar)."""
    if requested is not None:
        return requested
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False


class _Interrupt:
    """Ctrl-C as a flag, checked between slices, so that the simulation is never left in the
    middle of an event (the summary so far stays consistent); a second Ctrl-C interrupts at
    once."""

    def __init__(self) -> None:
        self.requested = False
        self._old: Any = None
        self._installed = False

    def __enter__(self) -> _Interrupt:
        if threading.current_thread() is threading.main_thread():
            self._old = signal.signal(signal.SIGINT, self._handle)
            self._installed = True
        return self

    def _handle(self, signum: int, frame: Any) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True

    def __exit__(self, *exc: Any) -> None:
        if self._installed:
            signal.signal(signal.SIGINT, self._old)


def _slices(start: int, until: int, step: int) -> Iterator[int]:
    t = start
    while t < until:
        t = min(until, t + step)
        yield t


def run_sliced(bus: Any, until_ns: int, *, progress: bool | None = None, desc: str = "simulating") -> bool:
    """Run a `SimBus` to ``until_ns`` in slices of simulated time (the same result as one
    ``bus.run(until=until_ns)``: the run stops at each slice's end and goes on from there).

    A progress bar (tqdm, in simulated seconds) is drawn on stderr when `show_progress` says so;
    on a terminal it appears only for runs longer than 2 s of wall clock. Ctrl-C stops the run
    at the end of the current slice: returns False then, True when the run reached
    ``until_ns``."""
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
    try:
        with _Interrupt() as stop:
            for t in _slices(bus.now(), until_ns, step):
                bus.run(until=t)
                if bar is not None:
                    now = round(t / 1e9, 3)
                    bar.update(now - done)
                    done = now
                if stop.requested:
                    return False
    finally:
        if bar is not None:
            bar.close()
    return True
