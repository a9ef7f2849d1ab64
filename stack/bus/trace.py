"""Trace records of the simulated bus and their export through python-can's writers (asc, blf, log, csv, trc, mf4, ...).

canstack does not write log formats itself: `can.Logger` picks the writer from the file suffix,
so Vector tools, candump tools and SavvyCAN read what we write.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

import can

from stack.wire.frame import Frame

__all__ = [
    "TraceRecord",
    "DiscardedTrace",
    "TraceWriter",
    "save_messages",
    "load_messages",
    "check_suffix",
    "SUFFIXES",
    "error_frame_content",
]

SUFFIXES = (".asc", ".blf", ".log", ".csv", ".trc", ".mf4", ".txt", ".db")

# SocketCAN error frames (linux/can/error.h): the error class in the identifier, details in the
# 8 data bytes. Names and values as in the kernel header.
CAN_ERR_DLC = 8
CAN_ERR_CRTL = 0x04  # controller problems, data[1]
CAN_ERR_PROT = 0x08  # protocol violations, data[2..3]
CAN_ERR_ACK = 0x20  # received no ACK on transmission
CAN_ERR_BUSOFF = 0x40
CAN_ERR_BUSERROR = 0x80
CAN_ERR_CNT = 0x200  # TX error counter in data[6], RX error counter in data[7]
CAN_ERR_CRTL_RX_WARNING = 0x04
CAN_ERR_CRTL_TX_WARNING = 0x08
CAN_ERR_CRTL_RX_PASSIVE = 0x10
CAN_ERR_CRTL_TX_PASSIVE = 0x20
CAN_ERR_CRTL_ACTIVE = 0x40
CAN_ERR_PROT_UNSPEC = 0x00
CAN_ERR_PROT_BIT = 0x01
CAN_ERR_PROT_FORM = 0x02
CAN_ERR_PROT_STUFF = 0x04
CAN_ERR_PROT_TX = 0x80
_PROT_TYPE = {
    "bit": CAN_ERR_PROT_BIT,
    "form": CAN_ERR_PROT_FORM,
    "stuff": CAN_ERR_PROT_STUFF,
    "stuff-arbitration": CAN_ERR_PROT_STUFF,
    "crc": CAN_ERR_PROT_UNSPEC,
    "ack": CAN_ERR_PROT_UNSPEC,
}
# CAN_ERR_PROT_LOC_* of each field (data[3]); the identifier's fields are split further below
_PROT_LOC = {
    "SOF": 0x03,
    "SRR": 0x04,
    "IDE": 0x05,
    "r1": 0x0D,
    "r0": 0x09,
    "DLC": 0x0B,
    "DATA": 0x0A,
    "CRC": 0x08,
    "CRC_DELIM": 0x18,
    "ACK_SLOT": 0x19,
    "ACK_DELIM": 0x1B,
    "EOF": 0x1A,
}
_LOC_ID28_21, _LOC_ID20_18, _LOC_SRTR, _LOC_RTR = 0x02, 0x06, 0x04, 0x0C
_LOC_ID17_13, _LOC_ID12_05, _LOC_ID04_00 = 0x07, 0x0F, 0x0E


def _pairs(text: str | None) -> dict[str, str]:
    """'a:8/0 b:0/1' or 'a:tx,b:rx' -> {'a': '8/0', 'b': '0/1'}."""
    out: dict[str, str] = {}
    for item in (text or "").replace(",", " ").split():
        name, _, value = item.partition(":")
        out[name] = value
    return out


def _location(rec: TraceRecord, field: str | None, position: int | None) -> int:
    """CAN_ERR_PROT_LOC_* for an error in ``field`` at stuffed ``position`` of the record's frame."""
    if field in _PROT_LOC:
        return _PROT_LOC[field]
    if field == "RTR":
        return _LOC_RTR if rec.frame.extended else _LOC_SRTR  # SFF: the RTR bit is in SRTR's place
    if field in ("ID", "ID_EXT") and position is not None:
        from stack.wire.coding import Field

        places = rec.frame.bits.fields.get(Field(field), ())
        index = sum(1 for p in places if p < position)  # a stuff bit counts with the bit before it
        if field == "ID":  # ID[10:0] (standard) or ID[28:18] (extended), most significant first
            return _LOC_ID28_21 if index < 8 else _LOC_ID20_18
        return _LOC_ID17_13 if index < 5 else (_LOC_ID12_05 if index < 13 else _LOC_ID04_00)
    return 0x00  # CAN_ERR_PROT_LOC_UNSPEC: an error delimiter, an overload frame


def error_frame_content(rec: TraceRecord) -> tuple[int, bytes]:
    """A failed attempt as a SocketCAN error frame (linux/can/error.h): (identifier with the
    error class bits, 8 data bytes), from the point of view of the node that found the error
    first (the transmitter when it is among them), as its controller would report it.

    Class: CAN_ERR_PROT | CAN_ERR_BUSERROR always, CAN_ERR_ACK for an ACK error, CAN_ERR_CNT
    (the node's TEC in data[6], REC in data[7], at most 255), CAN_ERR_CRTL when the node
    changed state (data[1]: TX/RX_WARNING at 96, TX/RX_PASSIVE at 128 for the counter that got
    there, CRTL_ACTIVE back to error active), CAN_ERR_BUSOFF when it went bus off. data[2] is
    the error type (PROT_BIT, PROT_FORM, PROT_STUFF; a CRC or ACK error has none of them), with
    PROT_TX when the node was transmitting; data[3] the location (CAN_ERR_PROT_LOC_*)."""
    d = rec.detail or {}
    roles = _pairs(d.get("roles"))
    first = [n for n in str(d.get("seen_by") or "").split(",") if n]
    node = next((n for n in first if roles.get(n) == "tx"), first[0] if first else rec.sender.split("+")[0])
    can_id = CAN_ERR_PROT | CAN_ERR_BUSERROR | CAN_ERR_CNT
    data = bytearray(CAN_ERR_DLC)
    kind = d.get("error")
    if kind == "ack":
        can_id |= CAN_ERR_ACK
    data[2] = _PROT_TYPE.get(str(kind), CAN_ERR_PROT_UNSPEC) | (CAN_ERR_PROT_TX if roles.get(node) == "tx" else 0)
    data[3] = _location(rec, d.get("field"), d.get("bit"))
    tec, _, rec_count = _pairs(d.get("counters")).get(node, "0/0").partition("/")
    tec_n, rec_n = int(tec or 0), int(rec_count or 0)
    data[6], data[7] = min(tec_n, 255), min(rec_n, 255)
    change = _pairs(d.get("states").replace("->", ">") if d.get("states") else None).get(node)
    if change:
        new = change.split(">")[-1]
        if new == "bus-off":
            can_id |= CAN_ERR_BUSOFF
        else:
            can_id |= CAN_ERR_CRTL
            if new == "error-active":
                data[1] = CAN_ERR_CRTL_ACTIVE
            elif new == "error-warning":
                data[1] = (CAN_ERR_CRTL_TX_WARNING if tec_n >= 96 else 0) | (
                    CAN_ERR_CRTL_RX_WARNING if rec_n >= 96 else 0
                )
            elif new == "error-passive":
                data[1] = (CAN_ERR_CRTL_TX_PASSIVE if tec_n >= 128 else 0) | (
                    CAN_ERR_CRTL_RX_PASSIVE if rec_n >= 128 else 0
                )
    return can_id, bytes(data)


class TraceRecord:
    """One bus event: a frame ('frame'), a failed attempt ending in an error frame ('error'),
    or a collision after arbitration ('collision').

    ``start``/``end`` in ns (SOF to end of EOF, or to the end of the error delimiter);
    ``sender`` node name(s); ``bits`` the stuffed length on the wire; ``losses`` arbitration
    rounds the frame lost before winning; ``queued`` the time it was queued; ``detail`` a dict
    (error kind, field, bit position, nodes that saw it, counters after).
    """

    __slots__ = ("kind", "start", "end", "sender", "frame", "bits", "losses", "queued", "detail")

    def __init__(
        self,
        kind: str,
        start: int,
        end: int,
        sender: str,
        frame: Frame,
        bits: int,
        losses: int,
        queued: int,
        detail: dict[str, Any] | None = None,
    ) -> None:
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
        return (
            self.kind,
            self.start,
            self.end,
            self.sender,
            self.frame.key,
            self.frame.dlc,
            self.frame.data,
            self.bits,
            self.losses,
            self.queued,
            tuple(sorted((self.detail or {}).items())),
        )

    def to_message(self, channel: Any = None) -> can.Message:
        """python-can message of this record (an error frame for 'error'/'collision', its
        content as SocketCAN encodes one: `error_frame_content`)."""
        if self.kind == "frame":
            return self.frame.to_message(timestamp=self.end / 1e9, channel=channel)
        can_id, data = error_frame_content(self)
        return can.Message(
            timestamp=self.end / 1e9,
            is_error_frame=True,
            channel=channel,
            arbitration_id=can_id,
            dlc=CAN_ERR_DLC,
            data=data,
            check=False,
        )

    def __repr__(self) -> str:
        return (
            f"TraceRecord({self.kind} {self.start}..{self.end} {self.sender} {self.frame!r}"
            f" bits={self.bits} losses={self.losses}{' ' + str(self.detail) if self.detail else ''})"
        )


class DiscardedTrace(list):  # type: ignore[type-arg]
    """The trace of a bus that records without keeping (``SimBus(record=True, keep=False)``):
    always empty, its records go only to the bus's `on_trace` listeners."""

    __slots__ = ()

    def append(self, rec: TraceRecord) -> None:
        """Keep nothing."""


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
    each `TraceRecord` — give it to ``SimBus.on_trace`` on a bus made with ``keep=False`` and the
    trace costs no memory however long the run — and `close` finishes the file.

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
        """Write one record (an error frame for a failed attempt)."""
        self.message(rec.to_message(self.channel))

    def message(self, msg: can.Message) -> None:
        """Write one python-can message (its timestamp in bus seconds)."""
        if self.suffix == ".trc" and (msg.is_remote_frame or msg.is_error_frame):
            self.left_out += 1
            return
        if self.error is not None:
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
