"""The frame value type and its rules: CAN 2.0A/B data and remote frames and CAN FD data frames
(ISO 11898-1:2015).

`Frame` is immutable and validated on construction. It is read from a `can.Message`, the type users
already hold, by that message's attributes (`Frame.from_message`; building one is
`stack.io.message.to_message`, at the boundary: this layer does not import python-can); inside
the engine it is the unit of arbitration.

CAN FD (``fd=True``) frames carry 0..8, 12, 16, 20, 24, 32, 48 or 64 bytes (DLC 9..15 mean 12..64
bytes); ``brs`` (bit rate switch) and ``esi`` (error state indicator, recessive = the transmitter is
error passive) exist only in FD frames. FD has no remote frames: its RRS bit is always dominant, so
an FD frame arbitrates exactly like a classical data frame with the same identifier (FDF comes
after the arbitration field) and `arbitration_key` is the same function for both.
"""

from __future__ import annotations

from typing import Any, Protocol

from .coding import FrameBits, encode
from .fd import FD_LENGTHS, encode_fd

__all__ = [
    "Frame",
    "MessageLike",
    "STANDARD_ID_MAX",
    "EXTENDED_ID_MAX",
    "FD_LENGTHS",
    "arbitration_key",
    "data_length",
    "len_to_dlc",
    "pad_to_fd_length",
    "id_text",
]

STANDARD_ID_MAX = 0x7FF
EXTENDED_ID_MAX = 0x1FFFFFFF

_FD_DLC = {n: dlc for dlc, n in enumerate(FD_LENGTHS)}
_FD_LENGTHS_TEXT = "0..8, 12, 16, 20, 24, 32, 48 or 64"


def data_length(dlc: int, fd: bool = False) -> int:
    """Bytes carried by a data frame with this DLC: min(DLC, 8) for a classical frame (DLC 9..15
    mean 8, CAN 2.0); for a CAN FD frame DLC 9..15 mean 12, 16, 20, 24, 32, 48, 64 bytes."""
    if fd:
        return FD_LENGTHS[dlc]
    return dlc if dlc < 8 else 8


def len_to_dlc(length: int) -> int:
    """The DLC of a data field of ``length`` bytes (the smallest DLC meaning that many bytes):
    0..8 for 0..8 bytes, 9..15 for the CAN FD lengths 12..64; any other length is a ValueError
    naming it and the valid lengths (no padding: see `pad_to_fd_length`)."""
    dlc = _FD_DLC.get(length) if isinstance(length, int) and not isinstance(length, bool) else None
    if dlc is None:
        raise ValueError(f"data of {length!r} bytes is not a CAN FD length: one of {_FD_LENGTHS_TEXT}")
    return dlc


def pad_to_fd_length(data: bytes | bytearray, fill: int = 0x00) -> bytes:
    """``data`` padded with ``fill`` bytes to the next CAN FD length (12 bytes -> 12, 13 -> 16,
    ..., at most 64). `Frame` never pads by itself: a length that is not an FD length is an error,
    and padding (and its value: 0x00 here, 0xCC in ISO 15765-2 transport) is the caller's choice."""
    if not 0 <= fill <= 0xFF:
        raise ValueError(f"fill byte {fill!r} out of range: must be 0..255")
    n = len(data)
    if n > 64:
        raise ValueError(f"data of {n} bytes: a CAN FD frame carries at most 64")
    target = next(x for x in FD_LENGTHS if x >= n)
    return bytes(data) + bytes([fill]) * (target - n)


def arbitration_key(can_id: int, extended: bool, remote: bool) -> int:
    """The arbitration field as a 32-bit number; the lower key wins bitwise arbitration.

    Bit order on the wire (dominant = 0): standard ID[10:0], RTR, IDE=0; extended ID[28:18],
    SRR=1, IDE=1, ID[17:0], RTR. Standard fields are left-aligned into the same 32 bits, so a
    data frame beats a remote frame with the same ID and a standard frame beats an extended frame
    with the same base ID, exactly as on the bus.
    """
    if extended:
        return ((can_id >> 18) << 21) | (3 << 19) | ((can_id & 0x3FFFF) << 1) | int(remote)
    return (can_id << 21) | (int(remote) << 20)


def id_text(can_id: int, extended: bool, remote: bool = False) -> str:
    """An identifier as every text output writes it: 0x-hex, 3 digits standard, 8 extended,
    ' RTR' for a remote frame (JSON output carries the integer)."""
    return (f"0x{can_id:08X}" if extended else f"0x{can_id:03X}") + (" RTR" if remote else "")


class MessageLike(Protocol):
    """What `Frame.from_message` reads of a message: the attributes of python-can's `can.Message`
    (any object that has them will do)."""

    @property
    def arbitration_id(self) -> int: ...
    @property
    def data(self) -> bytes | bytearray: ...
    @property
    def dlc(self) -> int: ...
    @property
    def is_extended_id(self) -> bool: ...
    @property
    def is_remote_frame(self) -> bool: ...
    @property
    def is_error_frame(self) -> bool: ...
    @property
    def is_fd(self) -> bool: ...
    @property
    def bitrate_switch(self) -> bool: ...
    @property
    def error_state_indicator(self) -> bool: ...


def _hex(v: int) -> str:
    """0x-hex for a value in an error message (a negative one as -0x..)."""
    return f"0x{v:X}" if v >= 0 else f"-0x{-v:X}"


class Frame:
    """A CAN 2.0 data or remote frame, or a CAN FD data frame: identifier, format, DLC and data.

    Rules enforced (ISO 11898-1:2015, CAN 2.0A/B):
    - identifier 0..0x7FF (standard, 11 bits) or 0..0x1FFFFFFF (extended, 29 bits);
    - classical (``fd=False``): DLC 0..15; a data frame carries min(DLC, 8) bytes, DLC 9..15 are
      kept and sent as given; a remote frame carries no data, its DLC is the length it requests;
    - CAN FD (``fd=True``): 0..8, 12, 16, 20, 24, 32, 48 or 64 data bytes, the DLC follows from the
      length (9..15 for 12..64); no remote frames (RRS is always dominant); ``brs`` switches to the
      data bit rate, ``esi`` is sent recessive by an error-passive transmitter. ``brs`` and ``esi``
      exist only in FD frames.

    ``dlc`` defaults to ``len(data)`` for a classical data frame, 0 for a remote frame and the DLC
    of the length for an FD frame.

    ``bits`` (the `FrameBits` on the wire) is computed on first use and kept in the slot
    ``encoded``; ``nbits`` is their number SOF..EOF, 0 until then. The engine's hot path reads
    ``frame.nbits or frame.wire_bits`` and ``frame.encoded or frame.bits``: a plain slot read once the
    frame is encoded (a property, or a ``__getattr__`` on the class, would cost a call on every
    attribute access).
    """

    __slots__ = ("can_id", "extended", "remote", "dlc", "data", "key", "fd", "brs", "esi", "encoded", "nbits")

    can_id: int
    extended: bool
    remote: bool
    dlc: int
    data: bytes
    key: int
    fd: bool
    brs: bool
    esi: bool
    encoded: FrameBits | None
    nbits: int

    def __init__(
        self,
        can_id: int,
        data: bytes | bytearray | list[int] | tuple[int, ...] = b"",
        *,
        extended: bool = False,
        remote: bool = False,
        dlc: int | None = None,
        fd: bool = False,
        brs: bool = False,
        esi: bool = False,
    ) -> None:
        if isinstance(can_id, bool) or not isinstance(can_id, int):
            raise TypeError(f"identifier must be an int, got {can_id!r}")
        limit = EXTENDED_ID_MAX if extended else STANDARD_ID_MAX
        if not 0 <= can_id <= limit:
            fmt = "an extended (29-bit)" if extended else "a standard (11-bit)"
            raise ValueError(f"identifier {_hex(can_id)} out of range for {fmt} frame: must be 0..0x{limit:X}")
        try:
            payload = bytes(data)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"data {data!r} is not a sequence of bytes 0..255: {exc}") from None
        if fd:
            dlc = _fd_dlc(payload, remote, dlc)
        else:
            if brs or esi:
                raise ValueError(
                    f"{'BRS' if brs else 'ESI'} exists only in CAN FD frames (ISO 11898-1:2015): give fd=True"
                )
            if remote and payload:
                raise ValueError(
                    f"a remote frame carries no data (got {len(payload)} byte{'s' if len(payload) != 1 else ''}); "
                    "give the requested length as dlc"
                )
            if len(payload) > 8:
                raise ValueError(
                    f"data of {len(payload)} bytes: a CAN 2.0 frame carries at most 8 (a CAN FD frame up to 64: fd=True)"
                )
            if dlc is None:
                dlc = 0 if remote else len(payload)
            if isinstance(dlc, bool) or not isinstance(dlc, int) or not 0 <= dlc <= 15:
                raise ValueError(f"DLC {dlc!r} out of range: must be 0..15")
            if not remote and len(payload) != data_length(dlc):
                raise ValueError(f"DLC {dlc} means {data_length(dlc)} data bytes, but {len(payload)} were given")
        # the slots' own setters: cheaper than object.__setattr__ (Frame is on the hot path)
        s_id, s_ext, s_rtr, s_dlc, s_data, s_key, s_fd, s_brs, s_esi, s_enc, s_nbits = _SETTERS
        s_id(self, can_id)
        s_ext(self, bool(extended))
        s_rtr(self, bool(remote))
        s_dlc(self, dlc)
        s_data(self, payload)
        s_key(self, arbitration_key(can_id, extended, remote))
        if fd:
            s_fd(self, True)
            s_brs(self, bool(brs))
            s_esi(self, bool(esi))
        else:
            s_fd(self, False)
            s_brs(self, False)
            s_esi(self, False)
        s_enc(self, None)
        s_nbits(self, 0)

    # -- immutability -------------------------------------------------------------------------
    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("Frame is immutable")

    def __delattr__(self, name: str) -> None:
        raise AttributeError("Frame is immutable")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Frame):
            return NotImplemented
        return (
            self.key == other.key
            and self.dlc == other.dlc
            and self.data == other.data
            and self.extended == other.extended
            and self.fd == other.fd
            and self.brs == other.brs
            and self.esi == other.esi
        )

    def __hash__(self) -> int:
        if self.fd:
            return hash((self.key, self.extended, self.dlc, self.data, True, self.brs, self.esi))
        return hash((self.key, self.extended, self.dlc, self.data))

    def __repr__(self) -> str:
        parts = [f"0x{self.can_id:0{8 if self.extended else 3}X}"]
        if self.extended:
            parts.append("extended=True")
        if self.remote:
            parts.append("remote=True")
            parts.append(f"dlc={self.dlc}")
        else:
            parts.append(f"data={self.data.hex()!r}" if self.data else "data=b''")
            if self.dlc > 8 and not self.fd:
                parts.append(f"dlc={self.dlc}")
        if self.fd:
            parts.append("fd=True")
            if self.brs:
                parts.append("brs=True")
            if self.esi:
                parts.append("esi=True")
        return f"Frame({', '.join(parts)})"

    def __reduce__(self) -> tuple[Any, ...]:
        if self.fd:
            return (_rebuild, (self.can_id, self.data, self.extended, self.remote, self.dlc, True, self.brs, self.esi))
        return (_rebuild, (self.can_id, self.data, self.extended, self.remote, self.dlc))

    # -- derived values ---------------------------------------------------------------------
    @property
    def length(self) -> int:
        """Number of data bytes carried (0 for a remote frame)."""
        return len(self.data)

    @property
    def bits(self) -> FrameBits:
        """The frame's exact bit sequence on the wire, computed once (`stack.wire.coding.encode`,
        FD: `stack.wire.fd.encode_fd`)."""
        b = self.encoded
        if b is None:
            b = encode_fd(self) if self.fd else encode(self)
            _SETTERS[9](self, b)
            _SETTERS[10](self, len(b.bits))
        return b

    @property
    def wire_bits(self) -> int:
        """Exact length in bits from SOF to the end of EOF, stuff bits included (FD: dynamic and
        fixed stuff bits)."""
        return self.nbits or self.bits.length

    # -- python-can boundary ------------------------------------------------------------------
    @classmethod
    def from_message(cls, msg: MessageLike) -> Frame:
        """The frame a `can.Message` describes, CAN FD included (``is_fd``, ``bitrate_switch``,
        ``error_state_indicator`` become ``fd``, ``brs``, ``esi``); error frames are refused.

        The message is read by its attributes (`MessageLike`), so python-can is not imported here;
        the conversion the other way, which builds a `can.Message`, is `stack.io.message.to_message`.
        python-can's ``dlc`` counts data bytes, so a classical message converts only with dlc 0..8
        (equal to its number of bytes) and an FD message's dlc must equal its number of bytes;
        anything else is named in the error, as are the rules `Frame` enforces.
        """
        if msg.is_error_frame:
            raise ValueError("an error frame is not a data or remote frame")
        extended = bool(msg.is_extended_id)
        brs, esi = bool(msg.bitrate_switch), bool(msg.error_state_indicator)
        if msg.is_fd:
            data = bytes(msg.data)
            if msg.dlc != len(data):
                raise ValueError(f"CAN FD message dlc {msg.dlc} does not match {len(data)} data bytes")
            return cls(
                msg.arbitration_id, data, extended=extended, remote=bool(msg.is_remote_frame), fd=True, brs=brs, esi=esi
            )
        if not 0 <= msg.dlc <= 8:
            raise ValueError(f"can.Message with dlc {msg.dlc}: only dlc 0..8 convert to a CAN 2.0 frame")
        if msg.is_remote_frame:
            return cls(msg.arbitration_id, extended=extended, remote=True, dlc=msg.dlc, brs=brs, esi=esi)
        data = bytes(msg.data)
        if len(data) != msg.dlc:
            raise ValueError(f"can.Message dlc {msg.dlc} does not match {len(data)} data bytes")
        return cls(msg.arbitration_id, data, extended=extended, brs=brs, esi=esi)


_SETTERS = tuple(Frame.__dict__[name].__set__ for name in Frame.__slots__)


def _fd_dlc(payload: bytes, remote: bool, dlc: int | None) -> int:
    """The DLC of an FD frame's data (the rules of `Frame` for ``fd=True``)."""
    if remote:
        raise ValueError(
            "CAN FD has no remote frames (its RRS bit is always dominant, ISO 11898-1:2015): "
            "send a classical remote frame (fd=False)"
        )
    n = len(payload)
    fd_dlc = _FD_DLC.get(n)
    if fd_dlc is None:
        raise ValueError(f"data of {n} bytes is not a CAN FD length: one of {_FD_LENGTHS_TEXT}")
    if dlc is None:
        return fd_dlc
    if isinstance(dlc, bool) or not isinstance(dlc, int) or not 0 <= dlc <= 15:
        raise ValueError(f"DLC {dlc!r} out of range: must be 0..15")
    if dlc == fd_dlc:
        return fd_dlc
    raise ValueError(f"DLC {dlc} means {FD_LENGTHS[dlc]} data bytes in a CAN FD frame, but {n} were given")


def _rebuild(
    can_id: int,
    data: bytes,
    extended: bool,
    remote: bool,
    dlc: int,
    fd: bool = False,
    brs: bool = False,
    esi: bool = False,
) -> Frame:
    return Frame(can_id, data, extended=extended, remote=remote, dlc=dlc, fd=fd, brs=brs, esi=esi)
