"""python-can messages and canstack frames: `frame_of` (a `can.Message` to be sent as a `Frame`,
or `InvalidFrame` naming why it cannot be one) and `error_frame_of` (a failed transmission as the
error frame SocketCAN delivers). Used by the ``canstack`` python-can interface (`stack.io.pycan`)."""

from __future__ import annotations

from typing import Any

import can

from stack.wire.frame import Frame

__all__ = [
    "InvalidFrame",
    "frame_of",
    "error_frame_of",
    "CAN_ERR_LOSTARB",
    "CAN_ERR_PROT",
    "CAN_ERR_ACK",
    "CAN_ERR_BUSERROR",
    "CAN_ERR_CNT",
]


class InvalidFrame(can.CanOperationError):
    """A message python-can accepts but the bus does not carry (an FD message on a bus opened
    without ``fd=True``, more than 8 bytes in a classical frame, an error frame)."""


_FRAME_CACHE: dict[tuple[int, bool, bool, int, bytes, bool, bool, bool], Frame] = {}


def frame_of(msg: can.Message, fd: bool = False) -> Frame:
    """The frame of a message, or `InvalidFrame` naming why it is none: an FD message needs a
    bus opened with ``fd=True`` (``fd``), as python-can's other FD-capable interfaces refuse it.

    Frames are cached by content: a node usually sends the same few frames again and again, and
    a frame's stuffed bits cost far more to compute than a look-up (see the benchmarks page).
    """
    if msg.is_fd and not fd:
        raise InvalidFrame("cannot send a CAN FD message on a canstack bus opened without fd=True")
    if msg.is_error_frame:
        raise InvalidFrame("an error frame cannot be sent: the controller signals errors itself")
    data = bytes(msg.data) if msg.data is not None else b""
    if not msg.is_fd and (len(data) > 8 or msg.dlc > 8):
        raise InvalidFrame(f"message with {max(len(data), msg.dlc)} bytes refused: a CAN 2.0 frame carries at most 8")
    key = (
        msg.arbitration_id,
        bool(msg.is_extended_id),
        bool(msg.is_remote_frame),
        msg.dlc,
        data,
        bool(msg.is_fd),
        bool(msg.bitrate_switch),
        bool(msg.error_state_indicator),
    )
    f = _FRAME_CACHE.get(key)
    if f is None:
        try:
            f = Frame.from_message(msg)
        except ValueError as exc:
            raise InvalidFrame(str(exc)) from None
        f.bits  # noqa: B018 - computed here, on the sender's thread, not on the runner's
        if len(_FRAME_CACHE) > 8192:
            _FRAME_CACHE.clear()
        _FRAME_CACHE[key] = f
    return f


# SocketCAN's error classes and details (linux/can/error.h), so that code written for SocketCAN
# reads a failed one-shot transmission the same way here
CAN_ERR_LOSTARB, CAN_ERR_PROT, CAN_ERR_ACK, CAN_ERR_BUSERROR, CAN_ERR_CNT = 0x002, 0x008, 0x020, 0x080, 0x200
CAN_ERR_PROT_BIT, CAN_ERR_PROT_FORM, CAN_ERR_PROT_STUFF, CAN_ERR_PROT_TX = 0x01, 0x02, 0x04, 0x80
CAN_ERR_PROT_LOC_CRC_SEQ, CAN_ERR_PROT_LOC_ACK = 0x08, 0x19
_PROT_TYPE = {
    "bit": CAN_ERR_PROT_BIT,
    "form": CAN_ERR_PROT_FORM,
    "stuff": CAN_ERR_PROT_STUFF,
    "stuff-arbitration": CAN_ERR_PROT_STUFF,
}


def error_frame_of(reason: str, tec: int, rec: int, timestamp: float, channel: Any = None) -> can.Message:
    """The error frame SocketCAN delivers for a failed transmission, from the engine's reason
    ('arbitration lost (one-shot)', 'ack error (one-shot)', 'crc error (one-shot)', ...).

    ``arbitration_id`` holds the error classes (as python-can shows a SocketCAN error frame):
    CAN_ERR_LOSTARB (data[0] 0: bit unknown) for a lost arbitration; CAN_ERR_ACK with
    CAN_ERR_PROT location ACK slot for a missing acknowledgement; CAN_ERR_PROT with the
    protocol-violation type (bit, form, stuff; location CRC sequence for a CRC error) and
    CAN_ERR_PROT_TX for other errors; always CAN_ERR_CNT with TEC in data[6] and REC in data[7].
    """
    data = bytearray(8)
    kind = reason.split(" ", 1)[0].lower()
    if reason.startswith("arbitration lost"):
        classes = CAN_ERR_LOSTARB
    elif kind == "ack":
        classes = CAN_ERR_ACK | CAN_ERR_PROT | CAN_ERR_BUSERROR
        data[2] = CAN_ERR_PROT_TX
        data[3] = CAN_ERR_PROT_LOC_ACK
    else:
        classes = CAN_ERR_PROT | CAN_ERR_BUSERROR
        data[2] = _PROT_TYPE.get(kind, 0) | CAN_ERR_PROT_TX
        if kind == "crc":
            data[3] = CAN_ERR_PROT_LOC_CRC_SEQ
    data[6] = min(tec, 255)
    data[7] = min(rec, 255)
    return can.Message(
        timestamp=timestamp,
        arbitration_id=classes | CAN_ERR_CNT,
        is_extended_id=False,
        is_error_frame=True,
        dlc=8,
        data=bytes(data),
        channel=channel,
        check=False,
    )
