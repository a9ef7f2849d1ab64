"""Bits on the wire: CRC-15, bit stuffing and the complete frame bit sequence (the encoder).

The CAN FD coding (stuff count, fixed stuff bits, CRC-17/21, worst cases) lives in `stack.wire.fd`,
which builds on this module; `FrameBits` describes both kinds.

Rules (ISO 11898-1, CAN 2.0A/B):
- CRC-15, generator 0x4599 (x^15+x^14+x^10+x^8+x^7+x^4+x^3+1), initial value 0, computed over
  the unstuffed bits SOF..end of data.
- Stuffing covers SOF..CRC sequence: after five equal bits (stuff bits included) the transmitter
  inserts one bit of the opposite level; a sixth equal bit there is a stuff error.
- Fixed-form fields after the CRC: CRC delimiter (1), ACK slot, ACK delimiter (1), EOF (7 × 1).
  A dominant bit in a fixed-form field is a form error (except the last EOF bit, where a
  receiver treats it as an overload condition, not an error).
Bit level convention: 0 = dominant, 1 = recessive.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from enum import Enum
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # pragma: no cover - the frame imports this module to encode itself
    from stack.wire.frame import Frame

__all__ = [
    "CRC15_POLY",
    "Field",
    "FrameBits",
    "crc15",
    "crc15_bytes",
    "stuff",
    "destuff",
    "stuff_string",
    "encode",
    "duration_ns",
    "unstuffed_length",
    "worst_case_length",
    "INTERMISSION_BITS",
]

CRC15_POLY = 0x4599
INTERMISSION_BITS = 3


class Field(str, Enum):
    """Frame fields in wire order, named as in ISO 11898-1:2015.

    Classical frames use RTR, r1 and r0; FD frames RRS (always dominant), FDF (recessive: an FD
    frame; it sits where a classical frame has r0, standard, or r1, extended), res, BRS and ESI,
    and in the CRC field the stuff count (3 Gray-coded bits), its parity bit and the fixed stuff
    bits (FIXED_STUFF: one before the stuff count and one after every 4 bits, each the complement
    of the bit before it).
    """

    SOF = "SOF"
    ID = "ID"  # base identifier, 11 bits
    SRR = "SRR"
    IDE = "IDE"
    ID_EXT = "ID_EXT"  # identifier extension, 18 bits
    RTR = "RTR"
    RRS = "RRS"  # FD: remote request substitution, always dominant
    R1 = "r1"
    R0 = "r0"
    FDF = "FDF"
    RES = "res"  # FD: reserved bit after FDF, dominant
    BRS = "BRS"
    ESI = "ESI"
    DLC = "DLC"
    DATA = "DATA"
    STUFF_COUNT = "STUFF_COUNT"  # FD: dynamic stuff bits mod 8, Gray-coded, 3 bits
    STUFF_PARITY = "STUFF_PARITY"  # FD: even parity over the stuff count
    FIXED_STUFF = "FIXED_STUFF"  # FD: the fixed stuff bits of the CRC field
    CRC = "CRC"
    CRC_DELIM = "CRC_DELIM"
    ACK_SLOT = "ACK_SLOT"
    ACK_DELIM = "ACK_DELIM"
    EOF = "EOF"

    def __str__(self) -> str:
        return self.value


def crc15(bits: Iterable[int]) -> int:
    """CRC-15/CAN (poly 0x4599, init 0) over a sequence of bits, most significant first."""
    crc = 0
    for b in bits:
        nxt = b ^ (crc >> 14)
        crc = (crc << 1) & 0x7FFF
        if nxt:
            crc ^= CRC15_POLY
    return crc


def crc15_bytes(data: bytes) -> int:
    """CRC-15/CAN over whole bytes, MSB first (check value over b"123456789" is 0x059E)."""
    return crc15(((byte >> (7 - i)) & 1) for byte in data for i in range(8))


def stuff(bits: Sequence[int]) -> tuple[list[int], list[int]]:
    """Insert stuff bits: after 5 equal bits, one of the opposite level (stuff bits count).

    Returns the stuffed bits and the indices (in the stuffed sequence) of the stuff bits.
    """
    out: list[int] = []
    positions: list[int] = []
    last = -1
    run = 0
    for b in bits:
        out.append(b)
        if b == last:
            run += 1
        else:
            last, run = b, 1
        if run == 5:
            positions.append(len(out))
            last ^= 1
            out.append(last)
            run = 1
    return out, positions


def destuff(bits: Sequence[int]) -> list[int]:
    """Remove stuff bits; raises ValueError naming the bit index at a stuff error.

    Inverse of `stuff`: destuff(stuff(x)[0]) == x. A stuff bit equal to the five before it is a
    stuff error.
    """
    out: list[int] = []
    last = -1
    run = 0
    skip = False
    for i, b in enumerate(bits):
        if skip:
            if b == last:
                raise ValueError(f"stuff error at bit {i}: sixth consecutive {'recessive' if b else 'dominant'} bit")
            last, run, skip = b, 1, False
            continue
        out.append(b)
        if b == last:
            run += 1
        else:
            last, run = b, 1
        if run == 5:
            skip = True
    return out


def _int_bits(value: int, width: int) -> list[int]:
    return [(value >> (width - 1 - i)) & 1 for i in range(width)]


def unstuffed_length(n: int, extended: bool) -> int:
    """Bits from SOF to end of EOF without stuffing: 44 + 8n standard, 64 + 8n extended."""
    return (64 if extended else 44) + 8 * n


def worst_case_length(n: int, extended: bool = False) -> int:
    """Worst-case stuffed length SOF..EOF for n data bytes of a classical frame (intermission not
    included); for both kinds, split by bit rate: `stack.wire.fd.worst_case_bits`.

    Adds floor((34 + 8n - 1) / 4) stuff bits (standard) or floor((54 + 8n - 1) / 4) (extended)
    to the unstuffed length.
    """
    if not 0 <= n <= 8:
        raise ValueError(f"{n} data bytes: a CAN 2.0 frame carries 0..8")
    stuffed_region = (54 if extended else 34) + 8 * n
    return unstuffed_length(n, extended) + (stuffed_region - 1) // 4


class FrameBits:
    """The exact bit sequence of one frame, SOF to the end of EOF, as sent by its transmitter.

    ``bits`` is a string of '0'/'1' with the ACK slot dominant (as seen on a bus where someone
    acknowledges); ``stuff_positions`` the indices of the (dynamic) stuff bits; ``crc_delim`` the
    index of the CRC delimiter. ``fields`` gives, per field, the stuffed positions of its bits in
    order (computed on first use: the engine needs only the length).

    CAN FD frames (``fd`` True) also have ``fixed_stuff_positions`` (the fixed stuff bits of the
    CRC field, also listed as the field FIXED_STUFF), ``stuff_count_bits`` (the 4 bits of the stuff
    count field as sent: Gray code of the dynamic stuff bits mod 8, then the parity bit) and
    ``crc_width`` 17 or 21 (15 for classical frames). ``brs``: the bits after BRS up to the CRC
    delimiter go at the data bit rate (`data_bits`, `duration_ns`).
    """

    __slots__ = (
        "bits",
        "crc",
        "stuff_positions",
        "crc_delim",
        "_layout",
        "_fields",
        "fd",
        "brs",
        "fixed_stuff_positions",
        "stuff_count_bits",
        "crc_width",
    )

    def __init__(
        self,
        bits: str,
        crc: int,
        stuff_positions: tuple[int, ...],
        crc_delim: int,
        layout: list[tuple[Field, int]],
        *,
        fd: bool = False,
        brs: bool = False,
        fixed_stuff_positions: tuple[int, ...] = (),
        stuff_count_bits: int | None = None,
        crc_width: int = 15,
    ) -> None:
        self.bits = bits
        self.crc = crc
        self.stuff_positions = stuff_positions
        self.crc_delim = crc_delim
        self._layout = layout
        self._fields: dict[Field, tuple[int, ...]] | None = None
        self.fd = fd
        self.brs = brs
        self.fixed_stuff_positions = fixed_stuff_positions
        self.stuff_count_bits = stuff_count_bits
        self.crc_width = crc_width

    def __eq__(self, other: object) -> bool:
        return isinstance(other, FrameBits) and (self.bits, self.crc) == (other.bits, other.crc)

    def __repr__(self) -> str:
        if self.fd:
            return (
                f"FrameBits(bits={self.bits!r}, crc=0x{self.crc:06X}, stuff_positions={self.stuff_positions}, "
                f"stuff_count_bits=0b{self.stuff_count_bits:04b}, fixed_stuff_positions={self.fixed_stuff_positions})"
            )
        return f"FrameBits(bits={self.bits!r}, crc=0x{self.crc:04X}, stuff_positions={self.stuff_positions})"

    @property
    def fields(self) -> dict[Field, tuple[int, ...]]:
        """Stuffed positions of each field's bits, in wire order (FD: FIXED_STUFF after CRC)."""
        f = self._fields
        if f is None:
            f = {}
            sp = sorted(self.stuff_positions + self.fixed_stuff_positions) if self.fd else self.stuff_positions
            k = 0  # next stuff position to skip
            pos = 0
            for fld, width in self._layout:
                out = []
                for _ in range(width):
                    while k < len(sp) and sp[k] == pos:
                        pos += 1
                        k += 1
                    out.append(pos)
                    pos += 1
                f[fld] = tuple(out)
            if self.fd:
                f[Field.FIXED_STUFF] = self.fixed_stuff_positions
            n = self.crc_delim
            for fld, width in ((Field.CRC_DELIM, 1), (Field.ACK_SLOT, 1), (Field.ACK_DELIM, 1), (Field.EOF, 7)):
                f[fld] = tuple(range(n, n + width))
                n += width
            self._fields = f
        return f

    @property
    def length(self) -> int:
        """Bits from SOF to end of EOF, stuff bits included."""
        return len(self.bits)

    @property
    def stuff_count(self) -> int:
        """Number of (dynamic) stuff bits: ISO's stuff bit count; FD fixed stuff bits are not
        counted (see ``fixed_stuff_positions``)."""
        return len(self.stuff_positions)

    @property
    def arbitration_end(self) -> int:
        """Position of the last bit of the arbitration field (RTR, or RRS in an FD frame)."""
        return self.fields[Field.RRS if self.fd else Field.RTR][-1]

    @property
    def data_bits(self) -> int:
        """Bits sent at the data bit rate: with BRS, those after BRS up to and including the CRC
        delimiter (stuff bits included); 0 without BRS and for classical frames.

        ISO 11898-1:2015 switches to the data bit timing at the sample point of BRS and back at the
        sample point of the CRC delimiter. Counting BRS at the nominal rate and the CRC delimiter
        at the data rate is exact for the frame's duration: BRS lasts sp_n * T_n + (1 - sp_d) * T_d
        and the CRC delimiter sp_d * T_d + (1 - sp_n) * T_n, together one nominal and one data bit
        time whatever the sample points sp_n, sp_d (see `bit_edges_ns` for where each bit starts).
        """
        if not self.brs:
            return 0
        return self.crc_delim - self.fields[Field.BRS][0]

    @property
    def nominal_bits(self) -> int:
        """Bits sent at the nominal bit rate (all of them without BRS); see `data_bits`."""
        return len(self.bits) - self.data_bits

    def duration_ns(self, bitrate: int, data_bitrate: int | None = None) -> int:
        """The frame's time on the bus from the start of SOF to the end of EOF in ns, rounded to
        the nearest ns: nominal_bits / bitrate + data_bits / data_bitrate (exact for any sample
        points, see `data_bits`). ``data_bitrate`` is needed only for an FD frame with BRS."""
        return duration_ns(self.nominal_bits, self.data_bits, bitrate, data_bitrate)

    def bit_edges_ns(
        self,
        bitrate: int,
        data_bitrate: int | None = None,
        sample_point: float = 0.8,
        data_sample_point: float = 0.75,
    ) -> list[float]:
        """The start time (ns after the start of SOF) of every bit, and the end of EOF last
        (``length + 1`` values). With BRS the bit timing switches to the data bit rate at the
        sample point of BRS and back at the sample point of the CRC delimiter (ISO 11898-1:2015),
        so those two bits last a mixed time that depends on the sample points (fractions of the bit
        time, 0 < sp < 1); the total is `duration_ns` whatever they are."""
        if not 0 < sample_point < 1 or not 0 < data_sample_point < 1:
            raise ValueError(
                f"sample points {sample_point!r}, {data_sample_point!r}: each a fraction of the bit time, 0 < sp < 1"
            )
        if bitrate <= 0:
            raise ValueError(f"bit rate {bitrate!r}: must be > 0 bit/s")
        tn = 1e9 / bitrate
        n = len(self.bits)
        if not self.brs:
            return [i * tn for i in range(n + 1)]
        if data_bitrate is None or data_bitrate <= 0:
            raise ValueError(f"data bit rate {data_bitrate!r}: an FD frame with BRS needs one > 0 bit/s")
        td = 1e9 / data_bitrate
        brs = self.fields[Field.BRS][0]
        delim = self.crc_delim
        out = [i * tn for i in range(brs + 1)]
        t = out[-1] + sample_point * tn + (1 - data_sample_point) * td  # end of BRS
        for _ in range(brs + 1, delim + 1):
            out.append(t)
            t += td
        t += data_sample_point * td - td + (1 - sample_point) * tn  # the CRC delimiter's two shares
        out.append(t)
        for _ in range(delim + 2, n + 1):
            t += tn
            out.append(t)
        return out

    def position(self, fld: Field | str, index: int = 0) -> int:
        """Stuffed bit position of bit ``index`` (0 = first sent) of a field; ValueError if none."""
        try:
            f = Field(fld) if not isinstance(fld, Field) else fld
        except ValueError:
            raise ValueError(f"unknown field {fld!r}: one of {', '.join(x.value for x in Field)}") from None
        pos = self.fields.get(f)
        if not pos:
            raise ValueError(f"this frame has no {f.value} field")
        if not 0 <= index < len(pos):
            raise ValueError(f"bit {index} outside field {f.value} of {len(pos)} bits (0..{len(pos) - 1})")
        return pos[index]

    def field_at(self, position: int) -> tuple[Field, int | None]:
        """The field a stuffed position belongs to and the bit index in it (None for a dynamic
        stuff bit, which is reported in the field of the bit before it; an FD fixed stuff bit is
        (FIXED_STUFF, its index))."""
        if not 0 <= position < len(self.bits):
            raise ValueError(f"bit {position} outside the frame (0..{len(self.bits) - 1})")
        if self.fd and position in self.fixed_stuff_positions:
            return Field.FIXED_STUFF, self.fixed_stuff_positions.index(position)
        for f, pos in self.fields.items():
            if f is Field.FIXED_STUFF:
                continue
            if pos and pos[0] <= position <= pos[-1] + (1 if position in self.stuff_positions else 0):
                if position in pos:
                    return f, pos.index(position)
                if position in self.stuff_positions and pos[0] < position:
                    # stuff bit right after or inside this field
                    nxt = [p for p in pos if p > position]
                    if nxt or position == pos[-1] + 1:
                        return f, None
        raise ValueError(f"bit {position} is not in any field")  # pragma: no cover


def duration_ns(nominal_bits: int, data_bits: int, bitrate: int, data_bitrate: int | None = None) -> int:
    """nominal_bits / bitrate + data_bits / data_bitrate in ns (bit rates in bit/s), rounded to the
    nearest ns (half up), in integers: exact when both bit times are whole ns."""
    if isinstance(bitrate, bool) or not isinstance(bitrate, int) or bitrate <= 0:
        raise ValueError(f"bit rate {bitrate!r}: must be a whole number of bit/s > 0")
    if not data_bits:
        return (2 * nominal_bits * 1_000_000_000 + bitrate) // (2 * bitrate)
    if isinstance(data_bitrate, bool) or not isinstance(data_bitrate, int) or data_bitrate <= 0:
        raise ValueError(f"data bit rate {data_bitrate!r}: an FD frame with BRS needs a whole number of bit/s > 0")
    num = (nominal_bits * data_bitrate + data_bits * bitrate) * 1_000_000_000
    den = bitrate * data_bitrate
    return (2 * num + den) // (2 * den)


def _crc_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte << 7
        for _ in range(8):
            crc = ((crc << 1) ^ CRC15_POLY) if crc & 0x4000 else (crc << 1)
        table.append(crc & 0x7FFF)
    return table


_CRC_TABLE = _crc_table()


def _crc15_int(value: int, nbits: int) -> int:
    """CRC-15 of the ``nbits`` low bits of ``value`` (MSB first): leading bits one at a time,
    then a byte at a time from a 256-entry table (faster than bit by bit: the benchmarks page)."""
    crc = 0
    lead = nbits % 8
    for i in range(nbits - 1, nbits - 1 - lead, -1):
        nxt = ((value >> i) & 1) ^ (crc >> 14)
        crc = (crc << 1) & 0x7FFF
        if nxt:
            crc ^= CRC15_POLY
    table = _CRC_TABLE
    for shift in range(nbits - lead - 8, -1, -8):
        crc = ((crc << 8) & 0x7FFF) ^ table[((crc >> 7) ^ (value >> shift)) & 0xFF]
    return crc


def stuff_string(raw: str) -> tuple[str, list[int]]:
    """Bit stuffing on a '0'/'1' string with str.find (C speed): after five equal bits, insert
    the opposite bit, which starts the next run (the rule of `stuff`; five equal bits at the very
    end are followed by a stuff bit too). Returns the stuffed string and the stuff bits' indices."""
    out: list[str] = []
    positions: list[int] = []
    n_out = 0
    rest = raw
    carried = False  # rest[0] is a stuff bit already written to out
    while True:
        j0 = rest.find("00000")
        j1 = rest.find("11111")
        if j0 < 0 and j1 < 0:
            out.append(rest[1:] if carried else rest)
            break
        j = j0 if j1 < 0 or (0 <= j0 < j1) else j1
        seg = rest[: j + 5]
        if carried:
            seg = seg[1:]
        stuffbit = "1" if rest[j] == "0" else "0"
        out.append(seg)
        n_out += len(seg)
        positions.append(n_out)
        out.append(stuffbit)
        n_out += 1
        rest = stuffbit + rest[j + 5 :]
        carried = True
    return "".join(out), positions


def _layout(frame: Frame) -> list[tuple[Field, int]]:
    n = 0 if frame.remote else len(frame.data)
    if frame.extended:
        return [
            (Field.SOF, 1),
            (Field.ID, 11),
            (Field.SRR, 1),
            (Field.IDE, 1),
            (Field.ID_EXT, 18),
            (Field.RTR, 1),
            (Field.R1, 1),
            (Field.R0, 1),
            (Field.DLC, 4),
            (Field.DATA, 8 * n),
            (Field.CRC, 15),
        ]
    return [
        (Field.SOF, 1),
        (Field.ID, 11),
        (Field.RTR, 1),
        (Field.IDE, 1),
        (Field.R0, 1),
        (Field.DLC, 4),
        (Field.DATA, 8 * n),
        (Field.CRC, 15),
    ]


def encode(frame: Frame) -> FrameBits:
    """The complete bit sequence of a classical frame: SOF..EOF with stuff bits, CRC and fixed
    fields (an FD frame's comes from `stack.wire.fd.encode_fd`; ``frame.bits`` picks the right one).

    Use ``frame.bits`` to get it cached on the frame. Built from integers and strings rather
    than bit lists, which are much slower, and random traffic encodes every frame once.
    """
    if frame.fd:
        raise ValueError("a CAN FD frame: its bits come from stack.wire.fd.encode_fd (or read frame.bits)")
    if frame.extended:
        cid = frame.can_id
        # SOF, ID[28:18], SRR=1, IDE=1, ID[17:0], RTR, r1, r0, DLC
        head = ((((cid >> 18) << 2) | 3) << 18 | (cid & 0x3FFFF)) << 3 | (int(frame.remote) << 2)
        head = (head << 4) | frame.dlc
        head_bits = 1 + 11 + 2 + 18 + 3 + 4
    else:
        # SOF, ID[10:0], RTR, IDE=0, r0=0, DLC
        head = (((frame.can_id << 1) | int(frame.remote)) << 2) << 4 | frame.dlc
        head_bits = 1 + 11 + 3 + 4
    data = frame.data
    nbits = head_bits + 8 * len(data)
    value = (head << (8 * len(data))) | int.from_bytes(data, "big") if data else head
    crc = _crc15_int(value, nbits)
    raw = format((value << 15) | crc, f"0{nbits + 15}b")
    stuffed, positions = stuff_string(raw)
    return FrameBits(stuffed + "1011111111", crc, tuple(positions), len(stuffed), _layout(frame))
