"""Trace records of the simulated bus, and the SocketCAN error frame a failed attempt reads as.

Writing them to files (asc, blf, log, csv, trc, mf4, ... through python-can's writers) is
`stack.io.tracefile`; as `can.Message` objects, `stack.io.message`.
"""

from __future__ import annotations

from typing import Any

from stack.wire.frame import Frame

__all__ = ["TraceRecord", "DiscardedTrace", "error_frame_content", "CAN_ERR_DLC"]

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
    states = d.get("states")
    change = _pairs(states.replace("->", ">") if states else None).get(node)
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
