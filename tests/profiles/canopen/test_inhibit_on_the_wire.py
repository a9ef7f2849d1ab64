"""A TPDO's inhibit time counts from its frame's start on the wire (CiA 301: the minimum time
between two transmissions), on a python-can bus too: there ``send`` returns when the frame is
handed over, and behind a ``canstack serve`` bus it reaches the wire later; the device reads the
real start from the bus's timestamp of its own frame (the bus opened with
``receive_own_messages=True``). Measured where a third party sees the frames: the timestamps of a
listener's python-can bus — on ``canstack serve`` the wire's end-of-frame times, so start-to-start
distances of equal frames.

A 10 ms inhibit time and an object that changes every millisecond: no two TPDOs closer than
10 ms. (Before the fix: 9.1 ms gaps behind ``canstack serve``.)"""

from __future__ import annotations

import threading
import time

import can
import pytest

from profiles.canopen import CanopenDevice
from stack.io.driver import PyCanDriver
from stack.io.serve import BusServer

pytestmark = [pytest.mark.wallclock]

INHIBIT_MS = 10
TPDO = {1: {"mapping": ["0x2002:0/32"], "transmission_type": 255, "inhibit_100us": INHIBIT_MS * 10}}


def run_device(interface: str, channel: str, *, own: bool, seconds: float = 0.6, **bus_kwargs):
    """Device 1 (TPDO1 on change, 10 ms inhibit) on a PyCanDriver, operational, its object changed
    every 1 ms; a listener records the TPDO frames' timestamps. Returns those timestamps (s)."""
    listener = can.Bus(interface=interface, channel=channel, **bus_kwargs)
    stamps: list[float] = []
    stop = threading.Event()

    def listen() -> None:
        while not stop.is_set():
            msg = listener.recv(0.05)
            if msg is not None and msg.arbitration_id == 0x181 and not msg.is_error_frame:
                stamps.append(msg.timestamp)

    reader = threading.Thread(target=listen, daemon=True)
    reader.start()
    driver = PyCanDriver(interface=interface, channel=channel, receive_own_messages=own, **bus_kwargs)
    node = driver.node("dev1")
    dev = CanopenDevice(node, 1, heartbeat_ms=0, tpdo=TPDO)
    counter = {"k": 0}

    def change() -> None:
        counter["k"] += 1
        dev.write(0x2002, 0, counter["k"])
        node.call_later(1_000_000, change)

    def begin() -> None:
        dev.start()
        dev.nmt.on_command(bytes([0x01, 1]))  # NMT start
        change()

    driver.start()
    try:
        driver.submit(begin)
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            time.sleep(0.02)
        with driver.lock:
            wire = dev.tpdo(1).wire_starts
    finally:
        driver.close()
        stop.set()
        reader.join(1.0)
        listener.shutdown()
    return stamps, wire


def gaps_ms(stamps: list[float]) -> list[float]:
    return [(b - a) * 1e3 for a, b in zip(stamps, stamps[1:])]


@pytest.mark.socket
def test_behind_canstack_serve_tpdos_are_never_closer_than_the_inhibit_time():
    with BusServer(500_000, listen=("127.0.0.1", 0)) as srv:
        # another node keeps the wire busy with high-priority frames, so TPDOs wait on it
        busy = can.Bus(interface="canstack", channel=srv.url)
        stop = threading.Event()

        def load() -> None:
            while not stop.is_set():
                try:
                    busy.send(can.Message(arbitration_id=0x010, data=bytes(8), is_extended_id=False), timeout=0.1)
                except can.CanError:
                    pass
                time.sleep(0.0005)

        loader = threading.Thread(target=load, daemon=True)
        loader.start()
        try:
            stamps, wire = run_device("canstack", srv.url, own=True)
        finally:
            stop.set()
            loader.join(1.0)
            busy.shutdown()
    gaps = gaps_ms(stamps)
    assert len(gaps) >= 20 and wire >= len(gaps)
    # end-of-frame timestamps of equal-length frames from the wire: start-to-start distances
    assert min(gaps) >= INHIBIT_MS - 0.001, sorted(gaps)[:5]


def test_on_pythons_virtual_bus_tpdos_are_never_closer_than_the_inhibit_time():
    """python-can's virtual bus has no wire time: a frame is stamped when it is handed over, and
    the device counts from that stamp of its own frame."""
    channel = f"inhibit-{time.monotonic_ns()}"
    stamps, wire = run_device("virtual", channel, own=True)
    gaps = gaps_ms(stamps)
    assert len(gaps) >= 20 and wire >= len(gaps)
    assert min(gaps) >= INHIBIT_MS - 0.001, sorted(gaps)[:5]


def test_the_frame_on_the_wire_moves_the_inhibit_time_later_only():
    """`Tpdo.started`: a later start pushes the end of the inhibit time and the event timer out;
    an earlier one (the driver's estimate after the bus's own) changes nothing."""
    from stack import SimBus

    bus = SimBus(500_000)
    d = CanopenDevice(bus.node("d"), 1, heartbeat_ms=0, tpdo={1: dict(TPDO[1], event_timer_ms=50)})
    bus.node("ack")
    d.start()
    d.nmt.on_command(bytes([0x01, 1]))
    bus.run(until=1_000_000)
    tp = d.tpdo(1)
    first = tp.inhibit_until
    tp.on_wire(first - INHIBIT_MS * 1_000_000 + 300_000)  # the bus says it started 0.3 ms later
    assert tp.inhibit_until == first + 300_000 and tp.event_at == first - 10_000_000 + 300_000 + 50_000_000
    tp.on_wire(first - INHIBIT_MS * 1_000_000)  # an earlier start: nothing moves
    assert tp.inhibit_until == first + 300_000
