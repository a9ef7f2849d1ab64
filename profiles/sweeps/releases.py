"""A `profiles.sweeps.networks.Network` on the simulated bus, released in a chosen pattern, and
what every instance measured — the quantities the response-time analysis bounds.

A network with a data bit rate runs on a CAN FD bus (`stack.SimBus`'s ``data_bitrate``), each
node with its ``fd`` (FD-enabled, or a tolerant classical controller) and the silent receiver
that acknowledges every frame FD-enabled. Bit times below (the blocker's head start, an error's
place) are nominal bits.

Release patterns (`PATTERNS`). Each message's instances are nominally released every T on its
node's clock (which may drift) and queued up to J later:

- ``random`` — the first nominal release uniform in [0, T], each queuing delay uniform in [0, J];
- ``critical`` — Davis et al. 2007's critical instant: every message's first instance queued at
  the same bus instant with its full jitter J (nominal release J earlier), the later ones on
  time, and the longest frame in time (or ``blocker``) queued one bit earlier so that it is on
  the wire then;
- ``alternate`` — random first release, the queuing delay alternating J, 0, J, 0, …: a late
  instance followed at once by an early one;
- ``extremes`` — random first release, each queuing delay J or 0 at random (a pattern of 64
  repeated).

Measured per message (`Measured`): ``queued``, the worst time from an instance's queuing (its
entering the node's queue) to the end of its frame's EOF at the transmitter — the quantity
``RtaResult.bound_ns`` bounds, less the 3-bit intermission that bound counts; ``nominal``, the
worst time from its nominal release to the end of EOF — what ``response_ns`` bounds; ``misses``,
instances ending more than D after their nominal release (the analysis' reference for
``schedulable``). An instance still pending when the run ends counts with the time it has waited
so far: a bound it has already passed is broken whether or not it is ever sent.

The bus also counts its error frames (`Run.error_frames`): without an error model there must be
none — the analysis assumes an error-free bus, and a tolerant node integrates on FD frames
rather than destroy them — which `run_network`'s caller checks.

Errors (`TimedErrors`), when the network has an error model: errors are placed by time, the
first burst at ``first_error_ns`` (random in [0, 2 ms] by default), so that no window of
T_error holds more than the model's ``burst`` errors. The analysis assumes error-active nodes:
a run in which a node leaves that state raises `ModelAssumptionError`.
"""

from __future__ import annotations

import random
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from profiles.sweeps.networks import MS, NetMsg, Network
from stack import ErrorState, FaultInjector, LocalClock, Node, RequestState, SimBus
from stack.io.progress import run_sliced
from stack.wire.coding import Field

__all__ = [
    "PATTERNS",
    "Measured",
    "TimedErrors",
    "Release",
    "ModelAssumptionError",
    "Run",
    "run_network",
    "simulate",
    "simulation_duration",
]

PATTERNS = {
    "random": "random first release, queuing delays uniform in [0, J]",
    "critical": "Davis et al. 2007's critical instant: all first instances queued at once, full jitter, "
    "a lower-priority frame on the wire",
    "alternate": "queuing delays alternating J, 0, J, 0, …",
    "extremes": "queuing delays J or 0 at random",
}
"""The release patterns and what each does (see the module docstring)."""

#: bus time of the critical instant: late enough for every drifting clock to have started
CRITICAL_AT_NS = 2 * MS
#: the longest run `simulation_duration` gives
MAX_DURATION_NS = 300 * MS


class ModelAssumptionError(RuntimeError):
    """A run left the conditions the analysis assumes (a node not error active, an error model
    that injected nothing): its measurements say nothing about the bounds."""


@dataclass
class Measured:
    """One message's worst times over a run, ns (see the module docstring)."""

    queued: int = 0
    nominal: int = 0
    sent: int = 0
    misses: int = 0


@dataclass
class Run:
    """One simulation of a network: each message's `Measured`, by name, and the error frames
    the bus saw (each error the error model injected makes one)."""

    measured: dict[str, Measured]
    error_frames: int


class TimedErrors(FaultInjector):
    """Errors by time: the first attempt starting at or after each scheduled instant, and the
    ``burst`` − 1 attempts after it, have their CRC delimiter flipped (a bit error for the
    transmitter, a form error for the receivers); the next burst starts ``t_error_ns`` after the
    last error of the previous one, so no window of T_error holds more than ``burst`` errors.
    An error's time counts every bit before it as a nominal bit: on a CAN FD bus it is late by
    what the data phase saves, and the next burst comes later still, within the model."""

    def __init__(self, bus: SimBus, t_error_ns: int, burst: int, first_ns: int) -> None:
        super().__init__(bus)
        self.t_error_ns = t_error_ns
        self.burst = burst
        self.next_at = first_ns
        self.left = 0
        self.times: list[int] = []

    def attempt(self, bus: SimBus, now: int, txs: Sequence[Any]) -> dict[str, Any] | None:
        """The base injector's faults, and a flipped CRC delimiter when an error is due."""
        spec = super().attempt(bus, now, txs)
        if self.left == 0 and now >= self.next_at:
            self.left = self.burst
        if self.left == 0:
            return spec
        pos = txs[0].frame.bits.fields[Field.CRC_DELIM][0]
        if spec is None:
            spec = {"flips": {}, "stuck": None, "deaf": [], "overload": None, "leave": None}
        spec["flips"][pos] = None
        t = now + pos * 10**9 // bus.bitrate
        self.times.append(t)
        self.left -= 1
        if self.left == 0:
            self.next_at = t + self.t_error_ns + 10**9 // bus.bitrate
        return spec


class Release:
    """Queues message ``m`` on ``node`` at its nominal releases (node clock) plus a queuing delay:
    the ``pattern`` list repeated (or ``after`` once the list is used up, if given), else uniform
    in [0, J] from ``rng``; logs each request with its nominal release as a bus time."""

    def __init__(
        self,
        m: NetMsg,
        node: Node,
        log: list[tuple[Any, int]],
        pattern: list[int] | None,
        after: int | None,
        rng: random.Random | None = None,
    ) -> None:
        if pattern is None and rng is None:
            raise ValueError(f"{m.name}: random queuing delays need an rng")
        self.m, self.node, self.log = m, node, log
        self.frame = m.frame
        self.pattern, self.after, self.rng = pattern, after, rng
        self.i = 0

    def jitter(self) -> int:
        """The queuing delay of the next instance."""
        i, p = self.i, self.pattern
        if p is None:
            return self.rng.randint(0, self.m.jitter_ns)  # type: ignore[union-attr]
        if i < len(p) or self.after is None:
            return p[i % len(p)]
        return self.after

    def start(self, nominal: int) -> None:
        """Schedule the instance nominally released at ``nominal`` (node clock)."""
        self.node.call_at(nominal + self.jitter(), self.fire, nominal)

    def fire(self, nominal: int) -> None:
        """Queue the instance and schedule the next."""
        req = self.node.send(self.frame)
        self.log.append((req, self.node.to_bus(nominal)))
        self.i += 1
        self.start(nominal + self.m.period_ns)


def simulation_duration(net: Network) -> int:
    """Bus time to simulate ``net``: 2 ms and twelve of its longest T + J (every message goes
    through several busy periods), at most `MAX_DURATION_NS`."""
    return min(MAX_DURATION_NS, 2 * MS + 12 * max(m.period_ns + m.jitter_ns for m in net.messages))


def simulate(
    net: Network,
    pattern: str,
    seed: int,
    duration_ns: int | None = None,
    blocker: str | None = None,
    first_error_ns: int | None = None,
) -> dict[str, Measured]:
    """`run_network`'s measurements alone."""
    return run_network(net, pattern, seed, duration_ns, blocker, first_error_ns).measured


def run_network(
    net: Network,
    pattern: str,
    seed: int,
    duration_ns: int | None = None,
    blocker: str | None = None,
    first_error_ns: int | None = None,
) -> Run:
    """Run ``net`` on `stack.SimBus` (a CAN FD bus when it has a data bit rate) with releases in
    ``pattern`` (`PATTERNS`) for ``duration_ns`` (default `simulation_duration`) and measure every
    instance (see the module docstring). In the critical pattern, ``blocker`` (default: the
    longest frame in time) is queued one nominal bit before the others. The same arguments give
    the same measurements. Ctrl-C raises KeyboardInterrupt; a wall-clock limit
    (`stack.io.progress.time_limit`) raises there too."""
    if pattern not in PATTERNS:
        raise ValueError(f"release pattern {pattern!r}: one of {', '.join(PATTERNS)}")
    if duration_ns is None:
        duration_ns = simulation_duration(net)
    rng = random.Random(seed)
    bus = SimBus(net.bitrate, data_bitrate=net.data_bitrate, seed=seed, record=False)
    nodes: dict[str, Node] = {}
    for n in net.nodes:
        clock = LocalClock(n.offset_ns, n.drift_ppm) if n.drift_ppm else None
        nodes[n.name] = bus.node(n.name, queue=n.queue, mailboxes=n.mailboxes, abort=n.abort, clock=clock, fd=n.fd)
    bus.node("ack")  # a silent receiver (FD-enabled on an FD bus): every frame is acknowledged
    injector = None
    if net.errors is not None:
        first = rng.randint(0, 2 * MS) if first_error_ns is None else first_error_ns
        injector = TimedErrors(bus, net.errors.t_error_ns, net.errors.burst, first)
    log: dict[str, list[tuple[Any, int]]] = {m.name: [] for m in net.messages}
    tau = 10**9 // net.bitrate
    if blocker is None:
        blocker = max(
            net.messages, key=lambda m: (m.frame.bits.duration_ns(net.bitrate, net.data_bitrate), m.can_id)
        ).name

    for m in net.messages:
        node = nodes[m.node]
        if pattern == "critical":
            first = node.to_local(CRITICAL_AT_NS - tau if m.name == blocker else CRITICAL_AT_NS)
            Release(m, node, log[m.name], [m.jitter_ns], 0).start(first - m.jitter_ns)
        else:
            nominal0 = node.now() + rng.randint(0, m.period_ns)
            own = random.Random(rng.random())
            if pattern == "random":
                extremes = None
            elif pattern == "alternate":
                extremes = [m.jitter_ns, 0]
            else:
                extremes = [m.jitter_ns if own.random() < 0.5 else 0 for _ in range(64)]
            Release(m, node, log[m.name], extremes, None, own).start(nominal0)

    if not run_sliced(bus, duration_ns, progress=False):
        raise KeyboardInterrupt
    _check_assumptions(net, nodes, injector)
    end = bus.now()
    out: dict[str, Measured] = {}
    for m in net.messages:
        r = out[m.name] = Measured()
        for req, nominal_bus in log[m.name]:
            if req.state is RequestState.SENT:
                q, n = req.t_done - req.t_queued, req.t_done - nominal_bus
                r.sent += 1
                r.misses += n > m.deadline_ns
            elif req.state is RequestState.QUEUED:
                q, n = end - req.t_queued, end - nominal_bus
            else:
                raise ModelAssumptionError(f"{m.name}: a request ended {req.state.name}, neither sent nor pending")
            r.queued = max(r.queued, q)
            r.nominal = max(r.nominal, n)
    return Run(out, bus.error_frames)


def _check_assumptions(net: Network, nodes: dict[str, Node], injector: TimedErrors | None) -> None:
    if injector is None:
        return
    if not injector.times:
        raise ModelAssumptionError(f"{net.label or 'network'}: the error model injected no error in the run")
    for n in nodes.values():
        if n.state not in (ErrorState.ACTIVE, ErrorState.WARNING):
            raise ModelAssumptionError(f"node {n.name} is {n.state}: the analysis assumes error-active nodes")
