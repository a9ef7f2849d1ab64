"""The python-can driver: stack nodes on python-can's `virtual` bus (and vcan when present)."""

import itertools
import os
import socket
import time

import can
import pytest

from stack.bus.sim import SimBus
from stack.cli.demo import run_demo_on_bus
from stack.controller.events import Received, TxDone, TxFailed
from stack.controller.node import Node
from stack.io.driver import RETRY_NS, PyCanDriver
from stack.io.message import to_message
from stack.wire.coding import INTERMISSION_BITS
from stack.wire.frame import Frame

# every test here runs nodes on a python-can bus in real time: threads and the wall clock
pytestmark = pytest.mark.wallclock
_ids = itertools.count()


def chan():
    return f"drv{os.getpid()}-{next(_ids)}"


def echo_ecu(node, log):
    """Protocol code written once: answers 0x100 with 0x180 carrying the doubled byte."""

    def on_rx(ev: Received):
        log.append(("rx", ev.frame))
        if ev.frame.can_id == 0x100:
            node.send(Frame(0x180, bytes([ev.frame.data[0] * 2 & 0xFF])))

    node.subscribe(on_rx, filters=[{"can_id": 0x100, "can_mask": 0x7FF}])
    node.listen(TxDone, lambda ev: log.append(("tx", ev.frame)))


def test_the_same_ecu_code_runs_on_the_simulated_bus_and_on_python_can():
    stim = [Frame(0x100, bytes([i])) for i in (1, 2, 3)]
    # simulated bus
    sim = SimBus(500_000)
    log_sim = []
    echo_ecu(sim.node("ecu"), log_sim)
    tester = sim.node("tester")
    for f in stim:
        tester.send(f)
    sim.run(duration=10_000_000)
    # python-can virtual bus
    ch = chan()
    log_pc = []
    with PyCanDriver(interface="virtual", channel=ch) as drv:
        echo_ecu(drv.node("ecu"), log_pc)
        with can.Bus(interface="virtual", channel=ch) as t:
            for f in stim:
                t.send(to_message(f))
            replies = [t.recv(10.0) for _ in stim]
    assert log_pc == log_sim
    assert [(m.arbitration_id, bytes(m.data)) for m in replies] == [(0x180, bytes([2 * i])) for i in (1, 2, 3)]


@pytest.mark.parametrize("policy, order", [("priority", [0x100, 0x200, 0x300]), ("fifo", [0x300, 0x200, 0x100])])
def test_the_node_orders_its_own_transmit_queue(policy, order):
    ch = chan()
    with can.Bus(interface="virtual", channel=ch) as mon, PyCanDriver(interface="virtual", channel=ch) as drv:
        node = drv.node("n", queue=policy)
        with drv.lock:  # queued at once, before the scheduler hands any to the bus
            for cid in (0x300, 0x200, 0x100):
                node.send(Frame(cid, b"\x00"))
        got = [mon.recv(10.0).arbitration_id for _ in order]
    assert got == order


def test_pacing_keeps_frames_one_wire_time_apart():
    ch = chan()
    frame = Frame(0x123, bytes(8))
    gap = (frame.bits.length + INTERMISSION_BITS) / 20_000  # 20 kbit/s: ~6.6 ms per frame
    with (
        can.Bus(interface="virtual", channel=ch) as mon,
        PyCanDriver(interface="virtual", channel=ch, pace_bitrate=20_000) as drv,
    ):
        node = drv.node("n")
        done = []
        node.listen(TxDone, done.append)
        with drv.lock:
            for _ in range(5):
                node.send(frame)
        got = [mon.recv(10.0) for _ in range(5)]
    stamps = [m.timestamp for m in got]
    for a, b in zip(stamps, stamps[1:]):
        assert b - a >= gap - 0.5e-3
    assert len(done) == 5 and all(isinstance(e, TxDone) and e.frame == frame for e in done)


def test_periodic_transmission_runs_on_wall_clock_timers():
    ch = chan()
    n = 60
    with can.Bus(interface="virtual", channel=ch) as mon, PyCanDriver(interface="virtual", channel=ch) as drv:
        with drv.lock:
            t0 = time.time()  # the timers run from here: frame k is due k periods later
            drv.node("n").send_periodic(Frame(0x10, b"\x01"), 10_000_000)
        got = [mon.recv(10.0) for _ in range(n)]
    assert all(m is not None for m in got)
    # each frame is stamped when handed to the bus: never before it is due (on the period's grid,
    # not drifting by the time each send took); late only by the thread's wake-up, and it
    # catches up (a loaded machine delays frames, it does not drop them)
    for k, m in enumerate(got):
        assert m.timestamp >= t0 + k * 0.010 - 1e-3
    assert got[-1].timestamp - t0 < (n - 1) * 0.010 + 0.5


def test_remote_frames_are_answered_by_the_node_mailbox():
    ch = chan()
    with can.Bus(interface="virtual", channel=ch) as t, PyCanDriver(interface="virtual", channel=ch) as drv:
        with drv.lock:
            drv.node("body").set_remote_reply(Frame(0x700, b"\x5a\x5a"))
        t.send(can.Message(arbitration_id=0x700, is_remote_frame=True, dlc=2, is_extended_id=False))
        reply = t.recv(10.0)
    assert (reply.arbitration_id, reply.is_remote_frame, bytes(reply.data)) == (0x700, False, b"\x5a\x5a")


def test_send_errors_retry_and_one_shot_fails():
    class Flaky(can.BusABC):
        def __init__(self):
            self.calls = 0
            self.sent = []
            super().__init__(channel="flaky")

        def send(self, msg, timeout=None):
            self.calls += 1
            if self.calls <= 2:
                raise can.CanOperationError("ENOBUFS")
            self.sent.append(msg)

        def _recv_internal(self, timeout):
            time.sleep(timeout or 0)
            return None, False

    flaky, oneshot_bus = Flaky(), Flaky()
    drv = PyCanDriver()
    n = drv.add(Node("n"), flaky)
    o = drv.node("o", can_bus=oneshot_bus, one_shot=True)
    failed = []
    o.listen(TxFailed, failed.append)
    with drv:
        with drv.lock:
            n.send(Frame(0x1, b"\x01"))
            o.send(Frame(0x2, b"\x02"))
        deadline = time.monotonic() + 30.0  # two retries after failed sends, then the third goes
        while not (flaky.sent and failed) and time.monotonic() < deadline:
            time.sleep(RETRY_NS / 1e9)
    flaky.shutdown()
    oneshot_bus.shutdown()
    assert len(flaky.sent) == 1 and n.retransmissions == 2 and n.tx_frames == 1
    assert len(failed) == 1 and "one-shot" in failed[0].reason and o.tx_failed == 1
    assert drv.errors == []  # two failed tries are congestion, not an error


def test_a_send_that_keeps_failing_is_reported():
    from stack.io.driver import SEND_FAILURES_REPORTED

    class Dead(can.BusABC):
        def __init__(self):
            super().__init__(channel="dead")

        def send(self, msg, timeout=None):
            raise can.CanOperationError("network is down")

        def _recv_internal(self, timeout):
            time.sleep(timeout or 0)
            return None, False

    dead = Dead()
    drv = PyCanDriver()
    n = drv.add(Node("n"), dead)
    with drv:
        with drv.lock:
            n.send(Frame(0x1, b"\x01"))
        end = time.monotonic() + 5.0
        while not drv.errors and time.monotonic() < end:
            time.sleep(RETRY_NS / 1e9)
    dead.shutdown()
    assert drv.errors == [f"n: send keeps failing ({SEND_FAILURES_REPORTED} tries): network is down"]


def test_demo_runs_on_the_virtual_bus(rerun_until):
    def run():
        text = run_demo_on_bus("virtual", chan(), 0.5, pace_bitrate=500_000)
        lines = {ln.split()[0]: ln.split() for ln in text.splitlines() if ln.strip().startswith("0x")}
        assert {"0x0A0", "0x0C1", "0x3E9", "0x18FEF100", "0x700"} <= set(lines), text
        assert "callback error" not in text
        return lines

    def timely(lines):
        # every 5 ms for 0.5 s; a starved driver thread sends late, or drops what overflows its
        # nodes' queues (as a controller whose host cannot keep up does)
        return 75 <= int(lines["0x0A0"][1]) <= 105 and float(lines["0x0A0"][2]) == pytest.approx(5.0, abs=0.5)

    rerun_until(run, timely)


def _has_vcan0() -> bool:
    return hasattr(socket, "AF_CAN") and os.path.exists("/sys/class/net/vcan0")


@pytest.mark.skipif(not _has_vcan0(), reason="needs SocketCAN (AF_CAN) and a vcan0 interface")
def test_demo_runs_on_vcan0():
    text = run_demo_on_bus("socketcan", "vcan0", 0.3)
    assert "0x0A0" in text and "callback error" not in text


def test_received_times_are_the_buses_timestamps():
    # on a canstack python-can bus every frame is stamped with its wire end time: two
    # back-to-back 8-byte frames at 500 kbit/s arrive one frame time apart (stuffed length +
    # 3 bits of intermission), whatever the reader thread's wake-ups

    ch = f"drvts{os.getpid()}"
    frame = Frame(0x123, bytes(8))
    got = []
    with (
        can.Bus(interface="canstack", channel=ch, bitrate=500_000) as tx,
        PyCanDriver(interface="canstack", channel=ch, bitrate=500_000) as drv,
    ):
        node = drv.node("n")
        node.subscribe(got.append)
        tx.send(to_message(frame))
        tx.send(to_message(frame))
        end = time.monotonic() + 30.0
        while len(got) < 2 and time.monotonic() < end:
            time.sleep(0.01)
    assert len(got) == 2
    wire_ns = (frame.bits.length + INTERMISSION_BITS) * 2000
    assert abs((got[1].time - got[0].time) - wire_ns) < 2_000
