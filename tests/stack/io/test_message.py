"""The python-can boundary: `Frame` to `can.Message` (`stack.io.message.to_message`) and back
(`Frame.from_message`), classical and CAN FD, checked against python-can's own rules (its
`Message` with ``check=True``) and through its virtual bus."""

from __future__ import annotations

import itertools

import can
import pytest

from stack.io.message import to_message
from stack.wire.frame import Frame

CLASSIC = [
    Frame(0x0C1, bytes.fromhex("4001087500000000")),
    Frame(0x18FEF100, b"\xff", extended=True),
    Frame(0x7FF, remote=True, dlc=8),
    Frame(0, b""),
]
FD = [
    Frame(0x123, bytes(range(12)), fd=True),
    Frame(0x123, bytes(range(64)), fd=True, brs=True),
    Frame(0x1ABCDE, bytes(range(20)), extended=True, fd=True, brs=True, esi=True),
    Frame(0x7, b"\x01\x02", fd=True, esi=True),
]
_channels = itertools.count()


@pytest.mark.parametrize("frame", CLASSIC + FD, ids=repr)
def test_a_frame_becomes_the_message_python_can_builds_from_the_same_fields(frame):
    # python-can's constructor with check=True validates its own rules (dlc = number of bytes for
    # CAN FD, no FD remote frames, BRS/ESI only in FD messages)
    expected = can.Message(
        timestamp=1.5,
        arbitration_id=frame.can_id,
        is_extended_id=frame.extended,
        is_remote_frame=frame.remote,
        is_fd=frame.fd,
        bitrate_switch=frame.brs,
        error_state_indicator=frame.esi,
        dlc=frame.dlc if frame.remote else len(frame.data),
        data=None if frame.remote else frame.data,
        check=True,
    )
    msg = to_message(frame, timestamp=1.5)
    assert msg.equals(expected), (msg, expected)
    assert Frame.from_message(msg) == frame


@pytest.mark.parametrize("frame", FD, ids=repr)
def test_fd_frames_cross_a_python_can_virtual_bus_with_their_fd_bits(frame):
    channel = f"house-fd-{next(_channels)}"
    with can.Bus(interface="virtual", channel=channel) as tx, can.Bus(interface="virtual", channel=channel) as rx:
        tx.send(to_message(frame))
        got = rx.recv(5.0)
    assert got is not None
    assert (got.is_fd, got.bitrate_switch, got.error_state_indicator) == (True, frame.brs, frame.esi)
    assert Frame.from_message(got) == frame


def test_a_classical_frame_with_dlc_above_8_keeps_its_dlc_on_the_message():
    # DLC 9..15 mean 8 bytes in CAN 2.0; python-can holds the raw DLC only unchecked
    msg = to_message(Frame(0x10, bytes(8), dlc=15))
    assert (msg.dlc, bytes(msg.data), msg.is_fd) == (15, bytes(8), False)


def test_messages_that_are_no_frame_are_refused_with_the_rule_they_break():
    with pytest.raises(ValueError, match="error frame"):
        Frame.from_message(can.Message(arbitration_id=1, is_error_frame=True))
    msg = can.Message(arbitration_id=1, data=bytes(8), check=False)
    msg.dlc = 12
    with pytest.raises(ValueError, match=r"dlc 12: only dlc 0\.\.8"):
        Frame.from_message(msg)
    with pytest.raises(ValueError, match="13 bytes is not a CAN FD length"):
        Frame.from_message(can.Message(arbitration_id=1, data=bytes(13), is_fd=True, check=False))
    with pytest.raises(ValueError, match="CAN FD has no remote frames"):
        Frame.from_message(can.Message(arbitration_id=1, is_fd=True, is_remote_frame=True, check=False))
    with pytest.raises(ValueError, match="BRS exists only in CAN FD frames"):
        Frame.from_message(can.Message(arbitration_id=1, bitrate_switch=True, check=False))
    with pytest.raises(ValueError, match="dlc 8 does not match 12 data bytes"):
        Frame.from_message(can.Message(arbitration_id=1, data=bytes(12), dlc=8, is_fd=True, check=False))
