"""A node: the software CAN controller the layers above talk to.

The node is sans-IO: it is attached to a driver (the simulated bus, or a python-can bus) that
gives it a clock and a wire. Layers above use only `send`, `subscribe`, `listen`, `call_at`,
`call_later` and `now`, so the same profile or ECU runs unchanged on either driver.

Controller features (per node): transmit queue policy (`stack.queues`), acceptance filters with
python-can semantics, a bounded receive FIFO that counts overruns, automatic replies to remote
frames, self-reception, listen-only and one-shot modes, and the counters a user expects.
"""

from __future__ import annotations

from collections import deque
from heapq import heappush
from typing import TYPE_CHECKING, Any, Callable, Iterable, Mapping, Protocol

import can

from stack.controller.confinement import ACTIVE, BUS_OFF, ErrorState, after_rx_success, after_tx_success, state_for
from stack.controller.events import ErrorStateChanged, Received, TxDone, TxFailed
from stack.controller.filters import AcceptanceFilter
from stack.wire.frame import Frame
from stack.controller.queues import QueueFull, TxRequest, make_queue

if TYPE_CHECKING:  # pragma: no cover
    from stack.bus.sim import SimBus

__all__ = ["Node", "NodeError", "Subscription", "Timer", "QueueFull", "ErrorState", "PeriodicTask", "Driver"]

_new_tuple = tuple.__new__  # Received(t, frame) without its Python-level __new__: 2x cheaper


class Driver(Protocol):
    """What a node needs from the driver it is attached to (`SimBus`, `PyCanDriver`).

    Clock and timers: ``now()`` and ``call_at(time, callback, args)`` (ns); ``rounds``, the
    number of arbitration rounds so far; ``_seq`` (a counter the node bumps for each request, so
    requests order deterministically) and ``_now`` (the current time, read directly on the hot
    path of `Node.send`); ``_contenders``, the simulated bus's arbitration heap that `Node.send`
pushes a new head onto directly, or None (then ``_offer`` is called). Notifications from the node: ``_offer(node, request)`` (a new head to
    arbitrate), ``_sync(node)`` (bring lazily buffered receptions up to date before the node is
    read), ``_reclassify(node)`` (subscriptions, listeners or modes changed),
    ``_filters_changed(node)``, ``_state_changed(node, old, new, time)`` (fault confinement) and
    ``_start_recovery(node)``; ``_rec_nonzero``, the nodes whose REC is above 0 (rule 8), a dict
    used as an ordered set so that their updates run in a deterministic order;
    ``_log`` and ``_log_base``, the delivery log lazily read receivers catch up from (a driver
    that delivers at once keeps an empty log).
    A driver reports back through the node's public `head`, `confirm`, `fail`, `deliver` and
    `remote_reply`.
    """

    rounds: int
    _contenders: list[Any] | None
    _seq: int
    _now: int
    _rec_nonzero: dict["Node", None]
    _log: Any
    _log_base: int

    def now(self) -> int: ...
    def call_at(self, time: int, callback: Callable[..., Any], args: tuple[Any, ...] = ()) -> "Timer": ...
    def _offer(self, node: "Node", req: TxRequest) -> None: ...
    def _sync(self, node: "Node") -> None: ...
    def _reclassify(self, node: "Node") -> None: ...
    def _filters_changed(self, node: "Node") -> None: ...
    def _state_changed(self, node: "Node", old: "ErrorState", new: "ErrorState", t: int) -> None: ...
    def _start_recovery(self, node: "Node") -> None: ...


class NodeError(Exception):
    """An operation the node cannot do in its current mode (listen-only, detached, bus off)."""


class Timer:
    """A pending callback on the driver's clock; `cancel()` stops it from running."""

    __slots__ = ("time", "callback", "args", "cancelled")

    def __init__(self, time: int, callback: Callable[..., Any], args: tuple[Any, ...]) -> None:
        self.time = time
        self.callback = callback
        self.args = args
        self.cancelled = False

    def cancel(self) -> None:
        """Do not run the callback."""
        self.cancelled = True

    def __lt__(self, other: "Timer") -> bool:  # pragma: no cover - heap entries carry a seq
        return self.time < other.time


class Subscription:
    """A receive callback with its own filters; `unsubscribe()` removes it."""

    __slots__ = ("node", "callback", "filter")

    def __init__(self, node: "Node", callback: Callable[[Received], Any], flt: AcceptanceFilter | None) -> None:
        self.node = node
        self.callback = callback
        self.filter = flt

    def unsubscribe(self) -> None:
        """Stop receiving through this callback."""
        self.node._unsubscribe(self)


class Node:
    """A CAN node with a software controller.

    Parameters name the controller's configuration: ``queue`` ('priority', 'fifo', 'mailbox'),
    ``mailboxes`` and ``abort`` for the mailbox policy, ``tx_queue_size``, ``rx_fifo_size``,
    acceptance ``filters`` (python-can format), ``receive_own_messages`` (self-reception),
    ``listen_only`` (no ACK, no transmission, no error flags), ``one_shot`` (no retransmission
    after a lost arbitration or an error).
    """

    def __init__(
        self,
        name: str = "node",
        *,
        queue: str = "priority",
        mailboxes: int | None = None,
        abort: bool = False,
        tx_queue_size: int = 1024,
        rx_fifo_size: int = 64,
        filters: Iterable[Mapping[str, Any]] | None = None,
        receive_own_messages: bool = False,
        listen_only: bool = False,
        one_shot: bool = False,
        auto_recovery: bool = True,
    ) -> None:
        if isinstance(rx_fifo_size, bool) or not isinstance(rx_fifo_size, int) or rx_fifo_size < 1:
            raise ValueError(f"rx_fifo_size {rx_fifo_size!r} must be a positive int")
        if not isinstance(name, str) or not name or not name.isprintable() or any(c.isspace() for c in name):
            raise ValueError(f"node name {name!r}: a non-empty name without spaces or control characters")
        for opt, val in (("abort", abort), ("receive_own_messages", receive_own_messages),
                         ("listen_only", listen_only), ("one_shot", one_shot), ("auto_recovery", auto_recovery)):
            if not isinstance(val, bool):
                raise ValueError(f"{opt} {val!r} must be True or False")
        if mailboxes is not None and (isinstance(mailboxes, bool) or not isinstance(mailboxes, int) or mailboxes < 1):
            raise ValueError(f"mailboxes {mailboxes!r}: a controller has at least 1 transmit mailbox")
        self.name = name
        self.queue = make_queue(queue, capacity=tx_queue_size, mailboxes=mailboxes, abort=abort)
        self.acceptance = AcceptanceFilter(filters)
        self._fifo: deque[tuple[int, Frame, Any]] = deque()
        self.rx_fifo_size = rx_fifo_size
        self.receive_own_messages = bool(receive_own_messages)
        self.listen_only = bool(listen_only)
        self.one_shot = bool(one_shot)
        # counters
        self.tx_frames = 0
        self._rx_frames = 0
        self._rx_overruns = 0
        self.retransmissions = 0
        self.tx_failed = 0
        self._arb_lost = 0
        # fault confinement (CAN 2.0 rules 1-12)
        self.tec = 0
        self.rec = 0
        self.state = ACTIVE
        self.auto_recovery = bool(auto_recovery)
        self._busoff_mark = 0
        self.bus_off_count = 0
        # wiring
        self.bus: "SimBus | Any | None" = None
        self._head: TxRequest | None = None
        self._subs: list[Subscription] = []
        self._listeners: dict[type, list[Callable[[Any], Any]]] = {}
        self._remote_replies: dict[tuple[int, bool], Frame] = {}
        self._cursor = 0  # lazy reception: position in the bus's delivery log
        self._ready_at = 0  # suspend transmission (error passive) ends here
        self._suspended = False  # set aside from arbitration until _ready_at
        self.connected = True
        self._on_bus = False  # connected and not bus off; kept by the bus

    # ------------------------------------------------------------------ clock and timers
    def now(self) -> int:
        """Current time of the driver's clock in ns."""
        return self._driver().now()

    def call_at(self, time: int, callback: Callable[..., Any], *args: Any) -> Timer:
        """Run ``callback(*args)`` at absolute driver time ``time`` (ns)."""
        return self._driver().call_at(int(time), callback, args)

    def call_later(self, delay: int, callback: Callable[..., Any], *args: Any) -> Timer:
        """Run ``callback(*args)`` ``delay`` ns from now."""
        d = self._driver()
        return d.call_at(d.now() + int(delay), callback, args)

    def _driver(self) -> Any:
        if self.bus is None:
            raise NodeError(f"node {self.name!r} is not attached to a bus")
        return self.bus

    # ------------------------------------------------------------------ transmit
    def send(self, frame: Frame | can.Message) -> TxRequest:
        """Queue a frame for transmission; returns its request (state, losses, retries).

        Raises `QueueFull` when the transmit queue has no room, `NodeError` in listen-only mode,
        when bus off, or when not attached.
        """
        if type(frame) is not Frame:
            frame = self._coerce(frame)
        bus = self.bus
        if bus is None or self.listen_only or self.state is BUS_OFF:
            self._refuse()
        seq = bus._seq = bus._seq + 1
        req = TxRequest(self, frame, seq, bus._now)
        q = self.queue
        by = q._by_key
        if by is not None:
            # priority queue (PriorityQueue.push), inlined: this runs once per frame sent
            if q._n >= q.capacity:
                raise QueueFull(f"transmit queue full ({q.capacity} frames)")
            key = req.key
            dq = by.get(key)
            if dq is None:
                dq = by[key] = deque()
                heappush(q._keys, key)
            dq.append(req)
            q._n += 1
        elif q.push(req):
            for m in q.moved:  # aborted out of a mailbox: not offered any more
                self._settle_losses(m)
        cur = self._head
        if cur is None:
            # nothing offered yet: the new head is the queue's (this request, unless others wait)
            new = q.head()
            self._head = new
            if new is not None:
                new.head_since = bus.rounds
                arb = bus._contenders
                if arb is None:
                    bus._offer(self, new)
                elif self._on_bus and not self._suspended:  # SimBus._offer, inlined (hot path)
                    heappush(arb, (new.key, new.seq, new))
        elif not cur.on_wire and req.key < cur.key:
            self._update_head()
        return req

    @staticmethod
    def _coerce(frame: Any) -> Frame:
        if isinstance(frame, Frame):
            return frame
        if isinstance(frame, can.Message):
            return Frame.from_message(frame)
        raise TypeError(f"send() takes a Frame or can.Message, not {type(frame).__name__}")

    def _refuse(self) -> None:
        if self.bus is None:
            raise NodeError(f"node {self.name!r} is not attached to a bus")
        if self.listen_only:
            raise NodeError(f"node {self.name!r} is listen-only: it cannot transmit")
        raise NodeError(f"node {self.name!r} is bus off: it cannot transmit until it recovers")

    def send_periodic(self, frame: "Frame | Callable[[], Frame]", period: int, *, offset: int = 0,
                      count: int | None = None) -> "PeriodicTask":
        """Send ``frame`` every ``period`` ns, first ``offset`` ns from now (a cyclic
        transmission on the node's clock; see `PeriodicTask`)."""
        return PeriodicTask(self, frame, period, offset=offset, count=count)

    def abort(self, req: TxRequest) -> bool:
        """Abort a queued request that is not on the wire; True if it was aborted."""
        if req.state != "queued" or req.on_wire or req.node is not self:
            return False
        self._settle_losses(req)
        req.state = "aborted"
        req.reason = "aborted"
        self.queue.remove(req)
        self._update_head()
        self._emit(TxFailed(self.bus.now() if self.bus else 0, req.frame, req, "aborted"))
        return True

    def pending(self) -> list[TxRequest]:
        """Requests still queued."""
        return self.queue.pending()

    def _settle_losses(self, req: TxRequest) -> None:
        # arbitration rounds lost while this request was the offered head
        if self._head is req and self.bus is not None and req.head_since >= 0 and self._eligible():
            lost = self.bus.rounds - req.head_since
            if lost > 0:
                req.losses += lost
                self._arb_lost += lost
            req.head_since = self.bus.rounds

    def _eligible(self) -> bool:
        return self.connected and not self._suspended and self.state is not BUS_OFF

    def _update_head(self) -> None:
        cur = self._head
        if cur is not None and cur.on_wire:
            return
        new = self.queue.head()
        if new is cur:
            return
        if cur is not None and cur.state == "queued":
            self._settle_losses(cur)
        self._head = new
        if new is not None and self.bus is not None:
            new.head_since = self.bus.rounds
            self.bus._offer(self, new)

    # ------------------------------------------------------------------ driver side
    @property
    def head(self) -> TxRequest | None:
        """The request this controller offers to arbitration now (None if nothing is queued)."""
        h = self._head
        return h if h is not None and h.state == "queued" else None

    def confirm(self, req: TxRequest, t: int) -> None:
        """The driver's report that ``req`` went out without error at ``t``: counts it, applies
        rule 7, picks the next head and emits `TxDone`."""
        req.on_wire = False
        req.state = "sent"
        req.t_done = t
        self.tx_frames += 1
        self.queue.remove(req)
        if self.tec:
            self._on_tx_success()
        self._update_head()
        self._emit(TxDone(t, req.frame, req))

    def fail(self, req: TxRequest, t: int, reason: str) -> None:
        """The driver's report that ``req`` will not be sent (one-shot failure): emits
        `TxFailed` and picks the next head."""
        req.on_wire = False
        req.state = "failed"
        req.reason = reason
        req.t_done = t
        self.tx_failed += 1
        self.queue.remove(req)
        self._update_head()
        self._emit(TxFailed(t, req.frame, req, reason))

    def deliver(self, t: int, frame: Frame, sender: Any = None) -> None:
        """The driver's report of a valid frame on the bus at ``t`` (acceptance filters, FIFO
        or subscriptions, as in simulation)."""
        self._deliver(t, frame, sender)

    def remote_reply(self, frame: Frame) -> Frame | None:
        """The data frame a mailbox answers this remote frame with, if one is configured."""
        if not frame.remote or self.listen_only:
            return None
        return self._remote_replies.get((frame.can_id, frame.extended))

    # ------------------------------------------------------------------ receive
    def subscribe(self, callback: Callable[[Received], Any],
                  filters: Iterable[Mapping[str, Any]] | None = None) -> Subscription:
        """Call ``callback(Received)`` for every received frame passing ``filters``.

        With at least one subscription the node works like a controller with a receive
        interrupt: frames go to the callbacks at reception time instead of the FIFO.
        """
        sub = Subscription(self, callback, AcceptanceFilter(filters) if filters else None)
        if self.bus is not None:
            self.bus._sync(self)
        self._subs.append(sub)
        if self.bus is not None:
            self.bus._reclassify(self)
        return sub

    def _unsubscribe(self, sub: Subscription) -> None:
        if sub in self._subs:
            self._subs.remove(sub)
            if self.bus is not None:
                self.bus._reclassify(self)

    def listen(self, event_type: type, callback: Callable[[Any], Any]) -> None:
        """Call ``callback(event)`` for events of ``event_type``: TxDone, TxFailed,
        ArbitrationLost (and the fault-confinement events of `stack.errors`)."""
        self._listeners.setdefault(event_type, []).append(callback)
        if self.bus is not None:
            self.bus._reclassify(self)

    def _emit(self, event: Any) -> None:
        for cb in self._listeners.get(type(event), ()):
            cb(event)

    def recv(self) -> tuple[int, Frame] | None:
        """Pop the oldest frame from the receive FIFO as (time_ns, frame), or None if empty."""
        bus = self.bus
        if bus is not None and self._cursor != bus._log_base + len(bus._log):
            bus._sync(self)  # frames delivered since the last read are still in the bus log
        if self._fifo:
            t, frame, _ = self._fifo.popleft()
            return t, frame
        return None

    def set_filters(self, filters: Iterable[Mapping[str, Any]] | None) -> None:
        """Replace the acceptance filters (python-can format; None accepts everything)."""
        flt = AcceptanceFilter(filters)
        if self.bus is not None:
            self.bus._sync(self)
        self.acceptance = flt
        if self.bus is not None:
            self.bus._filters_changed(self)

    def set_remote_reply(self, frame: Frame | None, *, can_id: int | None = None, extended: bool = False) -> None:
        """Answer remote frames for ``frame``'s identifier automatically with ``frame``
        (a mailbox configured for automatic RTR reply); None with can_id removes it."""
        if frame is None:
            if can_id is None:
                raise ValueError("give the frame to reply with, or can_id to remove a reply")
            self._remote_replies.pop((can_id, extended), None)
        else:
            if frame.remote:
                raise ValueError("the automatic reply to a remote frame must be a data frame")
            self._remote_replies[(frame.can_id, frame.extended)] = frame
        if self.bus is not None:
            self.bus._filters_changed(self)

    def _deliver(self, t: int, frame: Frame, sender: Any) -> None:
        """Reception at the end of a valid frame (eager path; see SimBus for the lazy one)."""
        if sender is self and not self.receive_own_messages:
            return
        acc = self.acceptance._cache.get(frame.key)
        if acc is None:
            acc = self.acceptance.accepts(frame)
        if not acc:
            return
        if self._subs:
            self._rx_frames += 1
            ev = _new_tuple(Received, (t, frame))  # Received(t, frame), 2x cheaper on this hot path
            for sub in tuple(self._subs):
                if sub.filter is None or sub.filter.accepts(frame):
                    sub.callback(ev)
        elif len(self._fifo) < self.rx_fifo_size:
            self._rx_frames += 1
            self._fifo.append((t, frame, sender))
        else:
            self._rx_overruns += 1

    @property
    def rx_fifo(self) -> deque[tuple[int, Frame, Any]]:
        """The receive FIFO as (time, frame, sender) entries, oldest first, brought up to date
        (the simulated bus fills buffering nodes lazily); `recv` pops from it."""
        if self.bus is not None:
            self.bus._sync(self)
        return self._fifo

    # ------------------------------------------------------------------ counters
    @property
    def rx_frames(self) -> int:
        """Frames received and accepted by the filters (delivered to the FIFO or callbacks)."""
        if self.bus is not None:
            self.bus._sync(self)
        return self._rx_frames

    @property
    def rx_overruns(self) -> int:
        """Accepted frames lost because the receive FIFO was full."""
        if self.bus is not None:
            self.bus._sync(self)
        return self._rx_overruns

    @property
    def arbitration_lost(self) -> int:
        """Arbitration rounds this node entered and lost."""
        n = self._arb_lost
        h = self._head
        if h is not None and h.state == "queued" and not h.on_wire and self.bus is not None and self._eligible():
            n += max(0, self.bus.rounds - h.head_since)
        return n

    def counters(self) -> dict[str, int]:
        """All counters by name (tx/rx frames, arbitration losses, retransmissions, overruns,
        failed transmissions, TEC/REC as Linux's txerr/rxerr)."""
        return {
            "tx_frames": self.tx_frames,
            "rx_frames": self.rx_frames,
            "rx_overruns": self.rx_overruns,
            "arbitration_lost": self.arbitration_lost,
            "retransmissions": self.retransmissions,
            "tx_failed": self.tx_failed,
            "txerr": self.tec,
            "rxerr": self.rec,
        }

    # ------------------------------------------------------------------ fault confinement
    def _on_tx_success(self) -> None:
        """Rule 7 (`stack.controller.confinement.after_tx_success`)."""
        self._set_counters(after_tx_success(self.tec), self.rec, self.bus.now() if self.bus else 0)

    def _on_rx_success(self) -> None:
        """Rule 8 (`stack.controller.confinement.after_rx_success`)."""
        self._set_counters(self.tec, after_rx_success(self.rec), self.bus.now() if self.bus else 0)

    state_for = staticmethod(state_for)

    def _set_counters(self, tec: int, rec: int, t: int) -> None:
        self.tec = tec
        self.rec = rec
        bus = self.bus
        if bus is not None:
            if rec > 0:
                bus._rec_nonzero[self] = None
            else:
                bus._rec_nonzero.pop(self, None)
        old = self.state
        if old is BUS_OFF:
            return  # only rule 12 leaves bus off
        new = self.state_for(tec, rec)
        if new is old:
            return
        self.state = new
        if bus is not None:
            bus._state_changed(self, old, new, t)
        self._emit(ErrorStateChanged(t, self.name, old.value, new.value, tec, rec))

    def recover(self) -> None:
        """Ask a bus-off controller to recover (rule 12: after 128 occurrences of 11
        consecutive recessive bits); needed when ``auto_recovery`` is off."""
        if self.state is not BUS_OFF:
            raise NodeError(f"node {self.name!r} is {self.state}, not bus off: nothing to recover")
        self._driver()._start_recovery(self)

    @property
    def error_state(self) -> ErrorState:
        """The fault confinement state (as `state`)."""
        return self.state

    def __repr__(self) -> str:
        return f"<Node {self.name!r} {self.state}>"


class PeriodicTask:
    """A frame sent every ``period`` ns on the node's clock (a cyclic transmission).

    ``frame`` may be a `Frame` or a callable returning the next frame (alive counters, changing
    signals). ``count`` limits the number of transmissions; `stop()` ends it.
    """

    def __init__(self, node: Node, frame: Frame | Callable[[], Frame], period: int, *,
                 offset: int = 0, count: int | None = None) -> None:
        if isinstance(period, bool) or not isinstance(period, int) or period <= 0:
            raise ValueError(f"period {period!r} ns must be a positive int")
        self.node = node
        self.frame = frame
        self.period = period
        self.count = count
        self.sent = 0
        self.overflows = 0
        self.skipped = 0
        self._stopped = False
        self._next = node.now() + max(0, int(offset))
        self._timer = node.call_at(self._next, self._fire)

    def _fire(self) -> None:
        if self._stopped:
            return
        f = self.frame() if callable(self.frame) else self.frame
        try:
            self.node.send(f)
        except QueueFull:
            self.overflows += 1
        except NodeError:
            self.skipped += 1  # bus off: a controller drops what the application writes
        self.sent += 1
        if self.count is not None and self.sent >= self.count:
            self._stopped = True
            return
        self._next += self.period
        self._timer = self.node.call_at(self._next, self._fire)

    def stop(self) -> None:
        """Stop sending."""
        self._stopped = True
        self._timer.cancel()

