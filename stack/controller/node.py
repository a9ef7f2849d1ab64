"""A node: the software CAN controller the layers above talk to.

The node is sans-IO: it is attached to a driver (the simulated bus, or a python-can bus) that
gives it a clock and a wire, through the contract of `stack.controller.contract`. Layers above use
only the node API (`stack.controller.api.NodeAPI`: `send`, `subscribe`, `listen`, `call_at`,
`call_later`, `now`, …), so the same profile or ECU runs unchanged on either driver.

Controller features (per node): transmit queue policy (`stack.controller.queues`), acceptance
filters with python-can semantics, a bounded receive FIFO that counts overruns, automatic
replies to remote frames, self-reception, listen-only and one-shot modes (per node and per
request), a latest start time per request, fault confinement (`stack.controller.confinement`),
an optional drifting local clock (`stack.controller.clock`), and the counters a user expects.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable, Mapping
from heapq import heappush
from operator import itemgetter
from typing import Any, NoReturn

from stack.controller.clock import LocalClock
from stack.controller.confinement import ACTIVE, BUS_OFF, ErrorState, after_rx_success, after_tx_success, state_for
from stack.controller.contract import CAPABILITIES, REPORTED_WITH, Driver, Timer, listen_refusal
from stack.controller.events import ArbitrationLost, ErrorStateChanged, TxDone, TxFailed
from stack.controller.exceptions import NodeError
from stack.controller.filters import AcceptanceFilter
from stack.controller.periodic import PeriodicTask
from stack.controller.queues import ABORTED, FAILED, QUEUED, SENT, QueueFull, SpecialRequest, TxRequest, make_queue
from stack.controller.receiver import Receiver, Subscription
from stack.wire.frame import Frame, MessageLike

__all__ = [
    "Node",
    "NodeError",
    "Subscription",
    "Timer",
    "QueueFull",
    "ErrorState",
    "PeriodicTask",
    "Driver",
    "FD",
    "TOLERANT",
    "CLASSIC",
    "FD_KINDS",
]

#: What a controller is towards CAN FD (ISO 11898-1:2015), the value of `Node.fd`:
FD = "fd"
"""FD enabled: sends and receives classical and CAN FD frames."""
TOLERANT = "tolerant"
"""A classical controller with ISO 11898-1:2015's protocol exception: at a recessive FDF bit it
goes bus integrating (no error frame) until it reads 11 recessive bits; it sends no FD frames."""
CLASSIC = "classic"
"""A CAN 2.0 controller (FD-intolerant): an FD frame is an error to it, answered with an error
frame that destroys the frame; it sends no FD frames."""
FD_KINDS = (FD, TOLERANT, CLASSIC)
"""The three, named as the receiver modes of `stack.wire.decoder.BitDecoder` (a node receives with
the decoder of its kind)."""

_EVERY_CAPABILITY = frozenset(CAPABILITIES)
_new_tuple = tuple.__new__  # an event without its Python-level __new__: one call fewer per frame
_sender = itemgetter(2)  # of a (time, frame, sender) reception


class Node(Receiver):
    """A CAN node with a software controller.

    Parameters name the controller's configuration: ``queue`` ('priority', 'fifo', 'mailbox'),
    ``mailboxes`` and ``abort`` for the mailbox policy, ``tx_queue_size``, ``rx_fifo_size``,
    acceptance ``filters`` (python-can format), ``receive_own_messages`` (self-reception),
    ``listen_only`` (no ACK, no transmission, no error flags), ``one_shot`` (no retransmission
    after a lost arbitration or an error; `send` can override it per frame), ``auto_recovery``
    (rule 12 without asking), ``clock`` (a `LocalClock`: the node's own oscillator), ``fd`` (what
    the controller is towards CAN FD: `FD`, `TOLERANT` or `CLASSIC`; see `fd`).

    Driver-side state (`stack.controller.contract`): ``offered`` is the request the controller
    offers to arbitration now; ``listeners`` the callbacks by event type (drivers read it to know
    whether a report runs user code) and ``tx_done_listeners`` its `TxDone` list (None when there
    is none: read once a frame sent); ``rounds_lost`` the arbitration rounds lost so far (a
    driver settling a round adds to it); ``on_bus``, ``suspended``, ``ready_at`` and
    ``rx_cursor`` are the driver's bookkeeping about this node, written by the driver only.
    """

    # the fields as slots (and a __dict__ for anything else): the engine reads them once a frame,
    # and CPython 3.11 reads an instance dict of over 30 keys more slowly
    __slots__ = (
        "name",
        "queue",
        "acceptance",
        "_fifo",
        "rx_fifo_size",
        "receive_own_messages",
        "_listen_only",
        "_one_shot",
        "_one_shot_pending",
        "clock",
        "tx_frames",
        "_rx_frames",
        "_rx_overruns",
        "retransmissions",
        "tx_failed",
        "rounds_lost",
        "bus_off_count",
        "tec",
        "rec",
        "state",
        "auto_recovery",
        "bus",
        "offered",
        "_subs",
        "listeners",
        "tx_done_listeners",
        "remote_replies",
        "rx_cursor",
        "ready_at",
        "suspended",
        "on_bus",
        "connected",
        "_fd",
        "__dict__",
        "__weakref__",
    )

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
        clock: LocalClock | None = None,
        fd: str | None = None,
    ) -> None:
        if fd is not None and fd not in FD_KINDS:
            raise ValueError(
                f"fd {fd!r}: one of 'fd' (FD enabled), 'tolerant' (classical, with ISO 11898-1:2015's "
                "protocol exception) or 'classic' (CAN 2.0, destroys FD frames); None: as the bus says"
            )
        if isinstance(rx_fifo_size, bool) or not isinstance(rx_fifo_size, int) or rx_fifo_size < 1:
            raise ValueError(f"rx_fifo_size {rx_fifo_size!r} must be a positive int")
        if not isinstance(name, str) or not name or not name.isprintable() or any(c.isspace() for c in name):
            raise ValueError(f"node name {name!r}: a non-empty name without spaces or control characters")
        for opt, val in (
            ("abort", abort),
            ("receive_own_messages", receive_own_messages),
            ("listen_only", listen_only),
            ("one_shot", one_shot),
            ("auto_recovery", auto_recovery),
        ):
            if not isinstance(val, bool):
                raise ValueError(f"{opt} {val!r} must be True or False")
        if mailboxes is not None and (isinstance(mailboxes, bool) or not isinstance(mailboxes, int) or mailboxes < 1):
            raise ValueError(f"mailboxes {mailboxes!r}: a controller has at least 1 transmit mailbox")
        if clock is not None and not isinstance(clock, LocalClock):
            raise ValueError(f"clock {clock!r}: a stack.controller.clock.LocalClock or None")
        self.name = name
        self.queue = make_queue(queue, capacity=tx_queue_size, mailboxes=mailboxes, abort=abort)
        self.acceptance = AcceptanceFilter(filters)
        self._fifo: deque[tuple[int, Frame, Any]] = deque()
        self.rx_fifo_size = rx_fifo_size
        self.receive_own_messages = bool(receive_own_messages)
        self._listen_only = bool(listen_only)
        self._one_shot = bool(one_shot)
        self._one_shot_pending = 0  # queued requests that are one-shot while the node is not
        self.clock = clock
        self._fd = fd  # None: as the driver's bus is (see `fd`)
        # counters
        self.tx_frames = 0
        self._rx_frames = 0
        self._rx_overruns = 0
        self.retransmissions = 0
        self.tx_failed = 0
        self.rounds_lost = 0  # arbitration rounds lost, settled (see `arbitration_lost`)
        self.bus_off_count = 0
        # fault confinement (rules 1-12, `stack.controller.confinement`)
        self.tec = 0
        self.rec = 0
        self.state = ACTIVE
        self.auto_recovery = bool(auto_recovery)
        # wiring
        self.bus: Driver | Any | None = None
        self.offered: TxRequest | None = None
        self._subs: list[Subscription] = []
        self.listeners: dict[type, list[Callable[[Any], Any]]] = {}  # by event type (read by drivers)
        self.tx_done_listeners: list[Callable[[Any], Any]] | None = None  # listeners[TxDone], kept by listen
        self.remote_replies: dict[tuple[int, bool], Frame] = {}
        # the driver's bookkeeping (written by the driver only)
        self.rx_cursor = 0  # lazy reception: position in the driver's delivery log
        self.ready_at = 0  # suspend transmission (error passive) ends here
        self.suspended = False  # set aside from arbitration until ready_at
        self.on_bus = False  # connected and not bus off
        self.connected = True

    # ------------------------------------------------------------------ modes
    @property
    def one_shot(self) -> bool:
        """No retransmission after a lost arbitration or an error (the default for `send`)."""
        return self._one_shot

    @one_shot.setter
    def one_shot(self, value: bool) -> None:
        if not isinstance(value, bool):
            raise ValueError(f"one_shot {value!r} must be True or False")
        self._one_shot = value
        if self.bus is not None:
            self.bus.node_changed(self)  # the driver watches one-shot nodes' arbitration

    @property
    def listen_only(self) -> bool:
        """Listen-only (silent) mode: the node receives but never drives the bus — no ACK, no
        transmission, no error flags. Switching it at run time takes effect from the next frame
        on the bus (the driver re-reads who acknowledges); frames already queued stay queued
        and are refused by `send` no more than before (abort them to drop them)."""
        return self._listen_only

    @listen_only.setter
    def listen_only(self, value: bool) -> None:
        if not isinstance(value, bool):
            raise ValueError(f"listen_only {value!r} must be True or False")
        self._listen_only = value
        if self.bus is not None:
            self.bus.node_changed(self)

    @property
    def fd(self) -> str:
        """What the controller is towards CAN FD (ISO 11898-1:2015): 'fd' (`FD`: FD enabled),
        'tolerant' (`TOLERANT`: classical, with the protocol exception) or 'classic' (`CLASSIC`: a
        CAN 2.0 controller, FD-intolerant). Given as ``fd=`` when the node is made; when not given,
        a node is FD enabled on a bus that carries CAN FD — its driver has a ``data_bitrate``, the
        contract's sign (`stack.controller.contract`) — and classic on one that has none, as the
        controllers of a classical network are."""
        kind = self._fd
        if kind is not None:
            return kind
        return FD if getattr(self.bus, "data_bitrate", None) else CLASSIC

    @property
    def fd_declared(self) -> bool:
        """True when the node was made with an explicit ``fd=`` (a driver checks that it can carry
        it: an FD-enabled node needs a bus with a data bit rate)."""
        return self._fd is not None

    @property
    def watches_arbitration(self) -> bool:
        """True when the driver must tell this node each arbitration round it loses: it has
        one-shot requests or `ArbitrationLost` listeners."""
        return self._one_shot or self._one_shot_pending > 0 or bool(self.listeners.get(ArbitrationLost))

    @property
    def subscribed(self) -> bool:
        """True when frames go to subscription callbacks (a receive interrupt) instead of the FIFO."""
        return bool(self._subs)

    # ------------------------------------------------------------------ clock and timers
    def now(self) -> int:
        """Current time of the node's clock in ns (the driver's, through the node's `LocalClock`)."""
        t = self._driver().now()
        return t if self.clock is None else self.clock.local(t)

    def call_at(self, time: int, callback: Callable[..., Any], *args: Any) -> Timer:
        """Run ``callback(*args)`` at time ``time`` (ns) of the node's clock."""
        t = int(time)
        return self._driver().call_at(t if self.clock is None else self.clock.bus(t), callback, args)

    def call_later(self, delay: int, callback: Callable[..., Any], *args: Any) -> Timer:
        """Run ``callback(*args)`` ``delay`` ns of the node's clock from now."""
        d = self._driver()
        if self.clock is None:
            return d.call_at(d.now() + int(delay), callback, args)
        return d.call_at(self.clock.bus(self.clock.local(d.now()) + int(delay)), callback, args)

    def to_local(self, t_bus: int) -> int:
        """A bus (driver) time as the node's local time."""
        return t_bus if self.clock is None or t_bus < 0 else self.clock.local(t_bus)

    def to_bus(self, t_local: int) -> int:
        """A local time of the node as the bus (driver) time."""
        return t_local if self.clock is None else self.clock.bus(t_local)

    @property
    def bit_ns(self) -> float | None:
        """The bit time of the bus the node is on, ns (None when detached or unknown)."""
        return None if self.bus is None else self.bus.bit_ns

    @property
    def capabilities(self) -> frozenset[str]:
        """What the driver underneath can know (`stack.controller.contract.CAPABILITIES`)."""
        return frozenset() if self.bus is None else self.bus.capabilities

    def _driver(self) -> Any:
        if self.bus is None:
            raise NodeError(f"node {self.name!r} is not attached to a bus")
        return self.bus

    # ------------------------------------------------------------------ transmit
    def send(
        self, frame: Frame | MessageLike, *, one_shot: bool | None = None, not_after: int | None = None
    ) -> TxRequest:
        """Queue a frame for transmission; returns its request (state, losses, retries). A
        `can.Message` is taken too, read by its attributes (`Frame.from_message`).

        ``one_shot`` overrides the node's mode for this frame. ``not_after`` is the latest start
        time (ns on the node's clock): a frame that has not started by then is withdrawn and
        reported as `TxFailed` ('not started by ...') — TTCAN's transmit-enable window.
        Raises `QueueFull` when the transmit queue has no room, `NodeError` in listen-only mode,
        when bus off, when not attached, or for a CAN FD frame when the node is not FD enabled
        (`fd`: a tolerant or classic controller sends classical frames only).
        """
        if type(frame) is not Frame:
            frame = self._coerce(frame)
        bus = self.bus
        if bus is None or self._listen_only or self.state is BUS_OFF:
            self._refuse()
        if frame.fd and self._fd != FD and (self._fd is not None or not getattr(bus, "data_bitrate", None)):
            self._refuse_fd(frame)  # (`fd`, spelt out: no property call per FD frame on the hot path)
        if one_shot is None and not_after is None and not self._one_shot:
            req = TxRequest(self, frame, next(bus.seqs), bus.now_ns)
        else:
            req = self._special_request(bus, frame, one_shot, not_after)
        q = self.queue
        by = q.fifos
        if by is not None:
            # priority queue (PriorityQueue.push), inlined: this runs once per frame sent
            if q.size >= q.capacity:
                raise QueueFull(f"transmit queue full ({q.capacity} frames)")
            key = req.key
            dq = by.get(key)
            if dq is None:
                dq = by[key] = deque()
                heappush(q.keys, key)
            dq.append(req)
            q.size += 1
            cur = self.offered
            if cur is None:
                # nothing offered yet: the new head is the queue's — this request when its key is
                # the lowest and nothing waits before it (PriorityQueue.head, inlined)
                new = req if dq[0] is req and q.keys[0] == key else (q.head() or req)
                self.offered = new
                new.head_since = bus.rounds
                bus.offer(self, new)
            elif not cur.on_wire and key < cur.key:
                self.update_head()
            return req
        if q.push(req):
            for m in q.moved:  # aborted out of a mailbox: not offered any more
                self.settle_losses(m)
        cur = self.offered
        if cur is None:
            # nothing offered yet: the new head is the queue's (this request, unless others wait)
            head = q.head()
            self.offered = head
            if head is not None:
                head.head_since = bus.rounds
                bus.offer(self, head)
        elif not cur.on_wire and req.key < cur.key:
            self.update_head()
        return req

    def _special_request(self, bus: Any, frame: Frame, one_shot: bool | None, not_after: int | None) -> TxRequest:
        if one_shot is not None and not isinstance(one_shot, bool):
            raise ValueError(f"one_shot {one_shot!r} must be True, False or None")
        nb = None
        if not_after is not None:
            if isinstance(not_after, bool) or not isinstance(not_after, int):
                raise ValueError(f"not_after {not_after!r}: a time in integer ns on the node's clock")
            nb = self.to_bus(not_after)
        req = SpecialRequest(
            self, frame, next(bus.seqs), bus.now(), self._one_shot if one_shot is None else one_shot, nb
        )
        if req.one_shot and not self._one_shot:
            self._one_shot_pending += 1
            if self._one_shot_pending == 1:
                bus.node_changed(self)
        if nb is not None:
            # withdrawn just after its latest start: an arbitration at not_after itself may start it
            req.expiry = bus.call_at(max(nb + 1, bus.now()), self._expire, (req,))
        return req

    def _expire(self, req: TxRequest) -> None:
        if req.state is QUEUED and not req.on_wire:
            bus = self._driver()
            latest = -1 if req.not_after is None else self.to_local(req.not_after)
            self.fail(req, bus.now(), f"not started by its latest start time {latest} ns", "expired")

    @staticmethod
    def _coerce(frame: Any) -> Frame:
        if isinstance(frame, Frame):
            return frame
        if hasattr(frame, "arbitration_id"):  # a can.Message, or anything with its attributes
            return Frame.from_message(frame)
        raise TypeError(f"send() takes a Frame or can.Message, not {type(frame).__name__}")

    def _refuse(self) -> NoReturn:
        if self.bus is None:
            raise NodeError(f"node {self.name!r} is not attached to a bus")
        if self.listen_only:
            raise NodeError(f"node {self.name!r} is listen-only: it cannot transmit")
        raise NodeError(f"node {self.name!r} is bus off: it cannot transmit until it recovers")

    def _refuse_fd(self, frame: Frame) -> NoReturn:
        data_rate = getattr(self.bus, "data_bitrate", None)
        why = (
            f"it is {self.fd!r}: only an FD-enabled controller sends FD frames"
            if data_rate or self._fd is not None
            else f"its bus {getattr(self.bus, 'name', '')!r} has no data bit rate (a classical CAN bus; "
            "CAN FD needs SimBus(bitrate, data_bitrate=...), equal to bitrate for FD without bit rate switching)"
        )
        raise NodeError(f"node {self.name!r} cannot send the CAN FD frame {frame!r}: {why}")

    def send_periodic(
        self, frame: Frame | Callable[[], Frame], period: int, *, offset: int = 0, count: int | None = None
    ) -> PeriodicTask:
        """Send ``frame`` every ``period`` ns, first ``offset`` ns from now (a cyclic
        transmission on the node's clock; see `PeriodicTask`)."""
        return PeriodicTask(self, frame, period, offset=offset, count=count)

    def abort(self, req: TxRequest) -> bool:
        """Abort a queued request that is not on the wire; True if it was aborted."""
        if req.state is not QUEUED or req.on_wire or req.node is not self:
            return False
        self.settle_losses(req)
        t = self.bus.now() if self.bus else 0
        self._finish(req, ABORTED, "aborted", t)
        self.update_head()
        self._emit(TxFailed(self.to_local(t), req.frame, req, "aborted", "aborted"))
        return True

    def pending(self) -> list[TxRequest]:
        """Requests still queued."""
        return self.queue.pending()

    def _finish(self, req: TxRequest, state: Any, reason: str, t: int) -> None:
        """Take a request out for good (sent requests go through `confirm`'s inlined copy)."""
        req.on_wire = False
        req.state = state
        req.reason = reason
        req.t_done = t
        self.queue.remove(req)
        if req.expiry is not None:
            req.expiry.cancel()
        if req.one_shot and not self._one_shot:
            self._one_shot_pending -= 1
            if self._one_shot_pending == 0 and self.bus is not None:
                self.bus.node_changed(self)

    def settle_losses(self, req: TxRequest) -> None:
        """Count the arbitration rounds ``req`` lost while it was the offered head (the driver's
        ``rounds`` against the round it became the head)."""
        if self.offered is req and self.bus is not None and req.head_since >= 0 and self.eligible:
            lost = self.bus.rounds - req.head_since
            if lost > 0:
                req.losses += lost
                self.rounds_lost += lost
            req.head_since = self.bus.rounds

    @property
    def eligible(self) -> bool:
        """Connected, not suspended and not bus off: the node takes part in arbitration."""
        return self.connected and not self.suspended and self.state is not BUS_OFF

    def update_head(self) -> None:
        """Offer the queue's head to the driver if it changed (unless a frame is on the wire)."""
        cur = self.offered
        if cur is not None and cur.on_wire:
            return
        new = self.queue.head()
        if new is cur:
            return
        if cur is not None and cur.state is QUEUED:
            self.settle_losses(cur)
        self.offered = new
        if new is not None and self.bus is not None:
            new.head_since = self.bus.rounds
            self.bus.offer(self, new)

    # ------------------------------------------------------------------ driver side
    @property
    def head(self) -> TxRequest | None:
        """The request this controller offers to arbitration now (None if nothing is queued)."""
        h = self.offered
        return h if h is not None and h.state is QUEUED else None

    def confirm(self, req: TxRequest, t: int, sof: int = -1, *, rule7: bool = True) -> TxRequest | None:
        """The driver's report that ``req`` went out without error (end of EOF at ``t``, its SOF
        at ``sof``, bus times): counts it, applies rule 7 (unless the driver applied the
        attempt's counters itself, ``rule7=False``), picks the next head and emits `TxDone`.

        Returns the next head when the driver must offer it to arbitration itself (None when
        the queue is empty or the node offered it already) — so that the simulated bus's fast
        loop pushes it onto its heap without another call.

        The one bookkeeping of a successful transmission, for every driver and both of the
        simulated bus's paths. The priority queue's removal and next head are inlined: this runs
        once per frame (the fast loop's figure in `python -m stack.bench`).
        """
        req.on_wire = False
        req.state = SENT
        req.t_done = t
        req.sof = sof
        self.tx_frames += 1
        q = self.queue
        by = q.fifos
        dq = None
        if by is not None:  # PriorityQueue.remove, inlined
            dq = by.get(req.key)
            if dq and dq[0] is req:
                dq.popleft()
            q.size -= 1
        else:
            q.remove(req)
        if req.expiry is not None or (req.one_shot and not self._one_shot):
            if req.expiry is not None:
                req.expiry.cancel()
            if req.one_shot and not self._one_shot:
                self._one_shot_pending -= 1
                if self._one_shot_pending == 0:
                    self._driver().node_changed(self)
        if self.tec and rule7:
            self.on_tx_success()
        listeners = self.tx_done_listeners
        if listeners:
            # confirm first, then pick the next head once (sends from the callbacks included)
            self.offered = None
            if self.clock is None:
                ev = _new_tuple(TxDone, (t, req.frame, req, sof))
            else:
                ev = TxDone(self.clock.local(t), req.frame, req, self.to_local(sof))
            for cb in listeners:
                cb(ev)
            if self.offered is None:
                self.update_head()
            return None
        if dq is not None:
            # the next head is the front of the lowest key's FIFO (PriorityQueue.head): the same
            # key again for a sender of one identifier, unless a lower key was queued meanwhile
            nxt = dq[0] if dq and dq[0].state is QUEUED and q.keys[0] == req.key else q.head()
            self.offered = nxt
            if nxt is not None:
                nxt.head_since = self.bus.rounds  # type: ignore[union-attr]  # a driver reports: attached
            return nxt
        self.update_head()
        return None

    def fail(self, req: TxRequest, t: int, reason: str, kind: str = "") -> None:
        """The driver's report that ``req`` will not be sent (one-shot failure, latest start
        time passed, a send that failed for good; ``kind`` says which in one word, see
        `TxFailed`): emits `TxFailed` and picks the next head."""
        self._finish(req, FAILED, reason, t)
        self.tx_failed += 1
        self.update_head()
        self._emit(TxFailed(self.to_local(t), req.frame, req, reason, kind))

    def retry(self, req: TxRequest) -> None:
        """The driver's report that an attempt of ``req`` failed and will be repeated
        (automatic retransmission): counts it and chooses the head again, as before any
        arbitration — a priority queue offers a better frame queued during the attempt, and
        mailboxes with abort may now abort ``req``'s mailbox for one (`TxQueue.reselect`); a
        FIFO and mailboxes without abort keep their order, so ``req`` is offered again."""
        req.on_wire = False
        req.retries += 1
        self.retransmissions += 1
        if self.bus is not None:
            req.head_since = self.bus.rounds
        self.queue.reselect()
        if self.offered is req:
            self.offered = None  # so that update_head offers the head even when it is req again
        self.update_head()

    def lost_arbitration(self, t: int, req: TxRequest, winner: Frame) -> None:
        """The driver's report that the offered ``req`` lost the round at bus time ``t`` to
        ``winner``: emits `ArbitrationLost`; a one-shot request fails."""
        self._emit(ArbitrationLost(self.to_local(t), req.frame, winner))
        if req.one_shot and req.state is QUEUED:
            r = self._driver().rounds
            lost = r - req.head_since
            if lost > 0:
                req.losses += lost
                self.rounds_lost += lost
            req.head_since = r
            self.fail(req, t, "arbitration lost (one-shot)", "arbitration")

    def unsubscribe(self, sub: Subscription) -> None:
        """Remove a subscription (`Subscription.unsubscribe`)."""
        if sub in self._subs:
            self._subs.remove(sub)
            if self.bus is not None:
                self.bus.node_changed(self)

    def listen(self, event_type: type, callback: Callable[[Any], Any]) -> None:
        """Call ``callback(event)`` for events of ``event_type``: TxDone, TxFailed,
        ArbitrationLost, ErrorStateChanged.

        An event the node's driver never reports is refused rather than waited for in silence
        (`stack.controller.contract.listen_refusal`): a type that is no event of the node's is a
        TypeError; an event its driver lacks the capability for (ArbitrationLost on a python-can
        bus) a `NodeError`, here or when the node is attached to such a driver
        (`check_listeners`)."""
        # not attached yet: only the type is checked, the driver's capabilities when it attaches
        why = listen_refusal(event_type, self.capabilities if self.bus is not None else _EVERY_CAPABILITY)
        if why is not None:
            raise (NodeError if event_type in REPORTED_WITH else TypeError)(
                f"node {self.name!r} cannot listen for {getattr(event_type, '__name__', event_type)}: {why}"
            )
        self.listeners.setdefault(event_type, []).append(callback)
        self.tx_done_listeners = self.listeners.get(TxDone)
        if self.bus is not None:
            self.bus.node_changed(self)

    def check_listeners(self, capabilities: frozenset[str]) -> None:
        """Raise `NodeError` when the node listens for an event a driver with ``capabilities``
        never reports (`stack.controller.contract.listen_refusal`): a driver calls it before it
        attaches the node, so that a listener added before is held to the same rule as `listen`."""
        for event_type, callbacks in self.listeners.items():
            why = listen_refusal(event_type, capabilities) if callbacks else None
            if why is not None:
                raise NodeError(f"node {self.name!r} listens for {event_type.__name__}, but {why}")

    def unlisten(self, event_type: type, callback: Callable[[Any], Any]) -> bool:
        """Stop calling ``callback`` for ``event_type`` (a layer that stops, e.g. a device taken off
        the bus); True if it was listening."""
        cbs = self.listeners.get(event_type)
        if not cbs or callback not in cbs:
            return False
        cbs.remove(callback)
        if not cbs:
            del self.listeners[event_type]
        self.tx_done_listeners = self.listeners.get(TxDone)
        if self.bus is not None:
            self.bus.node_changed(self)
        return True

    def _emit(self, event: Any) -> None:
        for cb in self.listeners.get(type(event), ()):
            cb(event)

    # ------------------------------------------------------------------ counters
    @property
    def arbitration_lost(self) -> int:
        """Arbitration rounds this node entered and lost."""
        n = self.rounds_lost
        h = self.offered
        if h is not None and h.state is QUEUED and not h.on_wire and self.bus is not None and self.eligible:
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
    def on_tx_success(self) -> None:
        """Rule 7 (`stack.controller.confinement.after_tx_success`)."""
        self.set_counters(after_tx_success(self.tec), self.rec, self.bus.now() if self.bus else 0)

    def on_rx_success(self) -> None:
        """Rule 8 (`stack.controller.confinement.after_rx_success`)."""
        self.set_counters(self.tec, after_rx_success(self.rec), self.bus.now() if self.bus else 0)

    state_for = staticmethod(state_for)

    def set_counters(self, tec: int, rec: int, t: int) -> None:
        """New TEC/REC at bus time ``t`` (the driver applied rules 1-8): the state follows rules
        9-11 (`state_for`); bus off is left only by rule 12 (`recovered`)."""
        self.tec = tec
        self.rec = rec
        bus = self.bus
        if bus is not None:
            bus.counters_changed(self)
        old = self.state
        if old is BUS_OFF:
            return
        new = state_for(tec, rec)
        if new is old:
            return
        self.state = new
        if new is BUS_OFF:
            self.bus_off_count += 1
        if bus is not None:
            bus.state_changed(self, old, new, t)
        self._emit(ErrorStateChanged(self.to_local(t), self.name, old.value, new.value, tec, rec))

    def recovered(self, t: int) -> None:
        """The driver's report that rule 12 is met at bus time ``t``: bus off ends with TEC and
        REC 0, error active."""
        old = self.state
        self.tec = self.rec = 0
        self.state = ACTIVE
        if self.bus is not None:
            self.bus.counters_changed(self)
            self.bus.state_changed(self, old, ACTIVE, t)
        self._emit(ErrorStateChanged(self.to_local(t), self.name, old.value, ACTIVE.value, 0, 0))

    def recover(self) -> None:
        """Ask a bus-off controller to recover (rule 12: after 128 occurrences of 11
        consecutive recessive bits); needed when ``auto_recovery`` is off."""
        if self.state is not BUS_OFF:
            raise NodeError(f"node {self.name!r} is {self.state}, not bus off: nothing to recover")
        self._driver().start_recovery(self)

    @property
    def error_state(self) -> ErrorState:
        """The fault confinement state (as `state`)."""
        return self.state

    def __repr__(self) -> str:
        return f"<Node {self.name!r} {self.state}>"
