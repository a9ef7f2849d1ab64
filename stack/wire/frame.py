"""The CAN 2.0A/B frame value type and its rules (ISO 11898-1 data and remote frames).

`Frame` is immutable and validated on construction. At the library boundary it converts to and
from `can.Message`, the type users already hold; inside the engine it is the unit of arbitration.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from .coding import FrameBits, encode

if TYPE_CHECKING:  # pragma: no cover
    import can  # imported where a Message is built: `canstack decode` starts without python-can

__all__ = [
    "Frame",
    "STANDARD_ID_MAX",
    "EXTENDED_ID_MAX",
    "arbitration_key",
    "data_length",
    "id_text",
]

STANDARD_ID_MAX = 0x7FF
EXTENDED_ID_MAX = 0x1FFFFFFF


def data_length(dlc: int) -> int:
    """Bytes carried by a data frame with this DLC: min(DLC, 8) (DLC 9..15 mean 8, CAN 2.0)."""
    return dlc if dlc < 8 else 8


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


def _hex(v: int) -> str:
    """0x-hex for a value in an error message (a negative one as -0x..)."""
    return f"0x{v:X}" if v >= 0 else f"-0x{-v:X}"


class Frame:
    """A CAN 2.0 data or remote frame: identifier, format, DLC 0..15 and data.

    Rules enforced (ISO 11898-1 / CAN 2.0A/B):
    - identifier 0..0x7FF (standard, 11 bits) or 0..0x1FFFFFFF (extended, 29 bits);
    - DLC 0..15; a data frame carries min(DLC, 8) bytes, DLC 9..15 are kept and sent as given;
    - a remote frame carries no data; its DLC is the length it requests.

    ``dlc`` defaults to ``len(data)`` for a data frame and 0 for a remote frame.
    """

    __slots__ = ("can_id", "extended", "remote", "dlc", "data", "key", "_bits", "_nbits")

    can_id: int
    extended: bool
    remote: bool
    dlc: int
    data: bytes
    key: int

    def __init__(
        self,
        can_id: int,
        data: bytes | bytearray | list[int] | tuple[int, ...] = b"",
        *,
        extended: bool = False,
        remote: bool = False,
        dlc: int | None = None,
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
        if remote and payload:
            raise ValueError(
                f"a remote frame carries no data (got {len(payload)} byte{'s' if len(payload) != 1 else ''}); "
                "give the requested length as dlc"
            )
        if len(payload) > 8:
            raise ValueError(f"data of {len(payload)} bytes: a CAN 2.0 frame carries at most 8")
        if dlc is None:
            dlc = 0 if remote else len(payload)
        if isinstance(dlc, bool) or not isinstance(dlc, int) or not 0 <= dlc <= 15:
            raise ValueError(f"DLC {dlc!r} out of range: must be 0..15")
        if not remote and len(payload) != data_length(dlc):
            raise ValueError(f"DLC {dlc} means {data_length(dlc)} data bytes, but {len(payload)} were given")
        sa = object.__setattr__
        sa(self, "can_id", can_id)
        sa(self, "extended", bool(extended))
        sa(self, "remote", bool(remote))
        sa(self, "dlc", dlc)
        sa(self, "data", payload)
        sa(self, "key", arbitration_key(can_id, extended, remote))
        sa(self, "_bits", None)
        sa(self, "_nbits", 0)

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
        )

    def __hash__(self) -> int:
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
            if self.dlc > 8:
                parts.append(f"dlc={self.dlc}")
        return f"Frame({', '.join(parts)})"

    def __reduce__(self) -> tuple[Any, ...]:
        return (_rebuild, (self.can_id, self.data, self.extended, self.remote, self.dlc))

    # -- derived values ---------------------------------------------------------------------
    @property
    def length(self) -> int:
        """Number of data bytes carried (0 for a remote frame)."""
        return len(self.data)

    @property
    def bits(self) -> FrameBits:
        """The frame's exact bit sequence on the wire, computed once (see `stack.bits`)."""
        b = self._bits
        if b is None:
            b = encode(self)
            object.__setattr__(self, "_bits", b)
            object.__setattr__(self, "_nbits", len(b.bits))
        return b

    @property
    def wire_bits(self) -> int:
        """Exact length in bits from SOF to the end of EOF, stuff bits included."""
        return self.bits.length

    # -- python-can boundary ------------------------------------------------------------------
    def to_message(self, timestamp: float = 0.0, channel: Any = None) -> can.Message:
        """This frame as a `can.Message` (classic CAN, dlc as on the wire)."""
        import can

        msg = can.Message(
            timestamp=timestamp,
            arbitration_id=self.can_id,
            is_extended_id=self.extended,
            is_remote_frame=self.remote,
            dlc=self.dlc,
            data=self.data,
            channel=channel,
            check=False,
        )
        return msg

    @classmethod
    def from_message(cls, msg: can.Message) -> Frame:
        """The frame a `can.Message` describes; CAN FD, error frames and dlc > 8 are refused.

        python-can's `Message` cannot carry a classic DLC 9..15 (its dlc is the byte count), so
        only dlc 0..8 convert; anything else is named in the error.
        """
        if msg.is_fd:
            raise ValueError("a CAN FD message is not a CAN 2.0 frame")
        if msg.is_error_frame:
            raise ValueError("an error frame is not a data or remote frame")
        if not 0 <= msg.dlc <= 8:
            raise ValueError(f"can.Message with dlc {msg.dlc}: only dlc 0..8 convert to a CAN 2.0 frame")
        if msg.is_remote_frame:
            return cls(msg.arbitration_id, extended=msg.is_extended_id, remote=True, dlc=msg.dlc)
        data = bytes(msg.data)
        if len(data) != msg.dlc:
            raise ValueError(f"can.Message dlc {msg.dlc} does not match {len(data)} data bytes")
        return cls(msg.arbitration_id, data, extended=msg.is_extended_id)


def _rebuild(can_id: int, data: bytes, extended: bool, remote: bool, dlc: int) -> Frame:
    return Frame(can_id, data, extended=extended, remote=remote, dlc=dlc)
