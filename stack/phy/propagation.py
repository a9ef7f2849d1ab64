"""Two nodes at the ends of a bus with propagation delay, simulated in time quanta: the ACK round
trip and arbitration.

A single receiver cannot feel propagation delay (`stack.phy.sync`): hard synchronisation absorbs
it. Two nodes at the ends of a bus can (`ack_exchange`, `arbitration_exchange`): the far node's
time base lags by the one-way delay, so its ACK bit, or the dominant bit with which it wins
arbitration, reaches the near node a round trip after that node's bit began and must arrive
before its sample point. `max_bus_length_simulated` searches the longest bus for which that holds
and sets it beside the Prop_Seg rule, which is stricter by Sync_Seg + Phase_Seg1 (kept free for
oscillator drift). Each node's bit timing is a `stack.phy.receiver.SyncReceiver`.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import can

from stack.phy.bittiming import BusDelays, Solution, max_bus_length
from stack.phy.boundary import last_working
from stack.phy.receiver import SyncReceiver
from stack.wire.coding import Field
from stack.wire.decoder import DecodedFrame
from stack.wire.frame import Frame

__all__ = [
    "Node",
    "DEFAULT_PHASES",
    "ARBITRATION_FIELDS",
    "Exchange",
    "BusLengthResult",
    "one_way_delay_ns",
    "ack_exchange",
    "arbitration_exchange",
    "max_bus_length_simulated",
]


@dataclass(frozen=True)
class Node:
    """A node's clock offset (ppm; > 0 runs fast) and propagation delay from the transmitter (ns)."""

    drift_ppm: float = 0.0
    delay_ns: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.drift_ppm) and -500_000 < self.drift_ppm < 500_000):
            raise ValueError(f"drift_ppm={self.drift_ppm}: a clock offset must be within +-500000 ppm")
        if not (math.isfinite(self.delay_ns) and self.delay_ns >= 0):
            raise ValueError(f"delay_ns={self.delay_ns}: a propagation delay must be >= 0")

    def tq_ns(self, nominal_tq_ns: float) -> float:
        """This node's time quantum: the nominal one divided by (1 + drift)."""
        return nominal_tq_ns / (1 + self.drift_ppm * 1e-6)


#: The phases (fractions of a time quantum) at which the simulations let a node's quanta fall
#: against the transmitter's: early, middle and late in a quantum.
DEFAULT_PHASES = (0.1, 0.5, 0.9)


#: Fields in which a transmitter that sends recessive and samples dominant has lost arbitration.
ARBITRATION_FIELDS = frozenset({Field.ID, Field.SRR, Field.IDE, Field.ID_EXT, Field.RTR})


@dataclass(frozen=True)
class Exchange:
    """Outcome of a two-node exchange (`ack_exchange`, `arbitration_exchange`).

    ``ok`` when everything happened as on an ideal bus; else ``kind`` is the first error seen:
    'ack' (a transmitter sampled its ACK slot recessive), 'bit' (a transmitter sampled a bit other
    than the one it sent, outside arbitration and the ACK slot), 'arbitration' (a node lost
    arbitration at another bit than the first one where the two identifiers differ, or the
    wrong node lost), a receiver's 'stuff', 'crc' or 'form' error, 'mismatch' (a valid but
    different frame) or 'lost' (the exchange did not finish). ``node`` is the node ('A' or 'B')
    that detected it, ``field``/``index``/``position`` the bit (index None for a stuff bit),
    ``winner`` the node whose frame won the bus (arbitration only), ``exchange`` which
    exchange ran ('ack' or 'arbitration').
    """

    ok: bool
    kind: str
    node: str | None
    field: Field | None
    index: int | None
    position: int | None
    delay_ns: float
    winner: str | None = None
    detail: str = ""
    exchange: str = ""

    def describe(self) -> str:
        """One line: 'ok' or the error, the node that saw it, its field and bit."""
        if self.ok:
            return "ok" + (f" (node {self.winner} won arbitration)" if self.winner else "")
        if self.exchange:
            return f"{self.exchange} exchange, " + replace(self, exchange="").describe()
        where = ""
        if self.field is not None:
            bit = f"bit {self.index}" if self.index is not None else "stuff bit"
            where = f" in {self.field.value} {bit} (bit {self.position} from SOF)"
        text = f"node {self.node}: {self.kind} error{where}" if self.node else f"{self.kind}{where}"
        return text + (f"; {self.detail}" if self.detail else "")

    def as_dict(self) -> dict[str, Any]:
        """JSON form: ok, kind, node, field, bit index, position, one-way delay, winner, detail."""
        return {
            "ok": self.ok,
            "kind": self.kind,
            "node": self.node,
            "field": self.field.value if self.field is not None else None,
            "bit": self.index,
            "position": self.position,
            "delay_ns": round(self.delay_ns, 3),
            "winner": self.winner,
            "detail": self.detail,
            "exchange": self.exchange,
        }


class _BusNode:
    """One node of the two-node bus: a `SyncReceiver` for its bit timing plus its CAN_TX output.

    The node's own output is seen at its RX without delay (the transmitter's time base is the
    reference, as in the Prop_Seg rule); the other node's output arrives ``delay_ns`` later.
    A transmitter drives each bit from the start of its Sync_Seg; a receiver drives the ACK slot
    dominant when the CRC it received matched.
    """

    def __init__(
        self,
        name: str,
        timing: can.BitTiming,
        tq_ns: float,
        first_tick_ns: float,
        frame: Frame | None,
        start_ns: float | None,
    ) -> None:
        self.name = name
        self.rx = SyncReceiver.from_timing(timing)
        self.tq_ns = tq_ns
        self.first_tick_ns = first_tick_ns
        self.ticks = 0
        self.frame = frame
        if frame is not None:
            bits = list(frame.bits.bits)
            bits[frame.bits.position(Field.ACK_SLOT)] = "1"  # the transmitter sends it recessive
            self.tx_bits: list[int] = [1 if c == "1" else 0 for c in bits]
        else:
            self.tx_bits = []
        self.start_ns = start_ns
        self.transmitting = frame is not None
        self.lost_at: int | None = None
        self.result: DecodedFrame | None = None
        self.done = False
        self._times: list[float] = [-math.inf]
        self._levels: list[int] = [1]

    @property
    def next_tick_ns(self) -> float:
        return self.first_tick_ns + self.ticks * self.tq_ns

    def drive(self, t: float, level: int) -> None:
        if level != self._levels[-1]:
            self._times.append(t)
            self._levels.append(level)

    def level_at(self, t: float) -> int:
        """This node's CAN_TX at time t (a change at exactly t is already visible)."""
        return self._levels[bisect_right(self._times, t) - 1]

    def bit_start(self, t: float) -> None:
        """The node's Sync_Seg of a new bit begins at t: drive that bit."""
        rx = self.rx
        i = len(rx.sampled)
        if self.transmitting:
            self.drive(t, self.tx_bits[i] if i < len(self.tx_bits) else 1)
        else:
            dec = rx.decoder
            ack = dec.in_frame and dec.field == Field.ACK_SLOT and dec.crc_matches
            self.drive(t, 0 if ack else 1)


def _exchange(
    timing: can.BitTiming,
    delay_ns: float,
    frame_a: Frame,
    frame_b: Frame | None,
    drift_a_ppm: float,
    drift_b_ppm: float,
    phase: float,
    b_start_ns: float | None,
    expected: tuple[str, int] | None,
) -> Exchange:
    """Run nodes A (transmits ``frame_a`` from t = 0) and B (receives, or transmits ``frame_b``)
    until both have finished the frame or the first error; see `ack_exchange`."""
    if not 0.0 <= phase < 1.0:
        raise ValueError(f"phase={phase}: the receiver's clock phase is a fraction of a tq, 0 <= phase < 1")
    if not (math.isfinite(delay_ns) and delay_ns >= 0):
        raise ValueError(f"delay_ns={delay_ns}: a propagation delay must be a finite number >= 0")
    tq_nominal = timing.brp * 1e9 / timing.f_clock
    tq_a, tq_b = Node(drift_a_ppm).tq_ns(tq_nominal), Node(drift_b_ppm).tq_ns(tq_nominal)
    # A ticks at t = 0 (its SOF); B's quanta fall `phase` tq after A's SOF edge reaches it
    a = _BusNode("A", timing, tq_a, -3 * tq_a, frame_a, 0.0)
    b = _BusNode("B", timing, tq_b, delay_ns + (phase - 3) * tq_b, frame_b, b_start_ns)
    other = {a: b, b: a}
    longest = max(len(frame_a.bits.bits), len(frame_b.bits.bits) if frame_b else 0)
    t_end = (longest + 4) * timing.nbt * max(tq_a, tq_b) * 1.1 + 2 * delay_ns + 10 * tq_nominal

    def fail(kind: str, node: _BusNode | None, pos: int | None, frame: Frame | None, detail: str = "") -> Exchange:
        fld: Field | None = None
        idx: int | None = None
        if pos is not None and frame is not None and pos < frame.bits.length:
            fld, idx = frame.bits.field_at(pos)
        return Exchange(False, kind, node.name if node else None, fld, idx, pos, delay_ns, None, detail)

    while True:
        t = min(a.next_tick_ns, b.next_tick_ns)
        if t > t_end:
            busy = [n.name for n in (a, b) if not n.done]
            return Exchange(
                False,
                "lost",
                None,
                None,
                None,
                None,
                delay_ns,
                None,
                f"node(s) {', '.join(busy)} did not finish the frame",
            )
        nodes = [n for n in (a, b) if n.next_tick_ns == t]
        started: dict[_BusNode, bool] = {}
        for n in nodes:  # outputs first, then reads: a node sees its own new bit in its Sync_Seg
            rx = n.rx
            started[n] = False
            if n.done:
                continue
            if rx.idle and n.transmitting and n.start_ns is not None and t >= n.start_ns and not rx.sampled:
                n.drive(t, 0)  # SOF
                started[n] = True
            elif not rx.idle and rx.position == 0:
                n.bit_start(t)
                started[n] = True
        for n in nodes:
            n.ticks += 1
            if n.done:
                continue
            rx = n.rx
            syncs = (rx.hard_syncs, rx.resyncs)
            sampled = len(rx.sampled)
            level = min(n.level_at(t), other[n].level_at(t - delay_ns))
            res = rx.tick(level)
            if not started[n] and not rx.idle and rx.position == 1 and (rx.hard_syncs, rx.resyncs) != syncs:
                # the edge made this quantum a Sync_Seg (hard sync, or resync with e < 0):
                # a node with a frame pending joins the SOF it saw, as ISO 11898-1 allows
                n.bit_start(t)
            if len(rx.sampled) > sampled and n.transmitting:
                i = len(rx.sampled) - 1
                bit, sent = rx.sampled[i], n.tx_bits[i] if i < len(n.tx_bits) else 1
                assert n.frame is not None
                fld, idx = n.frame.bits.field_at(i) if i < n.frame.bits.length else (None, None)
                if fld == Field.ACK_SLOT:
                    if bit == 1:
                        return fail("ack", n, i, n.frame, "ACK slot sampled recessive: no acknowledgement seen")
                elif bit != sent:
                    if sent == 1 and fld in ARBITRATION_FIELDS and idx is not None:
                        n.transmitting, n.lost_at = False, i
                        n.drive(t, 1)
                        if expected is None or expected != (n.name, i):
                            want = "none" if expected is None else f"node {expected[0]} at bit {expected[1]} from SOF"
                            return fail(
                                "arbitration", n, i, n.frame, f"node {n.name} lost arbitration here; expected {want}"
                            )
                    else:
                        return fail(
                            "bit",
                            n,
                            i,
                            n.frame,
                            f"sent {'recessive' if sent else 'dominant'}, sampled {'recessive' if bit else 'dominant'}",
                        )
            if res is not None:
                n.result = res
                n.done = True
                n.drive(t, 1)
                if res.error is not None:
                    e = res.error
                    return Exchange(
                        False,
                        e.kind,
                        n.name,
                        e.field,
                        e.index,
                        e.position,
                        delay_ns,
                        None,
                        "receiver error" if not n.transmitting else "transmitter's own frame",
                    )
        if a.done and b.done:
            break
    # both frames ended: check who won and what each node received
    if expected is not None:
        loser = a if expected[0] == "A" else b
        if loser.lost_at is None:
            return fail(
                "arbitration",
                loser,
                expected[1],
                loser.frame,
                f"node {loser.name} should have lost arbitration here and did not",
            )
    winner = next(n for n in (a, b) if n.frame is not None and n.lost_at is None)
    for n in (a, b):
        if n is not winner and (n.result is None or n.result.frame != winner.frame):
            return Exchange(
                False,
                "mismatch",
                n.name,
                None,
                None,
                None,
                delay_ns,
                None,
                f"node {n.name} received {n.result.frame if n.result else None}, "
                f"node {winner.name} sent {winner.frame}",
            )
    return Exchange(True, "ok", None, None, None, None, delay_ns, winner.name if frame_b is not None else None)


def one_way_delay_ns(delays: BusDelays) -> float:
    """One-way propagation delay between the two ends of the bus: bus length x cable delay +
    transceiver + comparator delay (half the round trip the Prop_Seg rule covers)."""
    return delays.round_trip_ns / 2


def ack_exchange(
    frame: Frame,
    timing: can.BitTiming,
    delays: BusDelays = BusDelays(),
    drift_a_ppm: float = 0.0,
    drift_b_ppm: float = 0.0,
    phase: float = 0.5,
) -> Exchange:
    """Node A transmits ``frame``; node B at the far end of the bus receives and acknowledges it.

    Rule (ISO 11898-1, ACK slot; Prop_Seg rule): B hard-synchronises on the SOF edge as it sees it,
    ``one_way_delay_ns(delays)`` after A sent it (in the quantum ``phase`` tq after the edge
    arrives), resynchronises on the later edges and drives the ACK slot dominant from the start
    of its own ACK bit when its CRC matched. A, which sends the ACK slot recessive, sees B's ACK a
    round trip after its own bit started and samples it at its own sample point: when the round
    trip plus B's synchronisation lag passes that point, A samples recessive and reports an ACK
    error in ACK_SLOT. Each node's clock is off by its ``drift_*_ppm``.
    """
    r = _exchange(timing, one_way_delay_ns(delays), frame, None, drift_a_ppm, drift_b_ppm, phase, None, None)
    return replace(r, exchange="ack")


def arbitration_exchange(
    frame_a: Frame,
    frame_b: Frame,
    timing: can.BitTiming,
    delays: BusDelays = BusDelays(),
    drift_a_ppm: float = 0.0,
    drift_b_ppm: float = 0.0,
    phase: float = 0.5,
    b_start_ns: float | None = None,
) -> Exchange:
    """Nodes A and B at the two ends of the bus start ``frame_a`` and ``frame_b`` together.

    Rule (ISO 11898-1 bitwise arbitration; Prop_Seg rule): A sends SOF at t = 0; B starts at
    ``b_start_ns`` or, when None, joins A's SOF as it arrives (the latest start that is still
    "together": B's time base then lags A's by the one-way delay, the worst case). Both
    hard-synchronise on the first SOF edge they see. At the first bit where the identifiers
    differ the node sending recessive must sample the other's dominant bit, which reaches it a
    round trip after its own bit began, before its sample point: it then loses arbitration
    there and receives (and acknowledges) the winner's frame. Anything else is reported: a node
    losing at another bit or the wrong node losing ('arbitration'), a bit error ('bit'), an
    ACK error ('ack') or a receiver's error. The frames need different arbitration keys.
    """
    fa, fb = frame_a.bits.bits, frame_b.bits.bits
    first = next((i for i, (x, y) in enumerate(zip(fa, fb)) if x != y), None)
    if first is None or frame_a.bits.field_at(first)[0] not in ARBITRATION_FIELDS:
        raise ValueError(f"{frame_a!r} and {frame_b!r}: arbitration needs frames whose arbitration fields differ")
    expected = ("A" if fa[first] == "1" else "B", first)
    r = _exchange(
        timing, one_way_delay_ns(delays), frame_a, frame_b, drift_a_ppm, drift_b_ppm, phase, b_start_ns, expected
    )
    return replace(r, exchange="arbitration")


#: Default frames for the bus-length search: A's frame (also the one acknowledged) and a frame for
#: B whose identifier is lower (0x652 < 0x65A, first differing at ID bit 7), so that B, the node
#: whose time base lags, must win with a dominant bit that crosses the bus back to A.
BUS_LENGTH_FRAMES = (Frame(0x65A, b"\x5a"), Frame(0x652, b"\xa5"))


@dataclass(frozen=True)
class BusLengthResult:
    """Outcome of `max_bus_length_simulated` (lengths in m).

    ``simulated_m``: the largest bus length at which the ACK round trip and arbitration still
    work; ``formula_m``: bittiming's Prop_Seg rule, Prop_Seg x tq >= 2 x (L x cable + transceiver
    + comparator); ``sample_point_m``: the length whose round trip just reaches the sample point,
    (Sync_Seg + Prop_Seg + Phase_Seg1) x tq = 2 x delays; ``quantum_m``: one tq of round trip as
    cable length, tq / (2 x cable ns/m); ``first_failure``: the exchange that failed just beyond
    ``simulated_m`` (None if none failed up to ``failure_length_m``).
    """

    simulated_m: float
    formula_m: float
    sample_point_m: float
    quantum_m: float
    failure_length_m: float
    first_failure: Exchange | None
    solution: Solution
    delays: BusDelays

    @property
    def reserve_m(self) -> float:
        """Simulated minus formula length: the Sync_Seg + Phase_Seg1 the Prop_Seg rule keeps free
        for phase errors (oscillator drift), less up to one tq of synchronisation lag."""
        return self.simulated_m - self.formula_m

    def as_dict(self) -> dict[str, Any]:
        """JSON form with the three lengths, the quantum, the first failure and the delays."""
        d = self.delays
        return {
            "simulated_m": round(self.simulated_m, 2),
            "formula_m": round(self.formula_m, 2),
            "sample_point_m": round(self.sample_point_m, 2),
            "quantum_m": round(self.quantum_m, 2),
            "failure_length_m": round(self.failure_length_m, 2),
            "prop_seg": self.solution.prop_seg,
            "phase_seg1": self.solution.phase_seg1,
            "tq_ns": round(self.solution.tq_ns, 3),
            "cable_delay_ns_per_m": d.cable_delay_ns_per_m,
            "transceiver_delay_ns": d.transceiver_delay_ns,
            "comparator_delay_ns": d.comparator_delay_ns,
            "first_failure": self.first_failure.as_dict() if self.first_failure else None,
        }


def max_bus_length_simulated(
    solution: Solution,
    delays: BusDelays | None = None,
    frames: tuple[Frame, Frame] = BUS_LENGTH_FRAMES,
    phases: Sequence[float] = DEFAULT_PHASES,
    drift_ppm: float = 0.0,
    resolution_m: float = 0.1,
) -> BusLengthResult:
    """The largest bus length at which `ack_exchange` and `arbitration_exchange` still work,
    beside bittiming's Prop_Seg rule (Prop_Seg >= 2 x (bus + transceiver + comparator delays)).

    ``delays`` gives the cable delay per m and the node delays (default: the solution's; its
    bus length is the variable searched). Every exchange runs at every B clock ``phase`` and with
    B's clock off by +drift_ppm and -drift_ppm (A nominal); bisection narrows the boundary to
    ``resolution_m``.

    What limits a real bus is the sample point: the far node's dominant bit (its ACK, or the bit
    that wins arbitration) starts one one-way delay after it saw the near node's bit start and
    crosses the bus back, so it must arrive within Sync_Seg + Prop_Seg + Phase_Seg1 of the near
    node's bit start. The far node synchronises in the quantum after the edge reaches it, up to
    one tq late, so with ideal clocks the simulated boundary lies within one tq of round trip
    (``quantum_m``) below ``sample_point_m``, depending on its clock phase. The Prop_Seg rule is
    stricter by Sync_Seg + Phase_Seg1: it keeps Phase_Seg1 free for the phase errors of
    oscillator drift, so the simulated length exceeds ``formula_m`` by about (1 + Phase_Seg1) tq
    of round trip, less the synchronisation lag. With the clocks at the oscillator tolerance a
    bus at ``formula_m`` still works; drift eats into the margin above it.
    """
    if delays is None:
        delays = solution.delays
    if delays.cable_delay_ns_per_m <= 0:
        raise ValueError("cable delay 0 ns/m: every bus length has the same delay, there is no maximum")
    if resolution_m <= 0:
        raise ValueError(f"resolution={resolution_m} m: needs a resolution > 0")
    if not (math.isfinite(drift_ppm) and 0 <= drift_ppm < 500_000):
        raise ValueError(f"drift_ppm={drift_ppm}: needs 0 <= drift < 500000 ppm")
    timing, tq = solution.timing, solution.tq_ns
    cable = delays.cable_delay_ns_per_m
    fa, fb = frames

    def failure(length: float) -> Exchange | None:
        d = replace(delays, bus_length_m=length)
        for drift in (drift_ppm, -drift_ppm) if drift_ppm else (0.0,):
            for ph in phases:
                for r in (
                    ack_exchange(fa, timing, d, 0.0, drift, ph),
                    arbitration_exchange(fa, fb, timing, d, 0.0, drift, ph),
                ):
                    if not r.ok:
                        return r
        return None

    formula = max_bus_length(solution.prop_seg, tq, delays)
    sample_point = max(0.0, ((1 + solution.tseg1) * tq / 2 - delays.node_delay_ns) / cable)
    quantum = tq / (2 * cable)
    # a round trip of a whole bit time (plus the drift) certainly fails
    hi = (timing.nbt * tq * (1 + drift_ppm * 1e-6) / 2) / cable + 1.0
    bad = failure(hi)
    if bad is None:
        return BusLengthResult(hi, formula, sample_point, quantum, hi, None, solution, delays)
    at_zero = failure(0.0)
    if at_zero is not None:
        return BusLengthResult(math.nan, formula, sample_point, quantum, 0.0, at_zero, solution, delays)
    lo, hi, bad = last_working(failure, 0.0, hi, bad, resolution_m)
    return BusLengthResult(lo, formula, sample_point, quantum, hi, bad, solution, delays)
