"""The third data-consistency case beside double reception and inconsistent omission: a receiver
misses a frame that the transmitter counts as sent, because two local errors at that receiver
push its error detection to the last EOF bit or beyond (README: "Errors and fault confinement").

The frame is ID 0x123, data 55 AA. Its stuffed bits (``Frame(0x123, b"\\x55\\xaa").bits``):

    position  0       SOF                0
              1..11   ID                 00100100011
              12..14  RTR, IDE, r0       000
              15,16   DLC bits 3,2       00
              17      stuff bit          1    (after the five 0s at 12..16)
              18,19   DLC bits 1,0       10   -> DLC 2
              20..35  DATA               0101010110101010
              36..50  CRC                001000010010101
              51      CRC delimiter      1
              52      ACK slot           0    (driven by the receivers)
              53      ACK delimiter      1
              54..60  EOF                1111111
              61..63  intermission       111

A transmitter's frame is valid when EOF ends without error (bit 60); a receiver's error flag
that starts in the intermission (61, 62) is an overload condition for everyone else.
"""

from __future__ import annotations

import pytest

from stack.bus.faults import FaultInjector
from stack.bus.sim import SimBus
from stack.wire.frame import Frame

F = Frame(0x123, b"\x55\xaa")


def test_frame_layout_the_comments_rely_on():
    fb = F.bits
    assert fb.stuff_positions == (17,)
    assert [fb.fields[f] for f in fb.fields if f.value == "DLC"] == [(15, 16, 18, 19)]
    assert fb.bits[54:61] == "1111111" and fb.length == 61


@pytest.mark.parametrize(
    "dlc_bit,error,detected_at",
    [
        # Directly: b reads DLC bit 0 (position 19) as 1 -> DLC 3. Its third data byte is the real
        # CRC's first 8 bits (36..43) and its CRC runs from 44: 44..50 "0010101", 51 '1', 52 '0',
        # 53 '1', then EOF. With the real EOF bit 0 (54) seen dominant by b, no 5 equal bits come
        # before its CRC has 15 bits (44..58); CRC delimiter 59, ACK slot 60 (b does not ACK: its CRC
        # is wrong), ACK delimiter 61 -> the CRC error is found at 61 and flagged from 62, after the
        # transmitter's last EOF bit (60).
        (3, "crc", 61),
        # Through a shifted stuff bit: b reads DLC bit 3 (position 15) as 1, so 12..16 are no longer
        # five 0s and b takes the stuff bit at 17 for a DLC bit: DLC 1,0,1,1 (15..18) = 11 -> 8 data
        # bytes from 19. Its data runs past the frame: 53 '1', 54 '0' (flipped), 55..59 '11111', so
        # the stuff bit due at 60 is recessive -> a stuff error at the last EOF bit, flag from 61.
        # Without the EOF flip, 53..57 would be five 1s and the stuff error would come at 58,
        # inside EOF, where the transmitter sees b's flag and retransmits.
        (0, "stuff", 60),
    ],
)
def test_receiver_misses_a_frame_the_transmitter_counts_as_sent(dlc_bit, error, detected_at):
    bus = SimBus(500_000)
    a, b, c = bus.node("a"), bus.node("b"), bus.node("c")
    fi = FaultInjector(bus)
    fi.flip(can_id=0x123, field="DLC", bit=dlc_bit, nodes=["b"])  # b's view of the DLC
    fi.flip(can_id=0x123, field="eof", bit=0, nodes=["b"])  # hides b's stuff error in EOF
    a.send(F)
    bus.run(until=2_000_000)

    rec = bus.trace[0]
    assert rec.kind == "frame" and len(bus.trace) == 1  # one attempt, and it went through
    d = rec.detail
    assert d["error"] == error and d["bit"] == detected_at and d["seen_by"] == "b"
    assert d["accepted_by"] == "c"
    # the transmitter: a success (rule 7 on TEC 0 keeps 0), no retransmission, nothing failed
    assert (a.tx_frames, a.retransmissions, a.tx_failed, a.tec) == (1, 0, 0, 0)
    # c received it, b did not: the frame is lost at b only, and nothing will resend it
    assert [f for _, f in iter(c.recv, None)] == [F] and c.rec == 0
    assert b.recv() is None
    # b: rule 1 (+1); a and c answer its flag in the intermission with overload flags, so b
    # reads dominant right after its own flag: rule 2 (+8)
    assert b.rec == 9 and d["rules"] == "b:rule 1,rule 2"


@pytest.mark.parametrize("dlc_bit", [3, 0])
def test_without_the_eof_flip_the_error_is_inside_eof_and_the_frame_is_resent(dlc_bit):
    # the contrast: b's stuff error comes at 58 (five 1s at 53..57 in its view), inside the
    # transmitter's EOF, so a sees b's flag, counts an error and sends the frame again; both
    # receivers end with exactly one copy
    bus = SimBus(500_000)
    a, b, c = bus.node("a"), bus.node("b"), bus.node("c")
    FaultInjector(bus).flip(can_id=0x123, field="DLC", bit=dlc_bit, nodes=["b"])
    a.send(F)
    bus.run(until=2_000_000)
    assert bus.trace[0].kind == "error" and bus.trace[0].detail["bit"] == 58
    assert bus.trace[0].detail["error"] == "stuff"
    assert (a.tx_frames, a.retransmissions) == (1, 1)
    assert [f for _, f in iter(b.recv, None)] == [F] == [f for _, f in iter(c.recv, None)]
