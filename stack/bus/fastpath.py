"""The simulated bus's fast loop: clean frames arbitrated and completed back to back, in one
loop with local variables, while no timer, fault, tie, suspension or special receiver needs the
general path (`stack.bus.arbitration`). It inlines the plain case of `Node.confirm`, of
`IdStats.add` and of the transmit queue's bookkeeping; differential tests compare its traces with
the general path's on random networks.

Hand-written on purpose (DESIGN.md allows it for the event loop); `python -m stack.bench` and the
benchmarks page say what it buys.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable
from math import inf
from typing import TYPE_CHECKING, Any

from stack.bus.delivery import LOG_LIMIT
from stack.bus.stats import IdStats
from stack.bus.trace import TraceRecord
from stack.controller.confinement import PASSIVE
from stack.controller.events import TxDone
from stack.controller.queues import QUEUED, SENT, TxRequest
from stack.wire.frame import Frame

if TYPE_CHECKING:  # pragma: no cover
    from stack.controller.contract import Timer
    from stack.controller.node import Node

__all__ = ["FastFrames", "NEVER"]

NEVER = 1 << 62  # a time no simulation reaches (ns: 146 years)
_tuple_new = tuple.__new__


class FastFrames:
    """The fast loop of `stack.bus.sim.SimBus` (a mixin: ``SimBus.run`` calls ``_fast_frames``
    when nothing needs the general path, and falls back to ``_arbitrate`` when it completes no
    frame)."""

    if not TYPE_CHECKING:  # SimBus declares the fields (the annotations below are their types)
        __slots__ = ()

    bitrate: int
    record: bool
    trace: list[TraceRecord]
    now_ns: int
    rounds: int
    frames_ok: int
    busy_ns: int
    delivered: int
    id_stats: dict[int, IdStats]
    _timers: list[tuple[int, int, Timer]]
    _contenders: list[tuple[int, int, TxRequest]]
    _suspended: list[Node]
    _dur: list[int]
    _ifs_ns: int
    _idle_at: int
    _log: list[tuple[int, Frame, Node]]
    _log_base: int
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
    _fd_ns: dict[str, int]
    _non_fd: list[Node]

    if TYPE_CHECKING:  # what SimBus adds that the fast loop uses

        def frame_ns(self, frame: Frame) -> int: ...
        def offer(self, node: Node, req: TxRequest) -> None: ...
        def _flush(self) -> None: ...

    fast = True  # the specialised loop below; tests turn it off to compare traces

    def _fast_frames(self, tt: float, limit: float, stop: float) -> int:
        """Arbitrate and complete clean frames back to back, in one loop with local variables,
        while no timer, fault, tie, suspension or special receiver needs the general path.

        Same results as `_arbitrate` + `_complete` (a test compares traces), and faster (the
        benchmarks page has the figure): it saves two method calls, the transmission tuple, a loop turn and the stores of the
        bus's clock and counters per frame (they live in locals until user code may run). Returns the
        number of frames it completed (0: let the general path take this one).
        """
        heap = self._contenders
        heappop = heapq.heappop
        heappush = heapq.heappush
        timers = self._timers
        dur = self._dur
        ifs = self._ifs_ns
        eager = self._eager
        lazy = self._lazy
        log = self._log
        id_stats = self.id_stats
        record = self.record
        rtr = self._rtr
        busoff = self._busoff  # sets: their identity is stable, their content is read live
        rec_nonzero = self._rec_nonzero
        now = self.now_ns
        idle_at = self._idle_at
        frames_ok = self.frames_ok
        rounds = self.rounds
        delivered = self.delivered
        flush_at = self._log_base + LOG_LIMIT  # the log is flushed when it holds LOG_LIMIT entries
        # one int bound: a frame starts and ends before the next timer (tt) and at or before
        # ``limit`` (int-to-int comparisons are cheaper than against float('inf'))
        if tt == inf:
            tt = NEVER
        after = NEVER if limit == inf else int(limit // 1) + 1  # the first whole ns past limit
        bound = tt if tt < after else after
        first = frames_ok
        busy = self.busy_ns
        # what makes every frame run code beyond the loop, the node's own aside (re-read whenever
        # user code ran: nothing else changes them while the loop runs)
        watched = eager or rec_nonzero or record
        non_fd = self._non_fd  # an FD frame with any of these on the bus takes the general path
        # (a list changed in place: read once)
        frame_ns = self.frame_ns
        fd_ns = self._fd_ns
        try:
            while frames_ok < stop:
                t0 = idle_at if idle_at > now else now
                if t0 >= bound:
                    break
                try:
                    req = heap[0][2]
                except IndexError:  # nothing to send
                    break
                node = req.node
                if (
                    req.state is not QUEUED
                    or node.offered is not req
                    or not node.on_bus
                    or node.ready_at > t0
                    or node.state is PASSIVE
                ):
                    break
                frame = req.frame
                nbits = frame.nbits or frame.wire_bits
                if frame.fd:
                    if non_fd or frame.esi:
                        break  # nodes that are not FD enabled, or an ESI to clear: the general path
                    if frame.brs:  # SimBus.frame_ns, its cache hit inlined
                        end = fd_ns.get(frame.encoded.bits)  # (encoded: nbits read it)
                        end = t0 + (frame_ns(frame) if end is None else end)
                    else:
                        end = t0 + dur[nbits]
                else:
                    if rtr and frame.remote:
                        break  # automatic replies: the general path
                    end = t0 + dur[nbits]
                heappop(heap)
                if heap and heap[0][0] == req.key:
                    heappush(heap, (req.key, req.seq, req))
                    break
                if end >= bound:
                    heappush(heap, (req.key, req.seq, req))
                    break
                # arbitration; the bus's clock and counters live in locals and are stored back
                # before any user code can run (and when the loop ends)
                if t0 > idle_at and busoff:
                    self._recessive_events += (t0 - idle_at) * self.bitrate // 11_000_000_000
                lost = rounds - req.head_since
                rounds += 1
                if lost > 0:
                    req.losses += lost
                    node.rounds_lost += lost
                req.head_since = rounds
                # completion
                now = end
                idle_at = end + ifs
                frames_ok += 1
                busy += idle_at - t0
                if busoff:
                    self._recessive_events += 1
                tx_listeners = node.tx_done_listeners
                called = tx_listeners or watched or node.tec
                if called:  # user code may run (callbacks, state-change listeners): bus state first
                    self.rounds = rounds
                    self.now_ns = end
                    self._idle_at = idle_at
                    self.frames_ok = frames_ok
                    self.busy_ns = busy
                if record:
                    rec = TraceRecord("frame", t0, end, node.name, frame, nbits, req.losses, req.t_queued)
                    self.trace.append(rec)
                    for cb in self._bus_listeners:
                        cb(rec)
                if lazy:
                    log.append((end, frame, node))
                    delivered += 1
                    if delivered >= flush_at:  # (delivered is _log_base + len(log): no len() a frame)
                        self._flush()
                        log = self._log
                        flush_at = self._log_base + LOG_LIMIT
                if called:
                    self.delivered = delivered
                for n in eager:
                    n.deliver(end, frame, node, t0)
                if rec_nonzero:
                    for n in tuple(rec_nonzero):
                        if n is not node and n.on_bus:
                            n.on_rx_success()
                st = id_stats.get(frame.key)
                if st is None:
                    st = id_stats[frame.key] = IdStats(frame.can_id, frame.extended)
                lat = end - req.t_queued  # IdStats.add, inlined
                st.count += 1
                st.total += lat
                st.losses += req.losses
                if lat < st.min:
                    st.min = lat
                if lat > st.max:
                    st.max = lat
                if req.special or node.clock is not None:  # one-shot, latest start, drift
                    self.rounds = rounds  # the node offers its next head at this round
                    nxt = node.confirm(req, end, t0)  # the one bookkeeping of a success
                    if nxt is not None:
                        self.offer(node, nxt)
                else:
                    # Node.confirm's plain case, inlined (a plain request: not one-shot — a one-shot
                    # node is watched, which keeps this loop off — no latest start, no local clock).
                    # Calling it costs a large share of `python -m stack.bench`'s frame figures
                    # (measured on the benchmarks page); test_fast_loop_matches_the_general_path_*
                    # guard this copy
                    req.state = SENT
                    req.t_done = end
                    req.sof = t0
                    node.tx_frames += 1
                    q = node.queue
                    by = q.fifos
                    if by is not None:  # PriorityQueue.remove, inlined
                        dq = by.get(req.key)
                        if dq and dq[0] is req:
                            dq.popleft()
                        q.size -= 1
                    else:
                        q.remove(req)
                    if node.tec:
                        node.on_tx_success()
                    if tx_listeners:  # (`called`: the bus's state is stored)
                        # confirm first, then pick the next head once (sends from the callbacks included)
                        node.offered = None
                        ev = _tuple_new(TxDone, (end, frame, req, t0))
                        for cb in tx_listeners:
                            cb(ev)
                        if node.offered is None:
                            node.update_head()
                    elif by is not None and not called:
                        # PriorityQueue.head, inlined: the same key again unless a lower key waits
                        # (one queued while req was on the wire: `send` leaves the head alone then)
                        if dq and dq[0].state is QUEUED and q.keys[0] == req.key:
                            nxt = dq[0]
                        else:
                            nxt = q.head()
                        node.offered = nxt
                        if nxt is not None:
                            nxt.head_since = rounds
                            heappush(heap, (nxt.key, nxt.seq, nxt))
                    else:
                        self.rounds = rounds  # the node offers its next head at this round
                        node.update_head()
                if called:  # user code ran: it may have changed what the loop relies on
                    if timers:
                        tt = timers[0][0]
                        bound = tt if tt < after else after
                    eager = self._eager
                    lazy = self._lazy
                    watched = eager or rec_nonzero or record
                    if self._arb_watch or self._faults is not None or self._suspended or self._ack_count < 2:
                        break
        finally:
            self.rounds = rounds
            self.delivered = delivered
            self.now_ns = now
            self._idle_at = idle_at
            self.frames_ok = frames_ok
            self.busy_ns = busy
        return frames_ok - first
