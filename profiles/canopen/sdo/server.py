"""The SDO server of a device (CiA 301 7.2.4): expedited and segmented transfers here, block
transfers in `profiles.canopen.sdo.block`.

Sans-IO: `SdoServer.on_request` takes the 8 data bytes of a frame on the client→server COB-ID
(0x600 + node-ID) and answers through ``send(data)`` (the device puts it on 0x580 + node-ID);
the transfer timeout runs on the node's timers.

Command bytes (byte 0; ccs = client command specifier in bits 7..5, scs = server's):

=====================================  ===================  ============================
request                                ccs                  response (scs)
=====================================  ===================  ============================
initiate download (e, s, n)            1 (0x20..0x2F)       0x60
download segment (t, n, c)             0 (0x00..0x1F)       0x20 | t
initiate upload                        2 (0x40)             0x4x: e, s, n; or 0x41 + size
upload segment (t)                     3 (0x60 / 0x70)      0x00..0x1F: t, n, c
abort transfer                         4 (0x80)             — (either side, 4-byte code)
block upload (cc, cs)                  5 (0xA0..0xA3)       6 (0xC0..0xC6)
block download (cc, s, cs)             6 (0xC0..0xC6)       5 (0xA0..0xA2)
=====================================  ===================  ============================

e = expedited, s = size indicated, n = bytes without data, t = toggle bit (bit 4), c = no more
segments. Bytes 1..2 are the index (little-endian), byte 3 the sub-index.

Refusals are abort frames (0x80, index, sub-index, abort code) with the codes of
`profiles.canopen.sdo.abort`; which rule gives which code is `profiles.canopen.dictionary`'s
business. A request that is not 8 bytes long is ignored (CANopenNode does the same); a request
while the device's NMT state has no SDO never reaches the server (the device drops it).
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Any

from profiles.canopen.dictionary import ObjectStore
from profiles.canopen.sdo import abort
from profiles.canopen.sdo.abort import SdoAbort
from profiles.canopen.sdo.block import CRC_SUPPORTED, BlockDownload, BlockUpload, Transfer

__all__ = ["SdoServer", "DEFAULT_TIMEOUT_NS"]

DEFAULT_TIMEOUT_NS = 1_000_000_000
"""Transfer timeout: CANopenNode's default SDO server timeout, 1000 ms."""

_HEADER = struct.Struct("<BHB")


class SegmentedDownload(Transfer):
    """Download segments after an initiate without the expedited bit (CiA 301 7.2.4.3.3-4)."""

    def __init__(self, server: SdoServer, index: int, sub: int, size: int | None) -> None:
        super().__init__(index, sub)
        self.server = server
        self.size = size
        self.toggle = 0
        self.buffer = bytearray()

    def on_request(self, req: bytes) -> None:
        """A download segment: toggle bit, data, last-segment bit (CiA 301 7.2.4.3.4)."""
        cmd = req[0]
        if cmd & 0xE0 != 0x00:
            raise SdoAbort(abort.COMMAND, f"expected a download segment, got command 0x{cmd:02X}")
        if cmd & 0x10 != self.toggle:
            raise SdoAbort(abort.TOGGLE_BIT, "download segment toggle bit not alternated")
        n = (cmd >> 1) & 0x07
        self.buffer += req[1 : 8 - n]
        if self.size is not None and len(self.buffer) > self.size:
            raise SdoAbort(abort.LENGTH_HIGH, f"{len(self.buffer)} bytes received, {self.size} indicated")
        store_size = self.server.store.size(self.index, self.sub)
        if store_size is not None and len(self.buffer) > store_size:
            raise SdoAbort(abort.LENGTH_HIGH, f"{len(self.buffer)} bytes for a {store_size}-byte object")
        if cmd & 0x01:
            if self.size is not None and len(self.buffer) != self.size:
                raise SdoAbort(abort.LENGTH_LOW, f"{len(self.buffer)} bytes received, {self.size} indicated")
            self.server.store.sdo_write(self.index, self.sub, bytes(self.buffer))
            self.done = True
        self.server.send(bytes([0x20 | self.toggle]) + bytes(7))
        self.toggle ^= 0x10


class SegmentedUpload(Transfer):
    """Upload segments after an initiate response with the size (CiA 301 7.2.4.3.5-6)."""

    def __init__(self, server: SdoServer, index: int, sub: int, data: bytes) -> None:
        super().__init__(index, sub)
        self.server = server
        self.data = data
        self.pos = 0
        self.toggle = 0

    def on_request(self, req: bytes) -> None:
        """An upload segment request: answered with the next 7 bytes (CiA 301 7.2.4.3.6)."""
        cmd = req[0]
        if cmd & 0xEF != 0x60:
            raise SdoAbort(abort.COMMAND, f"expected an upload segment request, got command 0x{cmd:02X}")
        if cmd & 0x10 != self.toggle:
            raise SdoAbort(abort.TOGGLE_BIT, "upload segment toggle bit not alternated")
        chunk = self.data[self.pos : self.pos + 7]
        self.pos += len(chunk)
        last = self.pos >= len(self.data)
        resp = bytes([self.toggle | ((7 - len(chunk)) << 1) | (0x01 if last else 0)]) + chunk + bytes(7 - len(chunk))
        self.server.send(resp)
        self.toggle ^= 0x10
        self.done = last


class SdoServer:
    """The default SDO server of a device (CiA 301 7.2.4; object 0x1200).

    ``send(data)`` transmits 8 bytes on the server→client COB-ID; ``call_later(delay_ns, cb)``
    returns a timer with ``cancel()`` (the node's). ``timeout_ns`` aborts a transfer the client
    stopped answering with 0x0504 0000; ``block_size`` is the number of segments per block the
    server asks for in a block download (1..127); ``block_timeout_ns`` ends a block download's
    sub-block that stopped short with the segments received in order (default: half of
    ``timeout_ns``, CANopenNode's; 0: never — the transfer's timeout then aborts it).

    Counters: ``requests`` (frames handled), ``aborts_sent``, ``aborts_received``, ``ignored``
    (not 8 bytes), and ``completed`` by transfer kind.
    """

    def __init__(
        self,
        store: ObjectStore,
        send: Callable[[bytes], Any],
        call_later: Callable[..., Any],
        *,
        timeout_ns: int = DEFAULT_TIMEOUT_NS,
        block_size: int = 127,
        block_timeout_ns: int | None = None,
    ) -> None:
        if not 1 <= block_size <= 127:
            raise ValueError(f"block_size {block_size!r}: an SDO block has 1..127 segments (CiA 301 7.2.4.3.9)")
        self.store = store
        self.send = send
        self.call_later = call_later
        self.timeout_ns = timeout_ns
        self.block_size = block_size
        self.block_timeout_ns = timeout_ns // 2 if block_timeout_ns is None else block_timeout_ns
        self.transfer: Transfer | None = None
        self._timer: Any = None
        self.requests = 0
        self.aborts_sent = 0
        self.aborts_received = 0
        self.ignored = 0
        self.last_abort: int | None = None
        self.completed: dict[str, int] = {
            "expedited download": 0,
            "expedited upload": 0,
            "segmented download": 0,
            "segmented upload": 0,
            "block download": 0,
            "block upload": 0,
        }

    # ------------------------------------------------------------------ frames
    def on_request(self, data: bytes) -> None:
        """Handle one client→server frame's data (CiA 301 7.2.4.3)."""
        if len(data) != 8:
            self.ignored += 1
            return
        self.requests += 1
        if data[0] == 0x80:  # abort transfer from the client (ccs 4): no answer
            self.aborts_received += 1
            self._finish()
            return
        t = self.transfer
        index, sub = (t.index, t.sub) if t is not None else _HEADER.unpack_from(data)[1:]
        try:
            if t is None:
                self.transfer = t = self._initiate(data)
            else:
                t.on_request(data)
        except SdoAbort as exc:
            self.abort(index, sub, exc.code)
            return
        if t is None or t.done:
            if t is not None:
                self.completed[t.kind] += 1
            self._finish()
        else:
            self._arm()

    def _initiate(self, req: bytes) -> Transfer | None:
        cmd, index, sub = _HEADER.unpack_from(req)
        ccs = cmd & 0xE0
        if ccs == 0x20:
            return self._initiate_download(cmd, index, sub, req)
        if ccs == 0x40:
            self.store.check_sdo_access(index, sub, upload=True)
            return self._initiate_upload(index, sub, self.store.sdo_read(index, sub))
        if ccs == 0xC0 and cmd & 0x01 == 0:
            var = self.store.check_sdo_access(index, sub, upload=False)
            size = struct.unpack_from("<L", req, 4)[0] if cmd & 0x02 else None
            _check_size(self.store, index, sub, size, var)
            self.send(bytes([0xA0 | CRC_SUPPORTED]) + req[1:4] + bytes([self.block_size, 0, 0, 0]))
            t: Transfer = BlockDownload(
                self,
                index,
                sub,
                size,
                crc=bool(cmd & CRC_SUPPORTED),
                block_size=self.block_size,
                block_timeout_ns=self.block_timeout_ns,
            )
            return t
        if ccs == 0xA0 and cmd & 0x03 == 0:
            self.store.check_sdo_access(index, sub, upload=True)
            data = self.store.sdo_read(index, sub)
            blksize, pst = req[4], req[5]
            if not 1 <= blksize <= 127:
                raise SdoAbort(abort.BLOCK_SIZE, f"block size {blksize}: 1..127")
            if 0 < len(data) <= pst:
                # protocol switch threshold: small data go by the normal upload (CiA 301 7.2.4.3.12)
                return self._initiate_upload(index, sub, data)
            t = BlockUpload(self, index, sub, data, crc=bool(cmd & CRC_SUPPORTED), block_size=blksize)
            self.send(bytes([0xC0 | CRC_SUPPORTED | 0x02]) + req[1:4] + struct.pack("<L", len(data)))
            return t
        raise SdoAbort(abort.COMMAND, f"command 0x{cmd:02X} does not start a transfer")

    def _initiate_download(self, cmd: int, index: int, sub: int, req: bytes) -> Transfer | None:
        var = self.store.check_sdo_access(index, sub, upload=False)
        if cmd & 0x02:  # expedited
            if cmd & 0x01:
                size = 4 - ((cmd >> 2) & 0x03)
            else:
                fixed = self.store.size(index, sub)
                size = fixed if fixed is not None and fixed < 4 else 4
            self.store.sdo_write(index, sub, bytes(req[4 : 4 + size]))
            self.send(bytes([0x60]) + req[1:4] + bytes(4))
            self.completed["expedited download"] += 1
            return None
        total = struct.unpack_from("<L", req, 4)[0] if cmd & 0x01 else None
        _check_size(self.store, index, sub, total, var)
        self.send(bytes([0x60]) + req[1:4] + bytes(4))
        return SegmentedDownload(self, index, sub, total)

    def _initiate_upload(self, index: int, sub: int, data: bytes) -> Transfer | None:
        head = struct.pack("<HB", index, sub)
        if 0 < len(data) <= 4:
            self.send(bytes([0x43 | ((4 - len(data)) << 2)]) + head + data + bytes(4 - len(data)))
            self.completed["expedited upload"] += 1
            return None
        self.send(bytes([0x41]) + head + struct.pack("<L", len(data)))
        return SegmentedUpload(self, index, sub, data)

    # ------------------------------------------------------------------ end of a transfer
    def abort(self, index: int, sub: int, code: int) -> None:
        """Send an abort transfer (0x80, index, sub-index, code) and forget the transfer."""
        self.send(struct.pack("<BHBL", 0x80, index, sub, code))
        self.aborts_sent += 1
        self.last_abort = code
        self._finish()

    def reset(self) -> None:
        """Forget any transfer without a word (the NMT state left SDO, or a reset)."""
        self._finish()

    def _finish(self) -> None:
        if self.transfer is not None:
            self.transfer.cancel()
        self.transfer = None
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _arm(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
        self._timer = self.call_later(self.timeout_ns, self._timed_out)

    def _timed_out(self) -> None:
        self._timer = None
        t = self.transfer
        if t is not None:
            self.abort(t.index, t.sub, abort.TIMEOUT)


def _check_size(store: ObjectStore, index: int, sub: int, size: int | None, var: Any) -> None:
    """An indicated size against a fixed-size object (CANopenNode checks it at initiate)."""
    fixed = store.size(index, sub)
    if size is not None and fixed is not None and size != fixed:
        raise SdoAbort(
            abort.LENGTH_HIGH if size > fixed else abort.LENGTH_LOW,
            f"{size} bytes indicated for a {fixed}-byte object 0x{index:04X}:{sub}",
        )
