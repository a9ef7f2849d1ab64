"""The python-can interface and `canstack serve` under the cases of the "Hardening" issue: filters
that are no list, clients that leave, frames queued at shutdown, plain channel names beside a
served bus, listen-only at run time (BusState.PASSIVE), failed one-shot transmissions."""

import itertools
import json
import logging
import os
import signal
import socket
import struct
import subprocess
import sys
import time
import warnings
from pathlib import Path

import can
import pytest

import stack.io.pycan as pycan
from stack.io.discovery import Announcement, local_servers
from stack.io.runner import get_runner
from stack.io.serve import ERROR, FILTERS, HELLO, SEND, TXEND, WELCOME, BusServer, encode_message

ROOT = Path(__file__).resolve().parents[3]
# every test here runs canstack buses in real time (their runner thread paces the simulated bus
# to the wall clock)
pytestmark = pytest.mark.wallclock
_ids = itertools.count()


def chan() -> str:
    return f"h{os.getpid()}-{next(_ids)}"


def msg(can_id, data=b""):
    return can.Message(arbitration_id=can_id, data=data, is_extended_id=False)


def nodes_on(runner):
    return runner.call(lambda: sorted(n.name for n in runner.sim.nodes))


def wait_for(fn, expected, timeout=30.0):
    """fn() once it equals ``expected`` (or its last value after ``timeout`` s, a deadline a
    passing test never reaches)."""
    end = time.monotonic() + timeout
    while True:
        v = fn()
        if v == expected or time.monotonic() > end:
            return v
        time.sleep(0.02)


def env_with_checkout(tmp_path=None):
    parts = [str(ROOT), os.environ.get("PYTHONPATH", "")]
    if tmp_path is not None:
        parts.insert(0, _entry_point_path(tmp_path))
    return dict(os.environ, PYTHONPATH=os.pathsep.join(parts))


def _entry_point_path(tmp_path: Path) -> str:
    """A dist-info with the project's `can.interface` entry point, as `pip install` writes it."""
    import tomllib

    info = tmp_path / "canstack_ep-0.0.dist-info"
    info.mkdir(exist_ok=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: canstack-ep\nVersion: 0.0\n")
    ep = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["entry-points"]["can.interface"]
    (info / "entry_points.txt").write_text("[can.interface]\n" + "".join(f"{k} = {v}\n" for k, v in ep.items()))
    return str(tmp_path)


@pytest.fixture
def server():
    with BusServer(500_000, listen=("127.0.0.1", 0)) as srv:
        yield srv


# ------------------------------------------------------------------------ filters that are no list
@pytest.mark.parametrize("bad", [5, True, 1.5, "0x100", {"can_id": 1, "can_mask": 0x7FF}])
def test_filters_that_are_no_list_are_refused_with_python_cans_error(bad):
    ch = chan()
    keep = can.Bus(interface="canstack", channel=ch)
    try:
        with pytest.raises(can.CanInitializationError, match=r"filters .* must be a list"):
            can.Bus(interface="canstack", channel=ch, can_filters=bad)
        with pytest.raises(can.CanInitializationError, match=r"filters .* must be a list"):
            keep.set_filters(bad)
        # the refused bus left nothing behind on the bus
        assert nodes_on(get_runner(ch)) == [keep.node_name]
    finally:
        keep.shutdown()


def _raw_join(server):
    s = socket.create_connection(server.address, timeout=10.0)
    s.sendall(
        encode_message(
            HELLO, json.dumps({"v": 2, "bus": "bus0", "bitrate": None, "node_name": None, "config": {}}).encode()
        )
    )
    return s


def _read(sock, until_types, timeout=30.0):
    """Messages until every type in ``until_types`` was seen once (or the timeout)."""
    sock.settimeout(0.1)
    buf, out = b"", []
    end = time.monotonic() + timeout
    while time.monotonic() < end and not set(until_types) <= {t for t, _ in out}:
        try:
            data = sock.recv(65536)
        except TimeoutError:
            continue
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


@pytest.mark.socket
@pytest.mark.parametrize("payload", [b"5", b"true", b"1.5", b'"abc"', b'{"can_id": 1, "can_mask": 1}'])
def test_served_filters_that_are_no_list_get_an_error_and_the_client_stays(server, payload, caplog):
    acker = can.Bus(interface="canstack", channel=server.url)  # acknowledges the raw client's frame
    s = _raw_join(server)
    try:
        assert WELCOME in {t for t, _ in _read(s, [WELCOME])}
        caplog.clear()
        s.sendall(encode_message(FILTERS, payload))
        s.sendall(encode_message(SEND, struct.pack("!IBB", 0x10, 0, 1) + b"\x01"))
        msgs = _read(s, [ERROR, TXEND])
        errors = [p.decode() for t, p in msgs if t == ERROR]
        assert errors and errors[0].startswith("FILTERS rejected: filters ") and "must be a list" in errors[0]
        # the connection is kept: the frame after the bad filters is sent and confirmed
        assert [p for t, p in msgs if t == TXEND] == [b"\x01"]
    finally:
        s.close()
        acker.shutdown()
    assert not [r for r in caplog.records if r.exc_info], "the server logged a traceback"


# ------------------------------------------------------------------------ clients that leave
def test_in_process_buses_that_shut_down_leave_the_bus_and_free_their_names():
    ch = chan()
    keep = can.Bus(interface="canstack", channel=ch)
    try:
        runner = get_runner(ch)
        for _ in range(300):
            can.Bus(interface="canstack", channel=ch).shutdown()
        assert nodes_on(runner) == [keep.node_name]
        with can.Bus(interface="canstack", channel=ch, node_name="ecu") as b:
            assert b.node_name == "ecu"
        with can.Bus(interface="canstack", channel=ch, node_name="ecu") as b:  # the name is free again
            assert nodes_on(runner) == sorted([keep.node_name, "ecu"])
    finally:
        keep.shutdown()


@pytest.mark.socket
@pytest.mark.subprocess
def test_served_clients_that_leave_are_removed_from_the_bus(server):
    keep = can.Bus(interface="canstack", channel=server.url)
    try:
        for _ in range(100):  # clients that say BYE
            can.Bus(interface="canstack", channel=server.url).shutdown()
        for _ in range(50):  # clients that vanish without a word
            s = _raw_join(server)
            _read(s, [WELCOME])
            s.close()
        proc = subprocess.Popen(
            [
                sys.executable,
                "-c",
                "import sys, can, stack.io.pycan, time\n"
                "b = can.Bus(interface='canstack', channel=sys.argv[1]); print('in', flush=True)\n"
                "time.sleep(60)",
                server.url,
            ],
            stdout=subprocess.PIPE,
            text=True,
            env=env_with_checkout(),
        )
        assert proc.stdout.readline().strip() == "in"
        proc.send_signal(signal.SIGKILL)  # a client process that dies
        proc.wait()
        assert wait_for(lambda: nodes_on(server.runner), [keep.node_name]) == [keep.node_name]
        with can.Bus(interface="canstack", channel=server.url, node_name="tester") as t:
            assert t.node_name == "tester"
        assert wait_for(lambda: nodes_on(server.runner), [keep.node_name]) == [keep.node_name]
        with can.Bus(interface="canstack", channel=server.url, node_name="tester") as t:  # free again
            assert t.node_name == "tester"
    finally:
        keep.shutdown()


# ------------------------------------------------------------------------ frames queued at shutdown
def test_shutdown_delivers_the_frames_still_queued_in_process(drain, settle):
    ch = chan()
    rx = can.Bus(interface="canstack", channel=ch, bitrate=125_000)
    try:
        tx = can.Bus(interface="canstack", channel=ch)
        for k in range(40):  # 40 frames of ~1 ms each at 125 kbit/s: most still queued
            tx.send(msg(0x100, k.to_bytes(2, "big")))
        tx.shutdown()
        got = [int.from_bytes(m.data, "big") for m in drain(rx, 40, timeout=30.0)]
        assert got == list(range(40))
        settle(ch)
        assert rx.recv(0) is None  # each once
    finally:
        rx.shutdown()


PLAYERLIKE = r"""
import sys, can, stack.io.pycan
bus = can.Bus(interface="canstack", channel=sys.argv[1])
for k in range(int(sys.argv[3])):
    bus.send(can.Message(arbitration_id=int(sys.argv[2]), data=k.to_bytes(2, "big"), is_extended_id=False))
bus.shutdown()
"""


@pytest.mark.socket
@pytest.mark.subprocess
def test_processes_that_send_and_shut_down_at_once_lose_nothing(drain, tmp_path):
    with BusServer(125_000, listen=("127.0.0.1", 0)) as srv:
        rx = can.Bus(interface="canstack", channel=srv.url)
        try:
            procs = [
                subprocess.Popen(
                    [sys.executable, "-c", PLAYERLIKE, srv.url, str(0x200 + i), "20"], env=env_with_checkout()
                )
                for i in range(3)
            ]
            assert [p.wait(60) for p in procs] == [0, 0, 0]
            got = drain(rx, 60, timeout=60.0)
            assert rx.recv(0.05) is None  # each once
        finally:
            rx.shutdown()
    assert len(got) == 60
    for i in range(3):
        assert [int.from_bytes(m.data, "big") for m in got if m.arbitration_id == 0x200 + i] == list(range(20))


@pytest.mark.socket
@pytest.mark.subprocess
def test_can_player_plays_the_whole_log_onto_a_served_bus(drain, tmp_path):
    log = tmp_path / "play.log"
    sent = [
        can.Message(
            timestamp=1.0 + 0.002 * i, arbitration_id=0x300 + i, data=bytes([i] * (i % 9)), is_extended_id=False
        )
        for i in range(8)
    ]
    with can.Logger(str(log)) as w:
        for m in sent:
            w.on_message_received(m)
    with BusServer(500_000, listen=("127.0.0.1", 0)) as srv:
        rx = can.Bus(interface="canstack", channel=srv.url)
        try:
            res = subprocess.run(
                [sys.executable, "-m", "can.player", "-i", "canstack", "-c", srv.url, str(log)],
                env=env_with_checkout(tmp_path),
                capture_output=True,
                text=True,
                timeout=120,
            )
            assert res.returncode == 0, res.stderr
            got = drain(rx, len(sent), timeout=30.0)
            assert rx.recv(0.05) is None  # each once
        finally:
            rx.shutdown()
    assert [(m.arbitration_id, bytes(m.data)) for m in got] == [(m.arbitration_id, bytes(m.data)) for m in sent]


def test_frames_nobody_can_acknowledge_are_dropped_at_shutdown_with_a_warning(caplog):
    lone = can.Bus(interface="canstack", channel=chan())
    lone.send(msg(0x1, b"\x01"))
    lone.send(msg(0x2, b"\x02"))
    with caplog.at_level(logging.WARNING, logger="stack.io.pycan"):
        lone.shutdown()
    assert any("2 queued frame(s) dropped at shutdown" in r.getMessage() for r in caplog.records)


# ------------------------------------------------------------------------ plain names beside a served bus
@pytest.fixture
def runtime_dir(tmp_path, monkeypatch):
    d = tmp_path / "run"
    d.mkdir()
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(d))
    monkeypatch.setattr("stack.io.pycan_channel._warned_private", False)  # a fresh process, for the warning
    return d


@pytest.mark.socket
def test_a_plain_channel_warns_once_when_a_local_server_runs(runtime_dir):
    with BusServer(500_000, listen=("127.0.0.1", 0)) as srv:
        assert [s["url"] for s in local_servers()] == [srv.url]
        with pytest.warns(pycan.PrivateBusWarning, match=r"'bus0' is a bus private to this process") as rec:
            a = can.Bus(interface="canstack", channel="bus0")
        assert srv.url in str(rec[0].message)
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # once per process: no second warning
            b = can.Bus(interface="canstack", channel="bus0")
        a.shutdown()
        b.shutdown()
    assert local_servers() == []  # the server withdrew its announcement


@pytest.mark.subprocess
def test_a_plain_channel_does_not_warn_without_a_live_local_server(runtime_dir):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    ann = Announcement("bus0", "tcp://127.0.0.1:1/bus0")  # this process: rewritten as a dead one below
    ann.path.write_text(json.dumps({"bus": "bus0", "url": "tcp://127.0.0.1:1/bus0", "pid": dead.pid}))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with can.Bus(interface="canstack", channel=chan()):
            pass
    assert not ann.path.exists()  # the stale announcement was removed


# ------------------------------------------------------------------------ BusState.PASSIVE = listen-only
def test_passive_state_is_listen_only_and_can_be_switched_at_run_time():
    ch = chan()
    a = can.Bus(interface="canstack", channel=ch, tx_queue_size=1)
    b = can.Bus(interface="canstack", channel=ch)
    try:
        b.state = can.BusState.PASSIVE  # before any traffic
        assert b.state is can.BusState.PASSIVE
        with pytest.raises(can.CanOperationError, match="listen-only"):
            b.send(msg(0x5, b""))
        a.send(msg(0x10, b"\x01"))
        # b does not acknowledge: a's frame fails with ACK errors, TEC rises (rule 3), and it
        # never completes (its queue slot is not freed)
        assert wait_for(lambda: a.tec > 0, True)
        with pytest.raises(can.CanOperationError, match="queue full"):
            a.send(msg(0x11, b"\x02"), timeout=0)
        b.state = can.BusState.ACTIVE  # at run time: b acknowledges again, the frame goes out
        assert b.state is can.BusState.ACTIVE
        a.send(msg(0x11, b"\x02"), timeout=10.0)  # room again: 0x10 was acknowledged
        # (an error-passive transmitter's frame reaches receivers despite the ACK error: its
        # passive error flag is recessive, so b may hold copies of 0x10 from before the switch)
        got = []
        end = time.monotonic() + 30.0
        while 0x11 not in got and time.monotonic() < end:
            m = b.recv(0.1)
            if m is not None:
                got.append(m.arbitration_id)
        assert got[-2:] == [0x10, 0x11] and set(got) == {0x10, 0x11}
        with pytest.raises(can.CanOperationError, match="cannot be set"):
            b.state = can.BusState.ERROR
    finally:
        a.shutdown()
        b.shutdown()


def test_going_passive_aborts_the_frames_still_queued():
    lone = can.Bus(interface="canstack", channel=chan(), tx_queue_size=4, flush_timeout=0)
    try:
        for k in range(3):  # nobody acknowledges: they stay queued
            lone.send(msg(0x20 + k, b""))
        lone.state = can.BusState.PASSIVE
        assert lone.last_tx_error == "aborted"
        lone.state = can.BusState.ACTIVE
        for k in range(4):  # every credit came back: the queue has room for 4 again
            lone.send(msg(0x30 + k, b""), timeout=0)
    finally:
        lone.shutdown()


def test_going_passive_while_the_own_frame_is_on_the_wire_stops_its_retransmission(settle, wait_until):
    ch = chan()
    lone = can.Bus(interface="canstack", channel=ch, bitrate=1_000, flush_timeout=0)  # ~60 ms per attempt
    runner = get_runner(ch)
    try:
        lone.send(msg(0x1, b""))
        # the first attempt is on the wire; nobody will acknowledge it
        wait_until(lambda: runner.call(lambda: runner.sim.rounds >= 1))

        def go_passive():  # on the bus's thread: the attempts started until the switch, exactly
            lone.state = can.BusState.PASSIVE
            return runner.sim.rounds

        started = runner.call(go_passive)
        assert wait_for(lambda: lone.last_tx_error, "aborted") == "aborted"
        settle(ch)
        assert runner.call(lambda: runner.sim.rounds) == started  # no attempt after the switch
        # one ACK error for each attempt made (rule 3), the one on the wire at the switch included
        assert wait_for(lambda: lone.tec, 8 * started) == 8 * started
    finally:
        lone.shutdown()


@pytest.mark.socket
@pytest.mark.subprocess
def test_python_can_logger_passive_records_a_served_bus_without_acknowledging(
    drain, tmp_path, server, interruptible_python, fill_until_logged
):
    asc = tmp_path / "rec.asc"
    proc = subprocess.Popen(
        # can.logger ends its log on Ctrl-C: a child that takes it, whatever the suite's SIGINT
        interruptible_python("-m", "can.logger", "-i", "canstack", "-c", server.url, "--passive", "-f", str(asc)),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env_with_checkout(tmp_path),
    )
    try:
        line = proc.stdout.readline()
        assert "Connected to CanstackBus" in line, line + proc.stderr.read()
        assert wait_for(lambda: server.runner.call(lambda: [n.listen_only for n in server.sim.nodes]), [True]) == [True]
        with (
            can.Bus(interface="canstack", channel=server.url) as tx,
            can.Bus(interface="canstack", channel=server.url) as other,
        ):
            sent = [msg(0x600 + i, bytes([i])) for i in range(4)]
            for m in sent:
                tx.send(m)
            assert len(drain(other, 4, timeout=10.0)) == 4
            fill_until_logged(tx, asc, len(sent))
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert "Traceback" not in err, err
    read = [(m.arbitration_id, bytes(m.data)) for m in can.LogReader(str(asc))]
    assert read[: len(sent)] == [(m.arbitration_id, bytes(m.data)) for m in sent]
    filler = (fill_until_logged.filler_id, bytes(8))
    assert read[len(sent) :] and all(r == filler for r in read[len(sent) :])


# ------------------------------------------------------------------------ failed one-shot transmissions
def _check_ack_error_frame(m, channel):
    assert m is not None and m.is_error_frame and m.channel == channel
    # SocketCAN (linux/can/error.h): ACK class, protocol violation on transmission at the ACK slot,
    # the counters: one ACK error of an error-active transmitter is TEC 8 (rule 3)
    assert m.arbitration_id & 0x020 and m.arbitration_id & 0x008 and m.arbitration_id & 0x200
    assert m.data[2] & 0x80 and m.data[3] == 0x19
    assert (m.data[6], m.data[7]) == (8, 0)


def test_failed_one_shot_frame_arrives_as_an_error_frame_in_process(settle):
    ch = chan()
    lone = can.Bus(interface="canstack", channel=ch, one_shot=True)
    try:
        lone.send(msg(0x7, b"\x07"))  # alone on the bus: no acknowledgement, no retransmission
        _check_ack_error_frame(lone.recv(10.0), ch)
        assert lone.last_tx_error == "ack error (one-shot)"
        settle(ch)
        assert lone.recv(0) is None  # one attempt, one error frame
    finally:
        lone.shutdown()


def test_lost_arbitration_of_a_one_shot_frame_is_reported_as_socketcan_does(settle, wait_until):
    ch = chan()
    c = can.Bus(interface="canstack", channel=ch, bitrate=10_000)
    a = can.Bus(interface="canstack", channel=ch, one_shot=True)
    b = can.Bus(interface="canstack", channel=ch)
    runner = get_runner(ch)
    try:
        c.send(msg(0x700, b"\x00"))
        wait_until(lambda: runner.call(lambda: runner.sim.rounds >= 1))  # 0x700 has the bus alone

        def contend():  # queued at one instant on the bus's thread: they arbitrate with each other
            a.send(msg(0x200, b"\x02"))
            b.send(msg(0x100, b"\x01"))

        runner.call(contend)
        m = a.recv(10.0)
        while m is not None and not m.is_error_frame:
            m = a.recv(10.0)
        assert m is not None and m.arbitration_id == 0x002 | 0x200 and m.data[0] == 0
        assert a.last_tx_error == "arbitration lost (one-shot)"
        settle(ch)
        got = []
        while (x := c.recv(0)) is not None:
            got.append(x.arbitration_id)
        assert got == [0x100]  # 0x200 never sent
    finally:
        for bus in (a, b, c):
            bus.shutdown()


def test_ignore_rx_error_frames_keeps_them_out_of_recv(settle, wait_until):
    ch = chan()
    lone = can.Bus(interface="canstack", channel=ch, one_shot=True, ignore_rx_error_frames=True)
    try:
        lone.send(msg(0x7, b""))
        settle(ch)  # the one attempt is over
        assert wait_until(lambda: lone.last_tx_error) == "ack error (one-shot)"
        assert lone.recv(0) is None
    finally:
        lone.shutdown()


@pytest.mark.socket
def test_failed_one_shot_frame_arrives_as_an_error_frame_through_serve(server):
    lone = can.Bus(interface="canstack", channel=server.url, one_shot=True)
    try:
        lone.send(msg(0x7, b"\x07"))
        _check_ack_error_frame(lone.recv(10.0), server.url)
        assert wait_for(lambda: lone.last_tx_error, "ack error (one-shot)") == "ack error (one-shot)"
    finally:
        lone.shutdown()


@pytest.mark.parametrize(
    "reason,classes,d2,d3",
    [
        ("arbitration lost (one-shot)", 0x202, 0x00, 0x00),
        ("ack error (one-shot)", 0x2A8, 0x80, 0x19),
        ("bit error (one-shot)", 0x288, 0x81, 0x00),
        ("stuff error (one-shot)", 0x288, 0x84, 0x00),
        ("form error (one-shot)", 0x288, 0x82, 0x00),
        ("crc error (one-shot)", 0x288, 0x80, 0x08),
    ],
)
def test_error_frames_carry_socketcans_classes(reason, classes, d2, d3):
    m = pycan.error_frame_of(reason, 130, 5, timestamp=1.5, channel="x")
    assert (m.is_error_frame, m.arbitration_id, m.dlc, m.timestamp) == (True, classes, 8, 1.5)
    assert (m.data[2], m.data[3], m.data[6], m.data[7]) == (d2, d3, 130, 5)
