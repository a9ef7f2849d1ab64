"""Emergency (CiA 301 7.2.7): the producer of a device and the decoding a consumer needs.

The EMCY message (COB-ID from object 0x1014, default 0x080 + node-ID; bit 31 set disables it)
has 8 bytes: the emergency error code (bytes 0..1, little-endian), the error register 0x1001
(byte 2) and 5 bytes of manufacturer-specific error information. Error code 0x0000 is "error
reset or no error": the producer sends it when the last active error goes away.

The producer keeps the errors that are active (one EMCY when an error appears, none while it
stays), computes the error register from them (bit 0 generic error whenever any is active; bit
1 current 0x2xxx, bit 2 voltage 0x3xxx, bit 3 temperature 0x4xxx, bit 4 communication 0x81xx and
0x82xx, bit 7 manufacturer-specific 0xFFxx; see `register_bits`), keeps the
history in the pre-defined error field 0x1003 (sub-index 0 the number of errors, sub-index 1 the
newest: error code in bits 15..0, additional information in bits 31..16; writing 0 to sub-index
0 clears it, anything else is refused with 0x0609 0030) and spaces its messages by the inhibit
time 0x1015 (100 µs units). EMCY messages go out in pre-operational and operational only; the
ones raised meanwhile wait.
"""

from __future__ import annotations

import struct
from collections import deque
from collections.abc import Callable
from typing import Any, NamedTuple

from profiles.canopen import cob
from profiles.canopen.sdo import abort
from profiles.canopen.sdo.abort import SdoAbort
from stack import Frame

LOG_KEPT = 1000
"""EMCY messages a producer keeps in its ``log`` (the latest; ``sent`` counts every one)."""

__all__ = ["EmcyProducer", "Emcy", "decode_emcy", "register_bits", "describe", "ERROR_CODES"]

US = 1_000

#: emergency error codes used by this profile (CiA 301 table "emergency error codes"); the
#: communication ones are CANopenNode's choices for the same events
ERROR_CODES = {
    0x0000: "error reset or no error",
    0x1000: "generic error",
    0x8100: "communication - generic (SYNC timeout, TPDO outside the synchronous window)",
    0x8110: "CAN overrun (objects lost)",
    0x8120: "CAN in error passive mode",
    0x8130: "life guard error or heartbeat error",
    0x8140: "recovered from bus off",
    0x8200: "protocol error - generic (wrong PDO mapping)",
    0x8210: "PDO not processed due to length error",
    0x8220: "PDO length exceeded",
    0x8240: "unexpected SYNC data length",
    0x8250: "RPDO timeout",
}

_CLASSES = [  # (code, mask, description): the classes of CiA 301's table, most specific first
    (0x0000, 0xFF00, "error reset or no error"),
    (0x1000, 0xFF00, "generic error"),
    (0x2000, 0xF000, "current"),
    (0x3000, 0xF000, "voltage"),
    (0x4000, 0xF000, "temperature"),
    (0x5000, 0xFF00, "device hardware"),
    (0x6000, 0xF000, "device software"),
    (0x7000, 0xFF00, "additional modules"),
    (0x8000, 0xF000, "monitoring"),
    (0x9000, 0xFF00, "external error"),
    (0xF000, 0xFF00, "additional functions"),
    (0xFF00, 0xFF00, "device specific"),
]


class Emcy(NamedTuple):
    """A decoded EMCY message."""

    code: int
    register: int
    info: bytes

    @property
    def is_reset(self) -> bool:
        """Error reset / no error (code 0x00xx)."""
        return self.code & 0xFF00 == 0


def decode_emcy(data: bytes) -> Emcy:
    """Split an EMCY message (CiA 301 7.2.7.3.1); shorter messages are padded with zeros."""
    data = bytes(data).ljust(8, b"\x00")
    code, reg = struct.unpack_from("<HB", data)
    return Emcy(code, reg, data[3:8])


def describe(code: int) -> str:
    """The error code's meaning: this profile's own codes exactly, others by CiA 301 class."""
    if code in ERROR_CODES:
        return ERROR_CODES[code]
    for value, mask, text in _CLASSES:
        if code & mask == value:
            return text
    return "unknown"


def register_bits(code: int) -> int:
    """The error register bits an error code sets (CiA 301 7.5.2.2), generic error included."""
    bits = 0x01
    top = code >> 12
    if top == 0x2:
        bits |= 0x02
    elif top == 0x3:
        bits |= 0x04
    elif top == 0x4:
        bits |= 0x08
    elif code & 0xFF00 in (0x8100, 0x8200):
        bits |= 0x10
    elif code & 0xFF00 == 0xFF00:
        bits |= 0x80
    return bits


class EmcyProducer:
    """Reports errors of a device (objects 0x1001, 0x1003, 0x1014, 0x1015).

    ``send(frame)`` queues a frame, ``call_at``/``now`` are the node's, ``allowed()`` says
    whether the NMT state lets EMCY out. ``history_size`` is the number of standard error
    fields of 0x1003 (0: no history). Counters: ``sent``, ``raised``, ``cleared``.
    """

    def __init__(
        self,
        send: Callable[[Frame], Any],
        call_at: Callable[..., Any],
        now: Callable[[], int],
        allowed: Callable[[], bool],
        *,
        history_size: int = 8,
    ) -> None:
        self.send = send
        self.call_at = call_at
        self.now = now
        self.allowed = allowed
        self.cob_id = 0
        self.enabled = False
        self.inhibit_ns = 0
        self.history_size = history_size
        self.history: list[int] = []  # 0x1003 entries, newest first
        self.active: dict[Any, int] = {}  # error condition -> its error code
        self.sent = 0
        self.raised = 0
        self.cleared = 0
        # (time queued, message) of the EMCY sent, the latest LOG_KEPT (``sent`` counts them all):
        # a device that reports and clears an error every SYNC would fill memory on a long run
        self.log: deque[tuple[int, Emcy]] = deque(maxlen=LOG_KEPT)
        self._queue: deque[bytes] = deque()
        self._next_allowed = 0
        self._timer: Any = None

    def configure(self, cob_id_emcy: int, inhibit_100us: int) -> None:
        """Objects 0x1014 and 0x1015."""
        self.cob_id = cob_id_emcy & 0x7FF
        self.enabled = not cob_id_emcy & 0x8000_0000 and self.cob_id != 0
        self.inhibit_ns = inhibit_100us * 100 * US

    def check_cob_id(self, value: int) -> None:
        """Validator of 0x1014 (CANopenNode's rules): bits 30..11 are 0, an enabled CAN-ID is not
        restricted, and the CAN-ID changes only while EMCY is disabled (0x0609 0030 otherwise)."""
        can_id = value & 0x7FF
        enabled = not value & 0x8000_0000 and can_id != 0
        if value & 0x7FFF_F800 or (cob.is_restricted(can_id) and enabled):
            raise SdoAbort(abort.INVALID_VALUE, f"0x1014: 0x{value:08X} is no usable COB-ID EMCY")
        if self.enabled and enabled and can_id != self.cob_id:
            raise SdoAbort(abort.INVALID_VALUE, "0x1014: set bit 31 (not valid) before changing the CAN-ID")

    @property
    def register(self) -> int:
        """The error register 0x1001: the bits of every active error."""
        reg = 0
        for code in self.active.values():
            reg |= register_bits(code)
        return reg

    def report(self, code: int, info: bytes = b"", additional: int = 0, *, key: Any = None) -> bool:
        """Raise error ``code`` (1..0xFFFF) with up to 5 bytes of manufacturer-specific ``info``;
        ``additional`` (16 bits) goes into the 0x1003 entry. ``key`` names the error condition
        (CANopenNode's error status bit; default: the code), so two conditions may share a code.
        Sends an EMCY unless the condition is active already; returns whether it was new."""
        if not 0 < code <= 0xFFFF:
            raise ValueError(f"emergency error code 0x{code:X}: 0x0001..0xFFFF (0x0000 is the reset)")
        if len(info) > 5:
            raise ValueError(f"EMCY manufacturer-specific information is 5 bytes at most, got {len(info)}")
        key = code if key is None else key
        if key in self.active:
            return False
        self.active[key] = code
        self.raised += 1
        if self.history_size:
            self.history.insert(0, ((additional & 0xFFFF) << 16) | code)
            del self.history[self.history_size :]
        self._emit(code, info)
        return True

    def clear(self, key: Any) -> bool:
        """The error condition ``key`` (as given to `report`) went away; when it was the last
        one, an error reset EMCY (0x0000) goes out. Returns whether it was active."""
        if self.active.pop(key, None) is None:
            return False
        self.cleared += 1
        if not self.active:
            self._emit(0x0000, b"")
        return True

    def reset(self) -> None:
        """Reset communication/application: no active error, nothing queued (0x1003 is kept
        unless cleared through SDO)."""
        self.active.clear()
        self._queue.clear()
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _emit(self, code: int, info: bytes) -> None:
        self._queue.append(struct.pack("<HB", code, self.register) + bytes(info).ljust(5, b"\x00"))
        self.flush()

    def flush(self) -> None:
        """Send what waits, respecting the inhibit time and the NMT state (call on entering
        pre-operational or operational)."""
        while self._queue and self._timer is None:
            if not self.enabled or not self.allowed():
                return
            now = self.now()
            if now < self._next_allowed:
                self._timer = self.call_at(self._next_allowed, self._inhibit_over)
                return
            data = self._queue.popleft()
            self.send(Frame(self.cob_id, data))
            self.sent += 1
            self.log.append((now, decode_emcy(data)))
            self._next_allowed = now + self.inhibit_ns

    def on_sent(self, sof: int) -> None:
        """An EMCY frame went out, started at ``sof``: the inhibit time counts from there (the
        minimum time between two EMCY messages, not between two queued ones)."""
        if self.inhibit_ns:
            self._next_allowed = max(self._next_allowed, sof + self.inhibit_ns)

    def _inhibit_over(self) -> None:
        self._timer = None
        self.flush()

    # ------------------------------------------------------------------ 0x1003
    def read_history(self, sub: int) -> bytes:
        """0x1003 as read: sub-index 0 the number of errors, n the n-th newest; beyond the
        number of errors 'no data available' (0x0800 0024, CANopenNode)."""
        if sub == 0:
            return bytes([len(self.history)])
        if sub <= len(self.history):
            return struct.pack("<L", self.history[sub - 1])
        raise SdoAbort(abort.NO_DATA, f"0x1003 holds {len(self.history)} errors, sub-index {sub} is empty")

    def write_history(self, sub: int, value: Any, data: bytes) -> None:
        """Validator of 0x1003: only 0 may be written, to sub-index 0, and it clears the
        history (CiA 301 7.5.2.3; anything else 0x0609 0030)."""
        if sub != 0 or value != 0:
            raise SdoAbort(abort.INVALID_VALUE, "0x1003: only 0 may be written to sub-index 0 (clears the history)")
        self.history.clear()
