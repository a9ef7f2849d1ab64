"""Diagnostics of a DBC ECU: a `UdsServer` whose data identifiers are the ECU's signals.

`attach_uds(ecu, request_id, response_id)` puts a UDS server on the ECU's node with:

- 0xF186 ActiveDiagnosticSessionDataIdentifier (1 byte, ISO 14229-1 C.1), read-only;
- 0xF190 VINDataIdentifier (17 ASCII characters), read-only;
- one DID per signal the ECU transmits, numbered from ``first_did`` (default 0x1000) in the
  order of the DBC's messages and signals: the signal's raw value, big-endian, in as many bytes
  as its bits need (two's complement for a signed signal; IEEE 754 for a float signal). Reading
  gives the current value; writing (in a non-default session) sets it through `Ecu.set`, so the
  DBC's range applies (out of range: NRC 0x31) and the interaction layer sends it as for any
  write.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable
from typing import Any

from .uds import DataIdentifier, UdsServer

__all__ = ["attach_uds", "signal_dids", "DID_ACTIVE_SESSION", "DID_VIN", "DEFAULT_VIN"]

DID_ACTIVE_SESSION = 0xF186
DID_VIN = 0xF190
DEFAULT_VIN = "CANSTACK000000001"


def _signal_bytes(sig: Any) -> int:
    return (sig.length + 7) // 8


def _to_raw(sig: Any, value: Any) -> int | float:
    conv = sig.conversion
    if isinstance(value, str):
        return int(conv.choice_to_number(value))
    num = getattr(value, "value", value)  # a NamedSignalValue
    raw = conv.scaled_to_raw(num)
    return float(raw) if sig.is_float else round(raw)


def _encode(sig: Any, raw: int | float) -> bytes:
    n = _signal_bytes(sig)
    if sig.is_float:
        return struct.pack(">d" if sig.length == 64 else ">f", float(raw))
    mask = (1 << (8 * n)) - 1
    return (int(raw) & mask).to_bytes(n, "big")


def _decode(sig: Any, data: bytes) -> int | float:
    if sig.is_float:
        return float(struct.unpack(">d" if sig.length == 64 else ">f", data)[0])
    raw = int.from_bytes(data, "big")
    if sig.is_signed and raw >= 1 << (8 * len(data) - 1):
        raw -= 1 << (8 * len(data))
    return raw


def signal_dids(ecu: Any, first_did: int = 0x1000) -> list[DataIdentifier]:
    """One `DataIdentifier` per signal ``ecu`` transmits, from ``first_did`` on (see the module
    docstring for the encoding)."""
    out: list[DataIdentifier] = []
    did = first_did
    for message in ecu.tx_messages:
        for sig in ecu.db.get_message_by_name(message).signals:
            out.append(_signal_did(ecu, message, sig, did))
            did += 1
    return out


def _signal_did(ecu: Any, message: str, sig: Any, did: int) -> DataIdentifier:
    def read() -> bytes:
        return _encode(sig, _to_raw(sig, ecu.get(sig.name, message=message)))

    def write(data: bytes) -> None:
        value = sig.conversion.raw_to_scaled(_decode(sig, data), False)
        ecu.set(sig.name, value, message=message)  # SignalRangeError is a ValueError: NRC 0x31

    return DataIdentifier(did, f"{message}.{sig.name}", read, write, _signal_bytes(sig) if not sig.is_float else None)


def attach_uds(
    ecu: Any,
    request_id: int,
    response_id: int,
    *,
    vin: str = DEFAULT_VIN,
    first_did: int = 0x1000,
    dids: Iterable[DataIdentifier] = (),
    **server: Any,
) -> UdsServer:
    """A `UdsServer` on ``ecu``'s node answering on ``request_id``/``response_id``, with the
    session and VIN DIDs, a DID per transmitted signal, and ``dids`` of the application;
    ``server`` goes to `UdsServer` (``on_reset``, ``stmin_ms``, ``block_size``, ``extended``)."""
    text = vin.encode("ascii")
    if len(text) != 17:
        raise ValueError(f"VIN {vin!r}: a VIN has 17 characters (ISO 3779), not {len(text)}")
    srv = UdsServer(ecu.node, request_id, response_id, **server)
    srv.add_did(DataIdentifier(DID_ACTIVE_SESSION, "ActiveDiagnosticSession", lambda: bytes((srv.session,))))
    srv.add_did(DataIdentifier(DID_VIN, "VIN", lambda: text))
    for d in signal_dids(ecu, first_did):
        srv.add_did(d)
    for d in dids:
        srv.add_did(d)
    return srv
