"""`canstack serve`: several clients (threads and processes) on one served bus, robustness
against dying and hostile clients, loopback-only by default."""

import argparse
import json
import logging
import os
import re
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import can
import pytest

from stack.cli import CliError
from stack.cli.serve import register
from stack.io.serve import BYE, ERROR, FILTERS, HELLO, SEND, TXEND, WELCOME, BusServer, encode_message

ROOT = Path(__file__).resolve().parents[3]
# every test here serves or joins a bus running in real time
pytestmark = pytest.mark.wallclock


def msg(can_id, data=b""):
    return can.Message(arbitration_id=can_id, data=data, is_extended_id=False)


@pytest.fixture
def server():
    with BusServer(500_000, listen=("127.0.0.1", 0)) as srv:
        yield srv


@pytest.mark.socket
def test_three_clients_in_threads_get_every_frame_once_in_order(drain, server):
    buses = [can.Bus(interface="canstack", channel=server.url) for _ in range(3)]
    n = 200
    received = {}

    def client(i):
        for k in range(n):
            buses[i].send(msg(0x100 + i, k.to_bytes(2, "big")), timeout=10.0)
        received[i] = drain(buses[i], 2 * n, timeout=60.0)

    threads = [threading.Thread(target=client, args=(i,)) for i in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    try:
        for i in range(3):
            got = received[i]
            assert buses[i].recv(0.05) is None  # nothing more: no duplicates
            assert len(got) == 2 * n
            for j in range(3):
                seq = [int.from_bytes(m.data, "big") for m in got if m.arbitration_id == 0x100 + j]
                assert seq == ([] if j == i else list(range(n)))  # each sender's frames once, in order
            stamps = [m.timestamp for m in got]
            assert stamps == sorted(stamps)
    finally:
        for b in buses:
            b.shutdown()


@pytest.mark.socket
def test_unix_socket_and_receive_own(drain, tmp_path, wait_until):
    path = str(tmp_path / "bus.sock")
    with BusServer(250_000, unix=path, name="body") as srv:
        assert srv.url == f"unix://{path}/body"
        a = can.Bus(interface="canstack", channel=srv.url, receive_own_messages=True)
        b = can.Bus(interface="canstack", channel=srv.url, bitrate=250_000)
        try:
            assert a.bitrate == 250_000
            a.send(msg(0x42, b"\x01"))
            own, other = a.recv(10.0), b.recv(10.0)
            assert (own.is_rx, other.is_rx) == (False, True)
            assert own.timestamp == other.timestamp
            b.set_filters([{"can_id": 0x7, "can_mask": 0x7FF}])
            # the filters travel on b's connection, the frames on a's: wait until the server's
            # node for b has them
            node = srv.runner.call(lambda: next(n for n in srv.sim.nodes if n.name == b.node_name))
            wait_until(lambda: srv.runner.call(lambda: node.acceptance.filters) is not None)
            a.send(msg(0x42, b"\x02"))
            a.send(msg(0x7, b"\x03"))
            assert [m.arbitration_id for m in drain(b, 1, timeout=30.0)] == [0x7]
            assert b.recv(0.05) is None  # 0x42 was filtered out
        finally:
            a.shutdown()
            b.shutdown()
        with pytest.raises(can.CanInitializationError, match="serves bus 'body'"):
            can.Bus(interface="canstack", channel=f"unix://{path}/other")
        with pytest.raises(can.CanInitializationError, match="runs at 250000"):
            can.Bus(interface="canstack", channel=srv.url, bitrate=500_000)


CLIENT = r"""
import sys, time, can, stack.io.pycan
bus = can.Bus(interface="canstack", channel=sys.argv[1])
print("ready", flush=True)
k = 0
while True:
    bus.send(can.Message(arbitration_id=0x300, data=k.to_bytes(4, "big"), is_extended_id=False), timeout=1)
    k += 1
    time.sleep(0.0005)
"""


@pytest.mark.socket
@pytest.mark.subprocess
def test_a_client_process_that_dies_does_not_disturb_the_others(drain, server):
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.Popen([sys.executable, "-c", CLIENT, server.url], stdout=subprocess.PIPE, text=True, env=env)
    a = can.Bus(interface="canstack", channel=server.url)
    b = can.Bus(interface="canstack", channel=server.url)
    try:
        assert proc.stdout.readline().strip() == "ready"
        assert drain(b, 20, timeout=30.0)  # the dying client was sending
        for k in range(300):
            a.send(msg(0x100, k.to_bytes(2, "big")), timeout=10.0)
            if k == 100:
                proc.send_signal(signal.SIGKILL)
        got = []
        deadline = time.monotonic() + 60.0
        while len(got) < 300 and (m := b.recv(max(0.0, deadline - time.monotonic()))) is not None:
            if m.arbitration_id == 0x100:
                got.append(int.from_bytes(m.data, "big"))
        assert got == list(range(300))
        # the server still accepts clients
        with can.Bus(interface="canstack", channel=server.url) as c:
            a.send(msg(0x101, b"\x01"))
            assert c.recv(10.0).arbitration_id == 0x101
    finally:
        proc.kill()
        proc.wait()
        a.shutdown()
        b.shutdown()


def _raw(server):
    s = socket.create_connection(server.address, timeout=10.0)
    return s


def _read_msgs(sock, until=None, timeout=30.0):
    """The messages the server sends until it closes the connection, or until ``until(msgs)``
    holds; the ``timeout`` is a deadline for either."""
    deadline = time.monotonic() + timeout
    buf = b""
    out = []
    while until is None or not until(out):
        left = deadline - time.monotonic()
        if left <= 0:
            break
        sock.settimeout(left)
        try:
            data = sock.recv(65536)
        except TimeoutError:
            break
        if not data:
            break
        buf += data
        while len(buf) >= 5:
            length, mtype = struct.unpack_from("!IB", buf)
            if len(buf) < 4 + length:
                break
            out.append((mtype, buf[5 : 4 + length]))
            buf = buf[4 + length :]
    return out


def _hello(**kw):
    return encode_message(
        HELLO, json.dumps({"v": 2, "bus": "bus0", "bitrate": None, "node_name": None, "config": {}, **kw}).encode()
    )


@pytest.mark.socket
def test_hostile_clients_are_rejected_and_the_server_keeps_serving(drain, server):
    good_a = can.Bus(interface="canstack", channel=server.url)
    good_b = can.Bus(interface="canstack", channel=server.url)
    try:
        # 1. an absurd length prefix: framing error, connection closed
        s = _raw(server)
        s.sendall(struct.pack("!IB", 1 << 30, SEND) + b"x" * 100)
        msgs = _read_msgs(s)
        assert msgs and msgs[0][0] == ERROR and b"length" in msgs[0][1]
        s.close()
        # 2. no HELLO first
        s = _raw(server)
        s.sendall(encode_message(SEND, b"\x00" * 6))
        assert _read_msgs(s)[0][0] == ERROR
        s.close()
        # 3. HELLO with bad JSON, bad option types
        for bad in (
            encode_message(HELLO, b"{not json"),
            _hello(config={"tx_queue_size": "huge"}),
            _hello(config={"evil": 1}),
            _hello(v=99),
            encode_message(HELLO, b"[" * 5_000),
            _hello(node_name="\x01\x02"),
        ):
            s = _raw(server)
            s.sendall(bad)
            assert _read_msgs(s)[0][0] == ERROR
            s.close()
        # 4. a joined client sending bad frames, bad filters, unknown types, garbage bytes
        s = _raw(server)
        s.sendall(_hello())
        s.sendall(encode_message(SEND, struct.pack("!IBB", 0xFFFFFFFF, 0, 0)))  # ID out of range
        s.sendall(encode_message(SEND, struct.pack("!IBB", 0x10, 0, 3) + b"\x01"))  # DLC mismatch
        s.sendall(encode_message(SEND, b"\x01"))  # too short
        s.sendall(encode_message(FILTERS, b'[{"can_id": "x"}]'))
        s.sendall(encode_message(0x7F, b"\xde\xad"))
        s.sendall(encode_message(SEND, struct.pack("!IBB", 0x10, 0, 1) + b"\x01"))  # finally a good one
        # one TXEND per SEND (three rejected, the last sent), one ERROR each for the bad FILTERS
        # and the unknown type
        msgs = _read_msgs(
            s, until=lambda m: [t for t, _ in m].count(TXEND) == 4 and [t for t, _ in m].count(ERROR) == 2
        )
        types = [t for t, _ in msgs]
        assert types[0] in (WELCOME, 0x13)
        txends = [p for t, p in msgs if t == TXEND]
        assert [p[:1] for p in txends] == [b"\x00", b"\x00", b"\x00", b"\x01"]
        assert b"rejected" in txends[0]
        assert types.count(ERROR) == 2
        s.sendall(encode_message(BYE))
        s.close()
        assert server.rejected >= 13
        # the well-behaved clients saw exactly the one valid frame and still work
        got = drain(good_b, 1, timeout=30.0)
        assert [(m.arbitration_id, bytes(m.data)) for m in got] == [(0x10, b"\x01")]
        assert good_b.recv(0.05) is None  # nothing else
        good_a.send(msg(0x20, b"\x02"))
        assert good_b.recv(10.0).arbitration_id == 0x20
    finally:
        good_a.shutdown()
        good_b.shutdown()


@pytest.mark.socket
def test_clients_refused_at_once_leave_no_session_behind(server):
    """A connection closed by the server the moment it is accepted (a framing error in its first
    bytes) is removed from the sessions it was registered in: the server registers a session
    before its threads run, so the leaving can never come first."""
    for _ in range(20):
        s = _raw(server)
        s.sendall(struct.pack("!IB", 1 << 30, SEND))
        assert _read_msgs(s)[0][0] == ERROR
        s.close()
    assert server.wait_sessions(0, timeout=10.0), [x.peer for x in server.sessions]
    assert server.rejected == 20


def _parser():
    p = argparse.ArgumentParser()
    sub = p.add_subparsers(dest="command")
    register(sub)
    return p


def test_non_loopback_listen_is_refused_without_allow_remote():
    with pytest.raises(ValueError, match="not loopback"):
        BusServer(listen=("0.0.0.0", 0))
    args = _parser().parse_args(["serve", "--listen", "0.0.0.0:0"])
    with pytest.raises(CliError, match="not loopback"):
        args.func(args)
    with pytest.raises(SystemExit):
        _parser().parse_args(["serve", "--listen", "nowhere"])


@pytest.mark.socket
@pytest.mark.subprocess
def test_serve_command_runs_a_bus_other_processes_join(interruptible_python):
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    code = (
        "import argparse, sys; from stack.cli.serve import register; p = argparse.ArgumentParser(); "
        "register(p.add_subparsers()); a = p.parse_args(sys.argv[1:]); sys.exit(a.func(a))"
    )
    args = ["serve", "--listen", "127.0.0.1:0", "--bitrate", "125000", "--name", "cli0", "--duration", "120"]
    proc = subprocess.Popen(
        interruptible_python("-c", code, *args),  # Ctrl-C stops it, whatever the suite's SIGINT
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        line = proc.stdout.readline()
        assert line.startswith("serving cli0 at 125000 bit/s on tcp://127.0.0.1:"), line + proc.stderr.read()
        url = line.split()[-1]
        with can.Bus(interface="canstack", channel=url) as a, can.Bus(interface="canstack", channel=url) as b:
            assert a.bitrate == 125_000
            a.send(msg(0x3, b"\x01\x02\x03"))
            m = b.recv(10.0)
            assert (m.arbitration_id, bytes(m.data)) == (0x3, b"\x01\x02\x03")
        proc.send_signal(signal.SIGINT)
        assert proc.wait(30) == 0  # Ctrl-C is serve's normal end
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.socket
def test_unix_path_that_is_not_a_stale_socket_is_never_replaced(tmp_path):
    path = tmp_path / "bus.sock"
    path.write_text("precious")
    with pytest.raises(ValueError, match="exists and is not a socket"):
        BusServer(500_000, unix=str(path))
    assert path.read_text() == "precious"
    path.unlink()
    with BusServer(500_000, unix=str(path)) as srv:
        with pytest.raises(ValueError, match="in use by a running server"):
            BusServer(500_000, unix=str(path))
        assert srv.url.startswith("unix://")
    assert not path.exists()  # the server removed its own socket
    # a stale socket (its server gone without closing) is taken over
    stale = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    stale.bind(str(path))
    stale.close()
    with BusServer(500_000, unix=str(path)) as srv:
        c = can.Bus(interface="canstack", channel=srv.url)
        c.shutdown()


@pytest.mark.socket
def test_unix_channel_naming_the_socket_itself_says_to_add_the_bus_name(tmp_path):
    path = str(tmp_path / "bus.sock")
    with (
        BusServer(500_000, unix=path, name="body"),
        pytest.raises(can.CanInitializationError, match=r"is the socket itself; add the bus name"),
    ):
        can.Bus(interface="canstack", channel=f"unix://{path}")


# ---------------------------------------------------------------------------- the command line
def _cli(*args, timeout=20):
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run(
        [sys.executable, "-m", "stack.cli", "serve", *args], capture_output=True, text=True, env=env, timeout=timeout
    )


def test_serve_help_describes_every_option_and_the_client_channels():
    sub = argparse.ArgumentParser().add_subparsers()
    register(sub)
    serve = sub.choices["serve"]
    helps = {a.dest: a.help for a in serve._actions if a.dest != "help"}
    assert set(helps) == {"bitrate", "data_bitrate", "listen", "unix", "name", "allow_remote", "duration"}
    assert all(h and h != argparse.SUPPRESS for h in helps.values()), helps
    text = serve.format_help()
    assert "tcp://127.0.0.1:29536/bus0" in text and "unix:///path/to/socket/bus0" in text
    assert "private to the process" in text


@pytest.mark.socket
@pytest.mark.subprocess
def test_serve_on_an_address_in_use_says_which_and_what_to_do():
    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen(1)
    port = busy.getsockname()[1]
    try:
        res = _cli("--listen", f"127.0.0.1:{port}")
    finally:
        busy.close()
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in res.stderr and "[Errno" not in lines[0]
    assert f"127.0.0.1:{port} is already in use" in lines[0] and "--listen HOST:0" in lines[0]


@pytest.mark.subprocess
def test_serve_on_a_unix_path_in_a_missing_directory_names_it(tmp_path):
    path = tmp_path / "no-such-dir" / "bus.sock"
    res = _cli("--unix", str(path))
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in res.stderr and "[Errno" not in lines[0]
    assert str(path) in lines[0] and "does not exist" in lines[0]


@pytest.mark.socket
def test_clients_joining_and_leaving_are_logged_with_node_and_peer(server, caplog):
    with caplog.at_level(logging.INFO, logger="stack.io.serve"):
        bus = can.Bus(interface="canstack", channel=server.url, node_name="dash")
        # the server registers a session before the client hears its WELCOME
        [peer] = [s.peer for s in server.sessions]
        assert peer.startswith("127.0.0.1:")
        bus.shutdown()
        assert server.wait_sessions(0, timeout=10.0)  # gone, its leaving logged
    lines = [r.getMessage() for r in caplog.records if r.levelno == logging.INFO]
    me = rf"\S+\[{os.getpid()}\] from {re.escape(peer)}"  # the client names its program and pid
    assert any(re.fullmatch(rf"client {me} joined bus 'bus0' as node 'dash'", ln) for ln in lines), lines
    assert any(re.fullmatch(rf"client {me} \(node 'dash'\) left bus 'bus0': said BYE", ln) for ln in lines), lines


@pytest.mark.socket
@pytest.mark.subprocess
def test_a_client_in_another_process_is_logged_by_its_program_and_pid(server, caplog, tmp_path):
    script = tmp_path / "dashboard.py"
    script.write_text(
        "import sys, can\n"
        "import stack.io.pycan\n"
        "bus = can.Bus(interface='canstack', channel=sys.argv[1])\n"
        "bus.shutdown()\n"
    )
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    with caplog.at_level(logging.INFO, logger="stack.io.serve"):
        proc = subprocess.Popen([sys.executable, str(script), server.url], env=env, stderr=subprocess.PIPE, text=True)
        try:
            _, err = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
        assert proc.returncode == 0, err
        assert server.wait_sessions(0, timeout=10.0)
    joined = [r.getMessage() for r in caplog.records if "joined" in r.getMessage()]
    assert len(joined) == 1 and joined[0].startswith(f"client dashboard.py[{proc.pid}] from 127.0.0.1:"), joined
