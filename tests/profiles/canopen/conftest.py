"""Fixtures of the CANopen profile's tests: a simulated bus at 1 Mbit/s, and the ``canopen``
library attached to it as a second implementation (`SimNetwork`).

`SimNetwork` is a ``canopen.Network`` whose frames go through a node of the simulated bus: each
``send_message`` queues the frame and runs the bus for ``step_ns`` of simulated time, so the
answers are in the library's queues before it reads them (its blocking reads then return at
once). Deterministic and fast; the real-time interop tests (`test_interop.py`) run the library
on a real python-can bus instead.
"""

from __future__ import annotations

import canopen
import pytest

from stack import Frame, SimBus

MS = 1_000_000
US = 1_000


class SimNetwork(canopen.Network):
    """The ``canopen`` library's network on a node of a `SimBus` (see the module docstring)."""

    def __init__(self, bus: SimBus, name: str = "canopen-lib", step_ns: int = 2 * MS) -> None:
        super().__init__()
        self.sim = bus
        self.step_ns = step_ns
        self.node = bus.node(name)
        self.frames: list[tuple[int, Frame]] = []  # everything this node received
        self.node.subscribe(self._received)

    def _received(self, ev) -> None:
        self.frames.append((ev.time, ev.frame))
        if not ev.frame.remote:
            self.notify(ev.frame.can_id, bytearray(ev.frame.data), ev.time / 1e9)

    def send_message(self, can_id, data, remote=False):
        data = bytes(data or b"")
        frame = Frame(can_id, remote=True, dlc=len(data)) if remote else Frame(can_id, data)
        self.node.send(frame)
        self.sim.run(until=self.sim.now() + self.step_ns)
        for _ in range(200):  # until every answer is out (a block of 127 segments takes ~17 ms)
            if not any(n.pending() for n in self.sim.nodes):
                break
            self.sim.run(until=self.sim.now() + self.step_ns)

    def run(self, ns: int) -> None:
        """Let the bus run (nothing sent)."""
        self.sim.run(until=self.sim.now() + ns)


@pytest.fixture
def bus():
    return SimBus(1_000_000, seed=7)


@pytest.fixture
def spy(bus):
    """A node recording every frame on the bus: list of (time, Frame)."""
    n = bus.node("spy")
    log: list[tuple[int, Frame]] = []
    n.subscribe(lambda ev: log.append((ev.time, ev.frame)))
    return log


@pytest.fixture
def lib(bus):
    """The canopen library on the simulated bus."""
    net = SimNetwork(bus)
    yield net


@pytest.fixture
def device(bus):
    """``device(node_id, **options)``: a started CanopenDevice on its own node of ``bus``."""
    from profiles.canopen import CanopenDevice

    def make(node_id, eds=None, **options):
        d = CanopenDevice(bus.node(f"dev{node_id}"), node_id, eds, **options)
        d.start()
        return d

    return make


@pytest.fixture
def remote(request, lib, device):
    """Device 5 (default EDS; the test module's ``REMOTE_OPTIONS``, if any, as its options) and
    the canopen library's RemoteNode for it."""
    from profiles.canopen.dictionary import DEFAULT_EDS

    dev = device(5, **getattr(request.module, "REMOTE_OPTIONS", {}))
    node = canopen.RemoteNode(5, str(DEFAULT_EDS))
    lib.add_node(node)
    lib.run(2 * MS)
    return dev, node


@pytest.fixture
def master_node(bus):
    """A plain node that plays master by hand: ``master_node.send(Frame(...))``."""
    return bus.node("master")


def _frames_with(log, can_id, *, remote=False):
    return [(t, f) for t, f in log if f.can_id == can_id and f.remote == remote]


@pytest.fixture
def frames_with():
    """``frames_with(log, can_id, remote=False)``: the (time, Frame) of ``log`` with that ID."""
    return _frames_with
