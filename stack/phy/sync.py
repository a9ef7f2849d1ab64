"""Bit synchronisation: drifting clocks and bus lengths, simulated with a receiver in time quanta.

The receiver, `SyncReceiver` (time quanta; hard synchronisation, resynchronisation with SJW,
sampling, CAN FD's two timings), lives in `stack.phy.receiver` and is importable from here; the
CAN FD transmitter's secondary sample point is simulated in `stack.phy.tdc`.

The simulation sends frames from a transmitter at its own clock to a receiver whose clock is
off by ``drift_ppm``; it finds the largest drift that still receives every frame and compares it
with the ISO 11898-1 oscillator tolerance (a guaranteed bound for two nodes each off by df, so a
single drifting receiver works up to about twice that).

A single receiver cannot feel propagation delay: hard synchronisation absorbs it. Two nodes at the
ends of a bus can (`ack_exchange`, `arbitration_exchange`): the far node's time base lags by the
one-way delay, so its ACK bit, or the dominant bit with which it wins arbitration, reaches the
near node a round trip after that node's bit began and must arrive before its sample point.
`max_bus_length_simulated` searches the longest bus for which that holds and sets it beside the
Prop_Seg rule, which is stricter by Sync_Seg + Phase_Seg1 (kept free for oscillator drift).
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Any

import can

from stack.phy.bittiming import BusDelays, Solution, max_bus_length
from stack.phy.receiver import SyncReceiver
from stack.wire.coding import Field
from stack.wire.decoder import BitError, DecodedFrame
from stack.wire.frame import Frame

__all__ = [
    "Node",
    "SyncReceiver",
    "Reception",
    "DriftResult",
    "Failure",
    "receive",
    "worst_case_frames",
    "frames_received",
    "max_drift",
    "ARBITRATION_FIELDS",
    "Exchange",
    "BusLengthResult",
    "one_way_delay_ns",
    "ack_exchange",
    "arbitration_exchange",
    "max_bus_length_simulated",
]


# ---------------------------------------------------------------------------------------------
# Simulation


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


@dataclass(frozen=True)
class Reception:
    """What a receiver made of one transmitted frame.

    ``ok`` when the frame was decoded without error and equals the one sent; else ``kind`` is
    the error ('stuff', 'crc', 'form'), 'mismatch' (a valid but different frame) or 'lost'
    (no frame ended); ``error`` is the decoder's `BitError` when there is one.
    """

    ok: bool
    kind: str
    error: BitError | None
    decoded: DecodedFrame | None
    resyncs: int
    max_phase_error: int
    misread: int | None = None
    misread_field: str | None = None

    def describe(self) -> str:
        """One line: 'ok' or the error with its field and bit."""
        if self.ok:
            return "ok"
        where = ""
        if self.misread is not None:
            where = f"; first misread bit {self.misread} from SOF ({self.misread_field})"
        if self.error is not None:
            return f"{self.error}{where}"
        return self.kind + where


def receive(
    frame: Frame,
    timing: can.BitTiming,
    rx: Node = Node(),
    tx: Node = Node(),
    phase: float = 0.5,
) -> Reception:
    """Send ``frame`` from ``tx`` and let a `SyncReceiver` with ``rx``'s clock decode it.

    The bus carries the frame's bits (SOF..EOF, ACK slot dominant) each lasting one bit time of
    the transmitter's clock, delayed by ``rx.delay_ns - tx.delay_ns``. The receiver reads the bus
    once per own quantum; ``phase`` (0..1 tq) is where its quantum ticks fall relative to SOF.
    """
    if not 0.0 <= phase < 1.0:
        raise ValueError(f"phase={phase}: the receiver's clock phase is a fraction of a tq, 0 <= phase < 1")
    bits = [1 if c == "1" else 0 for c in frame.bits.bits]
    n = len(bits)
    tq_nominal = timing.brp * 1e9 / timing.f_clock
    bit_tx = timing.nbt * tx.tq_ns(tq_nominal)
    tq_rx = rx.tq_ns(tq_nominal)
    delay = rx.delay_ns - tx.delay_ns
    receiver = SyncReceiver.from_timing(timing)
    # start on an idle bus a few quanta before SOF reaches the receiver
    t0 = delay + (phase - 3) * tq_rx
    limit = int((n + 3) * bit_tx / tq_rx) + 8
    result: DecodedFrame | None = None
    for m in range(limit):
        idx = math.floor((t0 + m * tq_rx - delay) / bit_tx)
        result = receiver.tick(bits[idx] if 0 <= idx < n else 1)
        if result is not None:
            break
    # where sampling first went wrong: the decoder may only notice bits later (CRC, stuff)
    misread = next((i for i, b in enumerate(receiver.sampled) if i >= n or b != bits[i]), None)
    where: str | None = None
    if misread is not None and misread < n:
        fld, index = frame.bits.field_at(misread)
        where = f"{fld.value} bit {index}" if index is not None else f"stuff bit after {fld.value}"
    extra = (receiver.resyncs, receiver.max_phase_error, misread, where)
    if result is None:
        return Reception(False, "lost", None, None, *extra)
    if result.error is not None:
        return Reception(False, result.error.kind, result.error, result, *extra)
    if result.frame != frame:
        return Reception(False, "mismatch", None, result, *extra)
    return Reception(True, "ok", None, result, *extra)


def _edge_gaps(bits: str) -> list[int]:
    """Bits between consecutive recessive->dominant edges in the stuffed region."""
    edges = [i for i in range(1, len(bits)) if bits[i - 1] == "1" and bits[i] == "0"]
    return [b - a for a, b in zip(edges, edges[1:])]


@lru_cache(maxsize=1)
def worst_case_frames() -> tuple[Frame, ...]:
    """Frames that leave the longest stretches without a resynchronising edge.

    Stuffing bounds the distance between recessive->dominant edges to 10 bits (five dominant,
    a recessive stuff bit, four more recessive, a dominant stuff bit). Data made of 0000 1111
    runs, once a first run of five has forced a stuff bit, repeats that 10-bit pattern, so the
    phase error grows as long as possible before each resync, edge after edge. Picked among a
    few identifiers and every rotation of the pattern by the number of 10-bit gaps in a row;
    a frame of all-recessive data bytes and one of all-dominant ones complete the set.
    """
    best: list[tuple[int, Frame]] = []
    for can_id in (0x000, 0x00F, 0x0F0, 0x7FF, 0x3E0, 0x41F):
        for rot in range(8):
            byte = ((0x0F << rot) | (0x0F >> (8 - rot))) & 0xFF
            fr = Frame(can_id, bytes([byte]) * 8)
            run = longest = 0
            for g in _edge_gaps(fr.bits.bits):
                run = run + 1 if g == 10 else 0
                longest = max(longest, run)
            best.append((longest, fr))
    best.sort(key=lambda x: -x[0])
    return (best[0][1], Frame(0x7FF, b"\xff" * 8), Frame(0x000, b"\x00" * 8))


@dataclass(frozen=True)
class Failure:
    """The first failing reception at one drift: frame, receiver clock phase and what failed."""

    drift_ppm: float
    frame: Frame
    phase: float
    reception: Reception

    def as_dict(self) -> dict[str, Any]:
        """JSON form: drift, frame id/data, error kind, field, bit index in it and position."""
        err = self.reception.error
        return {
            "drift_ppm": round(self.drift_ppm, 3),
            "can_id": self.frame.can_id,
            "data": self.frame.data.hex(),
            "phase": self.phase,
            "kind": self.reception.kind,
            "field": err.field.value if err else None,
            "bit": err.index if err else None,
            "position": err.position if err else None,
            "misread_bit": self.reception.misread,
            "misread_field": self.reception.misread_field,
        }


DEFAULT_PHASES = (0.1, 0.5, 0.9)


def frames_received(
    timing: can.BitTiming,
    drift_ppm: float,
    frames: Sequence[Frame] | None = None,
    phases: Sequence[float] = DEFAULT_PHASES,
    delay_ns: float = 0.0,
) -> Failure | None:
    """None if a receiver off by +drift_ppm and by -drift_ppm receives every frame at every clock
    phase from a nominal-clock transmitter; else the first `Failure`."""
    frames = worst_case_frames() if frames is None else frames
    for d in (drift_ppm, -drift_ppm) if drift_ppm else (0.0,):
        rx = Node(d, delay_ns)
        for fr in frames:
            for ph in phases:
                r = receive(fr, timing, rx=rx, phase=ph)
                if not r.ok:
                    return Failure(d, fr, ph, r)
    return None


@dataclass(frozen=True)
class DriftResult:
    """Outcome of `max_drift`: the largest drift (ppm) receiving every frame, the ISO 11898-1
    oscillator tolerance of the timing (ppm), the first failure above it and the scan."""

    max_drift_ppm: float
    formula_ppm: float
    solution: Solution
    first_failure: Failure | None
    scan: tuple[tuple[float, Failure | None], ...] = field(default=())

    @property
    def margin(self) -> float:
        """How many times the formula's tolerance the simulation still receives."""
        return self.max_drift_ppm / self.formula_ppm if self.formula_ppm else math.inf

    def as_dict(self) -> dict[str, Any]:
        """JSON form with max_drift_ppm, formula_ppm, timing and first_failure."""
        s = self.solution
        return {
            "max_drift_ppm": round(self.max_drift_ppm, 3),
            "formula_ppm": round(self.formula_ppm, 3),
            "formula_resync_ppm": round(s.tolerance_resync * 1e4, 3),
            "formula_error_flag_ppm": round(s.tolerance_error_flag * 1e4, 3),
            "margin": round(self.margin, 3),
            "timing": {
                "brp": s.brp,
                "tseg1": s.tseg1,
                "tseg2": s.tseg2,
                "sjw": s.sjw,
                "nbt": s.nbt,
                "sample_point": round(s.sample_point, 3),
                "nof_samples": s.timing.nof_samples,
            },
            "first_failure": self.first_failure.as_dict() if self.first_failure else None,
            "scan": [
                {"drift_ppm": round(d, 3), "ok": f is None, "failure": None if f is None else f.reception.describe()}
                for d, f in self.scan
            ],
        }


def max_drift(
    solution: Solution,
    lo_ppm: float = 0.0,
    hi_ppm: float = 20_000.0,
    steps: int = 10,
    resolution_ppm: float = 10.0,
    frames: Sequence[Frame] | None = None,
    phases: Sequence[float] = DEFAULT_PHASES,
) -> DriftResult:
    """The largest receiver clock drift in [lo, hi] at which every frame is still received:
    a scan of ``steps`` intervals finds the first failing drift, bisection then narrows the
    boundary to ``resolution_ppm``. Compared with the oscillator tolerance formulas."""
    if not 0 <= lo_ppm < hi_ppm:
        raise ValueError(f"drift range {lo_ppm:g}..{hi_ppm:g} ppm: needs 0 <= low < high")
    if steps < 1 or resolution_ppm <= 0:
        raise ValueError(f"steps={steps}, resolution={resolution_ppm}: need steps >= 1 and resolution > 0")
    timing = solution.timing
    formula = solution.oscillator_tolerance * 1e4  # percent -> ppm
    scan: list[tuple[float, Failure | None]] = []
    good: float | None = None
    bad: tuple[float, Failure] | None = None
    for i in range(steps + 1):
        d = lo_ppm + (hi_ppm - lo_ppm) * i / steps
        f = frames_received(timing, d, frames, phases)
        scan.append((d, f))
        if f is not None:
            bad = (d, f)
            break
        good = d
    if bad is None:
        return DriftResult(hi_ppm, formula, solution, None, tuple(scan))
    if good is None:
        return DriftResult(math.nan, formula, solution, bad[1], tuple(scan))
    lo, (hi, failure) = good, bad
    while hi - lo > resolution_ppm:
        mid = (lo + hi) / 2
        f = frames_received(timing, mid, frames, phases)
        if f is None:
            lo = mid
        else:
            hi, failure = mid, f
    return DriftResult(lo, formula, solution, failure, tuple(scan))


# ---------------------------------------------------------------------------------------------
# Two nodes on a bus with propagation delay: the ACK round trip and arbitration

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
    lo = 0.0
    while hi - lo > resolution_m:
        mid = (lo + hi) / 2
        f = failure(mid)
        if f is None:
            lo = mid
        else:
            hi, bad = mid, f
    return BusLengthResult(lo, formula, sample_point, quantum, hi, bad, solution, delays)
