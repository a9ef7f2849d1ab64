"""Transmit PDOs (CiA 301 7.2.2, 7.5.2.37): when a device sends its process data.

Transmission types (0x1800 + n-1, sub-index 2):

======  =====================================================================================
0       acyclic synchronous: sent at the next SYNC after an event (a mapped object changed,
        or the application asked); the first SYNC in operational sends once.
1..240  cyclic synchronous: sent at every n-th SYNC. Without a SYNC start value the first
        one goes at SYNC n/2 + 1 after the PDO starts (CANopenNode spreads PDOs of equal type
        so); with a start value (sub-index 6) and a SYNC counter (0x1019 > 0) the first goes
        at the SYNC whose counter equals the start value.
252     synchronous RTR-only: the data are sampled at each SYNC and sent on a remote request.
253     event-driven RTR-only: sampled and sent on a remote request.
254/255 event-driven (manufacturer/profile specific): sent when a mapped object changes, when
        the application asks (`Tpdo.request`), when the event timer (sub-index 5, ms) expires
        since the last transmission, and once on entering operational; never sooner than the
        inhibit time (sub-index 3, 100 µs) after the previous one started — an event during the
        inhibit time is sent, with the data of that moment, when it ends.
======  =====================================================================================

Both the inhibit time and the event timer count from the start of the previous frame *on the
wire*: its `TxDone.sof` (exact on the simulated bus; on a python-can bus the driver's estimate,
one frame length before ``send`` returned) and, when the bus shows the device its own frames
(a python-can bus opened with ``receive_own_messages=True``, as ``canstack canopen`` does), the
start the bus itself reports for it (`Tpdo.on_wire`) — later than the estimate when the frame
waited on the wire after ``send`` returned, as it does behind a ``canstack serve`` bus. Once the
bus has shown the device one of its own frames, an event waits until the previous frame of the
PDO has been seen on the wire (at most `ECHO_WAIT_NS`): a frame still queued behind others on
the wire cannot be followed by the next one an inhibit time after it was handed over.

A synchronous TPDO that cannot start inside the synchronous window (0x1007, µs after the SYNC)
is not sent late: it is queued with that latest start time (`send(..., not_after=...)`) and the
controller withdraws it (`TxFailed`, "not started by ..."); the device counts it and reports
EMCY 0x8100 (CANopenNode: "TPDO outside SYNC window"). A remote request is answered when the
COB-ID allows RTR (bit 30 clear), for types 252/253 and for the others with their current data.
PDOs go out only in operational; leaving it takes back the ones still queued.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from profiles.canopen import cob
from profiles.canopen._state import NmtState
from profiles.canopen.pdo.common import Pdo, PdoHost
from profiles.canopen.pdo.mapping import pack
from profiles.responses import ResponseStats
from stack import Frame, TxRequest

__all__ = ["Tpdo", "ECHO_WAIT_NS"]

ECHO_WAIT_NS = 1_000_000_000
"""How long an event waits for the bus to show the PDO's previous frame before it goes anyway (a
bus that stopped echoing must not stop the PDO)."""


class Tpdo(Pdo):
    """Transmit PDO ``n`` (1-based) of a device.

    The host's ``transmit(frame, not_after=None)`` queues a frame (None when the controller
    refused it); ``sync_window_ns`` and ``sync_overflow`` come from the SYNC consumer. Counters
    and samples: ``queued``, ``sent``, ``late`` (withdrawn at the window's end), ``refused``,
    ``wire_starts`` (own frames the bus showed the device), ``event_at`` (when the event timer is due),
    ``sync_latencies`` (ns from the SYNC's reception to the end of this PDO's frame, one per
    synchronous transmission: a `ResponseStats`, bounded in memory).
    """

    receive = False
    kind = "TPDO"

    def __init__(
        self, host: PdoHost, n: int, transmit: Callable[..., TxRequest | None], sync_info: Callable[[], tuple[int, int]]
    ) -> None:
        self.transmit = transmit
        self.sync_info = sync_info  # () -> (window ns, counter overflow value)
        self.send_request = True
        self.sync_count: int | None = None
        self.sampled: bytes | None = None
        self.last_data: bytes | None = None
        self.inhibit_until = 0
        self.pending_event = False
        self.running = False
        self._inhibit_timer: Any = None
        self._event_timer: Any = None
        self.event_at = 0  # when the event timer is due (node clock)
        self._watching: list[tuple[int, int]] = []
        self.pending: dict[TxRequest, int | None] = {}
        self.queued = self.sent = self.late = self.refused = 0
        self.wire_starts = 0
        self.echoes = False  # the bus shows the device its own frames
        self.unseen = 0  # frames handed to the bus but not yet seen on the wire
        self._echo_timer: Any = None
        self.sync_latencies = ResponseStats()
        super().__init__(host, n, 0x1800 + n - 1, 0x1A00 + n - 1, cob.TPDO)

    # ------------------------------------------------------------------ configuration
    def load(self) -> None:
        """Read the parameters (`Pdo.load`) and restart the triggers as CANopenNode does after a
        change of the transmission type."""
        super().load()
        self.send_request = True
        self.sync_count = None
        self._watch()

    def _watch(self) -> None:
        for key in self._watching:
            self.store.unwatch(key[0], key[1], self._changed)
        self._watching = [(m.index, m.sub) for m in self.mapped if not m.dummy]
        for key in self._watching:
            self.store.watch(key[0], key[1], self._changed)

    @property
    def event_driven(self) -> bool:
        """Types 254 and 255."""
        return self.transmission_type >= 254

    def data(self) -> bytes:
        """The PDO's data now (the mapped objects packed)."""
        return pack(self.store, self.mapped)

    # ------------------------------------------------------------------ NMT
    def start(self) -> None:
        """Entering operational (or a change of configuration while operational)."""
        self.stop()
        self.running = True
        self.send_request = True
        if self.valid and self.event_driven:
            self._event()

    def stop(self) -> None:
        """Leaving operational: timers off, queued frames taken back."""
        self.running = False
        self.sync_count = None
        self.sampled = None
        self.pending_event = False
        self.inhibit_until = 0
        self.unseen = 0
        for t in (self._inhibit_timer, self._event_timer, self._echo_timer):
            if t is not None:
                t.cancel()
        self._inhibit_timer = self._event_timer = self._echo_timer = None
        node = self.host.node
        for req in list(self.pending):
            if node.abort(req):
                self.pending.pop(req, None)

    # ------------------------------------------------------------------ triggers
    def on_sync(self, counter: int | None, t: int) -> None:
        """A SYNC at ``t`` with ``counter`` (None without one)."""
        if not self.running or not self.valid:
            return
        tt = self.transmission_type
        if tt == 0:
            if self.send_request:
                self.send_request = False
                self._send(self.data(), t)
        elif tt <= 240:
            if self.sync_count is None:
                _, overflow = self.sync_info()
                if overflow and self.sync_start:
                    self.sync_count = -1  # wait for the start value
                else:
                    self.sync_count = tt // 2 + 1
            if self.sync_count == -1:
                if counter == self.sync_start:
                    self.sync_count = tt
                    self._send(self.data(), t)
                return
            self.sync_count -= 1
            if self.sync_count == 0:
                self.sync_count = tt
                self._send(self.data(), t)
        elif tt == 252:
            self.sampled = self.data()

    def request(self) -> None:
        """The application's event (CiA 301: manufacturer-specific event): a type 254/255 TPDO
        goes now (or when its inhibit time ends), a type 0 at the next SYNC."""
        if not self.running or not self.valid:
            return
        if self.event_driven:
            self._event()
        elif self.transmission_type == 0:
            self.send_request = True

    def _changed(self, index: int, sub: int) -> None:
        if not self.running or not self.valid:
            return
        tt = self.transmission_type
        if tt == 0 or tt >= 254:
            if self.data() != self.last_data:
                self.request()

    def on_rtr(self, t: int) -> None:
        """A remote request on the PDO's COB-ID."""
        if not self.running or not self.valid or not self.rtr_allowed:
            return
        if self.transmission_type == 252:
            if self.sampled is not None:
                self._send(self.sampled, None)
        else:
            self._send(self.data(), None)

    def _event(self) -> None:
        now = self.host.node.now()
        if self.echoes and self.unseen:
            # the previous frame has not reached the wire yet: its start is still to come
            self.pending_event = True
            if self._echo_timer is None:
                self._echo_timer = self.host.node.call_at(now + ECHO_WAIT_NS, self._echo_wait_over)
            return
        if now < self.inhibit_until:
            self.pending_event = True
            if self._inhibit_timer is None:
                self._inhibit_timer = self.host.node.call_at(self.inhibit_until, self._inhibit_over)
            return
        self.pending_event = False
        self._send(self.data(), None)
        self.inhibit_until = now + self.inhibit_ns
        if self.event_ns:
            self._arm_event_timer(now + self.event_ns)

    def _arm_event_timer(self, at: int) -> None:
        if self._event_timer is not None:
            self._event_timer.cancel()
        self.event_at = at
        self._event_timer = self.host.node.call_at(at, self._event_timer_over)

    def _inhibit_over(self) -> None:
        self._inhibit_timer = None
        if self.pending_event and self.running:
            now = self.host.node.now()
            if now < self.inhibit_until:  # the last frame started later than queued: wait for it
                self._inhibit_timer = self.host.node.call_at(self.inhibit_until, self._inhibit_over)
            else:
                self._event()

    def _echo_wait_over(self) -> None:
        self._echo_timer = None
        if self.echoes and self.unseen:
            self.unseen = 0  # the bus stopped showing our frames: go by the estimate
            self._resume()

    def _resume(self) -> None:
        """A deferred event goes now, or when the inhibit time ends."""
        if not (self.pending_event and self.running):
            return
        node = self.host.node
        if node.now() < self.inhibit_until:
            if self._inhibit_timer is not None:
                self._inhibit_timer.cancel()
            self._inhibit_timer = node.call_at(self.inhibit_until, self._inhibit_over)
        else:
            self._event()

    def _event_timer_over(self) -> None:
        self._event_timer = None
        if self.running and self.valid and self.event_driven:
            self._event()

    # ------------------------------------------------------------------ frames
    def _send(self, data: bytes, t_sync: int | None) -> None:
        window, _ = self.sync_info()
        not_after = t_sync + window if (t_sync is not None and window) else None
        req = self.transmit(Frame(self.can_id, data), not_after=not_after)
        self.last_data = data
        if req is None:
            self.refused += 1
            return
        self.queued += 1
        self.pending[req] = t_sync

    def on_done(self, req: TxRequest, t: int, sof: int = -1) -> bool:
        """The controller sent ``req``: its frame ended at ``t`` and started at ``sof`` (TxDone);
        False when it was not this PDO's. The inhibit time counts from the start of the frame
        (CiA 301: the minimum time between two transmissions), not from when it was queued."""
        if req not in self.pending:
            return False
        t_sync = self.pending.pop(req)
        self.sent += 1
        if self.running and self.event_driven:
            self.unseen += 1  # until the bus shows it (when it shows the device its own frames)
        self.started(sof if sof >= 0 else t)
        if t_sync is not None:
            self.sync_latencies.add(t - t_sync)
        return True

    def started(self, sof: int) -> None:
        """The PDO's last frame started on the wire at ``sof``: the inhibit time and the event
        timer count from there (never earlier than they already do)."""
        if not (self.running and self.event_driven):
            return
        if self.inhibit_ns:
            self.inhibit_until = max(self.inhibit_until, sof + self.inhibit_ns)
        if self.event_ns and self._event_timer is not None and sof + self.event_ns > self.event_at:
            self._arm_event_timer(sof + self.event_ns)

    def on_wire(self, sof: int) -> None:
        """The bus showed the device its own frame of this PDO, started at ``sof`` (bus time on
        the node's clock): see the module docstring."""
        self.wire_starts += 1
        self.echoes = True
        self.unseen = max(0, self.unseen - 1)
        self.started(sof)
        if not self.unseen:
            if self._echo_timer is not None:
                self._echo_timer.cancel()
                self._echo_timer = None
            self._resume()

    def on_failed(self, req: TxRequest, kind: str) -> bool:
        """The controller gave ``req`` up (TxFailed, ``kind`` 'expired' at the window's end)."""
        if req not in self.pending:
            return False
        self.pending.pop(req)
        if kind == "expired":
            self.late += 1
        return True

    def state_allows(self) -> bool:
        """PDOs only in operational (CiA 301 NMT table)."""
        return self.host.nmt_state() is NmtState.OPERATIONAL
