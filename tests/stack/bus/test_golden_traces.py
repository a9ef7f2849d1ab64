"""Refactoring guard: three scenarios whose traces (every record, every node's counters) were
digested by the engine of commit 6e071d7, the last one before `stack` was split into layers.
A change that is not meant to change behaviour must keep them byte for byte; a change that is
(a bug fix) must say so in its commit and record the new digests here."""

from __future__ import annotations

import hashlib
import random

from stack.bus.faults import FaultInjector
from stack.bus.sim import SimBus
from stack.cli.demo import build_demo, build_fault_demo
from stack.wire.frame import Frame


def _digest(bus: SimBus) -> str:
    h = hashlib.sha256()
    for r in bus.trace:
        h.update(repr(r.as_tuple()).encode())
    h.update(repr(sorted((n.name, sorted(n.counters().items())) for n in bus.nodes)).encode())
    return h.hexdigest()[:16]


def test_demo_network_trace_is_unchanged():
    bus = SimBus(500_000, seed=1)
    build_demo(bus)
    bus.run(until=1_000_000_000)
    assert (len(bus.trace), _digest(bus)) == (670, "e82455b95a29f0f7")


def test_fault_demo_trace_is_unchanged():
    bus = SimBus(500_000, seed=1)
    build_fault_demo(bus)
    bus.run(until=600_000_000)
    assert (len(bus.trace), _digest(bus)) == (707, "23dcb7b3fd88699d")


def test_random_campaign_with_errors_and_a_disconnect_is_unchanged():
    bus = SimBus(250_000, seed=7)
    nodes = [bus.node(f"n{i}", queue=q) for i, q in enumerate(["priority", "fifo", "mailbox", "priority", "priority"])]
    rng = random.Random(3)
    for i, n in enumerate(nodes):
        if i % 2:
            n.subscribe(lambda ev: None)
        for _ in range(3):
            frame = Frame(rng.randrange(0x800), bytes(rng.randrange(9)))
            n.send_periodic(frame, rng.randrange(1, 5) * 1_000_000, offset=rng.randrange(1000) * 1000)
    fi = FaultInjector(bus)
    fi.bit_errors(2e-4)
    fi.bit_errors(1e-4, nodes=["n2"])
    fi.disconnect("n3", at=100_000_000, reconnect_at=150_000_000)
    bus.run(until=300_000_000)
    assert (len(bus.trace), _digest(bus)) == (739, "84cd2a03e0ceff90")
