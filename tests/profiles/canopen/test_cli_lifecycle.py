"""`canstack canopen` when its run ends from outside: the bus goes away (a `canstack serve`
stopped, even by SIGKILL) or a process manager sends SIGTERM to a device started in the
background (SIGINT ignored). It stops, says so in one line, and keeps its summary."""

import importlib.metadata
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from stack.io.serve import BusServer

ROOT = Path(__file__).resolve().parents[3]

pytestmark = [pytest.mark.wallclock, pytest.mark.subprocess, pytest.mark.socket]


def _env(tmp_path: Path) -> dict[str, str]:
    """The environment of a child that runs ``python -m stack.cli canopen`` from this checkout,
    with the command's entry point also before the checkout is re-installed."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), str(tmp_path), os.environ.get("PYTHONPATH", "")]))
    if not any(ep.name == "canopen" for ep in importlib.metadata.entry_points(group="canstack.commands")):
        dist = tmp_path / "canstack_canopen_entry-0.dist-info"
        dist.mkdir()
        (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: canstack-canopen-entry\nVersion: 0\n")
        (dist / "entry_points.txt").write_text("[canstack.commands]\ncanopen = profiles.canopen.cli:register\n")
    return env


def _ignore_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # as a background job (`cmd &`) starts


def _device(url: str, env: dict[str, str]) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "stack.cli", "canopen", "--node-id", "5", "--interface", "canstack", "--channel", url],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        preexec_fn=_ignore_sigint,
    )


def _finish(proc: subprocess.Popen[str], timeout: float = 60.0) -> tuple[str, str]:
    try:
        return proc.communicate(timeout=timeout)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


def _booted(proc: subprocess.Popen[str]) -> None:
    """Wait for the device's start line and its first NMT state change."""
    first = proc.stdout.readline()
    assert "Ctrl-C stops it" in first, first
    assert "NMT INITIALISING -> PRE_OPERATIONAL" in proc.stdout.readline()


def test_a_served_bus_killed_under_the_device_stops_it_with_one_line(tmp_path):
    env = _env(tmp_path)
    serve = subprocess.Popen(
        [sys.executable, "-m", "stack.cli", "serve", "--listen", "127.0.0.1:0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env=env,
    )
    device = None
    try:
        line = serve.stdout.readline()
        assert line.startswith("serving bus0"), line
        url = line.split()[-1]
        device = _device(url, env)
        _booted(device)
        serve.kill()  # SIGKILL: no goodbye on the socket, the connection just ends
        serve.wait(30)
        out, err = _finish(device)
    finally:
        if serve.poll() is None:
            serve.kill()
            serve.wait()
        if device is not None and device.poll() is None:
            device.kill()
            device.communicate()
    assert device.returncode == 1, err
    assert "node 5: PRE_OPERATIONAL" in out  # the summary is still printed
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith(f"canstack canopen: bus canstack {url} lost at "), lines[0]
    assert "the server closed the connection" in lines[0] or "connection lost" in lines[0]


def test_sigterm_stops_a_background_device_with_its_summary(tmp_path):
    with BusServer(500_000, listen=("127.0.0.1", 0)) as srv:
        device = _device(srv.url, _env(tmp_path))
        try:
            _booted(device)
            device.send_signal(signal.SIGTERM)
            out, err = _finish(device)
        finally:
            if device.poll() is None:
                device.kill()
                device.communicate()
    assert device.returncode == 128 + signal.SIGTERM, err
    assert "node 5: PRE_OPERATIONAL, 1 boot-up" in out and "Traceback" not in err
