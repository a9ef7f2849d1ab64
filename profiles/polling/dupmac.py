"""DeviceNet's duplicate MAC ID check at power-up (CIP Networks Library Vol. 3, chapter 2, the
network access state machine; summarised by Nick Jones of ODVA, "DeviceNet Duplicate MAC ID
Protocol Summary", 2002, on can-wiki.info and port.de).

What a node does, and what `DupMacCheck` implements:

1. At power-up it sends a Duplicate MAC ID *request* message, waits 1 s listening, sends a second
   request, waits 1 s more, and goes *online*. (The 1-s waits run from the end of each request on
   the bus: "transmit, then wait 1 second".)
2. While checking (the two seconds), a Duplicate MAC ID request *or* response carrying its own
   MAC ID sends it to the *communication fault* state.
3. Online, a request with its MAC ID is answered with a response; a response with its MAC ID sends
   it to communication fault (two network segments powered up apart and then joined).
4. Communication fault is left only by manual intervention (power cycle, reset) or a new MAC ID
   through the offline connection set — neither is modelled: the node stays faulted and silent.

The message (Message Group 2, message ID 7, the node's own MAC ID: identifier 0x400 | MAC << 3 |
7; Wireshark's DeviceNet dissector and device manuals, e.g. the Lika SFA-5000/10000 manual §6.4.1,
give the layout): 7 data bytes — byte 0 bit 7 the request/response flag (0 request, 1 response),
bits 6..0 the physical port number; bytes 1..2 the vendor ID and bytes 3..6 the serial number,
little-endian. Two devices with the same MAC ID differ in vendor and serial number, so their
requests differ in their data: on the bus they collide (a bit error in the data field) and are
retransmitted until one wins, rather than merging into one frame nobody notices.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from stack import Frame, NodeError, QueueFull, TxDone

if TYPE_CHECKING:  # pragma: no cover
    from stack import NodeAPI, Received, Timer, TxRequest

__all__ = [
    "DupMacCheck",
    "dup_mac_id",
    "encode_dup_mac",
    "decode_dup_mac",
    "CHECKING",
    "ONLINE",
    "COMMUNICATION_FAULT",
    "WAIT_NS",
]

CHECKING, ONLINE, COMMUNICATION_FAULT = "checking", "online", "communication fault"
WAIT_NS = 1_000_000_000
"""The wait after each of the two requests: 1 s."""
_GROUP_2_DUP_MAC = 7


def dup_mac_id(mac: int) -> int:
    """The identifier of MAC ID ``mac``'s Duplicate MAC ID messages: Group 2 message 7."""
    if isinstance(mac, bool) or not isinstance(mac, int) or not 0 <= mac <= 63:
        raise ValueError(f"MAC ID {mac!r} is not 0..63")
    return 0x400 | mac << 3 | _GROUP_2_DUP_MAC


def encode_dup_mac(*, response: bool, port: int, vendor_id: int, serial_number: int) -> bytes:
    """The 7 data bytes of a Duplicate MAC ID request or response (see the module docstring)."""
    if not 0 <= port <= 0x7F:
        raise ValueError(f"physical port {port!r} is not 0..127")
    if not 0 <= vendor_id <= 0xFFFF or not 0 <= serial_number <= 0xFFFF_FFFF:
        raise ValueError(f"vendor ID {vendor_id!r} (UINT) or serial number {serial_number!r} (UDINT) out of range")
    return bytes([(0x80 if response else 0) | port]) + struct.pack("<HL", vendor_id, serial_number)


def decode_dup_mac(data: bytes) -> tuple[bool, int, int, int] | None:
    """(response, port, vendor ID, serial number) of a Duplicate MAC ID message; None when it is
    not 7 bytes long."""
    if len(data) != 7:
        return None
    vendor, serial = struct.unpack_from("<HL", data, 1)
    return bool(data[0] & 0x80), data[0] & 0x7F, vendor, serial


class DupMacCheck:
    """The duplicate MAC ID check of one node with MAC ID ``mac_id`` (see the module docstring).
    ``on_online(t)`` when it goes online, ``on_fault(t, reason)`` when it enters communication
    fault. ``state`` is ``checking``, ``online`` or ``communication fault``; ``requests_sent``,
    ``responses_sent`` count what it sent."""

    def __init__(
        self,
        node: NodeAPI,
        mac_id: int,
        *,
        vendor_id: int = 0,
        serial_number: int = 0,
        port: int = 0,
        on_online: Callable[[int], Any] | None = None,
        on_fault: Callable[[int, str], Any] | None = None,
        wait_ns: int = WAIT_NS,
    ) -> None:
        self.node = node
        self.mac_id = mac_id
        self.can_id = dup_mac_id(mac_id)
        self.request = Frame(
            self.can_id, encode_dup_mac(response=False, port=port, vendor_id=vendor_id, serial_number=serial_number)
        )
        self.response = Frame(
            self.can_id, encode_dup_mac(response=True, port=port, vendor_id=vendor_id, serial_number=serial_number)
        )
        self.on_online = on_online
        self.on_fault = on_fault
        self.wait_ns = wait_ns
        self.state = CHECKING
        self.fault_reason: str | None = None
        self.requests_sent = 0
        self.responses_sent = 0
        self.online_at: int | None = None
        self._pending: TxRequest | None = None
        self._timer: Timer | None = None

    def start(self) -> None:
        """Power-up: listen for the node's MAC ID and send the first request."""
        self.node.subscribe(self._received, [{"can_id": self.can_id, "can_mask": 0x7FF, "extended": False}])
        self.node.listen(TxDone, self._done)
        self._send_request()

    def _send(self, frame: Frame) -> TxRequest | None:
        try:
            return self.node.send(frame)
        except (QueueFull, NodeError):
            return None

    def _send_request(self) -> None:
        self._pending = self._send(self.request)

    def _done(self, ev: TxDone) -> None:
        if ev.request is not self._pending or self.state != CHECKING:
            return
        self._pending = None
        self.requests_sent += 1
        # transmit, then wait 1 second: after the first request the second, after it online
        self._timer = self.node.call_at(ev.time + self.wait_ns, self._waited)

    def _waited(self) -> None:
        self._timer = None
        if self.state != CHECKING:
            return
        if self.requests_sent < 2:
            self._send_request()
            return
        self.state = ONLINE
        self.online_at = self.node.now()
        if self.on_online is not None:
            self.on_online(self.online_at)

    def _received(self, ev: Received) -> None:
        info = decode_dup_mac(ev.frame.data)
        if info is None or ev.frame.remote:
            return
        response = info[0]
        if self.state == CHECKING:
            self._fault(ev.time, "a Duplicate MAC ID " + ("response" if response else "request") + " while checking")
        elif self.state == ONLINE:
            if response:
                self._fault(ev.time, "a Duplicate MAC ID response while online")
            elif self._send(self.response) is not None:
                self.responses_sent += 1

    def _fault(self, t: int, reason: str) -> None:
        self.state = COMMUNICATION_FAULT
        self.fault_reason = reason
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self._pending is not None:
            self.node.abort(self._pending)
            self._pending = None
        if self.on_fault is not None:
            self.on_fault(t, reason)

    def figures(self) -> dict[str, Any]:
        """The check's state, what it sent, when it went online (ms) and why it faulted."""
        return {
            "state": self.state,
            "requests_sent": self.requests_sent,
            "responses_sent": self.responses_sent,
            "online_ms": None if self.online_at is None else self.online_at / 1e6,
            "fault": self.fault_reason,
        }
