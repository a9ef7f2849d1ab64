"""A python-can bus that goes away under `PyCanDriver`: noticed at once (the served bus's socket
closes, an interface is shut down, a receive that keeps failing), reported once with the bus and
the time, and never retried in a loop that holds the driver."""

import os
import threading
import time

import can
import pytest

from stack.controller.node import Node
from stack.io.driver import RECV_FAILURES_LOST, RETRY_NS, PyCanDriver
from stack.io.errors import BusLost
from stack.io.serve import BusServer
from stack.wire.frame import Frame

pytestmark = pytest.mark.wallclock


class _Dead(can.BusABC):
    """A bus whose sends fail (a congested or unplugged controller) and whose receive says
    nothing, or fails when ``recv_error`` is given."""

    def __init__(self, recv_error=None):
        self.sends = 0
        self.recv_error = recv_error
        super().__init__(channel="dead")

    def send(self, msg, timeout=None):
        self.sends += 1
        raise can.CanOperationError("ENOBUFS")

    def _recv_internal(self, timeout):
        if self.recv_error is not None:
            raise self.recv_error
        time.sleep(min(timeout or 0, 0.01))
        return None, False


def test_a_node_waiting_for_its_retry_does_not_hold_the_driver():
    """The head of a node whose send failed waits `RETRY_NS` for its next try; `_transmit`
    hands it back with that time instead of going round until the time has come (which held the
    driver's lock and a core for as long: 50-100 % CPU on a bus that had gone away)."""
    dead = _Dead()
    drv = PyCanDriver()
    node = drv.add(Node("n"), dead)
    with drv.lock:
        node.send(Frame(0x1, b"\x01"))
        assert drv._transmit() is not None and dead.sends == 1  # failed: a retry 1 ms later
        req = node.head
        retry_at = drv.now() + 10_000_000_000  # as if the retry were 10 s away
        drv._retry[req] = retry_at
        drv.offer(node, req)
        done = []
        th = threading.Thread(target=lambda: done.append(drv._transmit()))
        th.start()
        th.join(5.0)
        assert done == [retry_at], "the transmit loop went round until the retry time"
        assert drv.now() < retry_at and dead.sends == 1
    dead.shutdown()


@pytest.mark.socket
def test_a_served_bus_that_stops_is_noticed_at_once_with_its_name_and_time():
    with BusServer(500_000, listen=("127.0.0.1", 0)) as srv:
        url = srv.url
        peer = can.Bus(interface="canstack", channel=url)  # acknowledges
        drv = PyCanDriver(interface="canstack", channel=url)
        node = drv.node("ecu")
        seen = []
        drv.on_lost.append(seen.append)
        drv.start()
        try:
            drv.submit(lambda: node.send_periodic(Frame(0x100, b"\x01"), 5_000_000))
            assert peer.recv(30.0) is not None
            t_stop = drv.now()
            srv.close()  # the server goes away mid-run
            assert drv.gone.wait(30.0)
        finally:
            drv.close()
            peer.shutdown()
    lost = drv.lost
    assert lost is not None and seen == [lost]
    assert lost.node == "ecu" and url in lost.bus and lost.t_ns >= t_stop
    assert "closed the connection" in lost.reason
    line = lost.describe()
    assert line.startswith(f"bus canstack {url} lost at ") and "\n" not in line
    # nothing is handed to a bus that is gone: no frame is retried, no error repeats; the loss is
    # the one error (for owners that read only `errors`)
    assert drv.errors == [f"ecu: {line}"]


def test_an_interface_shut_down_under_the_driver_is_noticed():
    ch = f"lost{os.getpid()}"
    bus = can.Bus(interface="virtual", channel=ch)
    drv = PyCanDriver()
    drv.add(Node("n"), bus)
    with drv:
        bus.shutdown()
        assert drv.gone.wait(30.0)
    assert drv.lost.node == "n" and drv.lost.bus == bus.channel_info


def test_a_receive_that_keeps_failing_means_the_bus_is_gone():
    dead = _Dead(recv_error=can.CanOperationError("Network is down"))
    drv = PyCanDriver()
    drv.add(Node("n"), dead)
    with drv:
        assert drv.gone.wait(30.0)
    assert drv.lost.reason == f"receive keeps failing ({RECV_FAILURES_LOST} tries): Network is down"
    # said once, not every 50 ms, then the loss
    assert drv.errors == ["n: receive failed: Network is down", f"n: {drv.lost.describe()}"]
    dead.shutdown()


@pytest.mark.socket
def test_bus_lost_is_what_a_canstack_bus_raises_once_its_server_is_gone(drain):
    with BusServer(500_000, listen=("127.0.0.1", 0)) as srv:
        bus = can.Bus(interface="canstack", channel=srv.url)
    try:
        for _ in range(2):  # and it keeps saying so
            with pytest.raises(BusLost, match="is gone: the server closed the connection"):
                bus.recv(30.0)
        with pytest.raises(can.CanOperationError, match="is gone"):  # python-can's own class
            bus.send(can.Message(arbitration_id=1, is_extended_id=False))
    finally:
        bus.shutdown()


def test_retries_still_happen_on_a_bus_that_is_only_congested():
    # a send that fails (ENOBUFS) is retried as before: congestion is not a lost bus
    dead = _Dead()
    drv = PyCanDriver()
    node = drv.add(Node("n"), dead)
    with drv:
        with drv.lock:
            node.send(Frame(0x1, b"\x01"))
        end = time.monotonic() + 30.0
        while dead.sends < 3 and time.monotonic() < end:
            time.sleep(RETRY_NS / 1e9)
    dead.shutdown()
    assert dead.sends >= 3 and drv.lost is None
