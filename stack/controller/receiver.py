"""The receive side of a node's controller: acceptance filters, the receive FIFO with its
overruns, subscriptions (a receive interrupt), remote-reply mailboxes, and the reports a driver
makes about frames on the bus (`deliver`, and `absorb`/`absorb_positions` for a driver that
delivers lazily in batches). A mixin of `stack.controller.node.Node`."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable, Mapping
from operator import itemgetter
from typing import TYPE_CHECKING, Any

from stack.controller.clock import LocalClock
from stack.controller.events import Received
from stack.controller.filters import AcceptanceFilter
from stack.wire.frame import Frame

__all__ = ["Receiver", "Subscription"]

_new_tuple = tuple.__new__  # an event without its Python-level __new__: one call fewer per frame
_sender = itemgetter(2)  # of a (time, frame, sender) reception


class Subscription:
    """A receive callback with its own filters; `unsubscribe()` removes it."""

    __slots__ = ("node", "callback", "filter")

    def __init__(self, node: Receiver, callback: Callable[[Received], Any], flt: AcceptanceFilter | None) -> None:
        self.node = node
        self.callback = callback
        self.filter = flt

    def unsubscribe(self) -> None:
        """Stop receiving through this callback."""
        self.node.unsubscribe(self)


class Receiver:
    """Receive side of `Node` (see the module docstring)."""

    if not TYPE_CHECKING:  # Node declares the fields (the annotations below are their types)
        __slots__ = ()

    bus: Any  # the driver (`stack.controller.contract.Driver`, which takes the whole Node), or None
    clock: LocalClock | None
    acceptance: AcceptanceFilter
    receive_own_messages: bool
    rx_fifo_size: int
    rx_cursor: int
    remote_replies: dict[tuple[int, bool], Frame]
    _fifo: deque[tuple[int, Frame, Any]]
    _subs: list[Subscription]
    _rx_frames: int
    _rx_overruns: int
    _listen_only: bool

    if TYPE_CHECKING:  # what Node adds that the receive side uses

        def to_local(self, t_bus: int) -> int: ...

        def unsubscribe(self, sub: Subscription) -> None: ...

        @property
        def listen_only(self) -> bool: ...

    def deliver(self, t: int, frame: Frame, sender: Any = None, sof: int = -1) -> None:
        """The driver's report of a valid frame on the bus at ``t`` (start of frame ``sof``, bus
        times): acceptance filters, then the subscriptions or the FIFO."""
        if sender is self and not self.receive_own_messages:
            return
        acc = self.acceptance.cache.get(frame.key)
        if acc is None:
            acc = self.acceptance.accepts(frame)
        if not acc:
            return
        if self._subs:
            self._rx_frames += 1
            if self.clock is None:
                ev = _new_tuple(Received, (t, frame, sof))
            else:
                ev = Received(self.clock.local(t), frame, self.to_local(sof))
            for sub in tuple(self._subs):
                if sub.filter is None or sub.filter.accepts(frame):
                    sub.callback(ev)
        elif len(self._fifo) < self.rx_fifo_size:
            self._rx_frames += 1
            self._fifo.append((t, frame, sender))
        else:
            self._rx_overruns += 1

    def absorb(self, entries: list[tuple[int, Frame, Any]]) -> None:
        """A batch of receptions the driver logged for this buffering node, (time, frame,
        sender) in bus order: the ones the filters pass go into the FIFO until it is full, the
        rest are overruns (data overrun: the new frame is lost)."""
        fifo = self._fifo
        cap = self.rx_fifo_size
        acc = self.acceptance
        own = self.receive_own_messages
        n = len(entries)
        if acc.accepts_all and (own or self not in map(_sender, entries)):
            # every entry is for this node: copy what fits in C, count the rest as overruns
            room = cap - len(fifo)
            if room >= n:
                fifo.extend(entries)
                self._rx_frames += n
            else:
                room = max(room, 0)
                fifo.extend(entries[:room])
                self._rx_frames += room
                self._rx_overruns += n - room
            return
        cache = acc.cache
        i = 0
        got = 0
        while len(fifo) < cap and i < n:
            e = entries[i]
            i += 1
            if e[2] is self and not own:
                continue
            ok = cache.get(e[1].key)
            if ok is None:
                ok = acc.accepts(e[1])
            if ok:
                fifo.append(e)
                got += 1
        self._rx_frames += got
        if i >= n:
            return
        if acc.accepts_all:
            rest = n - i
            if not own:
                rest -= sum(1 for e in entries[i:] if e[2] is self)
            self._rx_overruns += rest
            return
        accepts = acc.accepts
        self._rx_overruns += sum(1 for e in entries[i:] if (own or e[2] is not self) and accepts(e[1]))

    def absorb_positions(self, log: list[tuple[int, Frame, Any]], positions: Iterable[int]) -> int | None:
        """Receptions at ``positions`` (ascending) of the driver's log, already filtered for this
        node: into the FIFO until it is full. Returns the position where the FIFO filled (the
        rest are overruns the driver counts with `count_overruns`), or None."""
        fifo = self._fifo
        cap = self.rx_fifo_size
        own = self.receive_own_messages
        got = 0
        stop_at = None
        for idx in positions:
            e = log[idx]
            if e[2] is self and not own:
                continue
            if len(fifo) >= cap:
                stop_at = idx
                break
            fifo.append(e)
            got += 1
        self._rx_frames += got
        return stop_at

    def count_overruns(self, n: int) -> None:
        """``n`` accepted frames lost because the receive FIFO was full."""
        self._rx_overruns += n

    @property
    def rx_free(self) -> int:
        """Room left in the receive FIFO (as last brought up to date)."""
        return self.rx_fifo_size - len(self._fifo)

    def remote_reply(self, frame: Frame) -> Frame | None:
        """The data frame a mailbox answers this remote frame with, if one is configured."""
        if not frame.remote or self.listen_only:
            return None
        return self.remote_replies.get((frame.can_id, frame.extended))

    def subscribe(
        self, callback: Callable[[Received], Any], filters: Iterable[Mapping[str, Any]] | None = None
    ) -> Subscription:
        """Call ``callback(Received)`` for every received frame passing ``filters``.

        With at least one subscription the node works like a controller with a receive
        interrupt: frames go to the callbacks at reception time instead of the FIFO.
        """
        sub = Subscription(self, callback, AcceptanceFilter(filters) if filters else None)
        if self.bus is not None:
            self.bus.sync(self)
        self._subs.append(sub)
        if self.bus is not None:
            self.bus.node_changed(self)
        return sub

    def recv(self) -> tuple[int, Frame] | None:
        """Pop the oldest frame from the receive FIFO as (time_ns, frame), or None if empty."""
        bus = self.bus
        if bus is not None and self.rx_cursor != bus.delivered:
            bus.sync(self)  # frames delivered since the last read are still in the driver's log
        if self._fifo:
            t, frame, _ = self._fifo.popleft()
            return (t if self.clock is None else self.clock.local(t)), frame
        return None

    def set_filters(self, filters: Iterable[Mapping[str, Any]] | None) -> None:
        """Replace the acceptance filters (python-can format; None accepts everything)."""
        flt = AcceptanceFilter(filters)
        if self.bus is not None:
            self.bus.sync(self)
        self.acceptance = flt
        if self.bus is not None:
            self.bus.filters_changed(self)

    def set_remote_reply(self, frame: Frame | None, *, can_id: int | None = None, extended: bool = False) -> None:
        """Answer remote frames for ``frame``'s identifier automatically with ``frame``
        (a mailbox configured for automatic RTR reply); None with can_id removes it."""
        if frame is None:
            if can_id is None:
                raise ValueError("give the frame to reply with, or can_id to remove a reply")
            self.remote_replies.pop((can_id, extended), None)
        else:
            if frame.remote:
                raise ValueError("the automatic reply to a remote frame must be a data frame")
            self.remote_replies[(frame.can_id, frame.extended)] = frame
        if self.bus is not None:
            self.bus.filters_changed(self)

    @property
    def rx_fifo(self) -> deque[tuple[int, Frame, Any]]:
        """The receive FIFO as (time, frame, sender) entries (bus times), oldest first, brought up
        to date (the simulated bus fills buffering nodes lazily); `recv` pops from it."""
        if self.bus is not None:
            self.bus.sync(self)
        return self._fifo

    @property
    def rx_frames(self) -> int:
        """Frames received and accepted by the filters (delivered to the FIFO or callbacks)."""
        if self.bus is not None:
            self.bus.sync(self)
        return self._rx_frames

    @property
    def rx_overruns(self) -> int:
        """Accepted frames lost because the receive FIFO was full."""
        if self.bus is not None:
            self.bus.sync(self)
        return self._rx_overruns
