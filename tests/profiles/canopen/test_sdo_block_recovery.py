"""SDO block download recovers from lost segments (CiA 301 7.2.4.3.10: ackseq is the last segment
received in order, 0 when none; the client sends the rest again), with a sub-block timeout of half
the SDO timeout as CANopenNode has it: the ``canopen`` library as the client on the simulated bus,
one chosen segment dropped on its way (fault injection at the client's end, which is where a lost
frame is lost: CAN itself repeats a frame destroyed on the wire).

Where the library cannot recover (a lost *last* segment: its retransmission path writes again
after the stream is done and raises), a client written here from CiA 301 takes its place."""

from __future__ import annotations

import struct

import canopen
import pytest

from profiles.canopen.dictionary import DEFAULT_EDS
from profiles.canopen.sdo import abort
from profiles.canopen.sdo.block import crc16
from stack import Frame

MS = 1_000_000
SDO_RX = 0x605  # client -> server of node 5


def library_client(lib, device, *, drop: set[int]):
    """The library's RemoteNode for device 5 whose k-th frame to the server (k in ``drop``,
    counting from 0) is lost, and whose reads let the simulated bus run until an answer is there."""
    dev = device(5)
    node = canopen.RemoteNode(5, str(DEFAULT_EDS))
    lib.add_node(node)
    lib.run(2 * MS)
    sent = {"n": 0}
    real_send = lib.send_message

    def send_message(can_id, data, remote=False):
        if can_id == SDO_RX:
            k = sent["n"]
            sent["n"] += 1
            if k in drop:
                return  # lost on its way
        real_send(can_id, data, remote)

    lib.send_message = send_message
    client = node.sdo
    real_read = client.read_response

    def read_response():
        for _ in range(3000):  # up to 3 s of simulated time: the answer comes, or the library times out
            if not client.responses.empty():
                break
            lib.run(1 * MS)
        return real_read()

    client.read_response = read_response
    return dev, node


BLOB = bytes((i * 13 + 5) & 0xFF for i in range(127 * 7 + 40))  # a full sub-block of 127 and 6 more


@pytest.mark.parametrize(
    "lost, what",
    [
        (1, "the first segment of the first sub-block"),
        (60, "a segment in the middle of the first sub-block"),
        (127, "the last segment of the first sub-block"),
    ],
)
def test_the_canopen_library_completes_a_block_download_after_a_lost_segment(lib, device, bus, spy, lost, what):
    """Frame 0 is the initiate, 1..127 the first sub-block, 128.. the second. (A segment lost in
    the *last* sub-block the library cannot recover: it has sent its last segment, and its
    retransmission writes to a stream that is done — see the hand-written client below.)"""
    dev, node = library_client(lib, device, drop={lost})
    with node.sdo[0x2201].open("wb", size=len(BLOB), block_transfer=True) as f:
        f.write(BLOB)
    assert dev.read(0x2201) == BLOB, what
    assert dev.sdo.completed["block download"] == 1 and dev.sdo.aborts_sent == 0
    acks = [f.data for t, f in spy if f.can_id == 0x585 and f.data[0] == 0xA2]
    # the sub-block with the lost segment is answered with the segments received in order before it
    assert acks[0][1] == lost - 1


def test_a_silent_client_is_still_aborted_one_sdo_timeout_after_its_last_frame(lib, device, bus, spy):
    # (lib: the library's node on the bus acknowledges frames; it plays no part)
    """The sub-block timeout answers (at 500 ms); the client says nothing more: 0x0504 0000 at
    1000 ms after its last frame."""
    dev = device(5)
    lib.run(2 * MS)
    client = bus.node("hand")
    client.send(Frame(SDO_RX, bytes([0xC6, 0x01, 0x22, 0x00]) + struct.pack("<L", 20)))
    bus.run(until=bus.now() + 2 * MS)
    client.send(Frame(SDO_RX, bytes([0x01]) + bytes(7)))  # segment 1 of 3; then silence
    bus.run(until=bus.now() + 2 * MS)
    t_last = max(t for t, f in spy if f.can_id == SDO_RX)
    bus.run(until=bus.now() + 1100 * MS)
    answers = [(t, f.data) for t, f in spy if f.can_id == 0x585 and t > t_last]
    assert [d[:2] for _, d in answers] == [b"\xa2\x01", b"\x80\x01"]
    ack_t, abort_t = answers[0][0], answers[1][0]
    assert 500 * MS <= ack_t - t_last < 501 * MS
    assert 1000 * MS <= abort_t - t_last < 1001 * MS
    assert struct.unpack_from("<L", answers[1][1], 4)[0] == abort.TIMEOUT


class HandClient:
    """A block-download client written from CiA 301 7.2.4.3.9-7.2.4.3.11 (not the library's): it
    sends a sub-block, waits for the server's answer, and sends again what follows ackseq."""

    def __init__(self, bus, lib_node_name="hand"):
        self.bus = bus
        self.node = bus.node(lib_node_name)
        self.rx: list[bytes] = []
        self.node.subscribe(lambda ev: self.rx.append(ev.frame.data) if ev.frame.can_id == 0x585 else None)

    def _answer(self, limit_ms=1500):
        n = len(self.rx)
        for _ in range(limit_ms):
            if len(self.rx) > n:
                return self.rx[n]
            self.bus.run(until=self.bus.now() + MS)
        raise AssertionError("no answer")

    def download(self, index, sub, data, drop=frozenset()):
        """Returns the server's answers after the initiate; ``drop``: segment numbers (1-based,
        over the whole transfer, first transmission only) that are lost."""
        self.node.send(Frame(SDO_RX, bytes([0xC6]) + struct.pack("<HB", index, sub) + struct.pack("<L", len(data))))
        ans = self._answer()
        assert ans[0] & 0xE0 == 0xA0
        blksize = ans[4]
        chunks = [data[i : i + 7] for i in range(0, len(data), 7)]
        pos, answers, dropped = 0, [], set()
        while pos < len(chunks):
            block = chunks[pos : pos + blksize]
            for seq, chunk in enumerate(block, 1):
                last = pos + seq == len(chunks)
                number = pos + seq
                if number in drop and number not in dropped:
                    dropped.add(number)
                    continue
                self.node.send(Frame(SDO_RX, bytes([(0x80 if last else 0) | seq]) + chunk.ljust(7, b"\0")))
            ack = self._answer()
            answers.append(ack)
            assert ack[0] == 0xA2
            pos += ack[1]  # ackseq: resume after the last segment received in order
            blksize = ack[2]
        n = 7 - len(chunks[-1])
        self.node.send(Frame(SDO_RX, bytes([0xC1 | n << 2]) + struct.pack("<H", crc16(data)) + bytes(5)))
        answers.append(self._answer())
        return answers


@pytest.mark.parametrize(
    "size, drop, first_ack",
    [
        (20, {1}, 0),  # 3 segments in one sub-block: the first lost
        (20, {2}, 1),
        (20, {3}, 2),  # the last segment (c bit set) lost
        (127 * 7 + 40, {128}, 127),  # the first segment of the last sub-block lost
        (127 * 7 + 40, {133}, 127),  # the very last one
        (127 * 7 + 40, {1, 133}, 0),
    ],
)
def test_a_client_written_from_the_standard_recovers_from_any_lost_segment(bus, device, size, drop, first_ack):
    dev = device(5)
    data = bytes((i * 7 + 1) & 0xFF for i in range(size))
    answers = HandClient(bus).download(0x2201, 0, data, drop=drop)
    assert dev.read(0x2201) == data and dev.sdo.aborts_sent == 0
    assert answers[-1][0] == 0xA1  # the end of the block download confirmed
    assert answers[0][1] == first_ack  # ackseq: the segments received in order before the loss
    assert dev.sdo.completed["block download"] == 1
