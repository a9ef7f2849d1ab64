"""What the commands that run a simulation or write files share: output paths and the optional
libraries their writers need, checked before a run (a long simulation must not end in an error
with nothing written); writing with the path in every error; and a simulation run in slices
with a progress bar on a terminal and Ctrl-C that stops between slices.
"""

from __future__ import annotations

import _thread
import contextlib
import contextvars
import importlib.util
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

from stack.cli import CliError, plural

__all__ = [
    "check_output",
    "check_trace_output",
    "check_plot_output",
    "check_plot_dir",
    "writing",
    "run_sliced",
    "show_progress",
    "TimeLimitExceeded",
    "GRACE_S",
    "time_limit",
    "WRITER_EXTRAS",
    "MAX_SIM_SECONDS",
    "trace_note",
    "trc_dropped",
]

T = TypeVar("T")

#: Trace suffixes whose python-can writer needs a library that is not a dependency of canstack:
#: suffix -> (module, canstack extra that installs it).
WRITER_EXTRAS = {".mf4": ("asammdf", "mf4")}

#: Longest simulated run a command accepts, in seconds of bus time: an hour at 1 Mbit/s is
#: about 30 million frames, minutes of computing; anything longer is a typo or needs a script.
MAX_SIM_SECONDS = 3600.0


def check_output(path: str, option: str) -> None:
    """An output file named on the command line: it must name a file (not a directory), in a
    directory that exists and can be written. Each failure names the option, the path and
    what is wrong with it."""
    if not path:
        raise CliError(f"{option} needs a file name")
    if os.path.isdir(path):
        raise CliError(f"{option} {path!r} is a directory, not a file")
    parent = os.path.dirname(os.path.abspath(path))
    # walk up to the first part that exists: a file there is not 'a missing directory'
    probe = parent
    while not os.path.exists(probe):
        probe = os.path.dirname(probe)
    if not os.path.isdir(probe):
        raise CliError(f"{option} {path!r}: {probe!r} is a file, not a directory")
    if probe != parent:
        raise CliError(f"{option} {path!r}: directory {parent!r} does not exist")
    if os.path.exists(path) and not os.access(path, os.W_OK):
        raise CliError(f"{option} {path!r}: the file exists and is not writable")
    if not os.access(parent, os.W_OK):
        raise CliError(f"{option} {path!r}: directory {parent!r} is not writable")


def check_trace_output(path: str, option: str = "--trace") -> str:
    """A trace file: a writable path, a suffix python-can has a writer for, and that writer's
    library installed. Returns the suffix."""
    from stack.bus.trace import check_suffix

    check_output(path, option)
    suffix = check_suffix(path)
    need = WRITER_EXTRAS.get(suffix)
    if need is not None and importlib.util.find_spec(need[0]) is None:
        module, extra = need
        raise CliError(
            f"{option} {path!r}: python-can writes {suffix} files with {module}, which is not "
            f"installed: pip install 'canstack[{extra}]'"
        )
    return suffix


def check_plot_output(path: str, option: str = "--plot") -> None:
    """A plot file: a writable path, matplotlib installed (the optional ``plot`` extra), and a
    format matplotlib writes (by suffix; none means PNG)."""
    check_output(path, option)
    if importlib.util.find_spec("matplotlib") is None:
        raise CliError(f"{option} needs matplotlib, which is not installed: pip install 'canstack[plot]'")
    suffix = Path(path).suffix.lower().lstrip(".")
    known = ("png", "svg", "pdf", "ps", "eps", "jpg", "jpeg", "tif", "tiff", "webp")
    if suffix and suffix not in known:
        raise CliError(
            f"{option} {path!r}: unknown image suffix '.{suffix}'; use one of " + ", ".join("." + k for k in known)
        )


def check_plot_dir(path: str, option: str = "--plot") -> None:
    """A directory for plots: an existing directory, or new ones (``a/b``: both are made) under
    the first part of the path that exists, which must be a writable directory; and matplotlib
    installed (the optional ``plot`` extra)."""
    if not path:
        raise CliError(f"{option} needs a directory name")
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise CliError(f"{option} {path!r}: is a file; give a directory for the plots")
    probe = p.absolute()
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        raise CliError(f"{option} {path!r}: {str(probe)!r} is a file, not a directory")
    if not os.access(probe, os.W_OK):
        raise CliError(f"{option} {path!r}: directory {str(probe)!r} is not writable")
    if importlib.util.find_spec("matplotlib") is None:
        raise CliError(f"{option} needs matplotlib, which is not installed: pip install 'canstack[plot]'")


def writing(path: str, option: str, write: Callable[[], T]) -> T:
    """Run ``write`` (which writes ``path``); an OSError becomes one line naming the option, the
    path and the reason (an error such as a full disk carries no file name of its own)."""
    try:
        return write()
    except OSError as exc:
        reason = exc.strerror or str(exc)
        raise CliError(f"{option} {path!r}: cannot write: {reason}") from None


def trace_note(path: str, dropped: int) -> str:
    """What a trace format left out, said once: python-can's .trc writer holds no remote or
    error frames (``dropped`` of them were in the run)."""
    if not str(path).lower().endswith(".trc") or not dropped:
        return ""
    return f" ({plural(dropped, 'remote or error frame')} left out: .trc cannot hold them)"


def trc_dropped(bus: Any) -> int:
    """Remote and error frames in a simulated trace: what a .trc file cannot hold."""
    return sum(1 for r in bus.trace if r.kind != "frame" or r.frame.remote)


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
    the current slice, or where it is when that does not come within `GRACE_S`: returns False
    then, True when the run reached ``until_ns``. ``time_limit`` (wall-clock seconds) raises
    `TimeLimitExceeded` when the run takes longer (default: the enclosing `time_limit` block's)."""
    if time_limit is None:
        time_limit = _TIME_LIMIT.get()
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
                    if stop.requested:
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
