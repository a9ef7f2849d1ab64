"""Bit synchronisation: a receiver working in time quanta, and a drifting-clock simulation.

Rules (ISO 11898-1 / Bosch CAN 2.0, see DESIGN.md "Bit timing and synchronisation"):
- Hard synchronisation: on the recessive->dominant edge that starts a frame (bus idle) the bit
  time restarts with the quantum holding that edge as Sync_Seg.
- Resynchronisation on recessive->dominant edges inside the frame, phase error e in tq:
  e = 0 in Sync_Seg; e > 0 before the sample point lengthens Phase_Seg1 by min(e, SJW);
  e < 0 after it shortens Phase_Seg2 by min(|e|, SJW) (|e| <= SJW starts the next bit at once).
- One synchronisation between two sample points, and only on an edge whose previous sample
  point was recessive (the value after the edge must differ from the last sampled value).
- The bit is sampled at the end of Phase_Seg1, once or three times (majority of the last three
  quanta of TSEG1), then destuffed and checked by `BitDecoder`.

The simulation sends frames from a transmitter at its own clock to a receiver whose clock is
off by ``drift_ppm``; it finds the largest drift that still receives every frame and compares it
with the ISO 11898-1 oscillator tolerance (a guaranteed bound for two nodes each off by df, so a
single drifting receiver works up to about twice that).
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any, Sequence

import can

from .bits import BitDecoder, BitError, DecodedFrame
from .bittiming import Solution, add_timing_arguments, limits_from_args, solve
from .frame import Frame

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
    "register",
]


# ---------------------------------------------------------------------------------------------
# The receiver


class SyncReceiver:
    """A CAN receiver's bit timing logic, advanced one time quantum at a time with `tick`.

    ``tseg1``/``tseg2``/``sjw`` are in tq (Sync_Seg is 1 tq); ``nof_samples`` is 1 or 3. `tick`
    takes the bus level read in that quantum (0 dominant, 1 recessive) and returns the
    `DecodedFrame` when a frame ends (valid or at its first error), else None. Counters
    ``hard_syncs``, ``resyncs`` and ``max_phase_error`` (largest |e| seen, in tq) describe the
    synchronisation work done.
    """

    def __init__(self, tseg1: int, tseg2: int, sjw: int, nof_samples: int = 1) -> None:
        if tseg1 < 1 or tseg2 < 1:
            raise ValueError(f"tseg1={tseg1}, tseg2={tseg2}: both segments need at least 1 tq")
        if not 1 <= sjw <= tseg2:
            raise ValueError(f"sjw={sjw}: needs 1 <= SJW <= Phase_Seg2 ({tseg2})")
        if nof_samples not in (1, 3):
            raise ValueError(f"nof_samples={nof_samples}: a bit is sampled once or three times")
        if nof_samples == 3 and tseg1 < 3:
            raise ValueError(f"tseg1={tseg1}: three samples need TSEG1 >= 3 tq")
        self.tseg1, self.tseg2, self.sjw, self.nof_samples = tseg1, tseg2, sjw, nof_samples
        self.decoder = BitDecoder()
        self.hard_syncs = 0
        self.resyncs = 0
        self.max_phase_error = 0
        self._prev = 1
        self._idle = True
        self._reads: list[int] = [1, 1, 1]
        self.sampled: list[int] = []  # bits sampled in the current/last frame, SOF first
        self._synced = True
        self._last_sample = 1
        self._new_bit()

    @classmethod
    def from_timing(cls, timing: can.BitTiming) -> "SyncReceiver":
        """A receiver for a `can.BitTiming` (its tseg1, tseg2, sjw and nof_samples)."""
        return cls(timing.tseg1, timing.tseg2, timing.sjw, timing.nof_samples)

    @property
    def idle(self) -> bool:
        """True while waiting for the edge that starts a frame."""
        return self._idle

    @property
    def position(self) -> int:
        """Quantum index within the current bit of the next tick (0 = Sync_Seg)."""
        return self._pos

    @property
    def sample_point(self) -> int:
        """Quantum index of the current bit's sample point: 1 + TSEG1, plus any lengthening."""
        return self._sample_at

    @property
    def bit_length(self) -> int:
        """Quanta in the current bit: NBT, lengthened or shortened by resynchronisation."""
        return self._bit_end

    def _new_bit(self) -> None:
        self._pos = 0
        self._sample_at = 1 + self.tseg1  # quantum index of the sample point
        self._bit_end = 1 + self.tseg1 + self.tseg2

    def tick(self, level: int) -> DecodedFrame | None:
        """Advance one time quantum with the bus read as ``level``; see the class docstring."""
        edge = self._prev == 1 and level == 0
        self._prev = level
        reads = self._reads
        reads[0], reads[1], reads[2] = reads[1], reads[2], level
        if self._idle:
            if not edge:
                return None
            # hard synchronisation: this quantum is Sync_Seg of SOF
            self._idle = False
            self.hard_syncs += 1
            self.sampled = []
            self._new_bit()
            self._synced = True
            self._last_sample = 1
        elif edge and not self._synced and self._last_sample == 1:
            self._resync()
        result = None
        if self._pos == self._sample_at:
            bit = level if self.nof_samples == 1 else int(reads[0] + reads[1] + reads[2] >= 2)
            self._synced = False
            self._last_sample = bit
            if self.decoder.position == 0 and bit == 1:
                # a recessive SOF sample: it was a glitch, not a frame (back to bus idle)
                self._idle = True
                return None
            self.sampled.append(bit)
            result = self.decoder.feed(bit)
            if result is not None:
                self._idle = True
                return result
        self._pos += 1
        if self._pos >= self._bit_end:
            self._new_bit()
        return result

    def _resync(self) -> None:
        """Resynchronisation on an edge at quantum ``_pos`` of the current bit."""
        pos = self._pos
        self._synced = True
        if pos == 0:
            return  # e = 0: the edge is in Sync_Seg
        self.resyncs += 1
        if pos <= self._sample_at:
            # e > 0: the edge is late, lengthen Phase_Seg1
            e = pos
            self._sample_at += min(e, self.sjw)
            self._bit_end = self._sample_at + self.tseg2
        else:
            # e < 0: the edge is early (it belongs to the next bit), shorten Phase_Seg2
            e = pos - self._bit_end
            if -e <= self.sjw:
                self._new_bit()  # the edge quantum becomes Sync_Seg, as a hard sync would
            else:
                self._bit_end -= self.sjw
        self.max_phase_error = max(self.max_phase_error, abs(e))


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
# CLI


def _drift_range(text: str) -> tuple[float, float]:
    lo, dots, hi = text.partition("..")
    try:
        a, b = (float(lo), float(hi)) if dots else (0.0, float(lo))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected LOW..HIGH in ppm, e.g. 0..20000") from None
    if not (0 <= a < b and math.isfinite(b)):
        raise argparse.ArgumentTypeError(f"{text!r}: a drift range needs 0 <= LOW < HIGH")
    if b >= 500_000:
        raise argparse.ArgumentTypeError(f"{text!r}: drift beyond 500000 ppm is not a clock offset")
    return a, b


def _run(args: argparse.Namespace) -> int:
    lim = limits_from_args(args)
    sol = solve(args.clock, args.bitrate, sample_point=args.sample_point, limits=lim, sjw=args.sjw)
    if args.samples == 3:
        t = sol.timing
        sol = Solution(
            type(t)(f_clock=t.f_clock, brp=t.brp, tseg1=t.tseg1, tseg2=t.tseg2, sjw=t.sjw, nof_samples=3),
            sol.prop_seg, sol.phase_seg1, sol.phase_seg2, sol.limits, sol.delays,
            sol.bitrate_nominal, sol.sample_point_nominal,
        )
    lo, hi = args.drift_ppm
    res = max_drift(sol, lo, hi, steps=args.steps, resolution_ppm=args.resolution)
    if args.json:
        print(json.dumps(res.as_dict(), indent=2))
        return 0
    s = sol
    print(
        f"{args.bitrate} bit/s, {args.clock} Hz clock: brp {s.brp}, {s.nbt} tq (tseg1 {s.tseg1}, tseg2 {s.tseg2}), "
        f"sjw {s.sjw}, sample point {s.sample_point:.1f} %, {s.timing.nof_samples} sample(s)"
    )
    print("frames: " + ", ".join(f"0x{f.can_id:03x} [{f.data.hex()}]" for f in worst_case_frames()))
    for d, f in res.scan:
        print(f"  drift +-{d:8.0f} ppm: {'ok' if f is None else f'fails ({f.drift_ppm:+.0f} ppm): ' + f.reception.describe()}")
    if math.isnan(res.max_drift_ppm):
        print(f"reception fails already at {lo:g} ppm")
    elif res.first_failure is None:
        print(f"frames received over the whole range, up to {hi:g} ppm")
    else:
        ff = res.first_failure
        print(f"largest drift received: {res.max_drift_ppm:.0f} ppm")
        print(
            f"first failure at {ff.drift_ppm:+.0f} ppm, frame 0x{ff.frame.can_id:03x}: {ff.reception.describe()}"
        )
    print(
        f"formula tolerance: {res.formula_ppm:.0f} ppm (SJW/(20 NBT) {s.tolerance_resync * 1e4:.0f}, "
        f"min(PS1,PS2)/(2(13 NBT-PS2)) {s.tolerance_error_flag * 1e4:.0f}); "
        f"simulation reaches {res.margin:.2f} x that"
    )
    return 0


def register(subparsers: Any) -> None:
    """Add the `sync` subcommand."""
    p = subparsers.add_parser(
        "sync",
        help="simulate resynchronisation with a drifting receiver clock",
        description="Find the largest receiver clock drift at which worst-case frames are still "
        "received, against the ISO 11898-1 oscillator tolerance.",
    )
    add_timing_arguments(p)
    p.add_argument("--drift-ppm", type=_drift_range, default=(0.0, 20_000.0), help="range LOW..HIGH in ppm (0..20000)")
    p.add_argument("--samples", type=int, choices=(1, 3), default=1, help="samples per bit (1 or 3)")
    p.add_argument("--steps", type=int, default=10, help="scan intervals before bisection (10)")
    p.add_argument("--resolution", type=float, default=10.0, help="bisection resolution in ppm (10)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=_run)
