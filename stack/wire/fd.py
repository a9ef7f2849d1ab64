"""CAN FD on the wire (ISO 11898-1:2015, "ISO CAN FD"): the FD encoder, CRC-17/21, the stuff count,
fixed stuff bits, worst-case frame lengths and frame durations at two bit rates.

Design note (the API later layers build on)
-------------------------------------------
- `stack.wire.frame.Frame(can_id, data, extended=..., fd=True, brs=..., esi=...)`: an FD data frame
  (0..8, 12, 16, 20, 24, 32, 48 or 64 bytes; no remote frames). ``frame.bits`` is a
  `stack.wire.coding.FrameBits` for both kinds; for FD it adds ``fd``, ``brs``,
  ``fixed_stuff_positions``, ``stuff_count_bits`` (Gray code + parity, as sent), ``crc_width``
  (17/21), and the fields RRS, FDF, res, BRS, ESI, STUFF_COUNT, STUFF_PARITY and FIXED_STUFF in
  ``fields``. ``stuff_count`` (and ``stuff_positions``) are the dynamic stuff bits only.
- Two bit rates: ``fb.nominal_bits`` + ``fb.data_bits`` = ``fb.length``; with BRS the data bits are
  those after BRS up to and including the CRC delimiter (see `FrameBits.data_bits` for why this
  split is exact); ``fb.duration_ns(bitrate, data_bitrate)`` is the frame's time SOF..EOF and
  ``fb.bit_edges_ns(...)`` where each bit starts, for given sample points.
- Worst case for response-time analysis, one API shape for both kinds:
  `worst_case_bits(n, extended, fd=..., brs=...)` -> `WorstCase(nominal, data)` (classical:
  ``(stack.wire.coding.worst_case_length(n, extended), 0)``), `worst_case_duration_ns(...)`, and
  `worst_case_fields` for a frame that is that long.
- `Frame` slots ``encoded`` (the FrameBits once computed, else None) and ``nbits`` (0 until then):
  hot paths read ``frame.nbits or frame.wire_bits`` and ``frame.encoded or frame.bits``.
- Receiving: `stack.wire.decoder.BitDecoder(mode)` with mode 'classic' (CAN 2.0, the default: the
  behaviour before FD), 'tolerant' or 'fd' (see `stack.wire.decoder`); what it has received is
  public (``can_id``, ``extended``, ``remote``, ``dlc``, ``fd``, ``brs``, ``esi``, ``field``,
  ``field_index``, ``received_data``, ``received_crc``); `DecodedFrame` adds ``fd``, ``brs``,
  ``esi`` and ``stuff_count_bits``. Errors are `BitError` with kind
  'stuff' (dynamic stuff bits), 'form' (fixed-form bits and FD fixed stuff bits, field
  FIXED_STUFF), 'crc' (field CRC, or STUFF_COUNT when the stuff count or its parity mismatched:
  both are CRC errors, signalled after the ACK delimiter) and 'exception' (the protocol exception
  event: an FD node that sees res recessive, or a "tolerant" classical node that sees FDF
  recessive, goes bus integrating without an error frame). Not modelled: the tolerance of ISO
  16845-1 test 8.2.7 for a CRC delimiter or ACK stretched to 2 bits by the switch back to the
  nominal rate (all nodes of the simulated bus sample the same bits).

The rules (ISO 11898-1:2015; 0 = dominant, 1 = recessive)
----------------------------------------------------------
- Standard FD frame: SOF, ID(11), RRS(0), IDE(0), FDF(1), res(0), BRS, ESI, DLC(4), data, CRC field;
  extended: SOF, ID(11), SRR(1), IDE(1), ID(18), RRS(0), FDF(1), res(0), BRS, ESI, DLC(4), data.
- Dynamic stuffing (after five equal bits, stuff bits included, one of the opposite level) from SOF
  to the end of the data field. When the five equal bits end with the last data bit no dynamic
  stuff bit is inserted there: the first fixed stuff bit takes its place and is not counted (the
  ISO 16845-1 conformance model of the CTU CAN FD project states this exception; its RTL does the
  same).
- CRC field: the stuff count (dynamic stuff bits mod 8 as a 3-bit Gray code, then an even-parity
  bit over those 3 bits), then the CRC sequence, CRC-17 (polynomial 0x1685B) for up to 16 data
  bytes and CRC-21 (0x102899) above. Fixed stuff bits: one before the stuff count and one after
  every 4 bits of stuff count + CRC, each the complement of the bit before it (6 with CRC-17, 7
  with CRC-21); no dynamic stuffing in the CRC field.
- The CRC register starts at 1 << (width - 1) and covers SOF to the end of the data field with the
  dynamic stuff bits, then the stuff count and parity; fixed stuff bits are not covered. (The
  catalogue entries CRC-17/CAN-FD and CRC-21/CAN-FD are the same polynomials with initial value 0.)
- A fixed stuff bit equal to the bit before it is a form error (ISO 16845-1:2016 test 7.2.8); a
  stuff count or parity mismatch is a CRC error.

Why hand-written: the encoder runs once per frame on the engine's hot path; CRCs go a byte at a
time from a 256-entry table over the frame as one integer, stuffing runs with str.find (see
`stack.wire.coding`).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from functools import cache
from typing import TYPE_CHECKING, NamedTuple

from .coding import INTERMISSION_BITS, Field, FrameBits, duration_ns, stuff_string, worst_case_length

if TYPE_CHECKING:  # pragma: no cover - the frame imports this module to encode itself
    from .frame import Frame

__all__ = [
    "FD_LENGTHS",
    "CRC17_POLY",
    "CRC21_POLY",
    "CRC17_INIT",
    "CRC21_INIT",
    "crc_width",
    "crc17",
    "crc21",
    "crc_fd_bytes",
    "crc_fd_int",
    "gray",
    "stuff_count_bits",
    "fixed_stuff_bits",
    "stuff_fd",
    "destuff_fd",
    "encode_fd",
    "WorstCase",
    "worst_case_bits",
    "worst_case_fields",
    "worst_case_duration_ns",
    "INTERMISSION_BITS",
]

#: Data lengths a CAN FD frame can carry, indexed by DLC (ISO 11898-1:2015 DLC table).
FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)

CRC17_POLY = 0x1685B
CRC21_POLY = 0x102899
#: ISO 11898-1:2015 initial register values: a leading 1 (Bosch's CAN FD 1.0 started at 0).
CRC17_INIT = 1 << 16
CRC21_INIT = 1 << 20

# bits before the data field and around it (SOF..DLC; fixed tail after the CRC delimiter)
_HEAD_BITS = {False: 22, True: 41}
_NOMINAL_HEAD = {False: 17, True: 36}  # SOF..BRS: sent at the nominal rate
_TAIL_BITS = 9  # ACK slot, ACK delimiter, EOF(7)


def crc_width(length: int) -> int:
    """CRC length of an FD frame with ``length`` data bytes: 17 up to 16 bytes, 21 above."""
    return 17 if length <= 16 else 21


def _crc_bits(bits: Iterable[int], poly: int, width: int, init: int) -> int:
    crc = init
    top = width - 1
    mask = (1 << width) - 1
    for b in bits:
        nxt = b ^ (crc >> top)
        crc = (crc << 1) & mask
        if nxt:
            crc ^= poly
    return crc


def crc17(bits: Iterable[int], init: int = CRC17_INIT) -> int:
    """CRC-17 (poly 0x1685B) over bits MSB first; ``init`` defaults to ISO's 1 << 16 (0 gives the
    catalogue CRC-17/CAN-FD, check value 0x04F03 over b"123456789")."""
    return _crc_bits(bits, CRC17_POLY, 17, init)


def crc21(bits: Iterable[int], init: int = CRC21_INIT) -> int:
    """CRC-21 (poly 0x102899) over bits MSB first; ``init`` defaults to ISO's 1 << 20 (0 gives the
    catalogue CRC-21/CAN-FD, check value 0x0ED841 over b"123456789")."""
    return _crc_bits(bits, CRC21_POLY, 21, init)


@cache
def _table(poly: int, width: int) -> tuple[int, ...]:
    mask = (1 << width) - 1
    top = 1 << (width - 1)
    out = []
    for byte in range(256):
        crc = byte << (width - 8)
        for _ in range(8):
            crc = ((crc << 1) ^ poly) if crc & top else (crc << 1)
        out.append(crc & mask)
    return tuple(out)


def _crc_int(value: int, nbits: int, poly: int, width: int, init: int) -> int:
    """The CRC of the ``nbits`` low bits of ``value`` (MSB first): the leading nbits % 8 bits one at
    a time, then a byte at a time from a 256-entry table."""
    crc = init
    mask = (1 << width) - 1
    top = width - 1
    lead = nbits % 8
    for i in range(nbits - 1, nbits - 1 - lead, -1):
        nxt = ((value >> i) & 1) ^ (crc >> top)
        crc = (crc << 1) & mask
        if nxt:
            crc ^= poly
    table = _table(poly, width)
    hi = width - 8
    for shift in range(nbits - lead - 8, -1, -8):
        crc = ((crc << 8) & mask) ^ table[((crc >> hi) ^ (value >> shift)) & 0xFF]
    return crc


def crc_fd_bytes(data: bytes, width: int, init: int = 0) -> int:
    """CRC-17 or CRC-21 (``width``) over whole bytes MSB first, initial value ``init`` (0: the
    catalogue's CRC-17/CAN-FD and CRC-21/CAN-FD)."""
    if width not in (17, 21):
        raise ValueError(f"CRC width {width!r}: CAN FD uses 17 or 21")
    poly = CRC17_POLY if width == 17 else CRC21_POLY
    return _crc_int(int.from_bytes(data, "big"), 8 * len(data), poly, width, init)


def crc_fd_int(value: int, nbits: int, width: int, init: int | None = None) -> int:
    """CRC-17 or CRC-21 (``width``) of the ``nbits`` low bits of ``value`` MSB first, with ISO's
    initial value 1 << (width - 1) unless ``init`` is given (a receiver's check of a whole frame)."""
    if width not in (17, 21):
        raise ValueError(f"CRC width {width!r}: CAN FD uses 17 or 21")
    poly = CRC17_POLY if width == 17 else CRC21_POLY
    return _crc_int(value, nbits, poly, width, 1 << (width - 1) if init is None else init)


def gray(n: int) -> int:
    """The Gray code of ``n`` (n ^ (n >> 1): 0..7 -> 000 001 011 010 110 111 101 100)."""
    return n ^ (n >> 1)


def stuff_count_bits(stuff_bits: int) -> int:
    """The 4 bits of the stuff count field for ``stuff_bits`` dynamic stuff bits: the Gray code of
    stuff_bits mod 8 (3 bits) then the even-parity bit over them (ISO 11898-1:2015)."""
    g = gray(stuff_bits & 7)
    return (g << 1) | ((g ^ (g >> 1) ^ (g >> 2)) & 1)


def fixed_stuff_bits(width: int) -> int:
    """Fixed stuff bits in the CRC field of a frame with a CRC of ``width`` bits: one before the
    stuff count and one after every 4 bits of the 4 + width that follow (6 for CRC-17, 7 for
    CRC-21)."""
    return 1 + (4 + width - 1) // 4


def stuff_fd(dynamic: Sequence[int], crc_field: Sequence[int]) -> tuple[list[int], list[int], list[int]]:
    """The FD stuffing rules over bit lists: dynamic stuffing of ``dynamic`` (SOF..end of data),
    then ``crc_field`` (stuff count + CRC) with a fixed stuff bit before it and after every 4 of
    its bits. Returns the bits and the positions of the dynamic and the fixed stuff bits."""
    out: list[int] = []
    dyn: list[int] = []
    last = -1
    run = 0
    n = len(dynamic)
    for i, b in enumerate(dynamic):
        out.append(b)
        if b == last:
            run += 1
        else:
            last, run = b, 1
        if run == 5 and i < n - 1:  # never after the last data bit: the fixed stuff bit comes there
            dyn.append(len(out))
            last ^= 1
            out.append(last)
            run = 1
    fixed: list[int] = []
    for i, b in enumerate(crc_field):
        if i % 4 == 0:
            fixed.append(len(out))
            out.append(1 - out[-1] if out else 1)
        out.append(b)
    return out, dyn, fixed


def destuff_fd(bits: Sequence[int], dynamic_bits: int) -> tuple[list[int], list[int]]:
    """Inverse of `stuff_fd`: the ``dynamic_bits`` unstuffed bits of the dynamic region and the
    CRC-field bits without fixed stuff bits. A sixth equal bit in the dynamic region is a stuff
    error, a fixed stuff bit equal to the bit before it a form error (ValueError naming the bit)."""
    out: list[int] = []
    last = -1
    run = 0
    i = 0
    while len(out) < dynamic_bits:
        if i >= len(bits):
            raise ValueError(f"bit sequence ended after {i} bits, inside the dynamic region")
        b = bits[i]
        if run == 5:
            if b == last:
                raise ValueError(f"stuff error at bit {i}: sixth consecutive {'recessive' if b else 'dominant'} bit")
            last, run = b, 1
            i += 1
            continue
        out.append(b)
        if b == last:
            run += 1
        else:
            last, run = b, 1
        i += 1
    rest: list[int] = []
    k = 0
    prev = bits[i - 1] if i else -1
    while i < len(bits):
        b = bits[i]
        if k % 5 == 0:
            if b == prev:
                raise ValueError(f"form error at bit {i}: fixed stuff bit equal to the bit before it")
        else:
            rest.append(b)
        prev = b
        k += 1
        i += 1
    return out, rest


def _layout_fd(extended: bool, n: int, width: int) -> list[tuple[Field, int]]:
    if extended:
        head = [(Field.SOF, 1), (Field.ID, 11), (Field.SRR, 1), (Field.IDE, 1), (Field.ID_EXT, 18), (Field.RRS, 1)]
    else:
        head = [(Field.SOF, 1), (Field.ID, 11), (Field.RRS, 1), (Field.IDE, 1)]
    return head + [
        (Field.FDF, 1),
        (Field.RES, 1),
        (Field.BRS, 1),
        (Field.ESI, 1),
        (Field.DLC, 4),
        (Field.DATA, 8 * n),
        (Field.STUFF_COUNT, 3),
        (Field.STUFF_PARITY, 1),
        (Field.CRC, width),
    ]


def encode_fd(frame: Frame) -> FrameBits:
    """The complete bit sequence of a CAN FD frame, SOF..EOF, per ISO 11898-1:2015 (the rules in
    the module docstring). Use ``frame.bits`` to get it cached on the frame."""
    cid = frame.can_id
    ctrl = 0b01000 | (frame.brs << 1) | frame.esi  # RRS=0, FDF=1, res=0, BRS, ESI
    if frame.extended:
        head = ((((cid >> 18) << 2) | 3) << 18 | (cid & 0x3FFFF)) << 5 | ctrl
    else:
        head = (cid << 6) | ctrl  # IDE=0 between RRS and FDF
    head = (head << 4) | frame.dlc
    data = frame.data
    n = len(data)
    nbits = _HEAD_BITS[frame.extended] + 8 * n
    value = (head << (8 * n)) | int.from_bytes(data, "big") if data else head
    stuffed, positions = stuff_string(format(value, f"0{nbits}b"))
    if positions and positions[-1] == len(stuffed) - 1:
        # five equal bits end the data field: the first fixed stuff bit replaces the stuff bit
        stuffed = stuffed[:-1]
        positions.pop()
    sc = stuff_count_bits(len(positions))
    width = 17 if n <= 16 else 21
    m = len(stuffed)
    crc = _crc_int(
        (int(stuffed, 2) << 4) | sc,
        m + 4,
        CRC17_POLY if width == 17 else CRC21_POLY,
        width,
        1 << (width - 1),
    )
    seq = format((sc << width) | crc, f"0{width + 4}b")
    parts = []
    fixed = []
    prev = stuffed[-1]
    pos = m
    for i in range(0, width + 4, 4):
        fixed.append(pos)
        chunk = seq[i : i + 4]
        parts.append(("1" if prev == "0" else "0") + chunk)
        pos += 1 + len(chunk)
        prev = chunk[-1]
    crc_field = "".join(parts)
    return FrameBits(
        stuffed + crc_field + "1011111111",
        crc,
        tuple(positions),
        m + len(crc_field),
        _layout_fd(frame.extended, n, width),
        fd=True,
        brs=frame.brs,
        fixed_stuff_positions=tuple(fixed),
        stuff_count_bits=sc,
        crc_width=width,
    )


# -- worst case ---------------------------------------------------------------------------------


class WorstCase(NamedTuple):
    """Worst-case length of a frame SOF..EOF: bits at the nominal and at the data bit rate."""

    nominal: int
    data: int

    @property
    def total(self) -> int:
        """All bits, SOF..EOF (intermission not included)."""
        return self.nominal + self.data


def _pattern(n: int, extended: bool, brs: bool) -> tuple[str, int]:
    """The dynamic region SOF..end of data as a pattern of '0', '1' and 'x' (free: identifier,
    ESI, data), and the index of BRS in it."""
    dlc = format(FD_LENGTHS.index(n), "04b")
    if extended:
        head = "0" + "x" * 11 + "11" + "x" * 18 + "010"  # SOF ID SRR IDE ID_EXT RRS FDF res
    else:
        head = "0" + "x" * 11 + "00" + "10"  # SOF ID RRS IDE FDF res
    return head + ("1" if brs else "0") + "x" + dlc + "x" * (8 * n), len(head)


@cache
def _max_stuff(n: int, extended: bool, brs: bool) -> tuple[int, int, str]:
    """The most dynamic stuff bits before and after BRS any FD frame with n data bytes can have,
    and an unstuffed dynamic region (a '0'/'1' string) that has both.

    Exact, by dynamic programming over the stuffing state (level and run length after each bit,
    at most 10 states) along the pattern of fixed and free bits: the rule of `stuff_fd`. The state
    after BRS is forced (FDF=1, res=0 before it cap its run at 2), so the most bits before and
    after it are reached by one frame; the DP checks that and returns that frame.
    """
    pattern, brs_at = _pattern(n, extended, brs)
    last = len(pattern) - 1
    # state (level, run) -> (stuff bits before/at BRS, after BRS, unstuffed bits so far)
    states: dict[tuple[int, int], tuple[int, int, str]] = {(-1, 0): (0, 0, "")}
    for i, p in enumerate(pattern):
        nxt: dict[tuple[int, int], tuple[int, int, str]] = {}
        for (lvl, run), (a, b, s) in states.items():
            for bit in (0, 1) if p == "x" else (int(p),):
                r = run + 1 if bit == lvl else 1
                na, nb, st = a, b, (bit, r)
                if r == 5 and i < last:
                    if i < brs_at:
                        na += 1
                    else:
                        nb += 1
                    st = (1 - bit, 1)
                cand = (na, nb, s + str(bit))
                old = nxt.get(st)
                if old is None or (cand[0], cand[1]) > (old[0], old[1]):
                    nxt[st] = cand
        states = nxt
        if i == brs_at and len(states) != 1:  # pragma: no cover - FDF, res before BRS force it
            raise AssertionError("the stuffing state after BRS is not unique")
    best = max(states.values(), key=lambda v: (v[0] + v[1], v[0]))
    return best


def worst_case_bits(n: int, extended: bool = False, *, fd: bool = False, brs: bool = False) -> WorstCase:
    """Worst-case length SOF..EOF of a frame with ``n`` data bytes: bits at the nominal rate and
    at the data rate (0 for classical frames and FD frames without BRS). One call for both kinds:
    ``worst_case_bits(n, extended).total == worst_case_length(n, extended)``.

    Classical frames: `stack.wire.coding.worst_case_length` (Davis et al. 2007). CAN FD, derived
    from ISO 11898-1:2015: the fixed bits SOF..DLC (22 standard, 41 extended) + 8n data bits + the
    most dynamic stuff bits any identifier, ESI and data can cause, then the CRC field: 4
    stuff-count bits, the CRC (17 bits up to 16 bytes, 21 above) and its fixed stuff bits (6 or 7),
    then the CRC delimiter, ACK slot, ACK delimiter and EOF(7). With BRS the bits after BRS up to
    the CRC delimiter count at the data rate (see `FrameBits.data_bits`).

    The stuff bits are exact, not a bound: the dynamic region mixes free bits (identifier, ESI,
    data) with fixed ones (SOF, SRR, IDE, RRS, FDF, res, BRS, the DLC of n bytes), so the closed
    forms of the literature (e.g. the Linux kernel's can_frame_bits: L + (L - 1) // 4 over the
    L bits SOF..data) over-count by 1 to 4 bits; `_max_stuff` finds the maximum over all frames
    by dynamic programming on the stuffing state. At most 3 stuff bits before BRS (standard,
    SOF..IDE) or 7 (extended); after it, e.g. 16 for 8 bytes and 128 for 64 bytes. Standard, 64
    bytes, BRS: 29 bits at the nominal rate, 678 at the data rate.
    """
    if not fd:
        if brs:
            raise ValueError("BRS exists only in CAN FD frames: give fd=True")
        return WorstCase(worst_case_length(n, extended), 0)
    _check_fd_length(n)
    before, after, _ = _max_stuff(n, extended, brs)
    width = crc_width(n)
    crc_field = 4 + width + fixed_stuff_bits(width)
    nominal = _NOMINAL_HEAD[extended] + before + _TAIL_BITS
    data = (_HEAD_BITS[extended] - _NOMINAL_HEAD[extended]) + 8 * n + after + crc_field + 1
    if brs:
        return WorstCase(nominal, data)
    return WorstCase(nominal + data, 0)


def worst_case_fields(n: int, extended: bool = False, *, brs: bool = False) -> tuple[int, bool, bytes]:
    """Identifier, ESI and data of an FD frame with ``n`` data bytes that is as long as
    `worst_case_bits` says at both bit rates (chosen by `_max_stuff`): what a worst-case analysis,
    or a test of it, sends as ``Frame(can_id, data, extended=..., fd=True, brs=..., esi=esi)``."""
    _check_fd_length(n)
    _, _, s = _max_stuff(n, extended, brs)
    if extended:
        can_id, esi = (int(s[1:12], 2) << 18) | int(s[14:32], 2), s[36]
    else:
        can_id, esi = int(s[1:12], 2), s[17]
    data = int(s[len(s) - 8 * n :], 2).to_bytes(n, "big") if n else b""
    return can_id, esi == "1", data


def _check_fd_length(n: int) -> None:
    if isinstance(n, bool) or not isinstance(n, int) or n not in FD_LENGTHS:
        raise ValueError(f"{n!r} data bytes is not a CAN FD length: one of 0..8, 12, 16, 20, 24, 32, 48 or 64")


def worst_case_duration_ns(
    n: int,
    extended: bool = False,
    *,
    fd: bool = False,
    brs: bool = False,
    bitrate: int,
    data_bitrate: int | None = None,
) -> int:
    """Worst-case time SOF..EOF in ns (rounded to the nearest ns) of a frame with ``n`` data bytes
    at these bit rates: `worst_case_bits` weighted by the two bit times. For FD frames both worst
    cases are reached by one frame (see `_max_stuff`), so this is the longest time, not a bound."""
    wc = worst_case_bits(n, extended, fd=fd, brs=brs)
    return duration_ns(wc.nominal, wc.data, bitrate, data_bitrate)
