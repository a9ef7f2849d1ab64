"""The simulated bus's side of an attempt replayed bit by bit (`stack.bus.attempt`): starting it,
the counters at state boundaries inside it, and applying its outcome — deliveries, transmitter
results, fault confinement (rules 1-8 as counted, 9-12 through the node), trace records."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING, Any

from stack.bus.attempt import AttemptResult, StuckFaults, sent_frame, simulate_attempt
from stack.bus.trace import TraceRecord
from stack.controller.confinement import BUS_OFF, PASSIVE, ErrorState
from stack.controller.queues import QUEUED, TxRequest
from stack.wire.frame import Frame

if TYPE_CHECKING:  # pragma: no cover
    from stack.controller.contract import Timer
    from stack.controller.node import Node

__all__ = ["BitLevelAttempts"]


class BitLevelAttempts:
    """Bit-level attempts of `stack.bus.sim.SimBus` (a mixin: the bus's scheduling calls
    ``_bitlevel`` to start one and ``_complete_bitlevel`` when it ends)."""

    if not TYPE_CHECKING:  # SimBus declares the fields (the annotations below are their types)
        __slots__ = ()

    reuse_unacked = True  # reuse the replay of an identical unacknowledged attempt; tests compare
    nodes: list[Node]
    _unacked: dict[Any, AttemptResult]
    trace: list[TraceRecord]
    now_ns: int
    bitrate: int
    data_bitrate: int | None
    rounds: int
    record: bool
    frames_ok: int
    error_frames: int
    busy_ns: int
    _idle_at: int
    _recessive_events: int
    _rtr: dict[tuple[int, bool], list[Node]]
    _bus_listeners: list[Callable[[TraceRecord], Any]]
    _log: list[tuple[int, Frame, Node]]
    _tx: tuple[tuple[TxRequest, ...], int, AttemptResult | None, Frame | None] | None
    _tx_end: int

    if TYPE_CHECKING:  # what SimBus adds that the bit-level side uses

        def call_at(self, time: int, callback: Callable[..., Any], args: tuple[Any, ...] = ()) -> Timer: ...
        def offer(self, node: Node, req: TxRequest) -> None: ...
        def _tx_success(self, q: TxRequest, end: int, idle: int, sof: int, *, passive: bool, rule7: bool) -> None: ...
        def _suspend(self, node: Node, idle: int) -> None: ...
        def _auto_reply(self, frame: Frame, sender: Node | None, receivers: Iterable[Node]) -> None: ...
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
    ) -> None:
        """Replay this attempt bit by bit (`stack.bus.attempt`) because something can go wrong in it.

        A frame nobody acknowledges (a node alone on its bus) is retransmitted at once, again and
        again, and in error passive every attempt is the same (rule 3, exception 1 leaves TEC
        alone): its replay is computed once per frame and nodes' states and counters and reused
        (`reuse_unacked`), so a lone transmitter costs a small part of the bit-level replay."""
        nodes = [n for n in self.nodes if n.on_bus]
        key = None
        if self.reuse_unacked and len(txs) == 1 and not (flips or stuck or deaf or collision or overload or leave):
            key = (
                txs[0].frame,
                txs[0].node.name,
                tuple((n.name, n.state, n.tec, n.rec, n.listen_only, n.fd) for n in nodes),
            )
            res = self._unacked.get(key)
            if res is None:
                res = simulate_attempt(txs, nodes, {}, None, (), None, None)
                if res.winner is None and not any(o.accepted for o in res.outcomes.values()):
                    if len(self._unacked) >= 256:
                        self._unacked.clear()
                    self._unacked[key] = res
        else:
            res = simulate_attempt(txs, nodes, flips or {}, stuck, deaf, overload, leave)
        res.collision = collision
        self._start_attempt(now, txs, nodes, res)

    def _start_attempt(self, now: int, txs: tuple[TxRequest, ...], nodes: list[Node], res: AttemptResult) -> None:
        """Put an attempt computed bit by bit (or by `stack.bus.fdnodes`) on the wire."""
        res.before = {n.name: n.state for n in nodes}  # the states the attempt was sent in
        self._tx = (txs, now, res, None)
        self._tx_end = now + self.attempt_ns(res.bits, res.data_phase)
        # state changes inside the attempt happen at their bit times (rules 9 and 10 take effect
        # at once); the counters' final values are applied when it completes
        by_name = {n.name: n for n in nodes}
        for name, o in res.outcomes.items():
            for bit, dt, dr in o.trail:
                if bit + 1 < res.bits:
                    self.call_at(
                        now + self.attempt_ns(bit + 1, res.data_phase),
                        self._interim_counters,
                        (by_name[name], o.tec0 + dt, o.rec0 + dr),
                    )

    def attempt_ns(self, bits: int, data_phase: tuple[int, int] | None = None) -> int:
        """The time from SOF to the start of bit ``bits`` of an attempt, ns: bits at the nominal
        rate, and those of ``data_phase`` (first and last bit, `AttemptResult.data_phase`) at the
        data bit rate — the exact sum floored to the ns, as `bits_to_ns` floors a classical frame's
        (so an FD frame without BRS lasts as long as a classical frame of as many bits)."""
        if data_phase is None or bits <= data_phase[0]:
            return bits * 1_000_000_000 // self.bitrate
        first, last = data_phase
        data = (bits if bits <= last else last + 1) - first
        n, d = self.bitrate, self.data_bitrate or self.bitrate
        return ((bits - data) * d + data * n) * 1_000_000_000 // (n * d)

    def attempt_bit(self, ns: int, data_phase: tuple[int, int] | None = None) -> int:
        """The bit of an attempt during which ``ns`` after its SOF falls, rounded up: the first bit
        that starts at or after it (the inverse of `attempt_ns`, on the exact times)."""
        n = self.bitrate
        if data_phase is None or ns * n <= data_phase[0] * 1_000_000_000:
            return -(-ns * n // 1_000_000_000)
        first, last = data_phase
        d = self.data_bitrate or n
        into = ns * n - first * 1_000_000_000  # past the data phase's start, in ns x nominal rate
        data = last + 1 - first
        if into * d <= data * n * 1_000_000_000:
            return first + -(-into * d // (n * 1_000_000_000))
        rest = into * d - data * n * 1_000_000_000  # past the data phase's end, in ns x n x d
        return last + 1 + -(-rest // (d * 1_000_000_000))

    def _interim_counters(self, node: Node, tec: int, rec: int) -> None:
        """Counters of a node in the middle of a bit-level attempt, at a state boundary."""
        node.set_counters(tec, rec, self.now_ns)

    def disturbance(self, now: int, stuck: StuckFaults, deaf: Iterable[Node] = ()) -> None:
        """Replay an attempt that no node transmits: a stuck-dominant fault starting on an idle
        bus, which every node reads as a start of frame (``stuck`` and ``deaf`` as in
        `stack.bus.attempt.simulate_attempt`)."""
        self._bitlevel(now, (), stuck=stuck, deaf=deaf)

    def _complete_bitlevel(self, txs: tuple[TxRequest, ...], start: int, end: int, idle: int, res: Any) -> None:
        """Apply a bit-level attempt: deliveries to the receivers that accepted the frame,
        transmitter outcomes, counter changes (rules 1-8) and the resulting states (9-12)."""
        outcomes = res.outcomes
        by_name = {n.name: n for n in self.nodes}
        self.busy_ns += idle - start
        self._idle_at = idle
        self._recessive_events += 1
        winner = res.winner
        # receivers that accepted (at the last-but-one EOF bit) keep the frame whatever happens next
        accepted = [(by_name[name], o) for name, o in outcomes.items() if o.accepted]
        sender = (winner or txs[0]).node if txs else None
        before = res.before or {name: by_name[name].state for name in outcomes}
        if accepted or winner is not None:
            self._flush_for_direct()
        for node, o in accepted:
            t_acc = start + self.attempt_ns(o.accept_bit + 2, res.data_phase)
            node.deliver(t_acc, o.frame, sender, start)
        for q in txs:  # self-reception: each transmitter that succeeded gets its own copy
            o = outcomes.get(q.node.name)
            if o is not None and o.success and q.node.receive_own_messages:
                q.node.deliver(end, sent_frame(q.frame, before[q.node.name] is PASSIVE), q.node, start)
        if winner is not None:
            self.frames_ok += 1
        else:
            self.error_frames += 1
        # counters: the error increments (rules 1-6) on the bases of rules 7 and 8
        for name, o in outcomes.items():
            node = by_name[name]
            # the bases carry rules 7 and 8 applied at the bit where they happened
            node.set_counters(o.tec0 + o.tec_delta, o.rec0 + o.rec_delta, end)
        for q in txs:
            node = q.node
            o = outcomes.get(node.name)
            q.on_wire = False
            if o is not None and o.success:
                self._tx_success(q, end, idle, start, passive=before[node.name] is PASSIVE, rule7=False)
                continue
            if o is not None and o.lost_arbitration:  # a flipped bit made it lose: not an error of its own
                q.losses += 1
                node.rounds_lost += 1
                q.head_since = self.rounds
                if q.one_shot:
                    node.fail(q, end, "arbitration lost (one-shot)", "arbitration")
                elif node.offered is q:
                    self.offer(node, q)
                continue
            if q.state is not QUEUED:
                continue
            if before.get(node.name) is PASSIVE or node.state is PASSIVE:
                self._suspend(node, idle)  # it transmitted as (or is now) error passive
            if q.one_shot:
                kind = o.detected[0] if o is not None and o.detected else "error"
                node.fail(q, end, f"{kind} error (one-shot)", kind.removesuffix("-arbitration"))
            elif node.state is BUS_OFF:
                pass  # stays queued; offered again after recovery
            else:
                node.retry(q)
        if winner is not None and winner.frame.remote and self._rtr:
            self._auto_reply(winner.frame, sender, [n for n, o in accepted])
        if self.record:
            changes = {n: (before[n], by_name[n].state) for n in outcomes if before[n] is not by_name[n].state}
            self._record_bitlevel(txs, start, end, res, changes)

    def _record_bitlevel(
        self,
        txs: tuple[TxRequest, ...],
        start: int,
        end: int,
        res: Any,
        changes: dict[str, tuple[ErrorState, ErrorState]],
    ) -> None:
        first = res.first_error
        detail: dict[str, Any] = {}
        if changes:
            detail["states"] = " ".join(f"{n}:{a.value}->{b.value}" for n, (a, b) in sorted(changes.items()))
        if first is not None:
            detail.update(error=first[0], field=first[1], bit=first[3])
        detail["seen_by"] = ",".join(sorted(n for n, o in res.outcomes.items() if o.primary))
        detail["counters"] = " ".join(f"{n.name}:{n.tec}/{n.rec}" for n in self.nodes if n.name in res.outcomes)
        detail["detected_by"] = ",".join(sorted(n for n, o in res.outcomes.items() if o.detected))
        detail["rules"] = ";".join(f"{n}:{','.join(o.rules)}" for n, o in sorted(res.outcomes.items()) if o.rules)
        detail["roles"] = ",".join(f"{n}:{o.role}" for n, o in sorted(res.outcomes.items()))
        acc = sorted(n for n, o in res.outcomes.items() if o.accepted)
        if acc:
            detail["accepted_by"] = ",".join(acc)
        integrating = sorted(n for n, o in res.outcomes.items() if o.integrating_bit >= 0)
        if integrating:
            detail["integrating"] = ",".join(integrating)
        before = res.before or {}
        if res.collision:
            detail["frames"] = " / ".join(repr(sent_frame(q.frame, before.get(q.node.name) is PASSIVE)) for q in txs)
        kind = "frame" if res.winner is not None else ("collision" if detail.get("frames") else "error")
        w = res.winner or txs[0] if txs else None
        if w is None:
            rec = TraceRecord(kind, start, end, "", Frame(0), res.bits, 0, start, detail)
        else:
            # the sender: every transmitter that got its frame through (identical frames from
            # several nodes), else every one that tried
            ok = [q.node.name for q in txs if getattr(res.outcomes.get(q.node.name), "success", False)]
            names = ok if res.winner is not None and ok else [q.node.name for q in txs]
            rec = TraceRecord(
                kind,
                start,
                end,
                "+".join(names),
                sent_frame(w.frame, before.get(w.node.name) is PASSIVE),
                res.bits,
                w.losses,
                w.t_queued,
                detail if (first or kind != "frame") else None,
            )
        self.trace.append(rec)
        for cb in self._bus_listeners:
            cb(rec)

    def _flush_for_direct(self) -> None:
        """Bring every buffering node up to date so a direct delivery lands in order."""
        if self._log:
            self._flush()
