"""TIME: the time stamp object (CiA 301 7.2.6), consumer and producer.

Object 0x1012 COB-ID TIME: bits 10..0 the CAN-ID (default 0x100), bit 31 set: the device
consumes TIME, bit 30 set: it produces TIME. The message carries a TIME_OF_DAY (CiA 301 7.1.6.5):
milliseconds after midnight in the low 28 bits of an UNSIGNED32 (the 4 high bits are reserved,
0), then the days since 1 January 1984 as UNSIGNED16, 6 bytes in all.

Sans-IO: the producer never reads a clock. It sends ``epoch_s`` (the Unix time at node time 0,
given by whoever starts the device) plus the node's time.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Any

from profiles.canopen import cob
from profiles.canopen.sdo import abort
from profiles.canopen.sdo.abort import SdoAbort
from stack import Frame

__all__ = ["encode_time_of_day", "decode_time_of_day", "TimeProducer", "EPOCH_1984", "DAY_MS", "check_cob_id_time"]

EPOCH_1984 = 441_763_200
"""1984-01-01T00:00:00Z as a Unix time (s): day 0 of TIME_OF_DAY."""
DAY_MS = 86_400_000
_TOD = struct.Struct("<LH")


def encode_time_of_day(unix_ms: int) -> bytes:
    """The 6 bytes of a TIME_OF_DAY for a Unix time in ms (CiA 301 7.1.6.5)."""
    rel = unix_ms - EPOCH_1984 * 1000
    if not 0 <= rel < 0x1_0000 * DAY_MS:
        raise ValueError(f"time {unix_ms} ms: TIME_OF_DAY covers 1984-01-01 .. 2163-06-06")
    days, ms = divmod(rel, DAY_MS)
    return _TOD.pack(ms, days)


def decode_time_of_day(data: bytes) -> int:
    """The Unix time in ms of a TIME_OF_DAY (the 4 reserved bits are ignored)."""
    if len(data) < 6:
        raise ValueError(f"a TIME_OF_DAY is 6 bytes, got {len(data)}")
    ms, days = _TOD.unpack_from(data)
    return EPOCH_1984 * 1000 + days * DAY_MS + (ms & 0x0FFF_FFFF)


def check_cob_id_time(value: int) -> None:
    """Validator of 0x1012: bits 29..11 are 0 and the CAN-ID is not restricted (0x0609 0030)."""
    if value & 0x3FFF_F800 or cob.is_restricted(value & 0x7FF):
        raise SdoAbort(abort.INVALID_VALUE, f"0x1012: 0x{value:08X} is no usable COB-ID TIME")


class TimeProducer:
    """Sends TIME every ``period_ns`` on ``cob_id``: ``epoch_ms`` + the node's time."""

    def __init__(self, send: Callable[[Frame], Any], call_at: Callable[..., Any], now: Callable[[], int]) -> None:
        self.send = send
        self.call_at = call_at
        self.now = now
        self.cob_id = 0x100
        self.period_ns = 0
        self.epoch_ms = EPOCH_1984 * 1000
        self.sent = 0
        self._next = 0
        self._timer: Any = None

    def start(self, cob_id: int, period_ns: int, epoch_ms: int) -> None:
        """Send now and then every ``period_ns`` (0: only now)."""
        self.stop()
        self.cob_id, self.period_ns, self.epoch_ms = cob_id & 0x7FF, period_ns, epoch_ms
        self._next = self.now()
        self._tick()

    def stop(self) -> None:
        """Stop producing."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _tick(self) -> None:
        self._timer = None
        self.send(Frame(self.cob_id, encode_time_of_day(self.epoch_ms + self.now() // 1_000_000)))
        self.sent += 1
        if self.period_ns:
            self._next += self.period_ns
            self._timer = self.call_at(self._next, self._tick)
