"""Bit synchronisation: drifting clocks and bus lengths, simulated with a receiver in time quanta.

The receiver, `SyncReceiver` (time quanta; hard synchronisation, resynchronisation with SJW,
sampling, CAN FD's two timings), lives in `stack.phy.receiver` and is importable from here; the
CAN FD transmitter's secondary sample point is simulated in `stack.phy.tdc`.

The simulation sends frames from a transmitter at its own clock to a receiver whose clock is
off by ``drift_ppm``; it finds the largest drift that still receives every frame and compares it
with the ISO 11898-1 oscillator tolerance (a guaranteed bound for two nodes each off by df, so a
single drifting receiver works up to about twice that).

A single receiver cannot feel propagation delay: hard synchronisation absorbs it. Two nodes at the
ends of a bus can: `stack.phy.propagation` simulates the ACK round trip and arbitration across a
bus and the longest bus they allow (its names are importable from here too).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import can

from stack.phy.bittiming import Solution
from stack.phy.propagation import (
    ARBITRATION_FIELDS,
    DEFAULT_PHASES,
    BusLengthResult,
    Exchange,
    Node,
    ack_exchange,
    arbitration_exchange,
    max_bus_length_simulated,
    one_way_delay_ns,
)
from stack.phy.receiver import SyncReceiver
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
