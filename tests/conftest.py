"""Test-wide settings and guards.

- hypothesis runs without per-example deadlines (a loaded CI machine is slow, not wrong), and
  with a fixed seed on CI so a run there is reproducible.
- A test that starts a process (``subprocess.Popen``, a multiprocessing process) must be marked
  ``@pytest.mark.subprocess``; one that binds or connects a socket ``@pytest.mark.socket``. A test
  that does so unmarked errors at its teardown, naming the marker (``wallclock`` cannot be seen
  from here: it is the reviewer's). Fixtures wider than a function are not checked: what they
  start belongs to every test that uses them.
- A process a test started and did not end is killed at its teardown, and the test errors (it
  should end what it starts in a ``finally``): a failed test never leaves a process spinning.
- At the end of the session no process the tests started may still be alive: the survivors are
  listed, killed, and the session fails.
- Fixtures: ``wait_until`` (poll a condition with a deadline instead of sleeping a fixed time) and
  ``interruptible_python`` (a Python child that takes Ctrl-C even when the suite runs with SIGINT
  ignored, as a background job does).
- Compiled modules are cached even where PYTHONDONTWRITEBYTECODE is set (as in many containers),
  outside the checkout: without the cache every worker, and every ``canstack`` the tests start,
  compiles the whole package and rewrites every test module again.
"""

from __future__ import annotations

import multiprocessing.process
import os
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Generator
from pathlib import Path
from typing import Any, TypeVar


def _cache_bytecode() -> None:
    """Where bytecode is not to be written (PYTHONDONTWRITEBYTECODE), cache it in a per-user
    directory outside the checkout instead, for this process and every process it starts (xdist
    workers, the ``canstack`` commands under test). A directory another user owns is not used."""
    if not sys.dont_write_bytecode or sys.pycache_prefix:
        return
    uid = os.getuid() if hasattr(os, "getuid") else 0
    prefix = Path(tempfile.gettempdir()) / f"canstack-tests-pycache-{uid}"
    try:
        prefix.mkdir(mode=0o700, exist_ok=True)
        if hasattr(os, "getuid") and prefix.stat().st_uid != uid:
            return
    except OSError:
        return
    sys.pycache_prefix = str(prefix)
    sys.dont_write_bytecode = False
    os.environ["PYTHONPYCACHEPREFIX"] = str(prefix)
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)


_cache_bytecode()

import pytest  # noqa: E402  (below the cache: hypothesis and the tests import through it)
from hypothesis import settings  # noqa: E402

settings.register_profile("canstack", deadline=None, derandomize=bool(os.environ.get("CI")))
settings.load_profile("canstack")

T = TypeVar("T")


# ------------------------------------------------------------------------------ what a test starts
class _Tracker:
    """What the running test started: processes and the kinds of resource it used."""

    def __init__(self) -> None:
        self.item: pytest.Item | None = None
        self.wide_fixture = 0  # > 0 while a module/session fixture is being set up
        self.used: set[str] = set()  # markers the test's actions ask for
        self.popens: list[subprocess.Popen[Any]] = []

    def start(self, item: pytest.Item) -> None:
        self.item, self.used, self.popens = item, set(), []

    def note(self, marker: str) -> None:
        if self.item is not None and not self.wide_fixture:
            self.used.add(marker)


_TRACK = _Tracker()


def _wrap(cls: Any, name: str, marker: str) -> None:
    original = getattr(cls, name)

    def wrapper(self: Any, *args: Any, **kwargs: Any) -> Any:
        _TRACK.note(marker)
        result = original(self, *args, **kwargs)
        if isinstance(self, subprocess.Popen) and _TRACK.item is not None and not _TRACK.wide_fixture:
            _TRACK.popens.append(self)
        return result

    setattr(cls, name, wrapper)


def _is_network(sock: socket.socket) -> bool:
    return sock.family in (socket.AF_INET, socket.AF_INET6, getattr(socket, "AF_UNIX", -1))


def _wrap_socket(name: str) -> None:
    original = getattr(socket.socket, name)

    def wrapper(self: socket.socket, *args: Any, **kwargs: Any) -> Any:
        if _is_network(self):
            _TRACK.note("socket")
        return original(self, *args, **kwargs)

    setattr(socket.socket, name, wrapper)


def _warm_matplotlib() -> None:
    """Build matplotlib's font cache before the guards watch: on a machine where it was never
    built, the first plot runs ``fc-list`` in a subprocess, which is matplotlib's, not the test's."""
    try:
        import matplotlib.font_manager  # noqa: F401  (builds the cache on first import)
    except ImportError:
        pass


def pytest_configure(config: pytest.Config) -> None:
    """Watch process starts and socket use for the marker check (once per session)."""
    _warm_matplotlib()
    _wrap(subprocess.Popen, "__init__", "subprocess")
    _wrap(multiprocessing.process.BaseProcess, "start", "subprocess")
    for name in ("bind", "connect", "connect_ex"):
        _wrap_socket(name)
    config.stash[_SESSION_START] = _group_members()


@pytest.hookimpl(wrapper=True)
def pytest_fixture_setup(fixturedef: pytest.FixtureDef[Any], request: pytest.FixtureRequest) -> Generator[None]:
    """What a module or session fixture starts is not the current test's."""
    wide = fixturedef.scope != "function"
    _TRACK.wide_fixture += wide
    try:
        return (yield)
    finally:
        _TRACK.wide_fixture -= wide


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item: pytest.Item) -> None:
    _TRACK.start(item)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_teardown(item: pytest.Item, nextitem: pytest.Item | None) -> Generator[None]:
    """After the test's own teardown: kill what it left running, then check its markers."""
    try:
        return (yield)
    finally:
        left = [p for p in _TRACK.popens if p.poll() is None]
        for p in left:
            p.kill()
            p.wait(10)
        used, _TRACK.item, _TRACK.popens = _TRACK.used, None, []
        missing = sorted(m for m in used if item.get_closest_marker(m) is None)
        problems = []
        if left:
            args = "; ".join(" ".join(map(str, p.args)) if isinstance(p.args, list) else str(p.args) for p in left)
            problems.append(f"left {len(left)} process(es) running, killed now (end them in a finally): {args}")
        if missing:
            problems.append(
                "uses " + ", ".join(missing) + " but is not marked " + ", ".join(f"@pytest.mark.{m}" for m in missing)
            )
        if problems:
            pytest.fail(f"{item.nodeid}: " + "; ".join(problems), pytrace=False)


# ------------------------------------------------------------------------------ the session's end
_SESSION_START = pytest.StashKey[set[int]]()
# a multiprocessing helper lives as long as the interpreter that started it
_INFRASTRUCTURE = ("multiprocessing.resource_tracker", "multiprocessing.forkserver")


def _group_members() -> set[int]:
    """Processes in this process group (the tests' children are, unless they made a session)."""
    try:
        import psutil
    except ImportError:
        return set()
    group = os.getpgid(0)
    out = set()
    for p in psutil.process_iter():
        try:
            if os.getpgid(p.pid) == group:
                out.add(p.pid)
        except (ProcessLookupError, PermissionError):
            pass
    return out


def _survivors(before: set[int]) -> list[Any]:
    """Processes the tests started that still run: children of this process (at any depth), and
    new members of its process group (children whose parent died)."""
    try:
        import psutil
    except ImportError:  # psutil comes with the test extra (dask[distributed]); without it no check
        return []
    me = psutil.Process()
    found = {p.pid: p for p in me.children(recursive=True)}
    for pid in _group_members() - before - {me.pid}:
        try:
            found.setdefault(pid, psutil.Process(pid))
        except psutil.NoSuchProcess:
            pass
    out = []
    for p in found.values():
        try:
            cmd = " ".join(p.cmdline())
            if p.status() == psutil.STATUS_ZOMBIE or any(s in cmd for s in _INFRASTRUCTURE):
                continue
        except psutil.NoSuchProcess:
            continue
        out.append(p)
    return out


@pytest.hookimpl(trylast=True)
def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    """No process the tests started may outlive them."""
    if hasattr(session.config, "workerinput"):  # pragma: no cover - an xdist worker: the controller checks
        return
    left = _survivors(session.config.stash.get(_SESSION_START, set()))
    if not left:
        return
    lines = []
    for p in left:
        try:
            lines.append(f"  pid {p.pid}: {' '.join(p.cmdline())}")
            p.kill()
        except Exception:  # gone meanwhile
            pass
    sys.stderr.write("\nprocesses the tests started are still running (killed now):\n" + "\n".join(lines) + "\n")
    session.exitstatus = pytest.ExitCode.TESTS_FAILED


# ------------------------------------------------------------------------------ fixtures
def _wait_until(condition: Callable[[], T], timeout: float = 10.0, what: str = "the condition") -> T:
    deadline = time.monotonic() + timeout
    delay = 0.001
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            pytest.fail(f"{what} did not hold within {timeout} s", pytrace=True)
        time.sleep(delay)
        delay = min(delay * 2, 0.02)


@pytest.fixture
def wait_until() -> Callable[..., Any]:
    """``wait_until(condition, timeout=10.0, what=...)``: call ``condition`` until it returns
    something true and return that, failing the test after ``timeout`` seconds of wall clock. The
    deadline is generous on purpose: a loaded machine is slow, not wrong; a passing test never
    waits for it."""
    return _wait_until


_CTRL_C_SHIM = (
    "import runpy, signal, sys\n"
    "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
    "mode, target, sys.argv = sys.argv[1], sys.argv[2], sys.argv[2:]\n"
    "if mode == '-m':\n"
    "    runpy.run_module(target, run_name='__main__', alter_sys=True)\n"
    "else:\n"
    "    sys.argv[0] = '-c'\n"
    "    exec(compile(target, '<string>', 'exec'), {'__name__': '__main__'})\n"
)


@pytest.fixture
def interruptible_python() -> Callable[..., list[str]]:
    """``interruptible_python("-m", "module", *args)`` or ``("-c", code, *args)``: the command line
    of a Python child that Ctrl-C (SIGINT) interrupts, as it does a program in the foreground of a
    terminal, even when this suite runs with SIGINT ignored (a background job), which its
    children would otherwise inherit."""

    def argv(mode: str, target: str, *args: str) -> list[str]:
        if mode not in ("-m", "-c"):
            raise ValueError(f"mode {mode!r}: '-m' (a module) or '-c' (code)")
        return [sys.executable, "-c", _CTRL_C_SHIM, mode, target, *args]

    return argv


@pytest.fixture
def rerun_until() -> Callable[..., Any]:
    """``rerun_until(run, timely, timeout=120.0)``: call ``run()`` until ``timely(result)`` holds
    and return that result, failing after ``timeout`` seconds of wall clock.

    For runs against the wall clock whose outcome needs a thread's timers to fire on time (a
    TDMA reference message inside its 1 ms window, a poll answered within its timeout): a loaded
    machine delays a whole run now and then, which no deadline inside the run can absorb. What
    must hold whatever the load is asserted inside ``run`` on every run; ``timely`` is the
    outcome a run the machine did not starve shows."""

    def rerun(run: Callable[[], T], timely: Callable[[T], Any], timeout: float = 120.0) -> T:
        deadline = time.monotonic() + timeout
        runs = 0
        while True:
            result = run()
            runs += 1
            if timely(result):
                return result
            if time.monotonic() > deadline:
                pytest.fail(f"no timely run in {runs} runs ({timeout} s); the last: {result!r}"[:2000])

    return rerun
