"""`canstack` commands stop on SIGTERM as on Ctrl-C, also in a background job, which inherits
SIGINT ignored: Ctrl-C cannot reach it there, and before SIGTERM was handled only SIGKILL stopped
it, with none of its clean-up (summary, trace, the served socket) done."""

from __future__ import annotations

import os
import re
import selectors
import subprocess
import sys
import time
from pathlib import Path

import can
import pytest

ROOT = Path(__file__).resolve().parents[3]

# `canstack` as a background job starts it: SIGINT ignored
BACKGROUND = (
    "import runpy, signal, sys\n"
    "signal.signal(signal.SIGINT, signal.SIG_IGN)\n"
    "runpy.run_module('stack.cli', run_name='__main__', alter_sys=True)\n"
)


def _canstack_in_the_background(*args: str) -> subprocess.Popen[bytes]:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.Popen(
        [sys.executable, "-c", BACKGROUND, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env
    )


def _read_until(stream, pattern: bytes, timeout: float = 60.0) -> bytes:
    """What ``stream`` (a pipe) says until ``pattern`` shows up in it."""
    seen = b""
    deadline = time.monotonic() + timeout
    with selectors.DefaultSelector() as sel:
        sel.register(stream, selectors.EVENT_READ)
        while not re.search(pattern, seen):
            left = deadline - time.monotonic()
            if left <= 0 or not sel.select(left):
                pytest.fail(f"{pattern!r} not seen within {timeout} s: {seen[-500:]!r}")
            chunk = os.read(stream.fileno(), 65536)
            if not chunk:
                pytest.fail(f"the stream ended before {pattern!r}: {seen[-500:]!r}")
            seen += chunk
    return seen


@pytest.mark.wallclock
@pytest.mark.subprocess
def test_sigterm_stops_a_simulation_between_slices_and_keeps_its_summary_and_trace(tmp_path):
    trace = tmp_path / "demo.asc"
    proc = _canstack_in_the_background("demo", "--duration", "3600", "--progress", "--trace", str(trace))
    try:
        # the progress bar has moved: the run is inside its slices
        _read_until(proc.stderr, rb"(?:[1-9]\d*|0)\.(?!000)\d{3}/3600\.000 s simulated")
        proc.terminate()
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 128 + 15, err  # as a shell reports a command ended by SIGTERM
    text = out.decode()
    stopped = re.search(r"interrupted at (\d+\.\d{3}) s of 3600 s: the summary so far", text)
    assert stopped and 0 < float(stopped.group(1)) < 3600
    assert "Traceback" not in err.decode() and "canstack: interrupted at" in err.decode()
    records = list(can.LogReader(str(trace)))
    assert records and records[-1].timestamp - records[0].timestamp <= float(stopped.group(1))


@pytest.mark.wallclock
@pytest.mark.socket
@pytest.mark.subprocess
def test_sigterm_stops_canstack_serve_and_it_removes_its_socket(tmp_path):
    path = tmp_path / "bus.sock"
    proc = _canstack_in_the_background("serve", "--unix", str(path), "--name", "bg")
    try:
        line = _read_until(proc.stdout, rb"\n").decode()
        assert line.startswith("serving bg at 500000 bit/s on unix://"), line
        with can.Bus(interface="canstack", channel=f"unix://{path}/bg") as client:
            assert client.bitrate == 500_000
        proc.terminate()
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err  # serve's clean stop, as after Ctrl-C
    assert "Traceback" not in err.decode()
    assert not path.exists()  # closed cleanly: the server removed its own socket
