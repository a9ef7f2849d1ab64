"""Arbitration and the completion of clean frames: the general path of `stack.bus.sim.SimBus`,
one event at a time (the model is described in `stack.bus.sim`; the fast loop,
`stack.bus.fastpath`, does the same for runs of clean frames, and a differential test compares
the two).

- An arbitration round: the lowest arbitration key among the contenders' heap wins; nodes that
  send the same arbitration field all transmit (a collision if their frames differ); nodes that
  watch arbitration hear of each round they lost. An attempt that can go wrong (a fault to
  inject, a tie, nobody to acknowledge) is replayed bit by bit (`stack.bus.bitlevel`), an FD frame
  that CAN 2.0 nodes answer is computed by `stack.bus.fdnodes` when it can be.
- A clean frame's completion: receivers validate it before the transmitter does (deliver first,
  then confirm the transmission), rule 8 for receivers with a REC above 0, per-identifier
  statistics, suspend transmission after sending error passive, automatic remote replies.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING, Any

from stack.bus.attempt import AttemptResult, StuckFaults, sent_frame
from stack.bus.delivery import LOG_LIMIT
from stack.bus.fdnodes import classic_fd_attempt
from stack.bus.stats import IdStats
from stack.bus.trace import TraceRecord
from stack.controller.confinement import BUS_OFF, PASSIVE
from stack.controller.queues import QUEUED, TxRequest
from stack.wire.frame import Frame

if TYPE_CHECKING:  # pragma: no cover
    from stack.controller.node import Node

__all__ = ["Arbitration"]


class Arbitration:
    """Arbitration rounds and clean completions of `stack.bus.sim.SimBus` (a mixin: ``SimBus.run``
    calls ``_arbitrate`` at an idle point and ``_complete`` at the end of the attempt on the wire;
    the bit-level side reports successes through ``_tx_success``)."""

    if not TYPE_CHECKING:  # SimBus declares the fields (the annotations below are their types)
        __slots__ = ()

    nodes: list[Node]
    bitrate: int
    record: bool
    trace: list[TraceRecord]
    now_ns: int
    rounds: int
    frames_ok: int
    collisions: int
    busy_ns: int
    delivered: int
    id_stats: dict[int, IdStats]
    _contenders: list[tuple[int, int, TxRequest]]
    _suspended: list[Node]
    _ifs_ns: int
    _suspend_ns: int
    _idle_at: int
    _tx: tuple[tuple[TxRequest, ...], int, AttemptResult | None, Frame | None] | None
    _tx_end: int
    _log: list[tuple[int, Frame, Node]]
    _lazy: list[Node]
    _eager: list[Node]
    _arb_watch: list[Node]
    _rtr: dict[tuple[int, bool], list[Node]]
    _ack_count: int
    _bus_listeners: list[Callable[[TraceRecord], Any]]
    _rec_nonzero: dict[Node, None]
    _faults: Any
    _recessive_events: int
    _busoff: set[Node]
    _non_fd: list[Node]
    _classic: list[Node]
    _eager_fd: list[Node]
    _fd_ack_count: int

    if TYPE_CHECKING:  # what SimBus and its other parts add that arbitration and completion use

        def frame_ns(self, frame: Frame) -> int: ...
        def offer(self, node: Node, req: TxRequest) -> None: ...
        def _flush(self) -> None: ...
        def _bitlevel(
            self,
            now: int,
            txs: tuple[TxRequest, ...],
            *,
            flips: dict[int, Any] | None = None,
            stuck: StuckFaults | None = None,
            deaf: Iterable[Node] = (),
            collision: bool = False,
            overload: dict[Node, int] | None = None,
            leave: dict[Node, int] | None = None,
        ) -> None: ...
        def _start_attempt(
            self, now: int, txs: tuple[TxRequest, ...], nodes: list[Node], res: AttemptResult
        ) -> None: ...
        def _complete_bitlevel(self, txs: tuple[TxRequest, ...], start: int, end: int, idle: int, res: Any) -> None: ...

    def _wake(self, now: int) -> None:
        still = []
        for n in self._suspended:
            if n.ready_at <= now:
                n.suspended = False
                h = n.offered
                if h is not None and h.state is QUEUED:
                    h.head_since = self.rounds
                    heapq.heappush(self._contenders, (h.key, h.seq, h))
            else:
                still.append(n)
        self._suspended = still

    def _valid(self, req: TxRequest) -> bool:
        return req.state is QUEUED and req.node.offered is req and req.node.on_bus

    def _arbitrate(self) -> None:
        now = self.now_ns
        if self._suspended:
            self._wake(now)
        heap = self._contenders
        heappop = heapq.heappop
        winner = None
        while heap:
            req = heap[0][2]
            node = req.node
            if req.state is not QUEUED or node.offered is not req or not node.on_bus:
                heappop(heap)
                continue
            if node.ready_at > now:  # error passive: suspend transmission
                heappop(heap)
                if not node.suspended:
                    node.suspended = True
                    self._suspended.append(node)
                continue
            winner = heappop(heap)[2]
            break
        if winner is None:
            return
        r = self.rounds
        self.rounds = r + 1
        if now > self._idle_at and self._busoff:  # rule 12 counts 11-bit recessive runs on an idle bus too
            self._recessive_events += (now - self._idle_at) * self.bitrate // 11_000_000_000
        if heap and heap[0][0] == winner.key:
            txs = self._tied(winner, now)
        else:
            txs = (winner,)
        for q in txs:
            lost = r - q.head_since
            if lost > 0:
                q.losses += lost
                q.node.rounds_lost += lost
            q.head_since = r + 1
            q.on_wire = True
        if self._arb_watch:
            self._notify_losers(now, r, txs)
        frame = winner.frame
        spec = self._faults.attempt(self, now, txs) if self._faults is not None else None
        if len(txs) > 1:
            # several nodes send the same arbitration field: replayed bit by bit, a collision if
            # their frames differ, else each is a transmitter and none receives the frame
            collision = self._first_difference(txs) is not None
            self.collisions += collision
            self._bitlevel(now, txs, collision=collision, **(spec or {}))
            return
        if spec is not None:
            self._bitlevel(now, txs, **spec)
            return
        if frame.fd:
            frame = sent_frame(frame, winner.node.state is PASSIVE)  # ESI: its state at SOF
            if self._classic:  # CAN 2.0 nodes destroy it (`stack.bus.fdnodes`)
                self._classic_attempt(now, winner, frame)
                return
            if self._fd_ack_count <= 1:  # only FD-enabled nodes acknowledge an FD frame
                self._bitlevel(now, txs)  # ACK error
                return
        elif self._ack_count <= 1:  # nobody but the transmitter (never listen-only) to acknowledge
            self._bitlevel(now, txs)  # ACK error
            return
        self._tx = (txs, now, None, frame)
        self._tx_end = now + self.frame_ns(frame)

    def _tied(self, winner: TxRequest, now: int) -> tuple[TxRequest, ...]:
        """Other nodes sending the same arbitration field: they all go on transmitting."""
        heap = self._contenders
        key = winner.key
        txs = [winner]
        while heap and heap[0][0] == key:
            q = heapq.heappop(heap)[2]
            if not self._valid(q) or q in txs or q.node is winner.node:
                continue
            if q.node.ready_at > now:
                if not q.node.suspended:
                    q.node.suspended = True
                    self._suspended.append(q.node)
                continue
            txs.append(q)
        return tuple(txs)

    def _classic_attempt(self, now: int, req: TxRequest, frame: Frame) -> None:
        """An FD frame on a bus with CAN 2.0 nodes: their error frame destroys it, or, when all of
        them are error passive or listen-only, their passive error flags leave it alone. The
        outcome is fully determined by the nodes' kinds, states and counters (`stack.bus.fdnodes`
        computes it without the bit-level replay, which a differential test compares it with);
        anything it does not cover is replayed bit by bit."""
        nodes = [n for n in self.nodes if n.on_bus]
        res = classic_fd_attempt(req, frame, nodes) if self.fast_fd_attempts else None
        if res is None:
            self._bitlevel(now, (req,))
        else:
            self._start_attempt(now, (req,), nodes, res)

    fast_fd_attempts = True  # `stack.bus.fdnodes` for FD frames with CAN 2.0 nodes; tests compare

    @staticmethod
    def _first_difference(txs: tuple[TxRequest, ...]) -> int | None:
        def bits(q: TxRequest) -> str:
            return sent_frame(q.frame, q.node.state is PASSIVE).bits.bits

        bits0 = bits(txs[0])
        diff = None
        for q in txs[1:]:
            b = bits(q)
            if b != bits0:
                d = next(i for i, (x, y) in enumerate(zip(bits0, b)) if x != y)
                diff = d if diff is None else min(diff, d)
        return diff

    def _notify_losers(self, now: int, r: int, txs: tuple[TxRequest, ...]) -> None:
        """Nodes that watch arbitration hear of each round their offered request lost
        (`Node.lost_arbitration`: ArbitrationLost, and a one-shot request fails)."""
        winners = {q.node for q in txs}
        wframe = sent_frame(txs[0].frame, txs[0].node.state is PASSIVE)  # as on the wire (ESI)
        for n in tuple(self._arb_watch):
            h = n.offered
            if n in winners or h is None or h.state is not QUEUED or h.on_wire or n.suspended:
                continue
            if not (n.connected and n.state is not BUS_OFF) or h.head_since > r:
                continue
            n.lost_arbitration(now, h, wframe)

    def _complete(self) -> None:
        assert self._tx is not None  # completing the attempt on the wire
        txs, start, detail, frame = self._tx
        self._tx = None
        end = self._tx_end
        idle = end + self._ifs_ns
        if detail is not None:
            self._complete_bitlevel(txs, start, end, idle, detail)
            return
        assert frame is not None  # a clean attempt carries its frame
        winner = txs[0]
        sender = winner.node
        # an FD frame reaches the FD-enabled nodes only (a tolerant node integrates meanwhile)
        skip = self._non_fd if frame.fd else ()
        self.frames_ok += 1
        self.busy_ns += idle - start
        self._idle_at = idle
        if self.record:
            rec = TraceRecord(
                "frame",
                start,
                end,
                sender.name if len(txs) == 1 else "+".join(q.node.name for q in txs),
                frame,
                frame.bits.length,
                winner.losses,
                winner.t_queued,
            )
            self.trace.append(rec)
            for cb in self._bus_listeners:
                cb(rec)
        # receivers validate the frame at the last-but-one EOF bit, before the transmitter
        # does at the last one: deliver first, then confirm the transmission
        if self._lazy:
            log = self._log
            log.append((end, frame, sender))
            self.delivered += 1
            if len(log) >= LOG_LIMIT:
                self._flush()
        for n in self._eager_fd if frame.fd else self._eager:
            n.deliver(end, frame, sender, start)
        if self._busoff:
            self._recessive_events += 1  # ACK delimiter + EOF + intermission: 11 recessive bits
        if self._rec_nonzero:
            for n in tuple(self._rec_nonzero):
                if n is not sender and n.on_bus and n not in skip:
                    n.on_rx_success()
        for q in txs:
            q.on_wire = False
            self._tx_success(q, end, idle, start, passive=q.node.state is PASSIVE, rule7=True)
        if frame.remote and self._rtr:
            self._auto_reply(frame, sender, self._rtr.get((frame.can_id, frame.extended), ()))

    def _auto_reply(self, frame: Frame, sender: Node | None, receivers: Iterable[Node]) -> None:
        """Mailboxes configured for automatic replies answer a remote frame they received."""
        key = (frame.can_id, frame.extended)
        holders = self._rtr.get(key, ())
        for n in receivers:
            if n in holders and n is not sender and n.on_bus and not n.listen_only:
                n.send(n.remote_replies[key])  # the mailbox's frame (Node.remote_reply)

    def _suspend(self, node: Node, idle: int) -> None:
        """Suspend transmission: an error-passive node that transmitted waits 8 more bits after
        the intermission; until then it is out of arbitration (not counted as losing)."""
        node.ready_at = idle + self._suspend_ns
        if not node.suspended:
            node.suspended = True
            self._suspended.append(node)

    def _tx_success(self, q: TxRequest, end: int, idle: int, sof: int, *, passive: bool, rule7: bool) -> None:
        """A transmission that went through: per-ID latency, suspend transmission if it was sent
        error passive, then the node's own bookkeeping (`Node.confirm`: counters, rule 7 unless
        the attempt's counters were applied already, the next head, `TxDone`)."""
        st = self.id_stats.get(q.key)
        if st is None:
            st = self.id_stats[q.key] = IdStats(q.frame.can_id, q.frame.extended)
        st.add(end - q.t_queued, q.losses)
        if passive:
            self._suspend(q.node, idle)
        nxt = q.node.confirm(q, end, sof, rule7=rule7)
        if nxt is not None:
            self.offer(q.node, nxt)
