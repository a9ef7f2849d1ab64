"""Frames and trace records as python-can messages: the boundary where canstack's `Frame` and
`TraceRecord` become the `can.Message` users and python-can's buses, writers and tools hold.

The sans-IO core (`stack.wire`, `stack.controller`, `stack.bus`) does not import python-can: a
`can.Message` is read by its attributes (`stack.wire.frame.Frame.from_message`), and built here.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

import can

from stack.bus.trace import CAN_ERR_DLC, TraceRecord, error_frame_content
from stack.wire.frame import Frame

if TYPE_CHECKING:  # pragma: no cover
    from stack.bus.sim import SimBus

__all__ = ["to_message", "record_to_message", "trace_messages"]


def to_message(frame: Frame, timestamp: float = 0.0, channel: Any = None) -> can.Message:
    """``frame`` as a `can.Message`: a classical frame with its DLC as on the wire (9..15 kept),
    a CAN FD frame with ``is_fd``, ``bitrate_switch`` and ``error_state_indicator`` from its
    ``fd``, ``brs`` and ``esi`` and python-can's dlc (the number of data bytes)."""
    if frame.fd:
        return can.Message(
            timestamp=timestamp,
            arbitration_id=frame.can_id,
            is_extended_id=frame.extended,
            is_fd=True,
            bitrate_switch=frame.brs,
            error_state_indicator=frame.esi,
            dlc=len(frame.data),
            data=frame.data,
            channel=channel,
            check=False,
        )
    return can.Message(
        timestamp=timestamp,
        arbitration_id=frame.can_id,
        is_extended_id=frame.extended,
        is_remote_frame=frame.remote,
        dlc=frame.dlc,
        data=frame.data,
        channel=channel,
        check=False,
    )


def record_to_message(rec: TraceRecord, channel: Any = None) -> can.Message:
    """A trace record as a `can.Message` stamped with its end of frame (s): the frame of a
    'frame' record; for an 'error' or 'collision' an error frame whose content is what SocketCAN
    reports for one (`stack.bus.trace.error_frame_content`)."""
    if rec.kind == "frame":
        return to_message(rec.frame, timestamp=rec.end / 1e9, channel=channel)
    can_id, data = error_frame_content(rec)
    return can.Message(
        timestamp=rec.end / 1e9,
        is_error_frame=True,
        channel=channel,
        arbitration_id=can_id,
        dlc=CAN_ERR_DLC,
        data=data,
        check=False,
    )


def trace_messages(bus: SimBus, channel: Any = None) -> Iterator[can.Message]:
    """A simulated bus's trace as python-can messages (failed attempts as error frames), on
    ``channel`` (the bus's name unless given)."""
    ch = bus.name if channel is None else channel
    for rec in bus.trace:
        yield record_to_message(rec, ch)
