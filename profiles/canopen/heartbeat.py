"""Heartbeat (CiA 301 7.2.8.3.2.2): the producer (object 0x1017, producer heartbeat time in ms)
and the consumer (object 0x1016, consumer heartbeat time: bits 23..16 node-ID, bits 15..0 time
in ms).

The heartbeat message is COB-ID 0x700 + node-ID with one byte, the NMT state (0 boot-up, 4
stopped, 5 operational, 127 pre-operational). A producer time of 0 disables the producer. As in
CANopenNode, the producer also sends at once when the NMT state changes and then counts its
period from there (a master learns of a stop without waiting for the next period).

The consumer starts monitoring a node at its first heartbeat (CANopenNode's "unknown" until
then) and reports a heartbeat event when the consumer time passes without one; after a timeout
it goes on counting each further consumer time without a heartbeat as ``missed``. A boot-up
message from a node that was being monitored is a remote reset (CANopenNode reports both with
EMCY 0x8130, "life guard error or heartbeat error").
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from profiles.canopen import cob
from profiles.canopen._state import NmtState, state_name
from profiles.canopen.sdo import abort
from profiles.canopen.sdo.abort import SdoAbort
from stack import Frame

__all__ = [
    "HeartbeatProducer",
    "HeartbeatConsumer",
    "MonitoredNode",
    "consumer_entry",
    "parse_consumer_entry",
    "check_consumer_entry",
]

MS = 1_000_000


def consumer_entry(node_id: int, time_ms: int) -> int:
    """The 0x1016 sub-index value for monitoring ``node_id`` with ``time_ms`` (CiA 301 7.5.2.x:
    bits 23..16 node-ID, bits 15..0 heartbeat time in ms, bits 31..24 reserved 0)."""
    if not 0 <= node_id <= 127 or not 0 <= time_ms <= 0xFFFF:
        raise ValueError(f"consumer heartbeat entry: node-ID {node_id!r} 0..127 and time {time_ms!r} 0..65535 ms")
    return (node_id << 16) | time_ms


def parse_consumer_entry(value: int) -> tuple[int, int]:
    """(node-ID, time in ms) of a 0x1016 sub-index value."""
    return (value >> 16) & 0xFF, value & 0xFFFF


def check_consumer_entry(sub: int, value: int, entries: dict[int, int]) -> None:
    """Validator of 0x1016 sub-index ``sub`` among the current ``entries`` ({sub: value}):
    bits 31..24 reserved and a node-ID 0..127 (0x0609 0030), and no node monitored twice with a
    non-zero time (0x0604 0043, CANopenNode's parameter incompatibility)."""
    if sub == 0:
        return
    nid, ms = parse_consumer_entry(value)
    if value >> 24 or nid > 127:
        raise SdoAbort(abort.INVALID_VALUE, f"0x1016:{sub}: bits 31..24 are reserved (0), node-ID 0..127")
    if nid and ms:
        for k, other_value in entries.items():
            other, other_ms = parse_consumer_entry(other_value)
            if k != sub and other == nid and other_ms:
                raise SdoAbort(
                    abort.PARAMETER_INCOMPATIBLE, f"0x1016:{sub}: node {nid} is monitored by sub-index {k} already"
                )


class HeartbeatProducer:
    """Sends the heartbeat of ``node_id`` every ``period_ms`` (object 0x1017).

    ``send(frame)`` queues a frame, ``call_at(t, cb)`` arms a timer, ``now()`` reads the node's
    clock, ``state()`` gives the NMT state to report. ``sent`` counts heartbeats queued.
    """

    def __init__(
        self,
        node_id: int,
        send: Callable[[Frame], Any],
        call_at: Callable[..., Any],
        now: Callable[[], int],
        state: Callable[[], NmtState],
    ) -> None:
        self.cob_id = cob.HEARTBEAT + node_id
        self.send = send
        self.call_at = call_at
        self.now = now
        self.state = state
        self.period_ns = 0
        self.running = False
        self._timer: Any = None
        self._next = 0
        self.sent = 0

    def configure(self, period_ms: int) -> None:
        """A new producer heartbeat time (a write of 0x1017): 0 stops the producer; otherwise
        a heartbeat goes out now and then every period (CANopenNode restarts the same way)."""
        self.period_ns = period_ms * MS
        if self.running:
            self._cancel()
            if self.period_ns:
                self._beat()

    def start(self) -> None:
        """Begin producing after the boot-up message: the first heartbeat one period later."""
        self.running = True
        self._cancel()
        if self.period_ns:
            self._next = self.now() + self.period_ns
            self._timer = self.call_at(self._next, self._tick)

    def stop(self) -> None:
        """Stop producing (the device stops, or resets)."""
        self.running = False
        self._cancel()

    def state_changed(self) -> None:
        """The NMT state changed: report it at once, then every period from now."""
        if self.running and self.period_ns:
            self._cancel()
            self._beat()

    def _beat(self) -> None:
        self.send(Frame(self.cob_id, bytes([int(self.state())])))
        self.sent += 1
        self._next = self.now() + self.period_ns
        self._timer = self.call_at(self._next, self._tick)

    def _tick(self) -> None:
        self._timer = None
        if not self.running or not self.period_ns:
            return
        self.send(Frame(self.cob_id, bytes([int(self.state())])))
        self.sent += 1
        self._next += self.period_ns  # on the period's grid: no drift from callback latency
        self._timer = self.call_at(self._next, self._tick)

    def _cancel(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None


@dataclass
class MonitoredNode:
    """What the consumer knows of one node (CANopenNode's CO_HBconsNode_t)."""

    node_id: int
    time_ns: int
    status: str = "unknown"  # unknown (no heartbeat yet) -> active -> timeout
    state: int | None = None
    received: int = 0
    missed: int = 0
    timeouts: int = 0
    remote_resets: int = 0
    lost: bool = False  # a timeout not yet followed by a heartbeat
    remote_reset: bool = False  # the last boot-up came while the node was being monitored
    last: int | None = None
    timer: Any = field(default=None, repr=False)

    @property
    def state_name(self) -> str:
        """The last state reported, by name ('UNKNOWN' before the first heartbeat)."""
        return "UNKNOWN" if self.state is None else state_name(self.state)


class HeartbeatConsumer:
    """Monitors the heartbeats of other nodes (object 0x1016, CiA 301 7.2.8.3.2.2).

    ``on_timeout(node)``, ``on_resume(node)`` (heartbeats again after a timeout),
    ``on_state(node, old, new)`` and ``on_bootup(node)`` are called with the `MonitoredNode`;
    ``call_at``/``now`` are the node's timers and clock.
    """

    def __init__(
        self,
        call_at: Callable[..., Any],
        now: Callable[[], int],
        *,
        on_timeout: Callable[[MonitoredNode], Any] | None = None,
        on_state: Callable[[MonitoredNode, int | None, int], Any] | None = None,
        on_bootup: Callable[[MonitoredNode], Any] | None = None,
        on_resume: Callable[[MonitoredNode], Any] | None = None,
    ) -> None:
        self.call_at = call_at
        self.now = now
        self.on_timeout = on_timeout
        self.on_resume = on_resume
        self.on_state = on_state
        self.on_bootup = on_bootup
        self.nodes: dict[int, MonitoredNode] = {}

    def configure(self, entries: list[tuple[int, int]]) -> None:
        """Monitor these (node-ID, time ms) pairs; node-ID 0 or time 0 leaves an entry unused
        (CiA 301). Monitoring of a node kept with the same time goes on undisturbed."""
        wanted = {nid: ms for nid, ms in entries if nid and ms}
        for nid in list(self.nodes):
            if nid not in wanted or self.nodes[nid].time_ns != wanted[nid] * MS:
                self._drop(nid)
        for nid, ms in wanted.items():
            if nid not in self.nodes:
                self.nodes[nid] = MonitoredNode(nid, ms * MS)

    def observe(self, node_ids: list[int]) -> None:
        """Follow these nodes' heartbeats and boot-ups without a consumer time (no timeout)."""
        for nid in node_ids:
            if nid not in self.nodes:
                self.nodes[nid] = MonitoredNode(nid, 0)

    def stop(self) -> None:
        """Stop monitoring (timers cancelled, nodes back to unknown)."""
        for m in self.nodes.values():
            if m.timer is not None:
                m.timer.cancel()
                m.timer = None
            m.status = "unknown"

    def _drop(self, nid: int) -> None:
        m = self.nodes.pop(nid)
        if m.timer is not None:
            m.timer.cancel()

    def cob_ids(self) -> list[int]:
        """The heartbeat COB-IDs to receive."""
        return [cob.HEARTBEAT + nid for nid in self.nodes]

    def on_heartbeat(self, node_id: int, data: bytes, t: int) -> None:
        """A heartbeat (or boot-up) of ``node_id`` received at ``t``."""
        m = self.nodes.get(node_id)
        if m is None or len(data) < 1:
            return
        state = data[0] & 0x7F
        m.received += 1
        m.last = t
        if state == NmtState.INITIALISING:
            m.remote_reset = m.status == "active"
            if m.remote_reset:
                m.remote_resets += 1
            old = m.state
            m.state = state
            m.status = "unknown"  # monitoring starts again with the next heartbeat
            if m.timer is not None:
                m.timer.cancel()
                m.timer = None
            if self.on_bootup is not None:
                self.on_bootup(m)
            if old != state and self.on_state is not None:
                self.on_state(m, old, state)
            return
        old = m.state
        m.state = state
        m.status = "active"
        if m.lost:
            m.lost = False
            if self.on_resume is not None:
                self.on_resume(m)
        if m.timer is not None:
            m.timer.cancel()
            m.timer = None
        if m.time_ns:
            m.timer = self.call_at(t + m.time_ns, self._expired, m, t + m.time_ns)
        if old != state and self.on_state is not None:
            self.on_state(m, old, state)

    def _expired(self, m: MonitoredNode, due: int) -> None:
        m.timer = None
        m.missed += 1
        if m.status == "active":
            m.status = "timeout"
            m.lost = True
            m.timeouts += 1
            if self.on_timeout is not None:
                self.on_timeout(m)
        m.timer = self.call_at(due + m.time_ns, self._expired, m, due + m.time_ns)
