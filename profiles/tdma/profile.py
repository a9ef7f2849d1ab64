"""The TDMA profile on one node (its messages in their time windows) and the gate that keeps a
CSMA node of the same bus inside the arbitrating windows.

A TDMA node runs an `Fse`; at each basic cycle in schedule it arms one timer per window of its
messages that the cycle's Cycle_Count selects, at the window's start on its own view of the
cycle. Each instance is released then (queued through `Profile.queue`, so the per-message rows
measure release → end of EOF) with its latest start:

- exclusive window: one-shot (no automatic retransmission: a frame destroyed by an error is not
  repeated in this window) and latest start = window start + Tx_Enable — a frame that could not
  start in time is withdrawn (`TxFailed` 'expired', counted as a late start) and waits for its
  next window; it is never sent late;
- single arbitrating window: as an exclusive one — one-shot, latest start the end of Tx_Enable
  (a frame that lost arbitration or was destroyed is not repeated there: it goes at its
  message's next trigger);
- merged arbitrating window: automatic retransmission inside the window (losers of arbitration
  try again at the next idle point) and latest start = the last start that still ends, with the
  error budget, inside the window.

A gated CSMA node knows nothing of the schedule but follows the reference messages as a time
slave (its own `Fse`); its gate answers each release with the next arbitrating window it fits in
— on its own view of the cycle, predicted for later cycles — and the latest start there.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from profiles.base import Context, Profile, frame_of
from profiles.tdma.fse import Fse
from profiles.tdma.monitor import Monitor
from profiles.tdma.schedule import frame_ns_worst

if TYPE_CHECKING:  # pragma: no cover
    from profiles.declarations import NodeDecl
    from profiles.tdma.schedule import Schedule, Window
    from stack import Frame, NodeAPI, Timer

__all__ = ["TdmaProfile", "GatedReceiver"]


class TdmaProfile(Profile):
    """A time-triggered node: its FSE (time master or time slave) and its messages in their
    windows (see the module docstring)."""

    kind = "tdma"

    def __init__(self, node: NodeAPI, decl: NodeDecl, context: Context) -> None:
        super().__init__(node, decl, context)
        s: Schedule = context.scenario.tables["tdma"]
        self.schedule = s
        prio = s.masters.index(decl.name) if decl.name in s.masters else None
        self.fse = Fse(node, s, priority=prio, listener=self)
        self.frames = {m.name: frame_of(m) for m in decl.messages}
        self._track_of = {m.name: context.recorder.track(m) for m in decl.messages}
        self.slots: list[tuple[Window, str]] = [
            (s.windows[i], m.name) for m in decl.messages for i in s.message_windows[m.name]
        ]
        self._timers: list[Timer] = []
        self.monitor = Monitor.of(context, s)
        self.monitor.profiles.append(self)

    def start(self) -> None:
        """Gate the scenario's CSMA nodes (once) and start the FSE."""
        self.monitor.attach(GatedReceiver)
        self.fse.start()

    def on_cycle(self, fse: Fse) -> None:
        """A basic cycle began in schedule: arm this cycle's windows of the node's messages."""
        for t in self._timers:
            t.cancel()
        cc = fse.cycle_count or 0
        self._timers = [
            self.node.call_at(fse.local(w.start_ns), self._open, w, name, fse.cycle_id)
            for w, name in self.slots
            if w.active(cc)
        ]

    def on_lost(self, fse: Fse) -> None:
        """Out of schedule: nothing more is sent until the node is synchronised again."""
        for t in self._timers:
            t.cancel()
        self._timers = []

    def _open(self, w: Window, name: str, cycle_id: int) -> None:
        fse = self.fse
        if fse.cycle_id != cycle_id or not fse.in_schedule:
            return
        s = self.schedule
        latest = fse.local(s.latest_start_ns(w, s.frame_ns[name]))
        req = self.queue(self.frames[name], self._track_of[name], one_shot=w.triggered, not_after=latest)
        if req is not None:
            self.monitor.tag(req, w, name)

    def set_data(self, name: str, data: bytes) -> None:
        """Application hook: the payload the next instances of message ``name`` carry."""
        old = self.frames[name]
        self.frames[name] = type(old)(old.can_id, data, extended=old.extended)

    def summary(self) -> dict[str, Any]:
        """The node's TTCAN state and counters."""
        return self.fse.state()


class GatedReceiver:
    """A CSMA node's view of the schedule: a time slave FSE and the gate
    (`profiles.csma.Gate`) that keeps its frames inside arbitrating windows."""

    def __init__(self, node: NodeAPI, name: str, schedule: Schedule) -> None:
        self.node = node
        self.name = name
        self.schedule = schedule
        self.fse = Fse(node, schedule)
        self.held = 0
        self.waits: list[int] = []

    def start(self) -> None:
        """Follow the reference messages."""
        self.fse.start()

    def gate(self, frame: Frame, now: int) -> tuple[int, int | None]:
        """When a frame released at local time ``now`` may be queued, and its latest start: the
        first arbitrating window, in this basic cycle or a later one of the matrix, whose last
        start for this frame (worst-case length and error budget) is not past. Not in schedule
        (no reference messages yet, or lost): withdrawn at once (latest start before now).

        The spine measures a CSMA message's response from the moment it is queued, so the time a
        gate holds a frame for its window is not in it: `state` reports it (``gate_wait_ms``)."""
        s = self.schedule
        fse = self.fse
        if not fse.in_schedule or fse.cycle_count is None:
            self.held += 1
            return now, now - 1
        length = frame_ns_worst(frame.dlc, frame.extended, frame.remote, s.bit_ns)
        ct = fse.cycle_time(now)
        arb = s.arbitrating()
        for k in range(s.matrix_cycles + 1):
            count = (fse.cycle_count + k) % s.matrix_cycles
            base = k * s.basic_cycle_ns
            for w in arb:
                if not w.active(count):
                    continue
                latest = base + s.latest_start_ns(w, length)
                if latest < base + w.start_ns or latest < ct:
                    continue
                start = max(now, fse.local(max(base + w.start_ns, ct)))
                self.waits.append(start - now)
                return start, fse.local(latest)
        self.held += 1
        return now, now - 1

    def state(self) -> dict[str, Any]:
        """The node's view of the schedule, how often the gate withdrew a frame at once (not in
        schedule) and how long it held frames for their window (ms, local clock)."""
        w = self.waits
        return dict(
            self.fse.state(),
            gated=True,
            withdrawn_unsynchronised=self.held,
            gate_wait_ms=None if not w else {"mean": sum(w) / len(w) / 1e6, "max": max(w) / 1e6},
        )
