"""The receiver's view of a frame's bits: destuffing, CRC and form checks (ISO 11898-1).

`BitDecoder` is fed one bit at a time (0 = dominant, 1 = recessive) from SOF, as a receiver
samples them, and reports the frame or the first error (stuff, CRC, form) where the standard
detects it; `decode` runs it over a whole bit string.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

from stack.wire.frame import Frame, data_length

from .coding import CRC15_POLY, Field

__all__ = ["BitError", "DecodedFrame", "BitDecoder", "decode"]


@dataclass(frozen=True)
class BitError:
    """A detected error: kind ('stuff', 'crc', 'form'), the field and bit index in it, and the
    position in the bit stream counted from SOF (stuff bits included)."""

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
    ``crc_ok`` whether it matched; ``ack`` whether the ACK slot was dominant; ``error`` the first
    error detected (None for a valid frame); ``length`` bits consumed from SOF (to the end of EOF
    for a valid frame, to the erroneous bit otherwise). ``overload`` is set when the last EOF bit
    was dominant (an overload condition, the frame stays valid for a receiver).
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

    @property
    def ok(self) -> bool:
        """True if the frame is valid for a receiver (no stuff, CRC or form error)."""
        return self.error is None and self.frame is not None


class BitDecoder:
    """A receiver's bit-stream state machine: feed one sampled bit at a time from SOF on.

    `feed` returns a `DecodedFrame` when the frame ends (after the last EOF bit, or at the bit
    where an error is detected) and None otherwise. Errors detected: stuff (sixth equal bit in
    SOF..CRC), form (dominant CRC delimiter, ACK delimiter, or EOF bits 1..6) and CRC (mismatch,
    reported when the ACK delimiter has been received, where the standard signals it).
    """

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Forget the current frame; the next bit fed is expected to be SOF."""
        self._pos = 0
        self._last = -1
        self._run = 0
        self._stuffing = True
        self._expect_stuff = False
        self._stuff_count = 0
        self._raw: list[int] = []
        self._field = Field.SOF
        self._field_index = 0
        self._crc = 0
        self._crc_rx = 0
        self._ext = False
        self._rtr = 0
        self._dlc = 0
        self._data_bits = 0
        self._data = 0
        self._id = 0
        self._ack = False
        self._crc_ok = False
        self._error: BitError | None = None
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

    @property
    def in_frame(self) -> bool:
        """True between SOF and the end of the frame."""
        return self._pos > 0

    @property
    def field(self) -> Field:
        """Field of the next expected bit."""
        return self._field

    @property
    def position(self) -> int:
        """Bits fed since SOF."""
        return self._pos

    @property
    def crc_matches(self) -> bool:
        """After the CRC delimiter: whether the received CRC matched (a receiver ACKs if so)."""
        return self._crc_ok

    def _result(self, error: BitError | None, overload: bool = False) -> DecodedFrame:
        frame = None
        header_done = self._li_done_header
        data = self.received_data if header_done else b""
        if error is None or (error.kind == "crc"):
            try:
                frame = Frame(self._id, data, extended=self._ext, remote=bool(self._rtr), dlc=self._dlc)
            except ValueError:  # pragma: no cover - header fields are range-checked by width
                frame = None
        res = DecodedFrame(
            frame=frame if error is None else None,
            crc=self._crc_rx if self._crc_done else None,
            crc_ok=self._crc_ok,
            ack=self._ack,
            error=error,
            length=self._pos,
            stuff_count=self._stuff_count,
            overload=overload,
            can_id=self._id if self._id_done else None,
            extended=self._ext,
            remote=bool(self._rtr),
            dlc=self._dlc if header_done else None,
            data=data if header_done else b"",
        )
        self.reset()
        return res

    # progress markers used by _result
    @property
    def _id_done(self) -> bool:
        return Field.RTR in self._done

    @property
    def received_data(self) -> bytes:
        """The data bytes received so far: all of them once the data field is complete, else
        only the whole bytes before the bit where the frame stopped (never a partial byte)."""
        if not self._li_done_header or self._rtr:
            return b""
        dlen = data_length(self._dlc)
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
            if self._expect_stuff:
                if bit == self._last:
                    return self._result(BitError("stuff", self._field, self._field_index, pos))
                self._last, self._run, self._expect_stuff = bit, 1, False
                self._stuff_count += 1
                if self._field == Field.CRC_DELIM:
                    self._stuffing = False
                return None
            if bit == self._last:
                self._run += 1
            else:
                self._last, self._run = bit, 1
            if self._run == 5:
                self._expect_stuff = True
            return self._stuffed_bit(bit, pos)
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
            else:
                self._field = Field.CRC_DELIM
                if not self._expect_stuff:
                    self._stuffing = False

    def _stuffed_bit(self, bit: int, pos: int) -> DecodedFrame | None:
        f = self._field
        if f != Field.CRC:
            self._crc = ((self._crc << 1) & 0x7FFF) ^ (CRC15_POLY if bit ^ (self._crc >> 14) else 0)
        if f == Field.ID:
            self._id = (self._id << 1) | bit
        elif f == Field.RTR:
            # in a standard frame this is RTR; if IDE turns out 1 it was SRR
            self._rtr = bit
            if self._ext:
                self._layout += [(Field.R1, 1), (Field.R0, 1), (Field.DLC, 4)]
        elif f == Field.IDE and self._li == 3:
            if bit:
                self._ext = True
                self._layout[2] = (Field.SRR, 1)
                self._layout += [(Field.ID_EXT, 18), (Field.RTR, 1)]
            else:
                self._layout += [(Field.R0, 1), (Field.DLC, 4)]
        elif f == Field.SRR:
            pass
        elif f == Field.ID_EXT:
            self._id = (self._id << 1) | bit
        elif f == Field.DLC:
            self._dlc = (self._dlc << 1) | bit
            if self._field_index == 3:
                n = 0 if self._rtr else data_length(self._dlc)
                self._layout += [(Field.DATA, 8 * n), (Field.CRC, 15)]
        elif f == Field.DATA:
            self._data = (self._data << 1) | bit
        elif f == Field.CRC:
            self._crc_rx = (self._crc_rx << 1) | bit
        if f == Field.SOF and self._li == 0:
            self._layout.insert(3, (Field.IDE, 1))
        self._advance()
        return None

    def _fixed_bit(self, bit: int, pos: int) -> DecodedFrame | None:
        f = self._field
        if f == Field.CRC_DELIM:
            self._crc_ok = self._crc == self._crc_rx
            if not bit:
                return self._result(BitError("form", f, 0, pos))
            self._field, self._field_index = Field.ACK_SLOT, 0
        elif f == Field.ACK_SLOT:
            self._ack = bit == 0
            self._field = Field.ACK_DELIM
        elif f == Field.ACK_DELIM:
            if not bit:
                return self._result(BitError("form", f, 0, pos))
            if not self._crc_ok:
                # a CRC error is signalled after the ACK delimiter
                return self._result(BitError("crc", Field.CRC, 0, pos))
            self._field, self._field_index = Field.EOF, 0
        elif f == Field.EOF:
            i = self._field_index
            if not bit:
                if i < 6:
                    return self._result(BitError("form", f, i, pos))
                return self._result(None, overload=True)
            if i == 6:
                return self._result(None)
            self._field_index = i + 1
        return None


def decode(bits: str | Sequence[int]) -> DecodedFrame:
    """Decode one frame from its bit sequence starting at SOF (a string of '0'/'1' or ints).

    Detects stuff, CRC and form errors and reports the first with its field and bit. A sequence
    that ends before the frame does raises ValueError naming the field it stopped in.
    """
    dec = BitDecoder()
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
