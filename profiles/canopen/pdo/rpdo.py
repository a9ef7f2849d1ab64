"""Receive PDOs (CiA 301 7.2.2, 7.5.2.35): process data written into the dictionary.

An RPDO of transmission type 254/255 writes its mapped objects when it arrives; one of type
0..240 (synchronous) keeps the last frame received and writes it at the next SYNC (CiA 301:
"the data is actuated at the next SYNC"). RPDOs are processed only in operational.

Length (CANopenNode's rules): a frame shorter than the mapping is not processed and is
reported with EMCY 0x8210 (PDO not processed due to length error); a longer one is processed
and reported with 0x8220 (PDO length exceeded); the next frame of the right length clears the
error. The event timer (sub-index 5, ms) monitors the RPDO after its first frame: no frame for
that long is reported with EMCY 0x8250 (RPDO timeout), cleared by the next frame.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from profiles.canopen import cob
from profiles.canopen.pdo.common import Pdo, PdoHost
from profiles.canopen.pdo.mapping import unpack
from profiles.canopen.sdo.abort import SdoAbort

__all__ = ["Rpdo", "PDO_LENGTH_SHORT", "PDO_LENGTH_LONG", "RPDO_TIMEOUT"]

PDO_LENGTH_SHORT = 0x8210
PDO_LENGTH_LONG = 0x8220
RPDO_TIMEOUT = 0x8250


class Rpdo(Pdo):
    """Receive PDO ``n`` (1-based) of a device.

    ``report(code, info, key)`` / ``clear(key)`` raise and clear EMCY conditions;
    ``applied(rpdo, written, t)`` is called after the objects were written with the list of
    (index, sub) written. Counters: ``received``, ``applied_count``, ``length_errors``,
    ``rejected`` (an object refused the value, e.g. outside its limits), ``timeouts``.
    """

    receive = True
    kind = "RPDO"

    def __init__(
        self,
        host: PdoHost,
        n: int,
        report: Callable[..., Any],
        clear: Callable[[Any], Any],
        applied: Callable[[Rpdo, list[tuple[int, int]], int], Any],
    ) -> None:
        self.report = report
        self.clear = clear
        self.applied = applied
        self.buffer: bytes | None = None
        self.running = False
        self.received = self.applied_count = self.length_errors = self.rejected = self.timeouts = 0
        self.last_time: int | None = None
        self._timer: Any = None
        super().__init__(host, n, 0x1400 + n - 1, 0x1600 + n - 1, cob.RPDO)

    def start(self) -> None:
        """Entering operational."""
        self.running = True

    def stop(self) -> None:
        """Leaving operational: a frame waiting for SYNC is dropped, monitoring stops."""
        self.running = False
        self.buffer = None
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def on_frame(self, data: bytes, t: int) -> None:
        """A frame on the RPDO's COB-ID at ``t``."""
        if not self.running or not self.valid:
            return
        self.received += 1
        key = f"{self.name}-length"
        if len(data) < self.size:
            self.length_errors += 1
            self.report(PDO_LENGTH_SHORT, self.size.to_bytes(2, "little"), key=key)
            return
        if len(data) > self.size:
            self.length_errors += 1
            self.report(PDO_LENGTH_LONG, self.size.to_bytes(2, "little"), key=key)
        else:
            self.clear(key)
        if self.event_ns:
            if self._timer is not None:
                self._timer.cancel()
            self.clear(f"{self.name}-timeout")
            self._timer = self.host.node.call_at(t + self.event_ns, self._timed_out)
        self.last_time = t
        if self.synchronous:
            self.buffer = bytes(data[: self.size])
        else:
            self.apply(bytes(data[: self.size]), t)

    def on_sync(self, t: int) -> None:
        """A SYNC: the data of a synchronous RPDO take effect now."""
        if self.buffer is not None and self.running:
            data, self.buffer = self.buffer, None
            self.apply(data, t)

    def apply(self, data: bytes, t: int) -> None:
        """Write the mapped objects (each one that refuses its value is counted and skipped)."""
        written = []
        for index, sub, raw in unpack(self.store, self.mapped, data):
            try:
                self.store.write(index, sub, raw)
                written.append((index, sub))
            except SdoAbort:
                self.rejected += 1
        self.applied_count += 1
        self.applied(self, written, t)

    def _timed_out(self) -> None:
        self._timer = None
        self.timeouts += 1
        self.report(RPDO_TIMEOUT, self.size.to_bytes(2, "little"), key=f"{self.name}-timeout")
