"""`canstack serve` under exhaustion and overload: accept() failing (out of file descriptors),
threads that cannot start, connections that never say HELLO, a bus that cannot keep up with real
time, SIGTERM. The server stays up, says what happened once, refuses cleanly, and serves again."""

import logging
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import can
import pytest

from stack.io.serve import BusServer
from stack.io.serve import server as server_module
from stack.io.serve.protocol import ERROR, Reader
from stack.io.serve.server import BEHIND_WARN_NS, MAX_UNJOINED

ROOT = Path(__file__).resolve().parents[3]
pytestmark = [pytest.mark.wallclock, pytest.mark.socket]


def _read_until_closed(sock: socket.socket, timeout: float = 30.0) -> list[tuple[int, bytes]]:
    sock.settimeout(timeout)
    reader = Reader()
    got = []
    while True:
        data = sock.recv(65536)
        if not data:
            return got
        got += reader.feed(data)


@pytest.mark.subprocess
def test_accept_failing_for_lack_of_file_descriptors_does_not_stop_the_server():
    """A server whose process runs out of file descriptors (EMFILE) logs it once, keeps the
    listening socket and accepts again once descriptors are free."""
    code = (
        "import logging, os, resource, sys\n"
        "from stack.io.serve import BusServer\n"
        "logging.basicConfig(level=logging.INFO, stream=sys.stderr, format='%(levelname)s %(message)s')\n"
        "srv = BusServer(500000, listen=('127.0.0.1', 0))\n"
        "soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)\n"
        "resource.setrlimit(resource.RLIMIT_NOFILE, (len(os.listdir('/proc/self/fd')) + 6, hard))\n"
        "print(srv.url, flush=True)\n"
        "sys.stdin.read()\n"
        "srv.close()\n"
    )
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.Popen(
        [sys.executable, "-c", code],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    raw: list[socket.socket] = []
    try:
        url = proc.stdout.readline().strip()
        assert url.startswith("tcp://127.0.0.1:"), url + proc.stderr.read()
        host, port = url[len("tcp://") :].split("/")[0].split(":")
        for _ in range(20):  # more than the server has descriptors for: the rest wait in its backlog
            raw.append(socket.create_connection((host, int(port)), timeout=10.0))
        # the failure is the server's first log line, said once — after, on a loaded machine, the
        # bus falling behind real time and catching up, which it may say first
        lines = [proc.stderr.readline()]
        while lines[-1] and "accept() failed" not in lines[-1] and len(lines) < 10:
            lines.append(proc.stderr.readline())
        line = lines[-1]
        assert line.startswith("WARNING bus 'bus0': accept() failed: Too many open files; retrying"), lines
        assert all("real time" in earlier for earlier in lines[:-1]), lines
        for s in raw:
            s.close()
        raw.clear()
        # descriptors come back as the server sees those connections end: a client joins again
        deadline = time.monotonic() + 60.0
        while True:
            try:
                with can.Bus(interface="canstack", channel=url) as bus:
                    assert bus.node_name.startswith("client")
                break
            except can.CanInitializationError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.2)
        proc.stdin.close()
        assert proc.wait(60) == 0
        err = "".join(lines) + proc.stderr.read()
    finally:
        for s in raw:
            s.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert err.count("accept() failed") == 1, err
    assert "INFO bus 'bus0': accepting clients again" in err and "Traceback" not in err


def test_a_client_the_server_cannot_start_a_thread_for_is_refused_cleanly(monkeypatch, caplog):
    real = server_module._Session.start
    failures = [RuntimeError("can't start new thread")]

    def start(self):
        if failures:
            raise failures.pop()
        real(self)

    monkeypatch.setattr(server_module._Session, "start", start)
    with BusServer(500_000, listen=("127.0.0.1", 0)) as srv, caplog.at_level(logging.WARNING, "stack.io.serve"):
        with pytest.raises(can.CanInitializationError, match="cannot start a thread for this client"):
            can.Bus(interface="canstack", channel=srv.url)
        assert srv.wait_sessions(0, timeout=10.0)
        with can.Bus(interface="canstack", channel=srv.url) as bus:  # the accept thread is still there
            assert bus.node_name == "client0"
    refused = [r.getMessage() for r in caplog.records if "refused" in r.getMessage()]
    assert len(refused) == 1 and refused[0].endswith(
        "refused: the server cannot start a thread for this client (can't start new thread): try again later"
    )


def test_connections_that_never_join_are_bounded():
    with BusServer(500_000, listen=("127.0.0.1", 0)) as srv:
        idle = [socket.create_connection(srv.address, timeout=10.0) for _ in range(MAX_UNJOINED)]
        try:
            assert srv.wait_sessions(MAX_UNJOINED, timeout=30.0)
            extra = socket.create_connection(srv.address, timeout=10.0)
            with extra:
                got = _read_until_closed(extra)  # refused at once: an ERROR, then closed
            assert [(t, p.decode()) for t, p in got] == [
                (ERROR, f"too many connections waiting to join ({MAX_UNJOINED}): try again later")
            ]
            assert srv.wait_sessions(MAX_UNJOINED, timeout=30.0)  # nothing kept of the refused one
        finally:
            for s in idle:
                s.close()
        assert srv.wait_sessions(0, timeout=30.0)
        with can.Bus(interface="canstack", channel=srv.url) as bus:
            assert bus.node_name == "client0"


def test_a_bus_behind_real_time_still_answers_joins_and_says_how_far_behind(caplog):
    """The engine made to need twice the wall time it simulates: the bus falls behind real time
    for good. Joins are still answered (the runner works in slices and answers between them), the
    client hears how far behind the bus is, and the server says so in its log, once."""
    with BusServer(500_000, listen=("127.0.0.1", 0)) as srv, caplog.at_level(logging.INFO, "stack.io.serve"):
        sim = srv.sim
        run = sim.run

        def slow_run(until=None, **kw):
            if until is not None and until > sim.now():
                time.sleep(2 * (until - sim.now()) / 1e9)
            return run(until, **kw)

        srv.runner.call(lambda: setattr(sim, "run", slow_run))
        deadline = time.monotonic() + 60.0
        while srv.runner.behind_ns < 2 * BEHIND_WARN_NS:
            assert time.monotonic() < deadline, "the bus did not fall behind"
            time.sleep(0.05)
        start = time.monotonic()
        bus = can.Bus(interface="canstack", channel=srv.url)
        try:
            joined_in = time.monotonic() - start
            behind_ms = bus._port.behind_ms
        finally:
            bus.shutdown()
    assert behind_ms >= 2 * BEHIND_WARN_NS / 1e6
    assert joined_in < 5.0  # not refused: a join waits at most 5 s for the server
    messages = [r.getMessage() for r in caplog.records]
    assert sum("behind real time: this machine cannot simulate" in m for m in messages) == 1
    assert any("s behind real time)" in m and "joined" in m for m in messages)


@pytest.mark.subprocess
def test_sigterm_removes_the_announcement_of_a_background_server(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    env = dict(
        os.environ, XDG_RUNTIME_DIR=str(run), PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])
    )
    proc = subprocess.Popen(
        [sys.executable, "-m", "stack.cli", "serve", "--listen", "127.0.0.1:0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),  # a background job
    )
    try:
        line = proc.stdout.readline()
        assert line.startswith("serving bus0"), line + proc.stderr.read()
        announced = list((run / "canstack").iterdir())
        assert len(announced) == 1 and str(proc.pid) in announced[0].name
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert list((run / "canstack").iterdir()) == []
