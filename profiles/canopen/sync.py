"""SYNC (CiA 301 7.2.5): consumer and producer.

Objects: 0x1005 COB-ID SYNC (bits 10..0 the CAN-ID, default 0x080; bit 30 set: this device
produces SYNC), 0x1006 communication cycle period (µs; the producer's period, and for a
consumer the expected period: CANopenNode reports a SYNC timeout, EMCY 0x8100, after 1.5
periods without one), 0x1007 synchronous window length (µs after the SYNC in which synchronous
PDOs may go out; 0: no window), 0x1019 synchronous counter overflow value (0: the SYNC has no
data; 2..240: it carries a counter 1..value that the producer increments and wraps; 1 and
241..255 are reserved).

A SYNC whose length does not match 0x1019 (0 bytes without a counter, 1 byte with one) is not a
SYNC for the device: it is ignored and reported (CANopenNode: EMCY 0x8240, unexpected SYNC
data length).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from profiles.canopen import cob
from profiles.canopen.sdo import abort
from profiles.canopen.sdo.abort import SdoAbort
from stack import Frame

__all__ = ["SyncConsumer", "SyncProducer", "SYNC_TIMEOUT_FACTOR", "check_cob_id_sync", "check_counter_overflow"]

US = 1_000

SYNC_TIMEOUT_FACTOR = 1.5
"""A consumer expecting a period reports a timeout after 1.5 periods (CANopenNode)."""


class SyncConsumer:
    """Receives SYNC and calls ``on_sync(counter, t)`` (counter None without one).

    ``on_length_error(dlc)`` and ``on_timeout(active)`` report the two SYNC errors;
    ``call_at`` is the node's timer. Counters: ``received``, ``length_errors``, ``timeouts``.
    """

    def __init__(
        self,
        call_at: Callable[..., Any],
        on_sync: Callable[[int | None, int], Any],
        *,
        on_length_error: Callable[[int], Any] | None = None,
        on_timeout: Callable[[bool], Any] | None = None,
    ) -> None:
        self.call_at = call_at
        self.on_sync = on_sync
        self.on_length_error = on_length_error
        self.on_timeout = on_timeout
        self.cob_id = 0x80
        self.producer = False
        self.period_ns = 0
        self.window_ns = 0
        self.overflow = 0
        self.received = 0
        self.length_errors = 0
        self.timeouts = 0
        self.last: int | None = None
        self.counter: int | None = None
        self.timed_out = False
        self._timer: Any = None

    def configure(self, cob_id_sync: int, period_us: int, window_us: int, overflow: int) -> None:
        """Objects 0x1005, 0x1006, 0x1007, 0x1019."""
        self.cob_id = cob_id_sync & 0x7FF
        self.producer = bool(cob_id_sync & 0x4000_0000)
        self.period_ns = period_us * US
        self.window_ns = window_us * US
        self.overflow = overflow

    def stop(self) -> None:
        """No SYNC monitoring (stopped, reset)."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self.last = None

    def on_frame(self, data: bytes, t: int) -> None:
        """A frame on the SYNC COB-ID at ``t``."""
        want = 1 if self.overflow else 0
        if len(data) != want:
            self.length_errors += 1
            if self.on_length_error is not None:
                self.on_length_error(len(data))
            return
        self.sync(data[0] if want else None, t)

    def sync(self, counter: int | None, t: int) -> None:
        """A SYNC at ``t`` (received, or sent by this device as producer)."""
        self.received += 1
        self.last = t
        self.counter = counter
        if self.timed_out:
            self.timed_out = False
            if self.on_timeout is not None:
                self.on_timeout(False)
        if self.period_ns and not self.producer:
            if self._timer is not None:
                self._timer.cancel()
            self._timer = self.call_at(t + int(self.period_ns * SYNC_TIMEOUT_FACTOR), self._timeout)
        self.on_sync(counter, t)

    def in_window(self, t: int) -> bool:
        """Whether ``t`` lies inside the synchronous window of the last SYNC (always, without a
        window)."""
        return not self.window_ns or self.last is None or t <= self.last + self.window_ns

    def _timeout(self) -> None:
        self._timer = None
        self.timeouts += 1
        self.timed_out = True
        if self.on_timeout is not None:
            self.on_timeout(True)


class SyncProducer:
    """Sends SYNC every ``period_ns`` on ``cob_id``, with a counter 1..overflow when ``overflow``
    is 2..240 (CiA 301 7.2.5.3). ``send(frame)`` queues the frame; ``sent`` counts them."""

    def __init__(self, send: Callable[[Frame], Any], call_at: Callable[..., Any], now: Callable[[], int]) -> None:
        self.send = send
        self.call_at = call_at
        self.now = now
        self.cob_id = 0x80
        self.period_ns = 0
        self.overflow = 0
        self.counter = 0
        self.sent = 0
        self.running = False
        self._next = 0
        self._timer: Any = None

    def configure(self, cob_id: int, period_ns: int, overflow: int = 0) -> None:
        """CAN-ID, period (ns) and counter overflow value (0 or 2..240)."""
        if overflow == 1 or overflow > 240:
            raise ValueError(f"SYNC counter overflow value {overflow!r}: 0 or 2..240 (CiA 301 7.5.2.40)")
        self.cob_id = cob_id & 0x7FF
        self.period_ns = period_ns
        self.overflow = overflow
        if self.running:
            self.start()

    def start(self, at: int | None = None) -> None:
        """Begin with a SYNC at ``at`` (now by default), counter from 1 (CiA 301: the counter is
        reset to 1 when the producer starts)."""
        self.stop()
        self.running = True
        self.counter = 0
        if self.period_ns:
            self._next = self.now() if at is None else at
            self._timer = self.call_at(self._next, self._tick)

    def stop(self) -> None:
        """Stop sending."""
        self.running = False
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def frame(self) -> Frame:
        """The next SYNC frame (advances the counter)."""
        if not self.overflow:
            return Frame(self.cob_id)
        self.counter = self.counter % self.overflow + 1
        return Frame(self.cob_id, bytes([self.counter]))

    def _tick(self) -> None:
        self._timer = None
        if not self.running:
            return
        self.send(self.frame())
        self.sent += 1
        self._next += self.period_ns
        self._timer = self.call_at(self._next, self._tick)


def check_cob_id_sync(value: int, sync: SyncConsumer) -> None:
    """Validator of 0x1005 (CANopenNode's rules): bits 31 and 29..11 are 0, the CAN-ID is not
    restricted, and a producer keeps its CAN-ID while it produces (0x0609 0030 otherwise)."""
    can_id = value & 0x7FF
    if value & 0xBFFF_F800:
        raise SdoAbort(abort.INVALID_VALUE, "0x1005: bits 31 and 29..11 must be 0 (11-bit COB-ID SYNC)")
    if cob.is_restricted(can_id):
        raise SdoAbort(abort.INVALID_VALUE, f"0x1005: CAN-ID 0x{can_id:03X} is restricted (CiA 301 7.3.5)")
    if sync.producer and value & 0x4000_0000 and can_id != sync.cob_id:
        raise SdoAbort(abort.INVALID_VALUE, "0x1005: stop producing SYNC (bit 30) before changing its CAN-ID")


def check_counter_overflow(value: int, period_us: int) -> None:
    """Validator of 0x1019: 0 or 2..240 (0x0609 0030), and only while the cycle period 0x1006
    is 0 (0x0800 0022, CANopenNode's ODR_DATA_DEV_STATE)."""
    if value == 1 or value > 240:
        raise SdoAbort(abort.INVALID_VALUE, f"0x1019: {value}; the counter overflow value is 0 or 2..240")
    if period_us:
        raise SdoAbort(abort.DEVICE_STATE, "0x1019 can change only while 0x1006 (cycle period) is 0")
