"""Trace files, written and read with python-can's writers and readers (asc, blf, log, csv, trc,
mf4, ...).

canstack does not write log formats itself: `can.Logger` picks the writer from the file suffix,
so Vector tools, candump tools and SavvyCAN read what it writes.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import can

from stack.io.message import record_to_message, trace_messages

if TYPE_CHECKING:  # pragma: no cover
    from stack.bus.sim import SimBus
    from stack.bus.trace import TraceRecord

__all__ = ["SUFFIXES", "check_suffix", "TraceWriter", "save_messages", "load_messages", "save_trace"]

SUFFIXES = (".asc", ".blf", ".log", ".csv", ".trc", ".mf4", ".txt", ".db")
"""The suffixes python-can has a writer for."""


def check_suffix(path: str | Path) -> str:
    """The trace file's suffix, lowercased; ValueError naming the file when python-can has no
    writer for it."""
    suffix = "".join(Path(path).suffixes[-1:]).lower()
    if suffix not in SUFFIXES:
        raise ValueError(
            f"trace file {str(path)!r}: unknown suffix {suffix or '(none)'!r}; use one of {', '.join(SUFFIXES)}"
        )
    return suffix


def save_messages(messages: Iterable[can.Message], path: str | Path) -> int:
    """Write messages with python-can's writer for the suffix (`TraceWriter`: timestamps as
    given, .asc and .blf counted from 0); returns how many were written.

    A .trc file (PCAN-View) cannot hold remote or error frames: python-can's writer drops each
    one with a warning of its own, so they are left out here, quietly, and not counted; the
    caller says how many (``canstack`` prints one line)."""
    with TraceWriter(path) as writer:
        for msg in messages:
            writer.message(msg)
    if writer.error is not None:
        raise writer.error
    return writer.written


class TraceWriter:
    """A trace file written as the bus runs (python-can's writer for the suffix): `write` takes
    each `stack.bus.trace.TraceRecord` — give it to ``SimBus.on_trace`` on a bus made with
    ``keep=False`` and the trace costs no memory however long the run — `message` a
    `can.Message` (what a python-can bus received), and `close` finishes the file.

    Timestamps are bus time, in every format: python-can's .asc writer counts from its first
    event and its .blf writer from its first message, so both are started at bus time 0 (an
    .asc comment event at 0, the .blf start time at 0); the others write the timestamps as they
    are. A .trc file holds no remote or error frames: they are counted in ``left_out``.

    A write that fails (a full disk) does not stop the run that feeds the writer: the first
    error is kept in ``error`` and nothing more is written; the caller reports it."""

    def __init__(self, path: str | Path, channel: Any = None) -> None:
        self.suffix = check_suffix(path)
        self.path = str(path)
        self.channel = channel
        self.written = 0
        self.left_out = 0
        self.error: OSError | None = None
        self._writer: Any = can.Logger(self.path)  # type: ignore[abstract]
        if isinstance(self._writer, can.ASCWriter):
            self._writer.log_event(f"canstack: timestamps are bus time of {channel or 'the bus'}", timestamp=0.0)
        elif isinstance(self._writer, can.BLFWriter):
            self._writer.start_timestamp = 0.0

    def write(self, rec: TraceRecord) -> None:
        """Write one record of a simulated bus (an error frame for a failed attempt)."""
        self.message(record_to_message(rec, self.channel))

    def message(self, msg: can.Message) -> None:
        """Write one python-can message (its timestamp in bus seconds)."""
        if self.suffix == ".trc" and (msg.is_remote_frame or msg.is_error_frame):
            self.left_out += 1
            return
        if self.error is not None or self._writer is None:
            return
        try:
            self._writer.on_message_received(msg)
        except OSError as exc:
            self.error = exc
            return
        self.written += 1

    def close(self) -> None:
        """Finish the file (idempotent; a failure is kept in ``error``)."""
        if self._writer is not None:
            writer, self._writer = self._writer, None
            try:
                writer.stop()
            except OSError as exc:
                self.error = self.error or exc

    def __enter__(self) -> TraceWriter:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def load_messages(path: str | Path) -> list[can.Message]:
    """Read a trace back with python-can's reader for the suffix."""
    check_suffix(path)
    return list(can.LogReader(str(path)))


def save_trace(bus: SimBus, path: str | Path) -> int:
    """Write a simulated bus's trace (``record=True``) with python-can's writer for the file's
    suffix (.asc, .blf, .log, .csv, .trc, .mf4 ...), failed attempts as error frames; returns
    the number of messages written."""
    return save_messages(trace_messages(bus), path)
