"""Conformance of the node API on both drivers: the same node-level behaviour tests run on the
simulated bus and on `PyCanDriver` over python-can's `virtual` bus, skipping only what a driver
says it cannot know (``node.capabilities``). A profile written against the node API and passing
here runs on either.

On the python-can side time is the wall clock: each test waits for its condition with a
deadline of a few seconds instead of asserting durations.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable
from typing import Any

import can
import pytest

from stack.bus.sim import SimBus
from stack.controller.clock import LocalClock
from stack.controller.events import ErrorStateChanged, Received, TxDone, TxFailed
from stack.controller.exceptions import NodeError
from stack.io.driver import PyCanDriver
from stack.wire.frame import Frame

BITRATE = 125_000
_channels = itertools.count()


class SimNet:
    """Nodes on a simulated bus; `wait` runs virtual time until the condition holds."""

    kind = "sim"

    def __init__(self) -> None:
        self.bus = SimBus(BITRATE, seed=1)
        self.driver = self.bus

    def node(self, name: str, **cfg: Any) -> Any:
        return self.bus.node(name, **cfg)

    def start(self) -> None:
        pass

    def wait(self, cond: Callable[[], bool], limit_s: float = 1.0) -> bool:
        end = self.bus.now() + int(limit_s * 1e9)
        while not cond() and self.bus.now() < end:
            self.bus.run(duration=200_000)
        return cond()

    def close(self) -> None:
        pass


class PyCanNet:
    """Nodes on python-can's virtual bus through PyCanDriver (wall clock), paced at BITRATE."""

    kind = "pycan"

    def __init__(self) -> None:
        self.channel = f"conformance-{time.monotonic_ns()}-{next(_channels)}"
        self.driver = PyCanDriver(interface="virtual", channel=self.channel, pace_bitrate=BITRATE)

    def node(self, name: str, **cfg: Any) -> Any:
        return self.driver.node(name, **cfg)

    def start(self) -> None:
        self.driver.start()

    def wait(self, cond: Callable[[], bool], limit_s: float = 10.0) -> bool:
        # a deadline, not a duration: a loaded machine is slow, not wrong
        end = time.monotonic() + limit_s
        while time.monotonic() < end:
            with self.driver.lock:
                if cond():
                    return True
            time.sleep(0.005)
        with self.driver.lock:
            return cond()

    def submit(self, fn: Callable[[], Any]) -> None:
        with self.driver.lock:
            fn()

    def close(self) -> None:
        self.driver.close()


@pytest.fixture(params=["sim", pytest.param("pycan", marks=pytest.mark.wallclock)])
def net(request):
    n = SimNet() if request.param == "sim" else PyCanNet()
    yield n
    n.close()


def _do(net: Any, fn: Callable[[], Any]) -> Any:
    """Run ``fn`` where node calls are safe (the driver's lock on the python-can side)."""
    if net.kind == "pycan":
        with net.driver.lock:
            return fn()
    return fn()


def test_frames_queued_together_go_out_lowest_identifier_first(net):
    a, b = net.node("a"), net.node("b")
    got: list[Received] = []
    b.subscribe(got.append)
    frames = [Frame(0x300, b"\x03"), Frame(0x100, b"\x01"), Frame(0x200, b"\x02")]
    _do(net, lambda: [a.send(f) for f in frames])
    net.start()
    assert net.wait(lambda: len(got) == 3)
    assert [ev.frame.can_id for ev in got] == [0x100, 0x200, 0x300]
    assert [ev.frame for ev in got] == sorted(frames, key=lambda f: f.can_id)


def test_fifo_queue_keeps_the_order_frames_were_queued(net):
    a, b = net.node("a", queue="fifo"), net.node("b")
    got: list[Received] = []
    b.subscribe(got.append)
    _do(net, lambda: [a.send(Frame(i, b"")) for i in (0x300, 0x100, 0x200)])
    net.start()
    assert net.wait(lambda: len(got) == 3)
    assert [ev.frame.can_id for ev in got] == [0x300, 0x100, 0x200]


def test_tx_done_and_received_carry_times_and_start_of_frame(net):
    a, b = net.node("a"), net.node("b")
    done: list[TxDone] = []
    got: list[Received] = []
    a.listen(TxDone, done.append)
    b.subscribe(got.append)
    frame = Frame(0x123, bytes(8))
    req = _do(net, lambda: a.send(frame))
    net.start()
    assert net.wait(lambda: done and got)
    assert done[0].request is req and req.state == "sent" and done[0].frame == frame
    assert done[0].time >= req.t_queued and got[0].time >= 0
    caps = a.capabilities
    length_ns = frame.bits.length * a.bit_ns
    if "sof" in caps:
        # the bus time of SOF: exactly one frame length before the end of EOF
        assert got[0].time - got[0].sof == pytest.approx(length_ns, abs=1)
        assert done[0].sof == got[0].sof and req.sof == got[0].sof
    elif "sof-estimate" in caps:
        assert got[0].time - got[0].sof == pytest.approx(length_ns, abs=1)
        assert done[0].time - done[0].sof == pytest.approx(length_ns, abs=1)
    else:  # pragma: no cover - every driver here estimates at least
        assert got[0].sof == -1


def test_bit_time_is_the_bus_bit_time(net):
    a = net.node("a")
    assert a.bit_ns == pytest.approx(1e9 / BITRATE)


def test_acceptance_filters_and_subscription_filters(net):
    a = net.node("a")
    b = net.node("b", filters=[{"can_id": 0x100, "can_mask": 0x700}])
    c = net.node("c")
    gb: list[int] = []
    gc: list[int] = []
    b.subscribe(lambda ev: gb.append(ev.frame.can_id))
    sub = c.subscribe(lambda ev: gc.append(ev.frame.can_id), filters=[{"can_id": 0x200, "can_mask": 0x7FF}])
    _do(net, lambda: [a.send(Frame(i)) for i in (0x101, 0x200, 0x1FF)])
    net.start()
    assert net.wait(lambda: len(gb) == 2 and len(gc) == 1)
    assert sorted(gb) == [0x101, 0x1FF] and gc == [0x200]
    _do(net, sub.unsubscribe)
    _do(net, lambda: a.send(Frame(0x200)))
    # the three frames before reached the node (its acceptance filters pass all), one callback
    # took one of them; without a subscription the next one goes to the FIFO
    assert net.wait(lambda: c.rx_frames == 4)
    assert gc == [0x200] and _do(net, c.recv)[1].can_id == 0x200


def test_receive_fifo_keeps_what_fits_and_counts_overruns(net):
    a, b = net.node("a"), net.node("b", rx_fifo_size=2)
    _do(net, lambda: [a.send(Frame(0x100 + i)) for i in range(5)])
    net.start()
    assert net.wait(lambda: a.tx_frames == 5 and b.rx_frames + b.rx_overruns == 5)
    assert (b.rx_frames, b.rx_overruns) == (2, 3)
    first = _do(net, b.recv)
    assert first is not None and first[1].can_id == 0x100


def test_a_mailbox_answers_remote_frames(net):
    a, b = net.node("a"), net.node("b")
    reply = Frame(0x700, b"\x5a\x5a")
    b.set_remote_reply(reply)
    got: list[Frame] = []
    a.subscribe(lambda ev: got.append(ev.frame))
    _do(net, lambda: a.send(Frame(0x700, remote=True, dlc=2)))
    net.start()
    assert net.wait(lambda: reply in got)


def test_timers_run_in_time_order_and_cancelled_ones_do_not(net):
    a = net.node("a")
    seen: list[str] = []

    def arm() -> None:
        a.call_later(20_000_000, seen.append, "late")
        a.call_later(5_000_000, seen.append, "early")
        t = a.call_later(10_000_000, seen.append, "cancelled")
        t.cancel()
        a.call_at(a.now() + 12_000_000, seen.append, "at")

    _do(net, arm)
    net.start()
    assert net.wait(lambda: len(seen) == 3)
    assert seen == ["early", "at", "late"]


def test_listen_only_node_cannot_send(net):
    a = net.node("a", listen_only=True)
    with pytest.raises(NodeError, match="listen-only"):
        _do(net, lambda: a.send(Frame(0x100)))


def test_latest_start_time_withdraws_a_frame_that_could_not_start(net):
    """TTCAN's transmit-enable window: the tenth frame of a back-to-back burst cannot start
    within 2 ms at 125 kbit/s (each frame with 8 bytes takes about 1 ms) and is withdrawn."""
    if "latest-start" not in net.driver.capabilities:
        pytest.skip("this driver cannot withdraw frames")
    a, b = net.node("a"), net.node("b")
    failed: list[TxFailed] = []
    a.listen(TxFailed, failed.append)
    got: list[int] = []
    b.subscribe(lambda ev: got.append(ev.frame.can_id))

    def burst() -> Any:
        for i in range(9):
            a.send(Frame(0x100 + i, bytes(8)))
        return a.send(Frame(0x200, bytes(8)), not_after=a.now() + 2_000_000)

    late = _do(net, burst)
    net.start()
    assert net.wait(lambda: len(got) == 9 and failed)
    assert late.state == "failed" and failed[0].request is late
    assert failed[0].reason.startswith("not started by")
    assert 0x200 not in got
    # one that can start in time goes out
    ok = _do(net, lambda: a.send(Frame(0x201), not_after=a.now() + 50_000_000))
    assert net.wait(lambda: 0x201 in got) and ok.state == "sent"


def test_local_clock_with_drift_speaks_local_time(net):
    """A node whose oscillator runs 2 % fast: its timers fire after 2 % less bus time, and its
    `now()` and event times are local."""
    a = net.node("a", clock=LocalClock(offset_ns=5_000_000, drift_ppm=20_000))
    ref = net.node("ref")
    fired: list[tuple[int, int]] = []

    def reads() -> tuple[int, int, int]:
        # the local reading between two bus readings: on the wall clock the thread may be
        # preempted between any two of them, never outside the pair
        return ref.now(), a.now(), ref.now()

    def arm() -> None:
        start = reads()
        a.call_later(100_000_000, lambda: fired.append((start, reads())))

    _do(net, arm)
    net.start()
    assert net.wait(lambda: fired)
    (b0, l0, b0_after), (b1, l1, b1_after) = fired[0]
    local_elapsed = l1 - l0
    assert local_elapsed >= 100_000_000
    if net.kind == "sim":
        # exactly 100 ms local = 100 ms / 1.02 of bus time (to the ns the conversion rounds)
        assert b1 - b0 == pytest.approx(100_000_000 / 1.02, abs=2)
        assert local_elapsed == pytest.approx(100_000_000, abs=2)
    else:  # wall clock: local time runs 2 % fast over the bus time between the same instants
        assert (b1 - b0_after) * 1.02 - 2 <= local_elapsed <= (b1_after - b0) * 1.02 + 2


def test_error_counters_and_states_follow_the_driver(net):
    """On the simulated bus the controller's own fault confinement runs (a node alone gets ACK
    errors and goes error passive at TEC 128); on a python-can bus the counters come from the
    bus's SocketCAN error frames (here sent by another connection on the virtual channel)."""
    caps = net.driver.capabilities
    a = net.node("a")
    changes: list[ErrorStateChanged] = []
    a.listen(ErrorStateChanged, changes.append)
    if "error-confinement" in caps:
        _do(net, lambda: a.send(Frame(0x100)))
        net.start()
        assert net.wait(lambda: a.state == "error-passive", limit_s=0.5)
        assert a.tec == 128 and [c.new for c in changes] == ["error-warning", "error-passive"]
    elif "error-frames" in caps:
        net.start()
        other = can.Bus(interface="virtual", channel=net.channel)
        try:  # CAN_ERR_CRTL | CAN_ERR_CNT: controller problem, TEC 130 and REC 5 in data[6]/[7]
            other.send(
                can.Message(
                    is_error_frame=True,
                    arbitration_id=0x004 | 0x200,
                    data=bytes([0, 0x20, 0, 0, 0, 0, 130, 5]),
                    is_extended_id=False,
                )
            )
            assert net.wait(lambda: a.state == "error-passive")
            assert (a.tec, a.rec) == (130, 5) and changes[-1].new == "error-passive"
        finally:
            other.shutdown()
    else:  # pragma: no cover
        pytest.skip("this driver knows no error counters")


def test_arbitration_lost_is_reported_where_the_driver_sees_arbitration(net):
    from stack.controller.events import ArbitrationLost

    if "arbitration-lost" not in net.driver.capabilities:
        pytest.skip("arbitration happens in the controller underneath: not visible to this driver")
    a, b = net.node("a"), net.node("b")
    lost: list[ArbitrationLost] = []
    b.listen(ArbitrationLost, lost.append)
    a.send(Frame(0x100))
    b.send(Frame(0x200))
    net.start()
    assert net.wait(lambda: b.tx_frames == 1)
    assert len(lost) == 1 and lost[0].winner.can_id == 0x100 and lost[0].frame.can_id == 0x200


def test_listening_for_an_event_the_driver_never_reports_is_an_error_not_silence(net):
    # the simulated bus sees every arbitration round; python-can's virtual bus shows none (the
    # controller underneath arbitrates), and PyCanDriver's documentation says so
    from stack.controller.events import ArbitrationLost

    a = net.node("a")
    sees_arbitration = net.kind == "sim"
    assert ("arbitration-lost" in a.capabilities) is sees_arbitration
    if sees_arbitration:
        a.listen(ArbitrationLost, print)
        assert a.unlisten(ArbitrationLost, print)
    else:
        with pytest.raises(
            NodeError,
            match=r"cannot listen for ArbitrationLost: its driver never reports it: that needs the capability 'arbitration-lost'",
        ):
            a.listen(ArbitrationLost, print)
        assert ArbitrationLost not in a.listeners
    # error states: the simulated bus runs fault confinement, PyCanDriver follows the bus's error frames
    a.listen(ErrorStateChanged, print)
    a.listen(TxDone, print)
    a.listen(TxFailed, print)
    with pytest.raises(TypeError, match=r"Received is not an event a node reports.*subscribe"):
        a.listen(Received, print)
    with pytest.raises(TypeError, match="str is not an event a node reports"):
        a.listen(str, print)


def test_a_node_listening_for_what_a_driver_never_reports_is_not_attached_to_it(net):
    from stack.controller.events import ArbitrationLost
    from stack.controller.node import Node

    node = Node("late")
    node.listen(ArbitrationLost, print)  # not attached yet: the driver is checked when it attaches
    if net.kind == "sim":
        net.bus.add(node)
        assert node.bus is net.bus
    else:
        wire = can.Bus(interface="virtual", channel=net.channel)
        try:
            with pytest.raises(NodeError, match=r"listens for ArbitrationLost, but its driver never reports it"):
                net.driver.add(node, wire)
        finally:
            wire.shutdown()
        assert node.bus is None and node not in net.driver.nodes
