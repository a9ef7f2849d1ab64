"""The canstack python-can interface: wire timing, arbitration, errors, filters, periodic tasks,
and interop with the real libraries (canopen, cantools, python-can's Notifier/Logger/logger)."""

import itertools
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import can
import pytest

from stack.io.pycan import CanstackBus, CanstackCyclicTask, InvalidFrame, running_buses
from stack.io.runner import get_runner
from stack.wire.coding import INTERMISSION_BITS
from stack.wire.frame import Frame

ROOT = Path(__file__).resolve().parents[3]
# every test here runs canstack buses in real time (their runner thread paces the simulated bus
# to the wall clock)
pytestmark = pytest.mark.wallclock
_ids = itertools.count()


def chan() -> str:
    return f"t{os.getpid()}-{next(_ids)}"


def msg(can_id, data=b"", **kw):
    return can.Message(arbitration_id=can_id, data=data, is_extended_id=kw.pop("extended", False), **kw)


def wire_ns(frame: Frame, bitrate: int) -> int:
    """SOF..EOF plus intermission, from the frame's stuffed bit stream."""
    return (frame.bits.length + INTERMISSION_BITS) * 1_000_000_000 // bitrate


@pytest.fixture
def pair():
    ch = chan()
    a = can.Bus(interface="canstack", channel=ch, bitrate=500_000)
    b = can.Bus(interface="canstack", channel=ch)
    yield a, b
    a.shutdown()
    b.shutdown()


def test_bus_created_through_python_can_is_a_canstack_node(pair):
    a, b = pair
    assert isinstance(a, CanstackBus) and a.bitrate == b.bitrate == 500_000
    assert a.node_name != b.node_name
    assert a.state is can.BusState.ACTIVE
    assert {"interface": "canstack", "channel": a.channel, "bitrate": 500_000} in can.detect_available_configs(
        "canstack"
    )


def test_back_to_back_frames_arrive_one_wire_time_apart(pair):
    a, b = pair
    frames = [msg(0x123, bytes([i]) * 8) for i in range(5)]
    t_send = time.time()
    for m in frames:
        a.send(m)
    got = [b.recv(10.0) for _ in frames]
    assert [bytes(m.data) for m in got] == [bytes(m.data) for m in frames]
    first = Frame(0x123, bytes([0]) * 8)
    # the first frame ends one frame length (SOF..EOF) after it started
    assert got[0].timestamp - t_send >= first.bits.length / 500_000 - 1e-4
    for prev, cur, m in zip(got, got[1:], frames[1:]):
        expected = wire_ns(Frame.from_message(m), 500_000) / 1e9
        assert cur.timestamp - prev.timestamp == pytest.approx(expected, abs=2e-6)
    assert all(m.is_rx and m.channel == a.channel for m in got)


def test_contending_frames_are_arbitrated_lowest_identifier_first(wait_until):
    ch = chan()
    a = CanstackBus(ch, bitrate=10_000)
    b = CanstackBus(ch)
    c = CanstackBus(ch)
    runner = get_runner(ch)
    try:
        a.send(msg(0x700, b"\x00"))
        # 0x700 has won the bus alone (an arbitration round has started it) ...
        wait_until(lambda: runner.call(lambda: runner.sim.rounds >= 1))

        def queue_the_rest() -> None:  # ... and the rest is queued at one instant, to contend
            a.send(msg(0x300, b"\x03"))
            b.send(msg(0x200, b"\x02"))
            b.send(msg(0x100, b"\x01"))
            a.send(msg(0x0F0, b"\x04", extended=True))  # extended 0x0F0: base ID 0 beats all

        # on the bus's own thread: its loop takes the four frames before it arbitrates again
        runner.call(queue_the_rest)
        got = [c.recv(10.0) for _ in range(5)]
    finally:
        for bus in (a, b, c):
            bus.shutdown()
    assert [m.arbitration_id for m in got] == [0x700, 0x0F0, 0x100, 0x200, 0x300]


def test_receive_own_messages_marks_them_tx(settle):
    ch = chan()
    a = CanstackBus(ch, receive_own_messages=True)
    b = CanstackBus(ch)
    try:
        a.send(msg(0x55, b"\x01\x02"))
        own = a.recv(10.0)
        other = b.recv(10.0)
        settle(ch)
        assert a.recv(0) is None  # its own frame once
    finally:
        a.shutdown()
        b.shutdown()
    assert own.arbitration_id == other.arbitration_id == 0x55
    assert own.is_rx is False and other.is_rx is True
    assert own.timestamp == other.timestamp  # both see the end of the same EOF


def test_filters_are_applied_by_the_node(pair, settle):
    a, b = pair
    b.set_filters([{"can_id": 0x100, "can_mask": 0x7F0, "extended": False}])
    for cid in (0x101, 0x200, 0x10F):
        a.send(msg(cid, b"\x00"))
    a.send(msg(0x105, b"\x00", extended=True))  # extended frame: filter asks for standard only
    settle(a.channel)  # the bus has carried all four: b has what passed its filter
    got = []
    while (m := b.recv(0)) is not None:
        got.append(m.arbitration_id)
    assert got == [0x101, 0x10F]
    b.set_filters(None)
    a.send(msg(0x200, b"\x00"))
    assert b.recv(10.0).arbitration_id == 0x200


def test_bad_input_raises_clear_can_errors(pair):
    a, b = pair
    with pytest.raises(InvalidFrame, match="FD"):
        a.send(can.Message(arbitration_id=1, data=bytes(12), is_fd=True))
    with pytest.raises(can.CanError, match="at most 8"):
        a.send(can.Message(arbitration_id=1, data=bytes(9), check=False))
    with pytest.raises(can.CanInitializationError, match="runs at 500000 bit/s"):
        can.Bus(interface="canstack", channel=a.channel, bitrate=250_000)
    with pytest.raises(can.CanInitializationError, match="unknown form"):
        can.Bus(interface="canstack", channel="udp://127.0.0.1:1/x")
    with pytest.raises(can.CanInitializationError, match="bus name"):
        can.Bus(interface="canstack", channel="no spaces please")
    with pytest.raises(can.CanInitializationError, match="unknown canstack option"):
        can.Bus(interface="canstack", channel=a.channel, colour="red")
    b.shutdown()
    with pytest.raises(can.CanOperationError, match="shut down"):
        b.send(msg(1, b""))


def test_listen_only_node_neither_sends_nor_acknowledges(wait_until):
    ch = chan()
    a = CanstackBus(ch, tx_queue_size=1)
    spy = CanstackBus(ch, listen_only=True)
    try:
        with pytest.raises(can.CanOperationError, match="listen-only"):
            spy.send(msg(1, b""))
        a.send(msg(0x10, b"\x01"), timeout=0)
        wait_until(lambda: a.tec > 0)
        # nobody acknowledges: the frame never completes (its queue slot is never freed) and
        # a's transmit error counter rises with each ACK error (rule 3)
        assert a.tec > 0
        with pytest.raises(can.CanOperationError, match="queue full"):
            a.send(msg(0x11, b""), timeout=0)
    finally:
        a.shutdown()
        spy.shutdown()


def test_full_transmit_queue_times_out_with_reason(wait_until):
    ch = chan()
    a = CanstackBus(ch, tx_queue_size=2)  # alone on the bus: no ACK, frames never complete
    try:
        a.send(msg(1, b""))
        a.send(msg(2, b""))
        t0 = time.monotonic()
        with pytest.raises(can.CanOperationError, match=r"transmit queue full \(2 frames\)"):
            a.send(msg(3, b""), timeout=0.05)
        assert time.monotonic() - t0 >= 0.04
        with pytest.raises(can.CanOperationError, match="queue full"):
            a.send(msg(3, b""), timeout=0)
        # no acknowledgement: TEC rises by 8 per attempt until error passive (rules 3 and 9)
        wait_until(lambda: a.state is can.BusState.PASSIVE)
        assert a.state is can.BusState.PASSIVE and a.tec >= 128
    finally:
        a.shutdown()


def test_native_periodic_task_keeps_the_simulated_period(pair, drain, settle):
    a, b = pair
    task = a.send_periodic(msg(0x321, b"\x00\x01"), 0.010)
    assert isinstance(task, CanstackCyclicTask)
    stamps = drain(b, 15, timeout=30.0)
    assert len(stamps) == 15
    task.modify_data(msg(0x321, b"\x07\x07"))
    # a frame the engine had queued before the change carries the old data; then the new
    after = []
    while not after or after[-1].data != b"\x07\x07":
        after += drain(b, 1, timeout=30.0) or pytest.fail("no frame with the new data")
    task.stop()
    settle(a.channel)  # stopped: the bus has nothing left to do, no timer
    while b.recv(0) is not None:
        pass
    assert b.recv(0) is None
    for x, y in zip(stamps, stamps[1:]):  # virtual clock: the period is exact (only sender)
        assert y.timestamp - x.timestamp == pytest.approx(0.010, abs=2e-6)
    assert [bytes(m.data) for m in stamps + after[:-1]] == [b"\x00\x01"] * (len(stamps) + len(after) - 1)
    # still on the period: a timestamp is the end of EOF, and the new data stuffs differently
    longer = (Frame.from_message(after[-1]).bits.length - Frame.from_message(stamps[-1]).bits.length) / 500_000
    assert after[-1].timestamp - stamps[-1].timestamp == pytest.approx(0.010 * len(after) + longer, abs=2e-6)


def test_periodic_task_with_duration_stops_by_itself(pair, drain, settle):
    a, b = pair
    a.send_periodic(msg(0x10, b"\x01"), 0.01, duration=0.05)
    got = drain(b, 5, timeout=30.0)
    settle(a.channel)  # no frame on the way and no timer left: the task has ended by itself
    while (m := b.recv(0)) is not None:
        got.append(m)
    assert len(got) == 5


def test_shutdown_removes_the_node_and_last_one_stops_the_bus():
    ch = chan()
    a = CanstackBus(ch)
    b = CanstackBus(ch)
    c = CanstackBus(ch)
    b.shutdown()
    a.send(msg(0x1, b"\x01"))
    assert c.recv(10.0).arbitration_id == 0x1
    assert ch in running_buses()
    a.shutdown()
    c.shutdown()
    assert ch not in running_buses()
    # a fresh bus with the same name may now start at another bitrate
    d = CanstackBus(ch, bitrate=125_000)
    assert d.bitrate == 125_000
    d.shutdown()


# ---------------------------------------------------------------------------- interop
def test_notifier_printer_and_logger_write_what_was_sent(tmp_path):
    ch = chan()
    a = can.Bus(interface="canstack", channel=ch, queue="fifo")  # sent in the order queued
    b = can.Bus(interface="canstack", channel=ch)
    out = tmp_path / "printed.txt"
    asc = tmp_path / "log.asc"
    printer = can.Printer(str(out))
    logger = can.Logger(str(asc))
    seen = can.BufferedReader()  # the notifier hands each message to the listeners in this order
    notifier = can.Notifier(b, [printer, logger, seen], timeout=0.05)
    sent = [msg(0x100 + i, bytes([i, i + 1])) for i in range(4)] + [msg(0x1ABCDE, b"\xff", extended=True)]
    for m in sent:
        a.send(m)
    deadline = time.monotonic() + 30.0  # the last message has passed the printer and the logger
    got = [m for _ in sent if (m := seen.get_message(max(0.0, deadline - time.monotonic()))) is not None]
    assert len(got) == len(sent)
    notifier.stop()
    printer.stop()
    logger.stop()
    a.shutdown()
    b.shutdown()
    read = list(can.LogReader(str(asc)))
    assert [(m.arbitration_id, m.is_extended_id, bytes(m.data)) for m in read] == [
        (m.arbitration_id, m.is_extended_id, bytes(m.data)) for m in sent
    ]
    assert out.read_text().count("\n") == len(sent)


def _entry_point_path(tmp_path: Path) -> str:
    """A dist-info with the project's `can.interface` entry point, as `pip install` writes it."""
    info = tmp_path / "canstack_ep-0.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: canstack-ep\nVersion: 0.0\n")
    import tomllib

    ep = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["entry-points"]["can.interface"]
    (info / "entry_points.txt").write_text("[can.interface]\n" + "".join(f"{k} = {v}\n" for k, v in ep.items()))
    return str(tmp_path)


@pytest.mark.socket
@pytest.mark.subprocess
def test_python_can_logger_command_records_a_served_bus_to_asc(tmp_path, interruptible_python, fill_until_logged):
    from stack.io.serve import BusServer

    asc = tmp_path / "rec.asc"
    env = dict(os.environ)
    # the entry point, exactly as the installed distribution declares it (pyproject.toml)
    env["PYTHONPATH"] = os.pathsep.join([_entry_point_path(tmp_path), str(ROOT), env.get("PYTHONPATH", "")])
    with BusServer(500_000, listen=("127.0.0.1", 0)) as server:
        proc = subprocess.Popen(
            # can.logger ends its log on Ctrl-C: a child that takes it, whatever the suite's SIGINT
            interruptible_python("-m", "can.logger", "-i", "canstack", "-c", server.url, "-f", str(asc)),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
        )
        try:
            line = proc.stdout.readline()
            assert "Connected to CanstackBus" in line, line + proc.stderr.read()
            with can.Bus(interface="canstack", channel=server.url) as tx:
                sent = [msg(0x700 + i, bytes(range(i))) for i in range(6)]
                for m in sent:
                    tx.send(m)
                fill_until_logged(tx, asc, len(sent))
            proc.send_signal(signal.SIGINT)
            _, err = proc.communicate(timeout=30)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    assert proc.returncode == 0 and "Traceback" not in err, err
    read = [(m.arbitration_id, bytes(m.data)) for m in can.LogReader(str(asc))]
    # what was sent, in order, then the fillers that made the logger write it out
    assert read[: len(sent)] == [(m.arbitration_id, bytes(m.data)) for m in sent]
    filler = (fill_until_logged.filler_id, bytes(8))
    assert read[len(sent) :] and all(r == filler for r in read[len(sent) :])


def _object_dictionary():
    import canopen
    from canopen.objectdictionary import ODVariable, datatypes

    od = canopen.ObjectDictionary()
    for index, name, dtype, access, default in [
        (0x1000, "Device type", datatypes.UNSIGNED32, "ro", 0x00020192),
        (0x1017, "Producer heartbeat time", datatypes.UNSIGNED16, "rw", 0),
        (0x2000, "Setpoint", datatypes.UNSIGNED16, "rw", 100),
        (0x2001, "Name", datatypes.VISIBLE_STRING, "rw", "canstack-local-node"),  # segmented SDO
    ]:
        var = ODVariable(name, index)
        var.data_type = dtype
        var.access_type = access
        var.default = default
        od.add_object(var)
    return od


def test_canopen_master_and_local_node_on_two_canstack_buses(wait_until):
    import canopen

    ch = chan()
    master = canopen.Network()
    master.connect(interface="canstack", channel=ch, bitrate=500_000)
    slave_net = canopen.Network()
    slave_net.connect(interface="canstack", channel=ch)
    try:
        local = canopen.LocalNode(5, _object_dictionary())
        slave_net.add_node(local)
        remote = master.add_node(5, _object_dictionary())
        # SDO upload (expedited and segmented) and download
        assert remote.sdo["Device type"].raw == 0x00020192
        assert remote.sdo["Name"].raw == "canstack-local-node"
        remote.sdo["Setpoint"].raw = 1234
        assert local.sdo["Setpoint"].raw == 1234
        remote.sdo.download(0x2001, 0, b"renamed by the master")
        assert local.sdo.upload(0x2001, 0) == b"renamed by the master"
        # NMT state change commanded by the master
        remote.nmt.state = "OPERATIONAL"
        wait_until(lambda: local.nmt.state == "OPERATIONAL")
        # heartbeat produced by the local node, received by the master
        local.nmt.start_heartbeat(50)
        assert remote.nmt.wait_for_heartbeat(timeout=10.0) == "OPERATIONAL"
        local.nmt.stop_heartbeat()
    finally:
        master.disconnect()
        slave_net.disconnect()


DBC = """VERSION ""

NS_ :

BS_:

BU_: Tester Dut

BO_ 256 Command: 2 Tester
 SG_ Enable : 0|1@1+ (1,0) [0|1] "" Dut
 SG_ Setpoint : 8|8@1+ (1,0) [0|255] "" Dut

BO_ 512 Status: 2 Dut
 SG_ Active : 0|1@1+ (1,0) [0|1] "" Tester
 SG_ Value : 8|8@1+ (1,0) [0|255] "" Tester

BO_ 768 Heartbeat: 1 Tester
 SG_ Counter : 0|8@1+ (1,0) [0|255] "" Dut

BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;
BA_DEF_DEF_ "GenMsgCycleTime" 0;
BA_ "GenMsgCycleTime" BO_ 768 20;
"""


def test_cantools_tester_drives_a_dut_on_another_canstack_bus(wait_until):
    import cantools
    from cantools.tester import Tester

    db = cantools.database.load_string(DBC, database_format="dbc")
    ch = chan()
    tester_bus = can.Bus(interface="canstack", channel=ch, bitrate=500_000)
    dut_bus = can.Bus(interface="canstack", channel=ch)
    stop = threading.Event()
    heartbeats = []

    def dut() -> None:  # doubles the setpoint, reports Enable as Active
        cmd, status, hb = (
            db.get_message_by_name("Command"),
            db.get_message_by_name("Status"),
            db.get_message_by_name("Heartbeat"),
        )
        while not stop.is_set():
            m = dut_bus.recv(0.05)
            if m is None:
                continue
            if m.arbitration_id == cmd.frame_id:
                s = cmd.decode(m.data)
                dut_bus.send(
                    can.Message(
                        arbitration_id=status.frame_id,
                        is_extended_id=False,
                        data=status.encode({"Active": s["Enable"], "Value": 2 * s["Setpoint"] % 256}),
                    )
                )
            elif m.arbitration_id == hb.frame_id:
                heartbeats.append(m.timestamp)

    th = threading.Thread(target=dut, daemon=True)
    th.start()
    tester = Tester("Dut", db, tester_bus)
    try:
        tester.start()  # starts the periodic Heartbeat (a native canstack periodic task)
        tester.send("Command", {"Enable": 1, "Setpoint": 21})
        assert tester.expect("Status", {"Active": 1}, timeout=10.0) == {"Active": 1, "Value": 42}
        tester.send("Command", {"Enable": 0, "Setpoint": 200})
        assert tester.expect("Status", None, timeout=10.0) == {"Active": 0, "Value": 144}
        wait_until(lambda: len(heartbeats) >= 10)  # the 20 ms heartbeat, read by the DUT's thread
        tester.stop()
    finally:
        stop.set()
        th.join(1.0)
        tester_bus.shutdown()
        dut_bus.shutdown()
    assert len(heartbeats) >= 8
    gaps = [y - x for x, y in zip(heartbeats, heartbeats[1:])]
    # the heartbeat period is exact except when the Command/Status exchange delayed one frame
    assert sum(1 for g in gaps if abs(g - 0.020) < 1e-3) >= len(gaps) - 2


@pytest.mark.parametrize(
    "kw,needle",
    [
        ({"queue": "mailbox", "mailboxes": "x"}, "mailboxes 'x'"),
        ({"listen_only": "maybe"}, "listen_only 'maybe' must be True or False"),
        ({"node_name": "a b"}, "node name 'a b'"),
        ({"node_name": "\x01\x02"}, "node name"),
        ({"data_bitrate": 2_000_000}, "a data phase is CAN FD's; open the bus with fd=True"),
    ],
)
def test_bad_node_options_are_refused(kw, needle):
    with pytest.raises(can.CanInitializationError, match=re.escape(needle)):
        can.Bus(interface="canstack", channel=f"opt{os.getpid()}", **kw)


def test_config_file_strings_for_flags_are_read():
    bus = can.Bus(
        interface="canstack", channel=f"optstr{os.getpid()}", listen_only="yes", mailboxes="2", queue="mailbox"
    )
    try:
        with pytest.raises(can.CanOperationError, match="listen-only"):
            bus.send(can.Message(arbitration_id=1, is_extended_id=False))
    finally:
        bus.shutdown()


@pytest.mark.subprocess
def test_interface_found_through_the_entry_point_alone(tmp_path):
    """python-can finds ``interface="canstack"`` through the installed distribution's
    ``can.interface`` entry point alone, in a fresh process that never imported stack.io.pycan
    (nothing patches python-can's tables at import any more), FD messages included."""
    code = (
        "import importlib.metadata, sys, can, can.interfaces\n"
        "eps = {e.name: e.value for e in importlib.metadata.entry_points(group='can.interface')}\n"
        "assert eps.get('canstack') == 'stack.io.pycan:CanstackBus', eps\n"
        "assert 'stack.io.pycan' not in sys.modules\n"
        "a = can.Bus(interface='canstack', channel='ep', fd=True)\n"
        "b = can.Bus(interface='canstack', channel='ep', fd=True)\n"
        "a.send(can.Message(arbitration_id=0x12, data=bytes(range(20)), is_fd=True, bitrate_switch=True))\n"
        "m = b.recv(10)\n"
        "a.shutdown(); b.shutdown()\n"
        "print(type(a).__module__, m.is_fd, m.bitrate_switch, len(m.data))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["stack.io.pycan", "True", "True", "20"]
