"""Trace records of the simulated bus and their export through python-can's writers (asc, blf, log, csv, trc, mf4, ...).

canstack does not write log formats itself: `can.Logger` picks the writer from the file suffix,
so Vector tools, candump tools and SavvyCAN read what we write.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable

import can

from stack.wire.frame import Frame

__all__ = ["TraceRecord", "save_messages", "load_messages", "check_suffix", "SUFFIXES"]

SUFFIXES = (".asc", ".blf", ".log", ".csv", ".trc", ".mf4", ".txt", ".db")


class TraceRecord:
    """One bus event: a frame ('frame'), a failed attempt ending in an error frame ('error'),
    or a collision after arbitration ('collision').

    ``start``/``end`` in ns (SOF to end of EOF, or to the end of the error delimiter);
    ``sender`` node name(s); ``bits`` the stuffed length on the wire; ``losses`` arbitration
    rounds the frame lost before winning; ``queued`` the time it was queued; ``detail`` a dict
    (error kind, field, bit position, nodes that saw it, counters after).
    """

    __slots__ = ("kind", "start", "end", "sender", "frame", "bits", "losses", "queued", "detail")

    def __init__(self, kind: str, start: int, end: int, sender: str, frame: Frame, bits: int,
                 losses: int, queued: int, detail: dict[str, Any] | None = None) -> None:
        self.kind = kind
        self.start = start
        self.end = end
        self.sender = sender
        self.frame = frame
        self.bits = bits
        self.losses = losses
        self.queued = queued
        self.detail = detail

    def as_tuple(self) -> tuple[Any, ...]:
        """A plain tuple for comparisons (determinism checks)."""
        return (self.kind, self.start, self.end, self.sender, self.frame.key, self.frame.dlc,
                self.frame.data, self.bits, self.losses, self.queued,
                tuple(sorted((self.detail or {}).items())))

    def to_message(self, channel: Any = None) -> can.Message:
        """python-can message of this record (an error frame for 'error'/'collision')."""
        if self.kind == "frame":
            return self.frame.to_message(timestamp=self.end / 1e9, channel=channel)
        return can.Message(timestamp=self.end / 1e9, is_error_frame=True, channel=channel,
                           arbitration_id=0, dlc=0, check=False)

    def __repr__(self) -> str:
        return (f"TraceRecord({self.kind} {self.start}..{self.end} {self.sender} {self.frame!r}"
                f" bits={self.bits} losses={self.losses}{' ' + str(self.detail) if self.detail else ''})")


def check_suffix(path: str | Path) -> str:
    """The trace file's suffix, lowercased; ValueError naming the file when python-can has no
    writer for it."""
    suffix = "".join(Path(path).suffixes[-1:]).lower()
    if suffix not in SUFFIXES:
        raise ValueError(
            f"trace file {str(path)!r}: unknown suffix {suffix or '(none)'!r}; use one of {', '.join(SUFFIXES)}")
    return suffix


def save_messages(messages: Iterable[can.Message], path: str | Path) -> int:
    """Write messages with python-can's writer for the suffix; returns how many were written."""
    check_suffix(path)
    n = 0
    with can.Logger(str(path)) as writer:  # type: ignore[abstract]
        for msg in messages:
            writer.on_message_received(msg)
            n += 1
    return n


def load_messages(path: str | Path) -> list[can.Message]:
    """Read a trace back with python-can's reader for the suffix."""
    check_suffix(path)
    return list(can.LogReader(str(path)))
