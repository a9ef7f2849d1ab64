"""Trace export through python-can's writers (asc, blf, log, csv, trc, mf4, ...).

canstack does not write log formats itself: `can.Logger` picks the writer from the file suffix,
so Vector tools, candump tools and SavvyCAN read what we write.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterable

import can

__all__ = ["save_messages", "load_messages", "check_suffix", "SUFFIXES"]

SUFFIXES = (".asc", ".blf", ".log", ".csv", ".trc", ".mf4", ".txt", ".db")


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
