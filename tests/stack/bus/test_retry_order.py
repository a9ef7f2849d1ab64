"""What a controller offers after a failed attempt: its queue's head, chosen again.

Each queue policy of `stack.controller.queues` decides the head before every arbitration; an
error does not change the policy. A frame L is on the wire when a better frame H is queued on
the same node; the error destroys L's attempt. What goes next is the policy's choice at that
moment, written here from the policies' definitions (module docstring of the queues):

- priority queue: the pending frame with the lowest key — H;
- FIFO: the oldest — L again;
- one mailbox without abort: L holds it, H waits in the backlog — L again;
- one mailbox with abort: the abort H asked for takes effect once L is off the wire (a transmit
  abort waits for the attempt to end) — H, then L from the backlog;
- two mailboxes, M queued into the second one during the attempt and H behind them in the
  backlog: without abort the mailboxes keep their contents and the best mailbox goes — M, then
  H (refilled into M's mailbox) beats L; with abort H takes M's mailbox at once and, after the
  error, M takes L's — H, M, L, a priority queue's order.
"""

from __future__ import annotations

import random
import time

import can
import pytest

from stack.bus.faults import FaultInjector
from stack.bus.sim import SimBus
from stack.controller.node import Node
from stack.io.driver import RETRY_NS, PyCanDriver
from stack.wire.frame import Frame

L, M, H = Frame(0x700, bytes(8)), Frame(0x600, bytes(8)), Frame(0x080, bytes(8))


def _sent_after_an_error(queue: str, mailboxes: int | None, abort: bool, during: list[Frame]) -> list[int]:
    """L alone on the wire; ``during`` queued 20 bits into it; L's first attempt destroyed (its
    CRC delimiter flipped, a form error for every node). The identifiers in the order sent."""
    bus = SimBus(500_000)
    a = bus.node("a", queue=queue, mailboxes=mailboxes, abort=abort)
    bus.node("b")
    FaultInjector(bus).flip(can_id=L.can_id, field="crc_delim", occurrence=1)
    a.send(L)
    for f in during:
        bus.call_at(bus.bits_to_ns(20), a.send, (f,))
    bus.run(duration=10_000_000)
    kinds = [(r.kind, r.frame.can_id) for r in bus.trace]
    assert kinds[0] == ("error", L.can_id), kinds  # the injected error struck L's first attempt
    assert a.retransmissions == 1
    return [cid for kind, cid in kinds if kind == "frame"]


@pytest.mark.parametrize(
    "queue, mailboxes, abort, during, order",
    [
        ("priority", None, False, [H], [H, L]),
        ("fifo", None, False, [H], [L, H]),
        ("mailbox", 1, False, [H], [L, H]),
        ("mailbox", 1, True, [H], [H, L]),
        ("mailbox", 2, False, [M, H], [M, H, L]),
        ("mailbox", 2, True, [M, H], [H, M, L]),
        ("priority", None, False, [M, H], [H, M, L]),
        ("fifo", None, False, [M, H], [L, M, H]),
    ],
)
def test_after_an_error_the_queue_head_is_chosen_again(queue, mailboxes, abort, during, order):
    assert _sent_after_an_error(queue, mailboxes, abort, during) == [f.can_id for f in order]


def test_without_the_error_the_frame_on_the_wire_goes_first():
    # the control case: the same queuing without a fault sends L first under every policy
    for queue, n, abort in [("priority", None, False), ("fifo", None, False), ("mailbox", 1, True)]:
        bus = SimBus(500_000)
        a = bus.node("a", queue=queue, mailboxes=n, abort=abort)
        bus.node("b")
        a.send(L)
        bus.call_at(bus.bits_to_ns(20), a.send, (H,))
        bus.run(duration=10_000_000)
        assert [r.frame.can_id for r in bus.trace] == [L.can_id, H.can_id]


@pytest.mark.wallclock
def test_a_failed_send_on_python_can_gives_way_to_a_better_frame():
    # PyCanDriver: the python-can bus refuses L's first send; H was queued meanwhile (from the
    # bus's send, under the driver's lock, as another thread's send would be once it has it).
    # A priority queue's next attempt is H; L follows. (The driver never marks a request on the
    # wire — its attempt is one call under the lock — so a send in between already re-selects.)
    class Refusing(can.BusABC):
        def __init__(self) -> None:
            self.sent: list[int] = []
            self.node: Node | None = None
            super().__init__(channel="refusing")

        def send(self, msg: can.Message, timeout: float | None = None) -> None:
            if not self.sent and msg.arbitration_id == L.can_id and self.node is not None:
                node, self.node = self.node, None
                node.send(H)
                raise can.CanOperationError("ENOBUFS")
            self.sent.append(msg.arbitration_id)

        def _recv_internal(self, timeout: float | None) -> tuple[None, bool]:
            return None, False

    wire = Refusing()
    drv = PyCanDriver()
    a = drv.add(Node("a"), wire)
    wire.node = a
    try:
        with drv:
            with drv.lock:
                a.send(L)
            deadline = time.monotonic() + 30.0
            while len(wire.sent) < 2 and time.monotonic() < deadline:
                time.sleep(RETRY_NS / 1e9)
    finally:
        wire.shutdown()
    assert wire.sent == [H.can_id, L.can_id]
    assert a.retransmissions == 1 and a.tx_frames == 2


def _network_with_lonely_spells(seed: int) -> tuple[object, ...]:
    """A seeded network of mixed queue policies whose nodes all leave the bus but one for a few
    spells: the one left gets ACK errors (retransmissions, frames queued during failed
    attempts), then the others come back and the fast loop takes over from that state."""
    rng = random.Random(seed)
    bus = SimBus(rng.choice([250_000, 500_000, 1_000_000]), seed=seed)
    nodes = []
    for i in range(rng.randint(2, 4)):
        policy = rng.choice(["priority", "fifo", "mailbox", "mailbox"])
        kw: dict[str, object] = {"queue": policy}
        if policy == "mailbox":
            kw.update(mailboxes=rng.randint(1, 3), abort=rng.random() < 0.5)
        nodes.append(bus.node(f"n{i}", **kw))
    for n in nodes:
        for _ in range(rng.randint(1, 3)):
            n.send_periodic(
                Frame(rng.randrange(0x800), bytes(rng.randint(0, 8))),
                bus.bits_to_ns(rng.choice([1_500, 4_000, 10_000])),  # a light load: spells stand out
                offset=rng.randint(0, 300_000),
                count=rng.randint(5, 30),
            )
    for k in range(rng.randint(1, 3)):
        start = k * 5_000_000 + rng.randint(0, 3_000_000)  # spells apart: one lonely node each
        lonely = rng.choice(nodes)
        bus.call_at(start + 1, lonely.send, (Frame(rng.randrange(0x800), bytes(rng.randint(0, 8))),))
        for n in nodes:
            if n is not lonely:
                bus.call_at(start, bus.disconnect, (n,))
                bus.call_at(start + rng.randint(200_000, 1_000_000), bus.reconnect, (n,))
    bus.run(until=15_000_000)
    return (
        [r.as_tuple() for r in bus.trace],
        {n.name: n.counters() for n in nodes},
        {n.name: sorted((r.frame.key, r.seq) for r in n.pending()) for n in nodes},
        bus.frames_ok,
        bus.rounds,
    )


@pytest.mark.parametrize("seed", range(40))
def test_fast_loop_matches_the_general_path_after_failed_attempts(monkeypatch, seed):
    monkeypatch.setattr(SimBus, "fast", True)
    fast = _network_with_lonely_spells(seed)
    assert sum(c["retransmissions"] for c in fast[1].values()), "no failed attempt: the test would show nothing"
    monkeypatch.setattr(SimBus, "fast", False)
    assert fast == _network_with_lonely_spells(seed)
