"""Trace files, written and read with python-can's writers and readers (asc, blf, log, csv, trc,
mf4, ...).

canstack does not write log formats itself: `can.Logger` picks the writer from the file suffix,
so Vector tools, candump tools and SavvyCAN read what it writes.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

import can

from stack.io.message import trace_messages

if TYPE_CHECKING:  # pragma: no cover
    from stack.bus.sim import SimBus

__all__ = ["SUFFIXES", "check_suffix", "save_messages", "load_messages", "save_trace"]

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
    """Write messages with python-can's writer for the suffix; returns how many were written.

    A .trc file (PCAN-View) cannot hold remote or error frames: python-can's writer drops each
    one with a warning of its own, so they are left out here, quietly, and not counted; the
    caller says how many (``canstack`` prints one line)."""
    suffix = check_suffix(path)
    n = 0
    with can.Logger(str(path)) as writer:  # type: ignore[abstract]
        for msg in messages:
            if suffix == ".trc" and (msg.is_remote_frame or msg.is_error_frame):
                continue
            writer.on_message_received(msg)
            n += 1
    return n


def load_messages(path: str | Path) -> list[can.Message]:
    """Read a trace back with python-can's reader for the suffix."""
    check_suffix(path)
    return list(can.LogReader(str(path)))


def save_trace(bus: SimBus, path: str | Path) -> int:
    """Write a simulated bus's trace (``record=True``) with python-can's writer for the file's
    suffix (.asc, .blf, .log, .csv, .trc, .mf4 ...), failed attempts as error frames; returns
    the number of messages written."""
    return save_messages(trace_messages(bus), path)
