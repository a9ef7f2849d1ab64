"""Checks of one poll-list entry, or of one node's own keys, that need nothing else of the
scenario: which keys an entry of each style takes, a request's payload, its timeout and retries,
a COS/cyclic connection's expected packet rates, a slave's fragmented I/O message and the
duplicate MAC ID check's identity. `profiles.polling.parse` applies them while it reads the
network; every error names the place it is given (``loc``: file, table and key) on one line."""

from __future__ import annotations

import zlib
from typing import TYPE_CHECKING, Any

from profiles.declarations import MessageDecl, ms_to_ns
from profiles.polling.config import POLL_KEYS, STYLES, WATCHDOG_EPRS
from profiles.polling.fragment import MAX_IO_SIZE, fragment
from profiles.schema import ScenarioError

if TYPE_CHECKING:  # pragma: no cover
    from profiles.declarations import NodeDecl

__all__ = [
    "STYLE_KEYS",
    "WHY_NOT",
    "check_entry_keys",
    "io_message",
    "dup_mac",
    "request_payload",
    "timing",
    "eprs",
]

# keys that mean something only for some styles (the others refuse them)
STYLE_KEYS = {
    "polled": {"slave", "name", "dlc", "data", "id", "extended", "response_id", "timeout_ms", "retries"},
    "remote": {"slave", "name", "extended", "response_id", "timeout_ms", "retries"},
    "bit_strobe": {"slaves", "name", "dlc", "data", "id", "extended", "response_ids", "timeout_ms"},
    "cos": {"slave", "name", "extended", "ack", "ack_id", "epr_ms"},
}
WHY_NOT = {
    ("bit_strobe", "retries"): "a bit-strobe command is a broadcast: repeating it makes every strobed slave answer "
    "again; a missed strobe response waits for the next cycle",
    ("remote", "dlc"): "a remote frame's DLC is the DLC of the data frame it asks for (the slave's response)",
    ("remote", "data"): "a remote frame carries no data",
    ("remote", "id"): "a remote frame has the identifier of the data frame it asks for (give response_id)",
    ("cos", "timeout_ms"): "the master does not poll a cos slave; it consumes what the slave produces",
    ("cos", "retries"): "the master does not poll a cos slave; it consumes what the slave produces",
}


def _err(loc: str, text: str) -> ScenarioError:
    return ScenarioError(f"{loc}: {text}")


def check_entry_keys(raw: dict[str, Any], style: str, loc: str) -> None:
    """A key of `POLL_KEYS` given on an entry of a style that does not take it (`STYLE_KEYS`) is
    refused, with the reason (`WHY_NOT`) or the styles that have it."""
    for k in POLL_KEYS:
        if k != "style" and k in raw and k not in STYLE_KEYS[style]:
            having = ", ".join(sorted(s for s in STYLES if k in STYLE_KEYS[s]))
            why = WHY_NOT.get((style, k), f"only {having} entries have it")
            raise _err(loc, f"{k}: not a key of a {style} entry ({why})")


def io_message(m: MessageDecl, loc: str) -> None:
    """A slave's message of ``size`` above 8 bytes goes in DeviceNet fragments: its frames are 8
    bytes long (dlc 8) and its I/O data (``io_data``, zeros by default) is stored in
    ``m.options['io_data']``; a COS/cyclic message is not fragmented here."""
    size, io = m.options.get("size"), m.options.get("io_data")
    if size is None:
        if io is not None:
            raise _err(loc, "io_data: only a message of size above 8 bytes (size = ...) has I/O data of its own")
        m.options.pop("io_data", None)
        return
    if m.interval_ns is not None:
        raise _err(loc, f"size: {size}: canstack fragments polled I/O only (a COS/cyclic message is one frame)")
    if m.dlc != 8:
        raise _err(loc, f"dlc: {m.dlc}: the fragments of a {size}-byte message are 8-byte frames (dlc = 8)")
    if io is None:
        data = bytes(size)
    else:
        try:
            data = bytes.fromhex(io)
        except ValueError:
            raise _err(loc, f"io_data: {io!r} is not hex bytes") from None
        if len(data) != size:
            raise _err(loc, f"io_data: {len(data)} bytes given for size {size}")
    m.options["io_data"] = data
    m.data = fragment(data)[0]


def dup_mac(d: NodeDecl, loc: str) -> tuple[int, int] | None:
    """(vendor ID, serial number) when the node runs the duplicate MAC ID check; the default
    serial number is the CRC-32 of the node's name, so that two nodes differ."""
    o = d.options
    if not o["dup_mac_check"]:
        for k, unset in (("vendor_id", 0), ("serial_number", None)):
            if o[k] != unset:
                raise _err(loc, f"{k}: only the duplicate MAC ID check sends it (dup_mac_check = true)")
        return None
    if o["mac_id"] is None:
        raise _err(loc, "dup_mac_check: the duplicate MAC ID check needs the node's mac_id")
    serial = o["serial_number"] if o["serial_number"] is not None else zlib.crc32(d.name.encode())
    return o["vendor_id"], serial


def request_payload(
    e: dict[str, Any], loc: str, default: bytes, *, fragmented: bool = False
) -> tuple[int, bytes, bytes | None]:
    """(DLC, data of the frame, the whole I/O message when it is fragmented) of a request."""
    data = default
    if e["data"] is not None:
        try:
            data = bytes.fromhex(e["data"])
        except ValueError:
            raise _err(loc, f"data: {e['data']!r} is not hex bytes") from None
        if len(data) > 8 and not fragmented:
            raise _err(loc, f"data: {len(data)} bytes: a CAN 2.0 frame carries at most 8")
        if len(data) > MAX_IO_SIZE:
            raise _err(loc, f"data: {len(data)} bytes: canstack takes I/O of at most {MAX_IO_SIZE} bytes")
        if len(data) > 8:
            if e["dlc"] is not None:
                raise _err(
                    loc,
                    f"dlc: {len(data)} bytes of data go in DeviceNet fragments of 8-byte frames: leave dlc out",
                )
            return 8, fragment(data)[0], data
    if e["dlc"] is not None:
        if e["data"] is not None and len(data) != e["dlc"]:
            raise _err(loc, f"data: {len(data)} byte{'s' if len(data) != 1 else ''} given for dlc {e['dlc']}")
        if e["data"] is None:
            data = (default + bytes(8))[: e["dlc"]]
    return len(data), data, None


def timing(e: dict[str, Any], d: NodeDecl, loc: str, style: str) -> tuple[int, int]:
    """(response timeout in ns, retries) of an entry: its own, else its master's default; a
    bit-strobe command is never repeated (a broadcast makes every strobed slave answer again)."""
    timeout = e["timeout_ms"] if e["timeout_ms"] is not None else d.options["timeout_ms"]
    if timeout is None:
        raise _err(loc, "key 'timeout_ms' is required (on the entry, or on the master for every entry)")
    retries = 0 if style == "bit_strobe" else (e["retries"] if e["retries"] is not None else d.options["retries"])
    return ms_to_ns(timeout), retries


def eprs(timed: list[MessageDecl], e: dict[str, Any], loc: str) -> dict[str, int]:
    """Each message's expected packet rate: a cyclic message's period (``epr_ms``, when
    given, must be it), a change-of-state message's ``epr_ms`` (required; its heartbeat, no
    faster than its production inhibit time ``sporadic_ms``)."""
    given = None if e["epr_ms"] is None else ms_to_ns(e["epr_ms"])
    out: dict[str, int] = {}
    for m in timed:
        if m.period_ns is not None:
            if given is not None and given != m.period_ns:
                raise _err(
                    loc,
                    f"epr_ms: {e['epr_ms']:g} is not the period of the cyclic message {m.name!r} "
                    f"({m.period_ns / 1e6:g} ms): a cyclic connection's expected packet rate is its period "
                    "(leave epr_ms out)",
                )
            out[m.name] = m.period_ns
            continue
        pit = m.sporadic_ns or 0
        if given is None:
            raise _err(
                loc,
                f"key 'epr_ms' is required for the change-of-state message {m.name!r}: the connection's "
                "expected packet rate, at which the slave sends its data when nothing changes (the "
                f"heartbeat; the watchdogs are {WATCHDOG_EPRS} x it), at least its sporadic_ms "
                f"{pit / 1e6:g} (the production inhibit time)",
            )
        if given < pit:
            raise _err(
                loc,
                f"epr_ms: {e['epr_ms']:g} is below the production inhibit time of {m.name!r} (its "
                f"sporadic_ms {pit / 1e6:g}): the heartbeat cannot come sooner than new data may",
            )
        out[m.name] = given
    return out
