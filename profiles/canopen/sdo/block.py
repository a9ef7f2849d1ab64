"""SDO block transfer, server side (CiA 301 7.2.4.3.9-7.2.4.3.16), and the base of every
transfer the server keeps between frames.

Block download: the client sends up to ``blksize`` segments (byte 0 = c | seqno 1..127, seven
data bytes each) without waiting; the server answers each sub-block with 0xA2, the last good
sequence number (ackseq) and the next block size. A segment out of sequence ends the sub-block at
once with the last good number, so the client sends the rest again (duplicates and segments
before the first good one are ignored, as in CANopenNode). A sub-block that stops short — its
first segment, a middle one followed by nothing, or its last one lost — ends when no segment has
come for the sub-block timeout (``block_timeout_ns``, by default half the SDO timeout, as
CANopenNode's ``block_SDOtimeoutTime_us``): the server answers with the segments it received in
order (ackseq 0 when it has none: CiA 301 7.2.4.3.10, "all segments shall be retransmitted"), and
the client sends the rest again in a new sub-block. The transfer's own timeout is not restarted
by that answer: a client that stays silent is aborted (0x0504 0000) one SDO timeout after its
last frame. The end request (0xC1 | n << 2, CRC) says how
many bytes of the last segment carry no data and gives the CRC; the server answers 0xA1.

Block upload: after the initiate (0xA0 | cc, blksize, pst) the server answers 0xC6 with the
size, waits for the client's start (0xA3), sends a sub-block, and on each acknowledgement
(0xA2, ackseq, blksize) goes on after the last segment acknowledged (resending the ones that
were not); when all is acknowledged it sends the end (0xC1 | n << 2, CRC) and waits for 0xA1.

The CRC is CRC-16-CCITT (polynomial 0x1021, initial value 0, no reflection: XMODEM), the
``binascii.crc_hqx`` of the standard library; it is used when both sides announce it (cc/sc,
bit 2 of the initiate command bytes).
"""

from __future__ import annotations

import binascii
import struct
from typing import Any

from profiles.canopen.sdo import abort
from profiles.canopen.sdo.abort import SdoAbort

__all__ = ["Transfer", "BlockDownload", "BlockUpload", "CRC_SUPPORTED", "crc16"]

CRC_SUPPORTED = 0x04
"""cc/sc: bit 2 of the block initiate command bytes."""


def crc16(data: bytes) -> int:
    """CRC-16-CCITT as SDO block transfers use it (CiA 301 7.2.4.3.16): XMODEM parameters."""
    return binascii.crc_hqx(data, 0)


class Transfer:
    """A transfer in progress: `on_request` handles the next client frame and may raise
    `SdoAbort`; ``done`` is set when the transfer is over."""

    def __init__(self, index: int, sub: int) -> None:
        self.index = index
        self.sub = sub
        self.done = False

    def on_request(self, req: bytes) -> None:  # pragma: no cover - every transfer overrides it
        """The next client frame of this transfer."""
        raise NotImplementedError

    def cancel(self) -> None:
        """The transfer ended: stop any timer of its own (a block download's sub-block timer)."""

    @property
    def kind(self) -> str:
        """The transfer's kind for the server's counters ('segmented download', ...)."""
        name = type(self).__name__
        return {
            "SegmentedDownload": "segmented download",
            "SegmentedUpload": "segmented upload",
            "BlockDownload": "block download",
            "BlockUpload": "block upload",
        }.get(name, name)


class BlockDownload(Transfer):
    """The server's half of a block download."""

    def __init__(
        self,
        server: Any,
        index: int,
        sub: int,
        size: int | None,
        *,
        crc: bool,
        block_size: int,
        block_timeout_ns: int | None = None,
    ) -> None:
        super().__init__(index, sub)
        self.server = server
        self.size = size
        self.crc = crc
        self.block_size = block_size
        self.buffer = bytearray()
        self.last_good = 0  # sequence number of the last segment accepted in this sub-block
        self.last_segment_seen = False
        self.retransmissions = 0
        self.sub_block_timeouts = 0
        self.block_timeout_ns = block_timeout_ns
        self._timer: Any = None
        self._arm()  # the first sub-block may start now

    def _arm(self) -> None:
        """(Re)start the sub-block timeout: from the last segment received, or from the server's
        answer that opened the sub-block (CANopenNode restarts it at both)."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self.block_timeout_ns and not self.last_segment_seen and not self.done:
            self._timer = self.server.call_later(self.block_timeout_ns, self._sub_block_timeout)

    def cancel(self) -> None:
        """The transfer ended (completed, aborted, or the server was reset): no timer left."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _sub_block_timeout(self) -> None:
        self._timer = None
        if self.done or self.last_segment_seen or self.server.transfer is not self:
            return
        self.sub_block_timeouts += 1
        self._ack()

    def on_request(self, req: bytes) -> None:
        """A segment of the sub-block (c | seqno, 7 bytes), or the end request after the last."""
        if self.last_segment_seen:
            self._end(req)
            return
        self._arm()  # any frame of the sub-block restarts its timeout (CANopenNode)
        seqno = req[0] & 0x7F
        if seqno == self.last_good + 1 and seqno <= self.block_size:
            self.buffer += req[1:8]
            self.last_good = seqno
            if req[0] & 0x80:
                self.last_segment_seen = True
                self._ack()
            elif seqno == self.block_size:
                self._ack()
            if self.size is not None and len(self.buffer) > self.size + 6:
                raise SdoAbort(abort.LENGTH_HIGH, f"more than the {self.size} bytes indicated")
            return
        if self.last_good == 0 or seqno == self.last_good:
            return  # not started yet, or a duplicate: ignore (CANopenNode)
        self.retransmissions += 1
        self._ack()  # out of sequence: the client resends everything after last_good

    def _ack(self) -> None:
        self.server.send(bytes([0xA2, self.last_good, self.block_size]) + bytes(5))
        self.last_good = 0
        self._arm()  # the next sub-block's timeout runs from this answer

    def _end(self, req: bytes) -> None:
        cmd = req[0]
        if cmd & 0xE3 != 0xC1:
            raise SdoAbort(abort.COMMAND, f"expected the end of a block download, got command 0x{cmd:02X}")
        n = (cmd >> 2) & 0x07
        if n:
            del self.buffer[-n:]
        data = bytes(self.buffer)
        if self.size is not None and len(data) != self.size:
            raise SdoAbort(
                abort.LENGTH_HIGH if len(data) > self.size else abort.LENGTH_LOW,
                f"{len(data)} bytes received, {self.size} indicated",
            )
        if self.crc:
            client_crc = struct.unpack_from("<H", req, 1)[0]
            if client_crc != crc16(data):
                raise SdoAbort(abort.CRC, f"CRC 0x{client_crc:04X} sent, 0x{crc16(data):04X} computed")
        self.server.store.sdo_write(self.index, self.sub, data)
        self.server.send(bytes([0xA1]) + bytes(7))
        self.done = True
        self.cancel()


class BlockUpload(Transfer):
    """The server's half of a block upload."""

    def __init__(self, server: Any, index: int, sub: int, data: bytes, *, crc: bool, block_size: int) -> None:
        super().__init__(index, sub)
        self.server = server
        self.data = data
        self.crc = crc
        self.block_size = block_size
        self.block_start = 0  # offset of the first byte of the current sub-block
        self.sent = 0  # segments sent in the current sub-block
        self.state = "start"  # -> "ack" -> "end"
        self.retransmissions = 0

    def on_request(self, req: bytes) -> None:
        """The client's start (0xA3), acknowledgement (0xA2) or end (0xA1)."""
        cmd = req[0]
        if self.state == "start":
            if cmd != 0xA3:
                raise SdoAbort(abort.COMMAND, f"expected the start of a block upload (0xA3), got 0x{cmd:02X}")
            self._send_block()
            self.state = "ack"
        elif self.state == "ack":
            if cmd != 0xA2:
                raise SdoAbort(abort.COMMAND, f"expected a block acknowledgement (0xA2), got 0x{cmd:02X}")
            ackseq, blksize = req[1], req[2]
            if not 1 <= blksize <= 127:
                raise SdoAbort(abort.BLOCK_SIZE, f"block size {blksize}: 1..127")
            if ackseq > self.sent:
                raise SdoAbort(abort.SEQUENCE, f"acknowledged segment {ackseq} of {self.sent} sent")
            if ackseq < self.sent:
                self.retransmissions += 1
            self.block_start = min(self.block_start + 7 * ackseq, len(self.data))
            self.block_size = blksize
            if self.block_start >= len(self.data):
                rest = len(self.data) % 7 or (7 if self.data else 0)
                n = 7 - rest
                crc = crc16(self.data) if self.crc else 0
                self.server.send(bytes([0xC1 | (n << 2)]) + struct.pack("<H", crc) + bytes(5))
                self.state = "end"
            else:
                self._send_block()
        else:
            if cmd != 0xA1:
                raise SdoAbort(abort.COMMAND, f"expected the end of a block upload (0xA1), got 0x{cmd:02X}")
            self.done = True

    def _send_block(self) -> None:
        pos = self.block_start
        self.sent = 0
        for seq in range(1, self.block_size + 1):
            chunk = self.data[pos : pos + 7]
            pos += 7
            last = pos >= len(self.data)
            self.server.send(bytes([(0x80 if last else 0) | seq]) + chunk + bytes(7 - len(chunk)))
            self.sent = seq
            if last:
                break
