"""Node guarding and life guarding (CiA 301 7.2.8.3.2.1), the remote-frame based error control
protocol that heartbeat replaced.

The master sends a remote frame on COB-ID 0x700 + node-ID every guard time (object 0x100C, ms);
the slave answers with one byte: bit 7 the toggle bit (0 in the first reply after boot-up or a
reset communication, then alternating), bits 6..0 its NMT state (4, 5 or 127). Life guarding:
the slave expects a guard request within the node life time, guard time × life time factor
(object 0x100D); when none comes it reports a life guarding event (CANopenNode: EMCY 0x8130).
A device answers guarding only while its producer heartbeat time 0x1017 is 0: the two protocols
exclude each other (CiA 301 7.2.8.3.2).

`NodeGuardingSlave` is the device side, `NodeGuardingMaster` the master side: it checks that a
reply comes before the next request and that the toggle bit alternates.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from profiles.canopen import cob
from profiles.canopen._state import NmtState, state_name
from stack import Frame

__all__ = ["NodeGuardingSlave", "NodeGuardingMaster", "GuardedNode"]

MS = 1_000_000


class NodeGuardingSlave:
    """Answers guard requests with toggle bit and state; watches the node life time.

    ``send(frame)``, ``call_at(t, cb, *args)`` are the node's; ``state()`` is the NMT state;
    ``on_life_guarding(event)`` is called with 'lost' when the life time passed without a
    request and 'resumed' when requests come again.
    """

    def __init__(
        self,
        node_id: int,
        send: Callable[[Frame], Any],
        call_at: Callable[..., Any],
        state: Callable[[], NmtState],
        on_life_guarding: Callable[[str], Any] | None = None,
    ) -> None:
        self.cob_id = cob.HEARTBEAT + node_id
        self.send = send
        self.call_at = call_at
        self.state = state
        self.on_life_guarding = on_life_guarding
        self.guard_time_ns = 0
        self.life_time_factor = 0
        self.toggle = 0
        self.replies = 0
        self.life_guarding_events = 0
        self.lost = False
        self._timer: Any = None

    def configure(self, guard_time_ms: int, life_time_factor: int) -> None:
        """Objects 0x100C and 0x100D; the life time is their product (0: no life guarding)."""
        self.guard_time_ns = guard_time_ms * MS
        self.life_time_factor = life_time_factor
        if self.life_time_ns == 0:
            self._cancel()

    @property
    def life_time_ns(self) -> int:
        """Node life time = guard time × life time factor (CiA 301 7.2.8.3.2.1)."""
        return self.guard_time_ns * self.life_time_factor

    def reset(self) -> None:
        """Boot-up or reset communication: the toggle bit starts at 0 again."""
        self.toggle = 0
        self.lost = False
        self._cancel()

    def on_request(self, t: int) -> None:
        """A guard request (remote frame on 0x700 + node-ID) at ``t``: reply, restart life time."""
        self.send(Frame(self.cob_id, bytes([self.toggle | (int(self.state()) & 0x7F)])))
        self.toggle ^= 0x80
        self.replies += 1
        if self.lost:
            self.lost = False
            if self.on_life_guarding is not None:
                self.on_life_guarding("resumed")
        self._cancel()
        if self.life_time_ns:
            self._timer = self.call_at(t + self.life_time_ns, self._life_time_over)

    def _life_time_over(self) -> None:
        self._timer = None
        self.lost = True
        self.life_guarding_events += 1
        if self.on_life_guarding is not None:
            self.on_life_guarding("lost")

    def _cancel(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None


@dataclass
class GuardedNode:
    """The master's view of a guarded node."""

    node_id: int
    requests: int = 0
    replies: int = 0
    missed: int = 0
    toggle_errors: int = 0
    state: int | None = None
    expect_toggle: int = 0
    waiting: bool = False
    timer: Any = field(default=None, repr=False)

    @property
    def state_name(self) -> str:
        """The state of the last reply ('UNKNOWN' before one)."""
        return "UNKNOWN" if self.state is None else state_name(self.state)


class NodeGuardingMaster:
    """Guards nodes: a remote frame on 0x700 + node-ID every ``guard_time_ms``; a reply missing
    when the next request is due, or a toggle bit that did not alternate, is a node guarding
    event (``on_event(node, 'no reply' | 'toggle')``)."""

    def __init__(
        self,
        send: Callable[[Frame], Any],
        call_at: Callable[..., Any],
        now: Callable[[], int],
        guard_time_ms: int,
        on_event: Callable[[GuardedNode, str], Any] | None = None,
    ) -> None:
        if guard_time_ms <= 0:
            raise ValueError(f"guard_time_ms {guard_time_ms!r}: a guard time is a positive number of ms (0x100C)")
        self.send = send
        self.call_at = call_at
        self.now = now
        self.period_ns = guard_time_ms * MS
        self.on_event = on_event
        self.nodes: dict[int, GuardedNode] = {}

    def guard(self, node_id: int) -> GuardedNode:
        """Start guarding ``node_id`` (the first request goes out now)."""
        g = self.nodes.get(node_id)
        if g is None:
            g = self.nodes[node_id] = GuardedNode(node_id)
            self._request(g, self.now())
        return g

    def stop(self) -> None:
        """Stop guarding every node."""
        for g in self.nodes.values():
            if g.timer is not None:
                g.timer.cancel()
                g.timer = None

    def _request(self, g: GuardedNode, t: int) -> None:
        if g.waiting:
            g.missed += 1
            if self.on_event is not None:
                self.on_event(g, "no reply")
        g.waiting = True
        g.requests += 1
        self.send(Frame(cob.HEARTBEAT + g.node_id, remote=True, dlc=1))
        g.timer = self.call_at(t + self.period_ns, self._request, g, t + self.period_ns)

    def on_reply(self, node_id: int, data: bytes) -> None:
        """A guarding reply (a data frame on 0x700 + node-ID while guarding)."""
        g = self.nodes.get(node_id)
        if g is None or len(data) != 1:
            return
        g.replies += 1
        g.waiting = False
        g.state = data[0] & 0x7F
        toggle = data[0] & 0x80
        if toggle != g.expect_toggle:
            g.toggle_errors += 1
            if self.on_event is not None:
                self.on_event(g, "toggle")
        g.expect_toggle = toggle ^ 0x80
