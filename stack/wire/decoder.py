"""The receiver's view of a frame's bits: destuffing, CRC and form checks (ISO 11898-1:2015).

`BitDecoder` is fed one bit at a time (0 = dominant, 1 = recessive) from SOF, as a receiver
samples them, and reports the frame or the first error (stuff, CRC, form) where the standard
detects it; `decode` runs it over a whole bit string.

What the receiver is (``mode``) decides what a recessive bit after IDE (standard) or RTR
(extended) means, the bit a classical frame sends dominant as r0/r1 and an FD frame recessive as
FDF:
- ``"classic"`` (the default): a CAN 2.0 receiver, for which that bit is reserved (accepted either
  way); an FD frame then decodes as garbage and ends in an error, as on a real CAN 2.0 controller
  (the "FD-intolerant" node of a mixed network).
- ``"fd"``: an ISO CAN FD receiver; FDF recessive starts an FD frame (res, BRS, ESI, the FD DLC
  table, dynamic stuffing to the end of the data field, then the stuff count, fixed stuff bits and
  CRC-17/21, see `stack.wire.fd`). A recessive res bit is the protocol exception event.
- ``"tolerant"``: a classical ISO 11898-1:2015 receiver with the protocol exception: FDF recessive
  is the protocol exception event.
The protocol exception is reported as an error of kind ``"exception"`` at that bit: the receiver
sends no error frame and goes bus integrating (waits for 11 recessive bits), which is the caller's.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

from stack.wire.frame import Frame, data_length

from .coding import CRC15_POLY, Field
from .fd import crc_fd_int, stuff_count_bits

__all__ = ["BitError", "DecodedFrame", "BitDecoder", "decode", "MODES"]

#: What a receiver can be (see the module docstring).
MODES = ("classic", "tolerant", "fd")

_SOF, _ID, _RTR, _IDE, _ID_EXT = Field.SOF, Field.ID, Field.RTR, Field.IDE, Field.ID_EXT
_R0, _R1, _RES, _BRS, _ESI, _DLC, _DATA = Field.R0, Field.R1, Field.RES, Field.BRS, Field.ESI, Field.DLC, Field.DATA
_STUFF_COUNT, _CRC, _CRC_DELIM = Field.STUFF_COUNT, Field.CRC, Field.CRC_DELIM
_ACK_SLOT, _ACK_DELIM, _EOF = Field.ACK_SLOT, Field.ACK_DELIM, Field.EOF


@dataclass(frozen=True)
class BitError:
    """A detected error: kind ('stuff', 'crc', 'form'; 'exception' for the protocol exception
    event), the field and bit index in it, and the position in the bit stream counted from SOF
    (stuff bits included).

    In FD frames a fixed stuff bit of the wrong level is a form error in field FIXED_STUFF (index:
    which fixed stuff bit), and a stuff count that does not match the dynamic stuff bits received
    (or whose parity is wrong) is a CRC error in field STUFF_COUNT, signalled, like every CRC error,
    after the ACK delimiter.
    """

    kind: str
    field: Field
    index: int
    position: int

    def __str__(self) -> str:
        return f"{self.kind} error in {self.field.value} bit {self.index} (bit {self.position} from SOF)"


@dataclass(frozen=True)
class DecodedFrame:
    """What a receiver made of one frame's bits.

    ``frame`` is None when the header did not complete. ``crc`` is the CRC as received,
    ``crc_ok`` whether it matched (FD: and the stuff count); ``ack`` whether the ACK slot was
    dominant; ``error`` the first error detected (None for a valid frame); ``length`` bits consumed
    from SOF (to the end of EOF for a valid frame, to the erroneous bit otherwise). ``overload`` is
    set when the last EOF bit was dominant (an overload condition, the frame stays valid for a
    receiver). ``stuff_count`` is the number of (dynamic) stuff bits removed; for FD frames
    ``stuff_count_bits`` is the stuff count field as received (Gray code and parity, 4 bits).
    """

    frame: Frame | None
    crc: int | None
    crc_ok: bool
    ack: bool
    error: BitError | None
    length: int
    stuff_count: int
    overload: bool = False
    can_id: int | None = None
    extended: bool = False
    remote: bool = False
    dlc: int | None = None
    data: bytes = b""
    fd: bool = False
    brs: bool = False
    esi: bool = False
    stuff_count_bits: int | None = None

    @property
    def ok(self) -> bool:
        """True if the frame is valid for a receiver (no stuff, CRC or form error)."""
        return self.error is None and self.frame is not None


class BitDecoder:
    """A receiver's bit-stream state machine: feed one sampled bit at a time from SOF on.

    `feed` returns a `DecodedFrame` when the frame ends (after the last EOF bit, or at the bit
    where an error is detected) and None otherwise. Errors detected: stuff (sixth equal bit in
    SOF..CRC, FD: SOF..data), form (dominant CRC delimiter, ACK delimiter, or EOF bits 1..6; FD: a
    fixed stuff bit equal to the bit before it) and CRC (mismatch, FD: or stuff count mismatch,
    reported when the ACK delimiter has been received, where the standard signals it). ``mode``:
    see the module docstring.

    What it has received so far is public and read-only: `can_id`, `extended`, `remote`, `dlc`,
    `fd`, `brs`, `esi`, `received_data`, `received_crc`, `field` and `field_index`.
    """

    def __init__(self, mode: str = "classic") -> None:
        if mode not in MODES:
            raise ValueError(f"receiver mode {mode!r}: one of {', '.join(MODES)}")
        self._mode = mode
        self._collect = mode == "fd"
        self.reset()

    def reset(self) -> None:
        """Forget the current frame; the next bit fed is expected to be SOF."""
        self._pos = 0
        self._last = -1
        self._run = 0
        self._stuffing = True  # dynamic stuffing: classical SOF..CRC, FD SOF..data
        self._fixed = False  # FD CRC field: fixed stuff bits
        self._fixed_k = 0
        self._expect_stuff = False
        self._stuff_count = 0
        self._field = Field.SOF
        self._field_index = 0
        self._crc = 0
        self._crc_rx = 0
        self._sraw = 0  # FD: every bit of the dynamic region (stuff bits included), then the stuff count
        self._dyn_len = 0
        self._sc_rx = 0
        self._sc_ok = True
        self._ext = False
        self._rtr = 0
        self._fd = False
        self._brs = 0
        self._esi = 0
        self._dlc = 0
        self._data = 0
        self._id = 0
        self._id_ok = False  # the identifier is complete (its format known)
        self._ack = False
        self._crc_ok = False
        self._layout: list[tuple[Field, int]] = [(Field.SOF, 1), (Field.ID, 11), (Field.RTR, 1)]
        self._li = 0
        self._done: set[Field] = set()

    def clone(self) -> BitDecoder:
        """An independent copy in the same state (receivers that saw the same bits so far)."""
        new = BitDecoder.__new__(BitDecoder)
        new.__dict__ = self.__dict__.copy()
        new._layout = list(self._layout)
        new._done = set(self._done)
        return new

    # -- what has been received (read-only) ---------------------------------------------------
    @property
    def mode(self) -> str:
        """What this receiver is: 'classic', 'tolerant' or 'fd'."""
        return self._mode

    @property
    def in_frame(self) -> bool:
        """True between SOF and the end of the frame."""
        return self._pos > 0

    @property
    def field(self) -> Field:
        """Field of the next expected bit."""
        return self._field

    @property
    def field_index(self) -> int:
        """Index in `field` of the next expected bit."""
        return self._field_index

    @property
    def position(self) -> int:
        """Bits fed since SOF."""
        return self._pos

    @property
    def crc_matches(self) -> bool:
        """After the CRC delimiter: whether the received CRC matched (FD: and the stuff count);
        a receiver ACKs if so."""
        return self._crc_ok

    @property
    def can_id(self) -> int | None:
        """The identifier, once complete: after IDE (dominant) in a standard frame, after the
        identifier extension in an extended one."""
        return self._id if self._id_ok else None

    @property
    def extended(self) -> bool:
        """True once IDE was received recessive."""
        return self._ext

    @property
    def remote(self) -> bool:
        """The RTR bit as received (always False in an FD frame, whose RRS it is)."""
        return bool(self._rtr) and not self._fd

    @property
    def dlc(self) -> int | None:
        """The DLC, once complete."""
        return self._dlc if Field.DLC in self._done else None

    @property
    def fd(self) -> bool:
        """True once FDF was received recessive by an FD receiver."""
        return self._fd

    @property
    def brs(self) -> bool:
        """The BRS bit of an FD frame (False until received)."""
        return bool(self._brs)

    @property
    def esi(self) -> bool:
        """The ESI bit of an FD frame (False until received)."""
        return bool(self._esi)

    def _result(self, error: BitError | None, overload: bool = False) -> DecodedFrame:
        frame = None
        header_done = self._li_done_header
        data = self.received_data if header_done else b""
        if error is None:
            try:
                frame = Frame(
                    self._id,
                    data,
                    extended=self._ext,
                    remote=self.remote,
                    dlc=self._dlc,
                    fd=self._fd,
                    brs=bool(self._brs),
                    esi=bool(self._esi),
                )
            except ValueError:  # pragma: no cover - header fields are range-checked by width
                frame = None
        res = DecodedFrame(
            frame=frame,
            crc=self._crc_rx if self._crc_done else None,
            crc_ok=self._crc_ok,
            ack=self._ack,
            error=error,
            length=self._pos,
            stuff_count=self._stuff_count,
            overload=overload,
            can_id=self.can_id,
            extended=self._ext,
            remote=self.remote,
            dlc=self._dlc if header_done else None,
            data=data if header_done else b"",
            fd=self._fd,
            brs=bool(self._brs),
            esi=bool(self._esi),
            stuff_count_bits=self._sc_rx if Field.STUFF_PARITY in self._done else None,
        )
        self.reset()
        return res

    @property
    def received_data(self) -> bytes:
        """The data bytes received so far: all of them once the data field is complete, else
        only the whole bytes before the bit where the frame stopped (never a partial byte)."""
        if not self._li_done_header or self.remote:
            return b""
        dlen = data_length(self._dlc, self._fd)
        if Field.DATA in self._done or dlen == 0:
            return self._data.to_bytes(dlen, "big") if dlen else b""
        if self._field != Field.DATA:
            return b""
        bits = self._field_index
        return (self._data >> (bits % 8)).to_bytes(bits // 8, "big")

    @property
    def received_crc(self) -> int | None:
        """The CRC sequence received, once complete."""
        return self._crc_rx if self._crc_done else None

    @property
    def _li_done_header(self) -> bool:
        return Field.DLC in self._done

    @property
    def _crc_done(self) -> bool:
        return Field.CRC in self._done

    def feed(self, bit: int) -> DecodedFrame | None:
        """Consume one bit (0 dominant, 1 recessive); see the class docstring."""
        pos = self._pos
        self._pos = pos + 1
        if self._stuffing:
            if self._collect:  # an FD receiver keeps every bit for the CRC-17/21 (stuff bits included)
                self._sraw = (self._sraw << 1) | bit
            if self._expect_stuff:
                if bit == self._last:
                    return self._result(BitError("stuff", self._field, self._field_index, pos))
                self._last, self._run, self._expect_stuff = bit, 1, False
                self._stuff_count += 1
                if self._field is _CRC_DELIM:
                    self._stuffing = False
                return None
            if bit == self._last:
                self._run += 1
            else:
                self._last, self._run = bit, 1
            if self._run == 5:
                self._expect_stuff = True
            return self._stuffed_bit(bit, pos)
        if self._fixed:
            return self._crc_field_bit(bit, pos)
        return self._fixed_bit(bit, pos)

    def _advance(self) -> None:
        self._field_index += 1
        f, width = self._layout[self._li]
        if self._field_index >= width:
            self._done.add(f)
            self._li += 1
            self._field_index = 0
            while self._li < len(self._layout) and self._layout[self._li][1] == 0:
                self._done.add(self._layout[self._li][0])
                self._li += 1
            if self._li < len(self._layout):
                self._field = self._layout[self._li][0]
                if self._field is _STUFF_COUNT:
                    # end of the FD data field: fixed stuffing from here (a pending dynamic stuff
                    # bit is replaced by the first fixed stuff bit)
                    self._stuffing = False
                    self._expect_stuff = False
                    self._fixed = True
                    self._dyn_len = self._pos
            else:
                self._field = _CRC_DELIM
                self._fixed = False
                if not self._expect_stuff:
                    self._stuffing = False

    def _stuffed_bit(self, bit: int, pos: int) -> DecodedFrame | None:
        # fields by how often their bits come (data first); module-level names and `is`: an
        # attribute of the Enum class is a descriptor call, dearer than a global read
        f = self._field
        if f is not _CRC:
            self._crc = ((self._crc << 1) & 0x7FFF) ^ (CRC15_POLY if bit ^ (self._crc >> 14) else 0)
        if f is _DATA:
            self._data = (self._data << 1) | bit
        elif f is _CRC:
            self._crc_rx = (self._crc_rx << 1) | bit
        elif f is _ID or f is _ID_EXT:
            self._id = (self._id << 1) | bit
        elif f is _DLC:
            self._dlc = (self._dlc << 1) | bit
            if self._field_index == 3:
                if self._fd:
                    n = data_length(self._dlc, True)
                    self._layout += [
                        (_DATA, 8 * n),
                        (_STUFF_COUNT, 3),
                        (Field.STUFF_PARITY, 1),
                        (_CRC, 17 if n <= 16 else 21),
                    ]
                else:
                    n = 0 if self._rtr else data_length(self._dlc)
                    self._layout += [(_DATA, 8 * n), (_CRC, 15)]
        elif f is _SOF:
            if self._li == 0:
                self._layout.insert(3, (Field.IDE, 1))
        elif f is _RTR:
            # in a standard frame this is RTR; if IDE turns out 1 it was SRR
            self._rtr = bit
            if self._ext:
                self._layout.append((Field.R1, 1))
                self._id_ok = True
        elif f is _IDE and self._li == 3:
            if bit:
                self._ext = True
                self._layout[2] = (Field.SRR, 1)
                self._layout += [(_ID_EXT, 18), (_RTR, 1)]
            else:
                self._layout.append((_R0, 1))
                self._id_ok = True
        elif f is _R1 or (f is _R0 and not self._ext):
            # standard r0 / extended r1: FDF in an ISO 11898-1:2015 frame
            if bit and self._mode != "classic":
                if self._mode == "tolerant":
                    return self._result(BitError("exception", Field.FDF, 0, pos))
                self._fd = True
                self._layout[self._li] = (Field.FDF, 1)
                self._layout[5 if self._ext else 2] = (Field.RRS, 1)  # it was RRS, not RTR
                self._done.add(Field.RRS)
                self._layout += [(_RES, 1), (_BRS, 1), (_ESI, 1), (_DLC, 4)]
            elif f is _R1:
                self._layout += [(_R0, 1), (_DLC, 4)]
            else:
                self._layout.append((_DLC, 4))
        elif f is _RES:
            if bit:  # protocol exception event (ISO 11898-1:2015): no error frame, bus integration
                return self._result(BitError("exception", _RES, 0, pos))
        elif f is _BRS:
            self._brs = bit
        elif f is _ESI:
            self._esi = bit
        self._advance()
        return None

    def _crc_field_bit(self, bit: int, pos: int) -> DecodedFrame | None:
        """A bit of an FD CRC field: a fixed stuff bit before every 4 bits, then stuff count,
        parity and CRC (no dynamic stuffing)."""
        k = self._fixed_k
        self._fixed_k = k + 1
        if k % 5 == 0:
            if bit == self._last:  # a fixed stuff bit must be the complement of the bit before it
                return self._result(BitError("form", Field.FIXED_STUFF, k // 5, pos))
            self._last = bit
            return None
        self._last = bit
        f = self._field
        if f is _CRC:
            self._crc_rx = (self._crc_rx << 1) | bit
        else:  # STUFF_COUNT, STUFF_PARITY: covered by the CRC
            self._sc_rx = (self._sc_rx << 1) | bit
            self._sraw = (self._sraw << 1) | bit
            if f is Field.STUFF_PARITY:
                width = self._layout[-1][1]
                self._crc = crc_fd_int(self._sraw, self._dyn_len + 4, width)
                self._sc_ok = self._sc_rx == stuff_count_bits(self._stuff_count)
        self._advance()
        return None

    def _fixed_bit(self, bit: int, pos: int) -> DecodedFrame | None:
        f = self._field
        if f is _EOF:
            i = self._field_index
            if not bit:
                if i < 6:
                    return self._result(BitError("form", f, i, pos))
                return self._result(None, overload=True)
            if i == 6:
                return self._result(None)
            self._field_index = i + 1
        elif f is _CRC_DELIM:
            self._crc_ok = self._crc == self._crc_rx and self._sc_ok
            if not bit:
                return self._result(BitError("form", f, 0, pos))
            self._field, self._field_index = _ACK_SLOT, 0
        elif f is _ACK_SLOT:
            self._ack = bit == 0
            self._field = _ACK_DELIM
        elif f is _ACK_DELIM:
            if not bit:
                return self._result(BitError("form", f, 0, pos))
            if not self._crc_ok:
                # a CRC error (FD: or stuff count error) is signalled after the ACK delimiter
                return self._result(BitError("crc", _CRC if self._sc_ok else _STUFF_COUNT, 0, pos))
            self._field, self._field_index = _EOF, 0
        return None


def decode(bits: str | Sequence[int], mode: str = "classic") -> DecodedFrame:
    """Decode one frame from its bit sequence starting at SOF (a string of '0'/'1' or ints), as a
    receiver of this ``mode`` ('classic', 'tolerant' or 'fd': see the module docstring).

    Detects stuff, CRC and form errors and reports the first with its field and bit. A sequence
    that ends before the frame does raises ValueError naming the field it stopped in.
    """
    dec = BitDecoder(mode)
    if isinstance(bits, str):
        seq: Iterator[int] = (1 if c == "1" else 0 for c in bits if c in "01")
    else:
        seq = iter(bits)
    first = True
    for b in seq:
        if first:
            first = False
            if b != 0:
                raise ValueError("a frame starts with a dominant SOF bit (0); got 1")
        res = dec.feed(b)
        if res is not None:
            return res
    raise ValueError(f"bit sequence ended after {dec.position} bits, inside field {dec.field.value}")
