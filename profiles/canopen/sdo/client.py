"""A sans-IO SDO client (CiA 301 7.2.4) for the master: expedited and segmented upload and
download, one transfer at a time per server, the others queued.

``send(data)`` transmits 8 bytes on the client→server COB-ID (0x600 + node-ID); responses from
the server (0x580 + node-ID) go to `SdoClient.on_response`. Each transfer ends in an
`SdoResult` handed to its ``done`` callback: the data of an upload, or the abort code (the
server's, or 0x0504 0000 when the server did not answer within ``timeout_ns``, after which the
client sends that abort itself, as CiA 301 says).
"""

from __future__ import annotations

import struct
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from profiles.canopen.sdo import abort

__all__ = ["SdoClient", "SdoResult"]

_HEADER = struct.Struct("<BHB")


@dataclass(frozen=True, slots=True)
class SdoResult:
    """How a transfer ended: ``data`` for an upload, ``abort_code`` None on success. (A frozen
    dataclass rather than a NamedTuple: its ``index``, CiA 301's word, would shadow
    ``tuple.index``.)"""

    index: int
    sub: int
    upload: bool
    data: bytes | None
    abort_code: int | None

    @property
    def ok(self) -> bool:
        """The transfer succeeded."""
        return self.abort_code is None

    @property
    def value(self) -> int:
        """An upload's data as an unsigned little-endian integer."""
        return int.from_bytes(self.data or b"", "little")

    def __str__(self) -> str:
        what = f"{'upload' if self.upload else 'download'} 0x{self.index:04X}:{self.sub}"
        code = self.abort_code
        if code is None:
            return f"{what}: ok" + (f" {self.data.hex()}" if self.data is not None else "")
        return f"{what}: abort 0x{code:08X} ({abort.ABORT_TEXT.get(code, 'unknown')})"


class _Transfer:
    def __init__(
        self, index: int, sub: int, upload: bool, data: bytes | None, done: Callable[[SdoResult], Any] | None
    ) -> None:
        self.index, self.sub, self.upload, self.data, self.done = index, sub, upload, data, done
        self.buffer = bytearray()
        self.size: int | None = None
        self.pos = 0
        self.toggle = 0
        self.phase = "initiate"


class SdoClient:
    """The SDO client of one server. Counters: ``completed``, ``aborted``, ``timeouts``."""

    def __init__(
        self, send: Callable[[bytes], Any], call_later: Callable[..., Any], *, timeout_ns: int = 500_000_000
    ) -> None:
        self.send = send
        self.call_later = call_later
        self.timeout_ns = timeout_ns
        self.queue: deque[_Transfer] = deque()
        self.current: _Transfer | None = None
        self._timer: Any = None
        self.completed = 0
        self.aborted = 0
        self.timeouts = 0
        self.results: list[SdoResult] = []

    @property
    def busy(self) -> bool:
        """A transfer is in progress or waiting."""
        return self.current is not None or bool(self.queue)

    def upload(self, index: int, sub: int, done: Callable[[SdoResult], Any] | None = None) -> None:
        """Read ``index:sub`` (CiA 301 7.2.4.3.5)."""
        self._add(_Transfer(index, sub, True, None, done))

    def download(self, index: int, sub: int, data: bytes, done: Callable[[SdoResult], Any] | None = None) -> None:
        """Write ``data`` to ``index:sub``: expedited up to 4 bytes, segmented beyond
        (CiA 301 7.2.4.3.3)."""
        self._add(_Transfer(index, sub, False, bytes(data), done))

    def cancel_all(self) -> None:
        """Drop every transfer without callbacks (the server reset or went away)."""
        self.queue.clear()
        self.current = None
        self._stop_timer()

    def _add(self, t: _Transfer) -> None:
        self.queue.append(t)
        if self.current is None:
            self._next()

    def _next(self) -> None:
        if self.current is not None or not self.queue:
            return
        t = self.current = self.queue.popleft()
        head = struct.pack("<HB", t.index, t.sub)
        if t.upload:
            self._request(bytes([0x40]) + head + bytes(4))
        elif t.data is not None and 0 < len(t.data) <= 4:
            n = 4 - len(t.data)
            self._request(bytes([0x23 | (n << 2)]) + head + t.data + bytes(n))
        else:
            assert t.data is not None
            self._request(bytes([0x21]) + head + struct.pack("<L", len(t.data)))

    def _request(self, data: bytes) -> None:
        self._stop_timer()
        self._timer = self.call_later(self.timeout_ns, self._timed_out)
        self.send(data)

    def on_response(self, data: bytes) -> None:
        """A frame from the server (CiA 301 7.2.4.3)."""
        t = self.current
        if t is None or len(data) != 8:
            return
        cmd = data[0]
        if cmd == 0x80:
            self._finish(None, struct.unpack_from("<L", data, 4)[0])
            return
        try:
            if t.phase == "initiate":
                self._initiated(t, cmd, data)
            elif t.upload:
                self._segment_up(t, cmd, data)
            else:
                self._segment_down(t, cmd)
        except _Protocol as exc:
            self.send(struct.pack("<BHBL", 0x80, t.index, t.sub, exc.code))
            self._finish(None, exc.code)

    def _initiated(self, t: _Transfer, cmd: int, data: bytes) -> None:
        _, index, sub = _HEADER.unpack_from(data)
        if (index, sub) != (t.index, t.sub):
            raise _Protocol(abort.GENERAL)
        if t.upload:
            if cmd & 0xE0 != 0x40:
                raise _Protocol(abort.COMMAND)
            if cmd & 0x02:
                size = 4 - ((cmd >> 2) & 0x03) if cmd & 0x01 else 4
                self._finish(bytes(data[4 : 4 + size]), None)
                return
            t.size = struct.unpack_from("<L", data, 4)[0] if cmd & 0x01 else None
            t.phase = "segments"
            self._request(bytes([0x60]) + bytes(7))
            return
        if cmd != 0x60:
            raise _Protocol(abort.COMMAND)
        if t.data is not None and 0 < len(t.data) <= 4:
            self._finish(None, None)
            return
        t.phase = "segments"
        self._send_segment(t)

    def _send_segment(self, t: _Transfer) -> None:
        assert t.data is not None
        chunk = t.data[t.pos : t.pos + 7]
        t.pos += len(chunk)
        last = t.pos >= len(t.data)
        self._request(bytes([t.toggle | ((7 - len(chunk)) << 1) | (1 if last else 0)]) + chunk + bytes(7 - len(chunk)))

    def _segment_down(self, t: _Transfer, cmd: int) -> None:
        if cmd & 0xE0 != 0x20:
            raise _Protocol(abort.COMMAND)
        if cmd & 0x10 != t.toggle:
            raise _Protocol(abort.TOGGLE_BIT)
        t.toggle ^= 0x10
        if t.data is not None and t.pos >= len(t.data):
            self._finish(None, None)
        else:
            self._send_segment(t)

    def _segment_up(self, t: _Transfer, cmd: int, data: bytes) -> None:
        if cmd & 0xE0 != 0x00:
            raise _Protocol(abort.COMMAND)
        if cmd & 0x10 != t.toggle:
            raise _Protocol(abort.TOGGLE_BIT)
        n = (cmd >> 1) & 0x07
        t.buffer += data[1 : 8 - n]
        t.toggle ^= 0x10
        if cmd & 0x01:
            if t.size is not None and len(t.buffer) != t.size:
                raise _Protocol(abort.LENGTH_MISMATCH)
            self._finish(bytes(t.buffer), None)
        else:
            self._request(bytes([0x60 | t.toggle]) + bytes(7))

    def _timed_out(self) -> None:
        self._timer = None
        t = self.current
        if t is None:
            return
        self.timeouts += 1
        self.send(struct.pack("<BHBL", 0x80, t.index, t.sub, abort.TIMEOUT))
        self._finish(None, abort.TIMEOUT)

    def _finish(self, data: bytes | None, code: int | None) -> None:
        t = self.current
        assert t is not None
        self._stop_timer()
        self.current = None
        res = SdoResult(t.index, t.sub, t.upload, data if t.upload else None, code)
        self.results.append(res)
        if code is None:
            self.completed += 1
        else:
            self.aborted += 1
        if t.done is not None:
            t.done(res)
        self._next()

    def _stop_timer(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None


class _Protocol(Exception):
    def __init__(self, code: int) -> None:
        super().__init__(code)
        self.code = code
