"""The contract between a controller (`stack.controller.node.Node`) and the driver it is attached
to — the simulated bus (`stack.bus.sim.SimBus`) or a python-can bus (`stack.io.driver.PyCanDriver`).

The controller owns it: drivers import this module and implement `Driver`; nothing here imports a
driver. It has two halves.

**What a node asks of its driver** (`Driver`): the bus clock and timers (`now`, `call_at`), the
bit time, a sequence number per request so that requests order deterministically (`next_seq`),
and notifications: a request to arbitrate (`offer`), lazily buffered receptions to bring up to
date before the node is read (`sync`, with `delivered` to tell whether anything is pending),
subscriptions, listeners or modes that changed (`node_changed`), acceptance filters or remote
replies that changed (`filters_changed`), error counters that changed (`counters_changed`), a
fault-confinement state change (`state_changed`) and a bus-off recovery to start
(`start_recovery`). ``capabilities`` says which node-level facts the driver can know (see
`CAPABILITIES`), so that profiles and the conformance tests can tell "not known here" from
"did not happen". A driver of a CAN FD bus has a ``data_bitrate`` (the bit rate of the data phase,
None or absent on a classical bus): a node whose `Node.fd` was not given is FD enabled on it.

**What a driver may do with a node** — its public driver-side surface, all documented on `Node`:
read ``offered`` (the request it offers to arbitration now), ``queue``, ``acceptance``,
``connected``, ``listen_only``, ``receive_own_messages``, ``rounds_lost``, ``listeners`` and
``tx_done_listeners`` (its `TxDone` callbacks, None when there are none); keep its own
per-node bookkeeping in ``on_bus``, ``suspended``, ``ready_at`` and ``rx_cursor`` (these four
are written only by the driver); and report through the methods `confirm` (a transmission
succeeded; it returns the next request for the driver to offer), `fail` (it will not be sent),
`retry` (an attempt failed and will be repeated), `deliver` (a valid frame was received),
`absorb` (a batch of lazily logged receptions), `count_overruns`, `remote_reply`,
`settle_losses`, `set_counters` and `recovered`. Before it attaches a node, a driver calls its
`check_listeners` with its capabilities: a node never waits in silence for an event its driver
does not report (`listen_refusal`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any, Protocol

from stack.controller.events import ArbitrationLost, ErrorStateChanged, TxDone, TxFailed

if TYPE_CHECKING:  # pragma: no cover
    from stack.controller.confinement import ErrorState
    from stack.controller.node import Node
    from stack.controller.queues import TxRequest

__all__ = ["Driver", "Timer", "CAPABILITIES", "REPORTED_WITH", "listen_refusal"]

CAPABILITIES = {
    "bus-time": "event times are the bus's own times (the simulated clock, or the bus's receive timestamps)",
    "sof": "start-of-frame times are exact (the bus time of the SOF bit)",
    "sof-estimate": "start-of-frame times are estimated from the end of frame minus the frame's length",
    "arbitration-lost": "ArbitrationLost events: the node learns each round it lost and to which frame",
    "error-confinement": "the driver runs the 12 fault-confinement rules: TEC/REC and ErrorStateChanged",
    "error-frames": "TEC/REC and state changes as the bus underneath reports them (SocketCAN error frames)",
    "one-shot": "one-shot requests are not retransmitted",
    "latest-start": "requests with a latest start time (not_after) are withdrawn when it passes",
}
"""Names a driver may list in its ``capabilities``, and what each promises."""

REPORTED_WITH: dict[type, tuple[str, ...]] = {
    TxDone: (),
    TxFailed: (),
    ArbitrationLost: ("arbitration-lost",),
    ErrorStateChanged: ("error-confinement", "error-frames"),
}
"""The events a node reports to `listen` callbacks, each with the capabilities of which its
driver needs one to report it (none: every driver reports it)."""


def listen_refusal(event_type: Any, capabilities: frozenset[str]) -> str | None:
    """Why a node on a driver with ``capabilities`` may not listen for ``event_type``, or None
    when it may: a type that is no event of the node's is never reported (received frames go to
    `subscribe`), and neither is an event that needs a capability the driver lacks (an
    `ArbitrationLost` where arbitration happens in the controller underneath). Listening for it
    would wait in silence."""
    needs = REPORTED_WITH.get(event_type)
    if needs is None:
        name = getattr(event_type, "__name__", repr(event_type))
        known = ", ".join(t.__name__ for t in REPORTED_WITH)
        hint = " (received frames: subscribe)" if name == "Received" else ""
        return f"{name} is not an event a node reports: it reports {known}{hint}"
    if needs and not capabilities.intersection(needs):
        have = ", ".join(sorted(capabilities)) or "none"
        return (
            "its driver never reports it: that needs the capability "
            f"{' or '.join(repr(c) for c in needs)} (the driver's capabilities: {have})"
        )
    return None


class Timer:
    """A pending callback on a driver's clock; `cancel()` stops it from running. ``time`` is the
    driver's (bus) time it is due at."""

    __slots__ = ("time", "callback", "args", "cancelled")

    def __init__(self, time: int, callback: Callable[..., Any], args: tuple[Any, ...]) -> None:
        self.time = time
        self.callback = callback
        self.args = args
        self.cancelled = False

    def cancel(self) -> None:
        """Do not run the callback."""
        self.cancelled = True

    def __lt__(self, other: Timer) -> bool:  # pragma: no cover - heap entries carry a seq
        return self.time < other.time


class Driver(Protocol):
    """What a node needs from the driver it is attached to (see the module docstring)."""

    rounds: int
    """Arbitration rounds so far (a node counts the rounds its offered request lost against it)."""
    delivered: int
    """Receptions logged for lazy receivers so far; a node whose ``rx_cursor`` equals it is up to
    date (a driver that delivers at once keeps it at 0)."""
    bit_ns: float | None
    """The bit time of the bus in ns, or None when the driver does not know the bitrate."""
    now_ns: int
    """The current bus time, ns, as `now()` gives it — an attribute a node reads without a call
    where it pays (`Node.send`, once per frame, on the engine's hot path); read-only
    to nodes (a driver with a live clock makes it a property)."""
    capabilities: frozenset[str]
    seqs: Iterator[int]
    """Increasing sequence numbers, shared by requests and timers (``next(driver.seqs)``: a C
    call, cheaper than a method on the per-frame path of `Node.send`)."""

    def now(self) -> int: ...
    def call_at(self, time: int, callback: Callable[..., Any], args: tuple[Any, ...] = ()) -> Timer: ...
    def offer(self, node: Node, req: TxRequest) -> None: ...
    def sync(self, node: Node) -> None: ...
    def node_changed(self, node: Node) -> None: ...
    def filters_changed(self, node: Node) -> None: ...
    def counters_changed(self, node: Node) -> None: ...
    def state_changed(self, node: Node, old: ErrorState, new: ErrorState, t: int) -> None: ...
    def start_recovery(self, node: Node) -> None: ...
