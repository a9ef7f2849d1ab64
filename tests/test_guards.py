"""The suite's own guards (tests/conftest.py), run on a small test file in a pytest of its own:
an unmarked test that starts a process or opens a socket errors, naming the marker; a process a
test leaves running is killed at its teardown; one that outlives the session fails it."""

from __future__ import annotations

import re
from pathlib import Path

import psutil
import pytest

pytest_plugins = ["pytester"]

CONFTEST = (Path(__file__).parent / "conftest.py").read_text(encoding="utf-8")

INNER = """
import socket, subprocess, sys
from pathlib import Path
import pytest

def test_process():
    subprocess.run([sys.executable, "-c", "pass"], check=True)

@pytest.mark.subprocess
def test_process_marked():
    subprocess.run([sys.executable, "-c", "pass"], check=True)

def test_socket():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.close()

def test_nothing():
    pass

@pytest.mark.subprocess
def test_leaves_one():
    p = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(600)"])
    Path("left.pid").write_text(str(p.pid))

@pytest.fixture(scope="module")
def server():
    # a module fixture's process is every test's: not checked per test, only at the session's end
    p = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(600)"])
    Path("outlives.pid").write_text(str(p.pid))
    return p

@pytest.mark.subprocess
def test_uses_the_server(server):
    assert server.poll() is None
"""


def _dead(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return True


@pytest.mark.subprocess
def test_the_guards_catch_unmarked_tests_and_kill_what_tests_leave_running(pytester):
    pytester.makeconftest(CONFTEST)
    pytester.makepyfile(test_inner=INNER)
    res = pytester.runpytest_subprocess("-p", "no:cacheprovider", "-q", "-rfE")
    out, err = res.stdout.str(), res.stderr.str()
    res.assert_outcomes(passed=6, errors=3)
    # markers: what the test did, not what it says
    assert "test_process: uses subprocess but is not marked @pytest.mark.subprocess" in out
    assert "test_socket: uses socket but is not marked @pytest.mark.socket" in out
    assert "test_process_marked:" not in out and "test_nothing:" not in out
    # a process left by a test: killed at its teardown, the test errors
    assert "test_leaves_one: left 1 process(es) running, killed now (end them in a finally)" in out
    assert _dead(int((pytester.path / "left.pid").read_text()))
    # a process that outlives the session: listed, killed, the session fails
    outlived = int((pytester.path / "outlives.pid").read_text())
    assert "processes the tests started are still running (killed now)" in err
    assert re.search(rf"pid {outlived}: .*time\.sleep\(600\)", err), err
    assert _dead(outlived)
    assert res.ret == pytest.ExitCode.TESTS_FAILED
