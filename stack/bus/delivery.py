"""Lazy reception on the simulated bus: receivers that only buffer frames (no callbacks) read a
shared delivery log when they are looked at, in batches, instead of being visited per frame.

Hand-written for the hot path (DESIGN.md allows it for the event loop): with 1000 filtered nodes
the bus costs about what it does with 10 (`python -m stack.bench`, "1000 nodes"), because the
log is indexed by identifier once per flush and each node walks only the positions its filters
pass, until its FIFO is full; the rest are counted as overruns by bisection. The FIFO's own rules
(filters, capacity, overruns) are the node's: `Node.absorb`, `Node.absorb_positions`.
"""

from __future__ import annotations

import heapq
from bisect import bisect_left
from collections import Counter
from collections.abc import Iterable
from operator import attrgetter, itemgetter
from typing import TYPE_CHECKING

from stack.wire.frame import Frame

if TYPE_CHECKING:  # pragma: no cover
    from stack.controller.node import Node

__all__ = ["LazyDelivery", "LOG_LIMIT"]

LOG_LIMIT = 1 << 15  # log entries before a flush: bounds memory, amortises the indexing
_second = itemgetter(1)
_third = itemgetter(2)
_key_of = attrgetter("key")


class LazyDelivery:
    """The simulated bus's delivery log (a mixin of `stack.bus.sim.SimBus`, which appends to
    ``_log`` as frames complete and counts them in ``delivered``)."""

    if not TYPE_CHECKING:  # SimBus declares the fields (the annotations below are their types)
        __slots__ = ()

    nodes: list[Node]
    delivered: int
    _log: list[tuple[int, Frame, Node]]
    _log_base: int
    _lazy: list[Node]
    _key_receivers: dict[int, tuple[Node, ...]]

    def sync(self, node: Node) -> None:
        """Bring a buffering node's FIFO and counters up to date from the delivery log."""
        log = self._log
        i = node.rx_cursor - self._log_base
        if i >= len(log) or node not in self._lazy:
            node.rx_cursor = self._log_base + len(log)
            return
        entries = log[i:] if i > 0 else log
        node.rx_cursor = self._log_base + len(log)
        node.absorb(entries)

    def _receivers_of(self, frame: Frame) -> tuple[Node, ...]:
        """Nodes whose acceptance filters pass this arbitration key (cached until filters change)."""
        r = self._key_receivers.get(frame.key)
        if r is None:
            r = tuple(n for n in self.nodes if n.acceptance.accepts(frame))
            self._key_receivers[frame.key] = r
        return r

    def _flush(self) -> None:
        """Hand the delivery log to every buffering node, then drop it.

        Work is per delivery that lands in a FIFO, plus per distinct identifier and receiver:
        the log is indexed by identifier once, each node walks only the positions of the
        identifiers its filters pass until its FIFO is full, and counts the rest as overruns by
        bisection. A thousand filtered nodes therefore cost about what ten do.
        """
        log = self._log
        base = self._log_base
        end = base + len(log)
        lazy = {n for n in self._lazy if n.rx_cursor < end}
        # nodes that read nothing since the last flush and whose FIFO is full only count
        # overruns: tallied per (identifier, sender) pair with C-level counting
        full = {n for n in lazy if n.rx_cursor == base and n.rx_free <= 0}
        total = len(log)
        per_sender: Counter[Node] | None = None
        if full:
            # nodes that accept every identifier need only the count per sender (one C pass);
            # filtered ones the count per (identifier, sender)
            everything = [n for n in full if n.acceptance.accepts_all]
            if everything:
                per_sender = Counter(map(_third, log))
                for node in everything:
                    node.count_overruns(total if node.receive_own_messages else total - per_sender.get(node, 0))
            filtered = full.difference(everything)
            if filtered:
                frames = list(map(_second, log))
                keys = list(map(_key_of, frames))
                pairs = Counter(zip(keys, map(_third, log)))
                sample = dict(zip(keys, frames))
                tally: dict[Node, int] = {}
                for (k, sender), c in pairs.items():
                    for node in self._receivers_of(sample[k]):
                        if node in filtered and (node is not sender or node.receive_own_messages):
                            tally[node] = tally.get(node, 0) + c
                for node, c in tally.items():
                    node.count_overruns(c)
            lazy -= full
        if lazy and any(not n.receive_own_messages for n in lazy):
            # a node that only sent (and does not receive its own frames) has nothing to take
            if per_sender is None:
                per_sender = Counter(map(_third, log))
            lazy = {n for n in lazy if n.receive_own_messages or per_sender.get(n, 0) != total}
        if not lazy:  # nobody else needs the entries one by one
            self._log_base = end
            self._log = []
            for node in self._lazy:
                node.rx_cursor = end
            return
        by_key: dict[int, list[int]] = {}
        by_sender: dict[Node, list[int]] = {}
        first: dict[int, Frame] = {}
        for idx, e in enumerate(log):
            k = e[1].key
            lst = by_key.get(k)
            if lst is None:
                by_key[k] = [idx]
                first[k] = e[1]
            else:
                lst.append(idx)
            s_lst = by_sender.get(e[2])
            if s_lst is None:
                by_sender[e[2]] = [idx]
            else:
                s_lst.append(idx)
        node_lists: dict[Node, list[list[int]]] = {}
        for k, lst in by_key.items():
            for node in self._receivers_of(first[k]):
                if node in lazy:
                    node_lists.setdefault(node, []).append(lst)
        for node in self._lazy:
            lists = node_lists.get(node)
            if lists:
                self._absorb_indexed(node, log, lists, node.rx_cursor - base, by_sender.get(node, ()))
        self._log_base = base + len(log)
        self._log = []
        for node in self._lazy:
            node.rx_cursor = self._log_base

    def _absorb_indexed(
        self,
        node: Node,
        log: list[tuple[int, Frame, Node]],
        lists: list[list[int]],
        start: int,
        own_positions: Iterable[int],
    ) -> None:
        """The log positions of the identifiers ``node``'s filters pass go to its FIFO
        (`Node.absorb_positions`); once it is full the rest are counted as overruns by
        bisection, without a walk."""
        merged = lists[0] if len(lists) == 1 else heapq.merge(*lists)
        stop_at = node.absorb_positions(log, (i for i in merged if i >= start))
        if stop_at is None:
            return
        rest = sum(len(lst) - bisect_left(lst, stop_at) for lst in lists)
        if not node.receive_own_messages:
            acc = node.acceptance.accepts
            rest -= sum(1 for i in own_positions if i >= stop_at and acc(log[i][1]))
        node.count_overruns(rest)
