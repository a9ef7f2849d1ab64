"""Transmit queue policies of a software CAN controller.

The controller offers one frame at a time to arbitration: the head of its queue. Which frame is
the head is the policy:

- ``PriorityQueue`` — the pending frame with the lowest arbitration key (the default; what a
  controller with enough mailboxes and lowest-ID-first selection does). Frames with equal keys
  keep their order.
- ``FifoQueue`` — strictly in the order queued (a single transmit buffer fed by a FIFO, e.g.
  SJA1000 behind the Linux qdisc): a low-priority frame blocks the ones behind it.
- ``MailboxQueue(n, abort)`` — n hardware mailboxes fed in order from a FIFO backlog; the
  controller sends the highest-priority mailbox. Without abort, a high-priority frame waits in
  the backlog while the mailboxes hold lower-priority frames (priority inversion); with abort,
  the lowest-priority mailbox that is not on the wire is aborted and put back at the front of
  the backlog to make room — when a frame is queued and again when a mailbox is refilled.
"""

from __future__ import annotations

import heapq
from collections import deque
from collections.abc import Sequence
from enum import Enum
from typing import TYPE_CHECKING, Any, Protocol

from stack.controller.exceptions import QueueFull
from stack.wire.frame import Frame

__all__ = [
    "TxRequest",
    "SpecialRequest",
    "RequestState",
    "RequestOwner",
    "TxQueue",
    "PriorityQueue",
    "FifoQueue",
    "MailboxQueue",
    "make_queue",
    "QueueFull",
    "QUEUED",
    "SENT",
    "FAILED",
    "ABORTED",
]


class RequestState(str, Enum):
    """Where a transmit request is: queued (pending or on the wire), sent, failed (one-shot
    failure, latest start time passed, bus off at shutdown) or aborted. A str enum: it compares
    equal to its value ('queued', 'sent', ...)."""

    QUEUED = "queued"
    SENT = "sent"
    FAILED = "failed"
    ABORTED = "aborted"

    def __str__(self) -> str:
        return self.value


# module constants: the engine compares states per frame, and a global is cheaper than an Enum
# member lookup (a descriptor call)
QUEUED = RequestState.QUEUED
SENT = RequestState.SENT
FAILED = RequestState.FAILED
ABORTED = RequestState.ABORTED


class RequestOwner(Protocol):
    """The controller a request belongs to: it can take the request back (`TxRequest.cancel`)."""

    name: str
    one_shot: bool

    def abort(self, req: TxRequest) -> bool: ...


class TxRequest:
    """One frame queued for transmission, with what happened to it.

    ``state`` is a `RequestState`; ``losses`` counts arbitration rounds lost, ``retries``
    retransmissions after errors. Times are the driver's (bus) clock in ns: ``t_queued``, ``sof``
    (start of frame of the attempt that succeeded) and ``t_done`` (end of EOF, or the failure),
    -1 until known. Per request: ``one_shot`` (no retransmission after a lost arbitration or an
    error) and ``not_after`` (latest start time on the bus clock, or None; a frame that has not
    started by then is withdrawn — TTCAN's transmit-enable window).
    """

    __slots__ = (
        "node",
        "frame",
        "key",
        "seq",
        "t_queued",
        "t_done",
        "sof",
        "head_since",
        "losses",
        "retries",
        "state",
        "reason",
        "on_wire",
    )

    # a plain request: the node's mode, no latest start; `SpecialRequest` holds its own (a request
    # is made per frame sent, so three fewer stores here show in `python -m stack.bench`'s 1 -> 1)
    not_after: int | None = None
    expiry: Any = None  # the driver's timer that withdraws it at not_after
    special = False  # a SpecialRequest: the simulated bus's fast loop reads it (no isinstance call)

    def __init__(self, node: RequestOwner, frame: Frame, seq: int, t_queued: int) -> None:
        self.node: Any = node
        self.frame = frame
        self.key = frame.key
        self.seq = seq
        self.t_queued = t_queued
        self.t_done = -1
        self.sof = -1
        self.head_since = -1
        self.losses = 0
        self.retries = 0
        self.state = QUEUED
        self.reason = ""
        self.on_wire = False

    @property
    def one_shot(self) -> bool:
        """No retransmission after a lost arbitration or an error: the node's mode when the
        frame is on the wire (a controller mode, as SocketCAN's ONE_SHOT)."""
        return self.node is not None and self.node.one_shot

    @property
    def done(self) -> bool:
        """True once the frame was sent, failed or was aborted."""
        return self.state is not QUEUED

    def cancel(self) -> bool:
        """Abort the request if it is still queued and not on the wire; True if aborted."""
        return self.node.abort(self)

    def __lt__(self, other: TxRequest) -> bool:  # heap order: arbitration key, then age
        return (self.key, self.seq) < (other.key, other.seq)

    def __repr__(self) -> str:
        return f"<TxRequest {self.frame!r} {self.state}>"


class SpecialRequest(TxRequest):
    """A request with a mode of its own: one-shot, and/or a latest start time (``not_after``, bus
    clock) with the driver's timer that withdraws it (``expiry``)."""

    __slots__ = ("one_shot", "not_after", "expiry")
    special = True
    if TYPE_CHECKING:  # the slot takes the place of TxRequest's property
        one_shot: bool

    def __init__(
        self, node: RequestOwner, frame: Frame, seq: int, t_queued: int, one_shot: bool, not_after: int | None
    ) -> None:
        super().__init__(node, frame, seq, t_queued)
        self.one_shot = one_shot
        self.not_after = not_after
        self.expiry = None


class TxQueue:
    """Interface of a transmit queue policy."""

    capacity: int
    # set by PriorityQueue, whose push and pop the node inlines on its hot path (Node.send,
    # Node.confirm): a FIFO per arbitration key, the heap of those keys, the number queued
    fifos: dict[int, deque[TxRequest]] | None = None
    keys: list[int]
    size: int

    moved: Sequence[TxRequest] = ()  # requests the last push moved out of hardware (mailboxes)

    def push(self, req: TxRequest) -> bool:
        """Queue a request; True if it moved other requests out of hardware (mailbox abort),
        which are then listed in ``moved``."""
        raise NotImplementedError

    def head(self) -> TxRequest | None:
        """The request the controller offers to arbitration now."""
        raise NotImplementedError

    def remove(self, req: TxRequest) -> bool:
        """Take a request out (sent, failed or aborted); True if it was queued."""
        raise NotImplementedError

    def reselect(self) -> None:
        """An attempt failed and its frame left the wire: let the policy reorder what it holds
        before the head is chosen again (only mailboxes with abort do: the failed frame's
        mailbox may now be aborted for a better one). Nothing by default."""

    def __len__(self) -> int:
        raise NotImplementedError

    def pending(self) -> list[TxRequest]:
        """All queued requests (any order)."""
        raise NotImplementedError


class PriorityQueue(TxQueue):
    """Lowest arbitration key first; FIFO among equal keys.

    Kept as a FIFO per arbitration key plus a heap of the keys that have one: queueing and
    sending a frame of a key already waiting is O(1) deque work, cheaper than a heap of
    (key, seq, request) tuples (a sender queues many frames of few identifiers). Requests
    taken out from the middle (aborted) stay until they reach the front and are skipped there.
    """

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self.keys: list[int] = []  # heap of the keys with a FIFO in fifos
        self.fifos: dict[int, deque[TxRequest]] = {}
        self.size = 0

    def push(self, req: TxRequest) -> bool:
        if self.size >= self.capacity:
            raise QueueFull(f"transmit queue full ({self.capacity} frames)")
        dq = self.fifos.get(req.key)
        if dq is None:
            dq = self.fifos[req.key] = deque()
            heapq.heappush(self.keys, req.key)
        dq.append(req)
        self.size += 1
        return False

    def head(self) -> TxRequest | None:
        keys = self.keys
        by = self.fifos
        while keys:
            dq = by[keys[0]]
            while dq and dq[0].state is not QUEUED:
                dq.popleft()
            if dq:
                return dq[0]
            del by[heapq.heappop(keys)]
        return None

    def remove(self, req: TxRequest) -> bool:
        dq = self.fifos.get(req.key)
        if dq and dq[0] is req:
            dq.popleft()
        # otherwise left in place and skipped by head() once its state is not 'queued'
        self.size -= 1
        return True

    def __len__(self) -> int:
        return self.size

    def pending(self) -> list[TxRequest]:
        return [r for dq in self.fifos.values() for r in dq if r.state is QUEUED]


class FifoQueue(TxQueue):
    """Strict queue order."""

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self._q: deque[TxRequest] = deque()
        self.size = 0

    def push(self, req: TxRequest) -> bool:
        if self.size >= self.capacity:
            raise QueueFull(f"transmit queue full ({self.capacity} frames)")
        self._q.append(req)
        self.size += 1
        return False

    def head(self) -> TxRequest | None:
        q = self._q
        while q and q[0].state is not QUEUED:
            q.popleft()
        return q[0] if q else None

    def remove(self, req: TxRequest) -> bool:
        q = self._q
        if q and q[0] is req:
            q.popleft()
        self.size -= 1
        return True

    def __len__(self) -> int:
        return self.size

    def pending(self) -> list[TxRequest]:
        return [r for r in self._q if r.state is QUEUED]


class MailboxQueue(TxQueue):
    """``n`` transmit mailboxes fed from a FIFO backlog; the best mailbox goes to arbitration."""

    def __init__(self, mailboxes: int, capacity: int, abort: bool = False) -> None:
        if isinstance(mailboxes, bool) or not isinstance(mailboxes, int) or mailboxes < 1:
            raise ValueError(f"mailboxes {mailboxes!r}: a controller has at least 1 transmit mailbox")
        self.capacity = capacity
        self.n = mailboxes
        self.abort = abort
        self.boxes: list[TxRequest] = []
        self.backlog: deque[TxRequest] = deque()
        self.aborts = 0

    def __len__(self) -> int:
        return len(self.boxes) + len(self.backlog)

    def push(self, req: TxRequest) -> bool:
        if len(self) >= self.capacity:
            raise QueueFull(f"transmit queue full ({self.capacity} frames)")
        self.moved = []
        if len(self.boxes) < self.n and not self.backlog:
            self.boxes.append(req)
            return False
        if self.abort:
            victims = [b for b in self.boxes if not b.on_wire]
            if victims:
                worst = max(victims)
                if req < worst:
                    self.boxes.remove(worst)
                    self.backlog.appendleft(worst)
                    self.boxes.append(req)
                    self.aborts += 1
                    self.moved = [worst]
                    return True
        self.backlog.append(req)
        return False

    def head(self) -> TxRequest | None:
        return min(self.boxes) if self.boxes else None

    def reselect(self) -> None:
        # the abort a better frame asked for while the failed one was on the wire takes effect
        # now that it is not (a transmit abort request waits for the end of the attempt)
        if self.abort:
            self._rebalance()

    def _rebalance(self) -> None:
        """With abort, a mailbox freed and refilled from the backlog's front is checked again:
        while the backlog holds a frame that beats the lowest-priority mailbox not on the wire,
        that mailbox is aborted back to the backlog's front and the better frame takes it (the
        same rule as when a frame is queued), so the mailboxes hold the best pending frames."""
        while self.backlog:
            best = min(self.backlog)
            victims = [b for b in self.boxes if not b.on_wire]
            if not victims:
                return
            worst = max(victims)
            if not best < worst:
                return
            self.backlog.remove(best)
            self.boxes.remove(worst)
            self.backlog.appendleft(worst)
            self.boxes.append(best)
            self.aborts += 1

    def remove(self, req: TxRequest) -> bool:
        if req in self.boxes:
            self.boxes.remove(req)
            if self.backlog:
                self.boxes.append(self.backlog.popleft())
            if self.abort:
                self._rebalance()
            return True
        try:
            self.backlog.remove(req)
        except ValueError:
            return False
        return True

    def pending(self) -> list[TxRequest]:
        return list(self.boxes) + list(self.backlog)


def make_queue(
    policy: str = "priority", *, capacity: int = 1024, mailboxes: int | None = None, abort: bool = False
) -> TxQueue:
    """Build a queue policy by name: 'priority', 'fifo' or 'mailbox' (needs ``mailboxes``)."""
    if isinstance(capacity, bool) or not isinstance(capacity, int) or capacity < 1:
        raise ValueError(f"transmit queue capacity {capacity!r} must be a positive int")
    if policy == "priority":
        return PriorityQueue(capacity)
    if policy == "fifo":
        return FifoQueue(capacity)
    if policy in ("mailbox", "mailboxes"):
        return MailboxQueue(mailboxes if mailboxes is not None else 3, capacity, abort)
    raise ValueError(f"unknown queue policy {policy!r}: one of 'priority', 'fifo', 'mailbox'")
