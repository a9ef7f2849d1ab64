"""The system matrix of a time-triggered CAN network (ISO 11898-4, TTCAN): the `Schedule` a
scenario's ``[tdma]`` table describes (read and checked by `profiles.tdma.parse`), and the
reference message's layout.

Terms are the standard's. A *basic cycle* starts with the *reference message* of the current
time master and is cut into *time windows*; ``matrix_cycles`` basic cycles (1, 2, 4 … 64) make
the *system matrix*, and the reference message's Cycle_Count says which row of the matrix runs.
A window is *exclusive* (one message of one node, sent without contention and without automatic
retransmission), *arbitrating* (event messages compete by CAN arbitration inside it) or *free*
(reserved). A window entry is used in the basic cycles ``c`` with ``c mod repeat == base_cycle``
(the standard's Repeat_Factor and Cycle_Offset), ``repeat`` a power of two.

An *arbitrating* window is a *single* arbitrating window (``arbitration = "single"``: a frame may
start only inside the Tx_Enable window at its start, without automatic retransmission — one that
loses arbitration or is destroyed waits for its message's next trigger) or a *merged* one
(``"merged"``, the default: the standard's sequence of consecutive arbitrating windows merged
into one, in which frames start throughout and retry after a lost arbitration, up to the last
start that still ends, with the error budget, inside it).

Times in the table are µs of the time master's clock; inside they are integer ns of it ("NTU
ns"). The network time unit (NTU): at level 1 the nominal bit time; at level 2 the time unit
ratio times the period of the CAN clock it is counted in (``tur`` × 1 / ``can_clock_mhz``, both
required at level 2; ISO 11898-4's TUR, held by M_TTCAN as NC/DC with NC 0x10000..0x1FFFF and DC
0x0001..0x3FFF, so 4.0002 ≤ TUR ≤ 131071). Time marks, Tx_Enable, Ref_Trigger_Offset and the
16-bit Cycle_Time count in NTU, so every time of the table is a whole number of NTU.

Ranges checked by `profiles.tdma.parse` (ISO 11898-4 as M_TTCAN and the TC1796 MultiCAN manual implement it): Tx_Enable
1..16 NTU (M_TTCAN TTOCF.TEW, 4 bits); Initial_Ref_Offset 0..127 NTU; Cycle_Time and the
Watch_Trigger within 16 bits of NTU; the matrix 1..64 basic cycles, a power of two; Repeat_Factor
a power of two up to the matrix, Cycle_Offset below it; 1..8 potential time masters. Gap mode
(Next_is_Gap, a basic cycle that waits for an event before its reference message) is not
modelled: ``gap_mode = true`` is refused.

Reference message (the numbers and where they come from):

- identifier: the configured ``reference_id`` with its three least significant bits replaced by
  the sending time master's priority 0..7 (0 highest: the lowest identifier wins arbitration) —
  up to 8 potential time masters (Bosch M_TTCAN user's manual §4.1.1; Infineon TC1796 MultiCAN
  manual §22.5.8: "the 3 least significant bits ID[2:0] … are taken from TMPRIO");
- data byte 0: bit 7 Next_is_Gap, bit 6 reserved (sent 0, ignored), bits 5..0 Cycle_Count
  0..63 — one byte at level 1 (DLC ≥ 1, M_TTCAN §4.1.1 and TC1796 "RMDLC at least 1 in level 1");
- level 2 (DLC ≥ 4, same sources): byte 1 bit 0 Disc_Bit (a discontinuity of the global time),
  bits 7..1 NTU_Res (the fraction of Master_Ref_Mark, 1/128 NTU); bytes 2..3 Master_Ref_Mark,
  the master's global time at the reference's start of frame in NTU, 16 bits. The byte order of
  Master_Ref_Mark (low byte in byte 2) is this module's choice: the sources found name the fields
  and the DLC but not their order.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import NamedTuple

from profiles.analysis.rta import frame_bits_worst
from stack import Frame

__all__ = [
    "Schedule",
    "Window",
    "ReferenceInfo",
    "encode_reference",
    "decode_reference",
    "EXCLUSIVE",
    "ARBITRATING",
    "FREE",
    "MATRIX_SIZES",
    "MAX_TIME_MASTERS",
    "CYCLE_TIME_NTU",
    "MARK_MODULUS",
    "frame_ns_worst",
    "SINGLE",
    "MERGED",
    "TX_ENABLE_NTU",
    "TUR_RANGE",
]

EXCLUSIVE = "exclusive"
ARBITRATING = "arbitrating"
FREE = "free"
SINGLE = "single"
MERGED = "merged"
TX_ENABLE_NTU = (1, 16)
"""Tx_Enable in NTU: M_TTCAN's TTOCF.TEW holds 0..15 for 1..16 NTU."""
TUR_RANGE = (0x10000 / 0x3FFF, float(0x1FFFF))
"""The time unit ratios M_TTCAN's TURCF can hold: NC / DC with NC 0x10000..0x1FFFF, DC 1..0x3FFF."""
MATRIX_SIZES = (1, 2, 4, 8, 16, 32, 64)
"""Basic cycles in a system matrix: Cycle_Count has 6 bits (0..63)."""
MAX_TIME_MASTERS = 8
"""Three identifier bits carry the time master's priority."""
CYCLE_TIME_NTU = 0xFFFF
"""Cycle_Time and the time marks are 16-bit NTU counts: a basic cycle (with its watch trigger)
fits in 65535 NTU (the Init_Watch_Trigger fires at 2^16 - 1, TC1796 §22.7.3)."""
REF_OFFSET_LIMIT = 127
"""Ref_Trigger_Offset is -127..127 NTU (ISO 11898-4 §7.4.3, as quoted by the TTCAN model in
Pipit); Initial_Ref_Offset is its start value for backup masters, 0..127."""
NTU_RES_BITS = 7
MARK_MODULUS = 1 << (16 + NTU_RES_BITS)
"""Master_Ref_Mark with NTU_Res: 16 integer and 7 fraction bits of NTU, wrapping."""


def frame_ns_worst(dlc: int, extended: bool, remote: bool, bit_ns: float, *, intermission: bool = True) -> int:
    """Worst-case length of a frame in ns (stuffing at its worst, Davis et al. 2007 eq. 1), with
    the 3-bit intermission or without it (SOF to the end of EOF)."""
    bits = frame_bits_worst(0 if remote else dlc, extended) - (0 if intermission else 3)
    return math.ceil(bits * bit_ns)


class ReferenceInfo(NamedTuple):
    """What a reference message's data says (see the module docstring for the layout)."""

    cycle_count: int
    next_is_gap: bool
    mark: int | None
    """Master_Ref_Mark with NTU_Res, in 1/128 NTU modulo `MARK_MODULUS` (level 2), else None."""
    disc: bool


def encode_reference(cycle_count: int, *, level: int, mark: int | None = None, disc: bool = False) -> bytes:
    """The reference message's data bytes: Cycle_Count in byte 0 (Next_is_Gap 0: no gap mode),
    and at level 2 NTU_Res/Disc_Bit in byte 1 and Master_Ref_Mark in bytes 2..3."""
    if not 0 <= cycle_count <= 63:
        raise ValueError(f"Cycle_Count {cycle_count} is outside 0..63")
    if level == 1:
        return bytes([cycle_count])
    m = (mark or 0) % MARK_MODULUS
    whole = m >> NTU_RES_BITS
    return bytes([cycle_count, ((m & 0x7F) << 1) | int(disc), whole & 0xFF, whole >> 8])


def decode_reference(data: bytes, level: int) -> ReferenceInfo | None:
    """Read a reference message's data; None when it is too short to be one at this level (a
    node does not accept it as a reference message, M_TTCAN §4.1.1)."""
    if len(data) < (1 if level == 1 else 4):
        return None
    b0 = data[0]
    if level == 1:
        return ReferenceInfo(b0 & 0x3F, bool(b0 & 0x80), None, False)
    mark = ((data[2] | (data[3] << 8)) << NTU_RES_BITS) | (data[1] >> 1)
    return ReferenceInfo(b0 & 0x3F, bool(b0 & 0x80), mark, bool(data[1] & 1))


@dataclass(frozen=True)
class Window:
    """One time window of the system matrix (an entry of ``[[tdma.windows]]``): from
    ``start_ns`` to ``end_ns`` of the basic cycle (NTU ns), of ``kind``, for ``messages``, in the
    basic cycles ``c`` with ``c mod repeat == base_cycle``. ``index`` is its number in the file
    (1-based)."""

    index: int
    start_ns: int
    length_ns: int
    kind: str
    messages: tuple[str, ...]
    base_cycle: int
    repeat: int
    arbitration: str = ""
    """An arbitrating window's kind: ``single`` or ``merged`` ("" for the others)."""

    @property
    def single(self) -> bool:
        """A single arbitrating window: starts only in Tx_Enable, no automatic retransmission."""
        return self.arbitration == SINGLE

    @property
    def triggered(self) -> bool:
        """A frame here must start within Tx_Enable and is not retransmitted (exclusive and single
        arbitrating windows)."""
        return self.kind == EXCLUSIVE or self.single

    @property
    def end_ns(self) -> int:
        """The end of the window in the basic cycle."""
        return self.start_ns + self.length_ns

    def active(self, cycle_count: int) -> bool:
        """True when the window is used in basic cycle ``cycle_count`` of the matrix (Repeat_Factor
        and Cycle_Offset: ``cycle_count mod repeat == base_cycle``)."""
        return cycle_count % self.repeat == self.base_cycle

    def label(self) -> str:
        """How errors and tables name it: ``window #3 (exclusive, 1200..1500 µs)``."""
        kind = f"{self.arbitration} {self.kind}" if self.arbitration else self.kind
        return f"window #{self.index} ({kind}, {self.start_ns / 1000:g}..{self.end_ns / 1000:g} µs)"


@dataclass(frozen=True)
class Schedule:
    """A checked ``[tdma]`` table: the reference message, the potential time masters in priority
    order, the basic cycle and matrix, Tx_Enable, the level, the backup masters' Initial_Ref_Offset
    and the Watch_Trigger, the error budget, and the windows; with the per-message facts the nodes
    need (worst-case lengths, windows by message, owners)."""

    reference_id: int
    reference_extended: bool
    masters: tuple[str, ...]
    basic_cycle_ns: int
    matrix_cycles: int
    tx_enable_ns: int
    level: int
    initial_ref_offset: int
    watch_ns: int
    error_budget_bits: int
    bitrate: int
    windows: tuple[Window, ...]
    ntu_ns: float = 0.0
    """One NTU in ns: the bit time at level 1, TUR / CAN clock at level 2 (0: the bit time)."""
    tur: float | None = None
    can_clock_mhz: float | None = None
    message_windows: Mapping[str, tuple[int, ...]] = field(default_factory=dict)
    """Message name -> positions in ``windows`` (0-based)."""
    owners: Mapping[str, str] = field(default_factory=dict)
    """Message name -> the node that sends it."""
    frame_ns: Mapping[str, int] = field(default_factory=dict)
    """Message name -> worst-case length with intermission (ns)."""
    gated: tuple[str, ...] = ()
    """CSMA nodes that the schedule gates (``tdma_gated = true``)."""

    @property
    def bit_ns(self) -> float:
        """The nominal bit time, ns (frame lengths)."""
        return 1e9 / self.bitrate

    @property
    def ntu_length(self) -> float:
        """One NTU, ns (the bit time at level 1)."""
        return self.ntu_ns or self.bit_ns

    def ntu(self, n: float) -> int:
        """``n`` NTU as ns."""
        return round(n * self.ntu_length)

    def bits(self, n: float) -> int:
        """``n`` bit times as ns."""
        return round(n * self.bit_ns)

    @property
    def reference_dlc(self) -> int:
        """1 at level 1, 4 at level 2 (the minimum the standard requires)."""
        return 1 if self.level == 1 else 4

    @property
    def reference_frame_ns(self) -> int:
        """Worst-case length of a reference message with intermission."""
        return frame_ns_worst(self.reference_dlc, self.reference_extended, False, self.bit_ns)

    @property
    def budget_ns(self) -> int:
        """The user's error budget per window, ns."""
        return self.bits(self.error_budget_bits)

    @property
    def reference_ids(self) -> tuple[int, ...]:
        """The identifiers of the reference messages, by time master priority."""
        return tuple(self.reference_id | p for p in range(len(self.masters)))

    def priority_of(self, can_id: int, extended: bool) -> int | None:
        """The time master priority a frame's identifier carries, if it is a reference message of
        this schedule (all identifier bits but the three least significant ones match)."""
        if extended != self.reference_extended or can_id & ~7 != self.reference_id:
            return None
        return can_id & 7

    def reference_frame(self, priority: int, cycle_count: int, *, mark: int | None = None, disc: bool = False) -> Frame:
        """The reference message time master ``priority`` sends to open basic cycle ``cycle_count``."""
        data = encode_reference(cycle_count, level=self.level, mark=mark, disc=disc)
        return Frame(self.reference_id | priority, data, extended=self.reference_extended)

    def latest_start_ns(self, w: Window, frame_ns: int) -> int:
        """The last cycle time a frame of worst-case length ``frame_ns`` (with intermission) may
        start in window ``w``: the end of its Tx_Enable window in an exclusive or single
        arbitrating window; in a merged arbitrating window the last start that still ends, with
        the error budget, inside it."""
        if w.triggered:
            return w.start_ns + self.tx_enable_ns
        return w.end_ns - frame_ns - self.budget_ns

    def windows_of(self, message: str) -> list[Window]:
        """The windows a TDMA message is sent in."""
        return [self.windows[i] for i in self.message_windows.get(message, ())]

    def arbitrating(self) -> list[Window]:
        """Arbitrating windows, by start."""
        return sorted((w for w in self.windows if w.kind == ARBITRATING), key=lambda w: w.start_ns)
