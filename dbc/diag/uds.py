"""A UDS server (ISO 14229-1) on any stack node, over ISO-TP (`dbc.diag.isotp`).

`UdsServer(node, request_id, response_id, dids=...)` answers diagnostic requests on a node of the
node API, sans-IO: a request arrives as an ISO-TP PDU, `respond` computes the response from the
server's state and the application's callables, and the response goes back over ISO-TP. The
services:

=====  =============================  ===========================================================
SID    service                        here
=====  =============================  ===========================================================
0x10   DiagnosticSessionControl       default (1), programming (2), extended (3); the positive
                                      response carries P2 (ms) and P2* (10 ms units)
0x11   ECUReset                       hard (1), key off/on (2), soft (3): the response is sent,
                                      the session returns to default, ``on_reset(kind)`` is called
0x14   ClearDiagnosticInformation     every DTC of the group (0xFFFFFF: all) is cleared
0x19   ReadDTCInformation             0x01 number of DTCs by status mask, 0x02 DTCs by status mask,
                                      0x0A supported DTCs
0x22   ReadDataByIdentifier           one or more DIDs; each `DataIdentifier`'s ``read()``
0x2E   WriteDataByIdentifier          a writable `DataIdentifier`'s ``write(data)``, in a
                                      non-default session
0x3E   TesterPresent                  keeps a non-default session alive (S3, 5 s)
=====  =============================  ===========================================================

Negative responses (0x7F, SID, NRC) use the standard's codes: 0x11 service not supported, 0x12
sub-function not supported, 0x13 incorrect message length or format, 0x22 conditions not correct,
0x31 request out of range, 0x7F service not supported in the active session. Bit 7 of a
sub-function suppresses the positive response. A non-default session falls back to the default
session after S3 (5 s) without a request.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

from stack import NodeAPI

from .isotp import IsoTpChannel

__all__ = ["UdsServer", "DataIdentifier", "Session", "NRC", "DTC_STATUS_AVAILABILITY", "P2_MS", "P2_STAR_MS", "S3_MS"]

P2_MS = 50
"""P2server_max announced in the DiagnosticSessionControl response (ms)."""
P2_STAR_MS = 5000
"""P2*server_max announced (ms; sent in units of 10 ms)."""
S3_MS = 5000
"""S3server: a non-default session without a request for this long returns to default (ms)."""

#: DTC status bits this server supports (ISO 14229-1 D.2): testFailed, confirmedDTC
DTC_STATUS_AVAILABILITY = 0x09
DTC_FORMAT_ISO14229_1 = 0x01


class NRC:
    """Negative response codes (ISO 14229-1 Annex A.1) the server uses."""

    SERVICE_NOT_SUPPORTED = 0x11
    SUBFUNCTION_NOT_SUPPORTED = 0x12
    INCORRECT_LENGTH = 0x13
    CONDITIONS_NOT_CORRECT = 0x22
    REQUEST_OUT_OF_RANGE = 0x31
    SERVICE_NOT_SUPPORTED_IN_SESSION = 0x7F


class Session:
    """Diagnostic sessions (ISO 14229-1 DiagnosticSessionControl sub-functions)."""

    DEFAULT = 0x01
    PROGRAMMING = 0x02
    EXTENDED = 0x03


@dataclass(frozen=True)
class DataIdentifier:
    """A data identifier: ``read()`` gives its bytes; ``write(data)`` (None: read-only) takes
    new bytes and raises `ValueError` when they are out of range; ``length`` is the number of
    bytes a write must carry (None: any)."""

    did: int
    name: str
    read: Callable[[], bytes]
    write: Callable[[bytes], Any] | None = None
    length: int | None = None


class _Negative(Exception):
    def __init__(self, nrc: int) -> None:
        self.nrc = nrc


class Exchange(NamedTuple):
    """One request and the response the server gave (None: none, suppressed)."""

    time: int
    request: bytes
    response: bytes | None


class UdsServer:
    """A UDS server on ``node``: requests on ``request_id``, responses on ``response_id``
    (ISO-TP normal addressing; ``stmin_ms``/``block_size`` are the flow control this server
    asks testers for). ``dids`` are its data identifiers; ``on_reset(kind)`` is called after
    an ECUReset response; ``log`` keeps every `Exchange`."""

    def __init__(
        self,
        node: NodeAPI,
        request_id: int,
        response_id: int,
        *,
        dids: Iterable[DataIdentifier] = (),
        on_reset: Callable[[int], Any] | None = None,
        extended: bool = False,
        stmin_ms: int = 0,
        block_size: int = 0,
    ) -> None:
        self.node = node
        self.dids: dict[int, DataIdentifier] = {}
        for d in dids:
            self.add_did(d)
        self.on_reset = on_reset
        self.session = Session.DEFAULT
        self.dtcs: dict[int, int] = {}
        self.log: list[Exchange] = []
        self._s3: Any = None
        self.channel = IsoTpChannel(
            node, request_id, response_id, self._on_request, extended=extended, stmin_ms=stmin_ms, block_size=block_size
        )
        self._services: Mapping[int, Callable[[bytes], bytes | None]] = {
            0x10: self._session_control,
            0x11: self._ecu_reset,
            0x14: self._clear_dtcs,
            0x19: self._read_dtcs,
            0x22: self._read_did,
            0x2E: self._write_did,
            0x3E: self._tester_present,
        }

    # ------------------------------------------------------------------ application side
    def add_did(self, did: DataIdentifier) -> None:
        """Serve one more data identifier (0x0000..0xFFFF, each once)."""
        if not 0 <= did.did <= 0xFFFF:
            raise ValueError(f"DID {did.did:#x}: a data identifier is 16 bits (0x0000..0xFFFF)")
        if did.did in self.dids:
            raise ValueError(f"DID {did.did:#06x} is already {self.dids[did.did].name}")
        self.dids[did.did] = did

    def set_dtc(self, code: int, status: int = 0x09) -> None:
        """Record a diagnostic trouble code (24 bits) with its status byte (default: testFailed
        and confirmedDTC)."""
        if not 0 <= code <= 0xFFFFFF:
            raise ValueError(f"DTC {code:#x}: a DTC is 24 bits (0x000000..0xFFFFFF)")
        self.dtcs[code] = status & 0xFF

    # ------------------------------------------------------------------ protocol side
    def _on_request(self, request: bytes) -> None:
        response = self.respond(request)
        self.log.append(Exchange(self.node.now(), request, response))
        if response is not None:
            self.channel.send(response)
        if request[:1] == b"\x11" and response is not None and response[0] == 0x51:
            self.session = Session.DEFAULT
            if self.on_reset is not None:
                self.on_reset(response[1])

    def respond(self, request: bytes) -> bytes | None:
        """The response to one request (None when the positive response is suppressed)."""
        if not request:
            return None
        sid = request[0]
        service = self._services.get(sid)
        if service is None:
            return bytes((0x7F, sid, NRC.SERVICE_NOT_SUPPORTED))
        self._restart_s3()
        try:
            return service(request)
        except _Negative as neg:
            return bytes((0x7F, sid, neg.nrc))

    def _restart_s3(self) -> None:
        if self._s3 is not None:
            self._s3.cancel()
            self._s3 = None
        if self.session != Session.DEFAULT:
            self._s3 = self.node.call_later(S3_MS * 1_000_000, self._s3_expired)

    def _s3_expired(self) -> None:
        self._s3 = None
        self.session = Session.DEFAULT

    @staticmethod
    def _subfunction(request: bytes, length: int) -> tuple[int, bool]:
        if len(request) != length:
            raise _Negative(NRC.INCORRECT_LENGTH)
        return request[1] & 0x7F, bool(request[1] & 0x80)

    def _session_control(self, request: bytes) -> bytes | None:
        sub, suppress = self._subfunction(request, 2)
        if sub not in (Session.DEFAULT, Session.PROGRAMMING, Session.EXTENDED):
            raise _Negative(NRC.SUBFUNCTION_NOT_SUPPORTED)
        self.session = sub
        self._restart_s3()
        if suppress:
            return None
        return bytes((0x50, sub)) + P2_MS.to_bytes(2, "big") + (P2_STAR_MS // 10).to_bytes(2, "big")

    def _ecu_reset(self, request: bytes) -> bytes | None:
        sub, suppress = self._subfunction(request, 2)
        if sub not in (1, 2, 3):
            raise _Negative(NRC.SUBFUNCTION_NOT_SUPPORTED)
        return None if suppress else bytes((0x51, sub))

    def _tester_present(self, request: bytes) -> bytes | None:
        sub, suppress = self._subfunction(request, 2)
        if sub != 0:
            raise _Negative(NRC.SUBFUNCTION_NOT_SUPPORTED)
        return None if suppress else b"\x7e\x00"

    def _read_did(self, request: bytes) -> bytes:
        ids = request[1:]
        if not ids or len(ids) % 2:
            raise _Negative(NRC.INCORRECT_LENGTH)
        out = bytearray(b"\x62")
        for i in range(0, len(ids), 2):
            did = int.from_bytes(ids[i : i + 2], "big")
            d = self.dids.get(did)
            if d is None:
                raise _Negative(NRC.REQUEST_OUT_OF_RANGE)
            out += ids[i : i + 2] + bytes(d.read())
        if len(out) > 4095:
            raise _Negative(NRC.INCORRECT_LENGTH)  # the response would not fit an ISO-TP PDU
        return bytes(out)

    def _write_did(self, request: bytes) -> bytes:
        if len(request) < 4:
            raise _Negative(NRC.INCORRECT_LENGTH)
        did = int.from_bytes(request[1:3], "big")
        d = self.dids.get(did)
        if d is None or d.write is None:
            raise _Negative(NRC.REQUEST_OUT_OF_RANGE)
        data = request[3:]
        if d.length is not None and len(data) != d.length:
            raise _Negative(NRC.INCORRECT_LENGTH)
        if self.session == Session.DEFAULT:
            raise _Negative(NRC.SERVICE_NOT_SUPPORTED_IN_SESSION)
        try:
            d.write(bytes(data))
        except ValueError:
            raise _Negative(NRC.REQUEST_OUT_OF_RANGE) from None
        return b"\x6e" + request[1:3]

    def _clear_dtcs(self, request: bytes) -> bytes:
        if len(request) != 4:
            raise _Negative(NRC.INCORRECT_LENGTH)
        group = int.from_bytes(request[1:4], "big")
        if group == 0xFFFFFF:
            self.dtcs.clear()
        elif group in self.dtcs:
            del self.dtcs[group]
        else:
            raise _Negative(NRC.REQUEST_OUT_OF_RANGE)
        return b"\x54"

    def _read_dtcs(self, request: bytes) -> bytes | None:
        if len(request) < 2:
            raise _Negative(NRC.INCORRECT_LENGTH)
        sub, suppress = request[1] & 0x7F, bool(request[1] & 0x80)
        if sub in (0x01, 0x02):
            if len(request) != 3:
                raise _Negative(NRC.INCORRECT_LENGTH)
            mask = request[2]
            hits = sorted((c, s) for c, s in self.dtcs.items() if s & mask & DTC_STATUS_AVAILABILITY)
            if sub == 0x01:
                body = bytes((0x59, 0x01, DTC_STATUS_AVAILABILITY, DTC_FORMAT_ISO14229_1)) + len(hits).to_bytes(
                    2, "big"
                )
            else:
                body = bytes((0x59, 0x02, DTC_STATUS_AVAILABILITY)) + b"".join(
                    c.to_bytes(3, "big") + bytes((s & DTC_STATUS_AVAILABILITY,)) for c, s in hits
                )
        elif sub == 0x0A:
            if len(request) != 2:
                raise _Negative(NRC.INCORRECT_LENGTH)
            body = bytes((0x59, 0x0A, DTC_STATUS_AVAILABILITY)) + b"".join(
                c.to_bytes(3, "big") + bytes((s & DTC_STATUS_AVAILABILITY,)) for c, s in sorted(self.dtcs.items())
            )
        else:
            raise _Negative(NRC.SUBFUNCTION_NOT_SUPPORTED)
        return None if suppress else body

    def close(self) -> None:
        """Stop answering."""
        self.channel.close()
        if self._s3 is not None:
            self._s3.cancel()
            self._s3 = None
