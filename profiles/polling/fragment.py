"""DeviceNet's fragmentation protocol for I/O messages longer than 8 bytes (CIP Networks Library
Vol. 3, chapter 3; the format as the ICP DAS I-7242D manual's worked example §7.2.11 and
Wireshark's DeviceNet dissector give it).

An I/O connection whose produced size is above 8 bytes sends every message in fragments, back to
back and without acknowledgement (unlike explicit messages, whose fragments are acknowledged one
by one). Each fragment is one CAN frame: a *fragmentation byte*, then up to 7 data bytes.

Fragmentation byte (this module's `encode_header` / `decode_header`):

=========  ========================================================
bits 7..6  fragment type: 0 first, 1 middle, 2 last (3 is the explicit protocol's acknowledge)
bits 5..0  fragment count: 0 for the first fragment, +1 for each next one, modulo 64
=========  ========================================================

ICP DAS's example: 10 bytes 01..0A on a poll command are ``00 01 02 03 04 05 06 07`` (first,
count 0) and ``81 08 09 0A`` (last, count 1).

What the receiver does (`Reassembler`): a first fragment starts a new message, dropping any
unfinished one; a middle or last fragment whose count is the previous one's + 1 (mod 64) is
appended; one whose count equals the previous one (a duplicate) is ignored; any other count drops
the unfinished message, and fragments are then ignored until the next first fragment; a last
fragment completes the message, which is delivered when its length is the connection's size and
dropped otherwise. A middle or last fragment without a first one is ignored.

canstack fragments only connections whose size is above 8 bytes, so a message always has a first
and a last fragment (at least two frames); the largest I/O size it takes is `MAX_IO_SIZE`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:  # pragma: no cover
    from profiles.declarations import MessageDecl

__all__ = [
    "FIRST",
    "MIDDLE",
    "LAST",
    "MAX_IO_SIZE",
    "fragment",
    "encode_header",
    "decode_header",
    "Reassembler",
    "io_frames",
]

FIRST, MIDDLE, LAST = 0, 1, 2
MAX_IO_SIZE = 255
"""The largest I/O connection size canstack takes, bytes (what DeviceNet scanners commonly allow
a slave per direction)."""
_COUNT = 64


def encode_header(kind: int, count: int) -> int:
    """The fragmentation byte of a fragment of ``kind`` (FIRST, MIDDLE, LAST) and ``count``."""
    if kind not in (FIRST, MIDDLE, LAST):
        raise ValueError(f"fragment type {kind!r} is not 0 (first), 1 (middle) or 2 (last)")
    return kind << 6 | (count % _COUNT)


def decode_header(byte: int) -> tuple[int, int]:
    """(fragment type, fragment count) of a fragmentation byte."""
    return byte >> 6, byte & 0x3F


def fragment(data: bytes) -> list[bytes]:
    """The frames' data of an I/O message of more than 8 bytes: the fragmentation byte and up to
    7 data bytes each (see the module docstring)."""
    if len(data) <= 8:
        raise ValueError(f"{len(data)} bytes fit one CAN frame: DeviceNet fragments only I/O longer than 8 bytes")
    chunks = [data[i : i + 7] for i in range(0, len(data), 7)]
    out = []
    for i, chunk in enumerate(chunks):
        kind = FIRST if i == 0 else LAST if i == len(chunks) - 1 else MIDDLE
        out.append(bytes([encode_header(kind, i)]) + chunk)
    return out


class Reassembler:
    """The receiving end of a fragmented I/O connection of ``size`` bytes (see the module
    docstring for the rules). `feed` returns the whole message when a fragment completes it.
    Counters: ``messages`` delivered, ``dropped`` (out of sequence, or the wrong length),
    ``duplicates`` and ``ignored`` fragments."""

    def __init__(self, size: int) -> None:
        self.size = size
        self.buffer: bytearray | None = None
        self.count = 0
        self.messages = 0
        self.dropped = 0
        self.duplicates = 0
        self.ignored = 0

    @property
    def busy(self) -> bool:
        """A message is being reassembled."""
        return self.buffer is not None

    def feed(self, data: bytes) -> bytes | None:
        """One fragment's frame data; the message when this fragment completes it."""
        if not data:
            self.ignored += 1
            return None
        kind, count = decode_header(data[0])
        if kind == FIRST:
            if self.buffer is not None:
                self.dropped += 1
            self.buffer = bytearray(data[1:])
            self.count = count
            return None
        if kind not in (MIDDLE, LAST) or self.buffer is None:
            self.ignored += 1
            return None
        if count == self.count:
            self.duplicates += 1
            return None
        if count != (self.count + 1) % _COUNT:
            self.buffer = None
            self.dropped += 1
            return None
        self.buffer += data[1:]
        self.count = count
        if kind == MIDDLE:
            return None
        message, self.buffer = bytes(self.buffer), None
        if len(message) != self.size:
            self.dropped += 1
            return None
        self.messages += 1
        return message


def io_frames(m: MessageDecl) -> list[bytes]:
    """The data of the frames a declared message of the master/slave network goes out in: one
    frame, or the fragments of its ``io_data`` (the I/O message) when that is longer than 8
    bytes (the connection scenario keys ``data`` of a poll entry and ``size`` of a slave's
    message set it)."""
    io = m.options.get("io_data")
    if io is not None and len(io) > 8:
        return fragment(io)
    return [m.data if m.data is not None else bytes(m.dlc)]
