"""The `canstack serve` wire protocol: message types, framing, encoding and decoding.

Pure: bytes in, values out (and back), no sockets, no threads, no clock. The server
(`stack.io.serve.server`) and the client (`stack.io.serve.client`) both speak through it.

Every message is ``uint32 length (big endian) | uint8 type | payload``; length counts the type
byte and the payload (at most `MAX_MESSAGE`).

=====  =========  =====================================================================
type   direction  payload
=====  =========  =====================================================================
0x01   c -> s     HELLO: JSON {"v": 2, "bus", "bitrate" | null, "node_name" | null,
                  "receive_own_messages", "config": {queue, mailboxes, abort,
                  tx_queue_size, listen_only, one_shot}, "client": "program[pid]",
                  "fd": bool, "data_bitrate" | null}; must be the first message
0x02   s -> c     WELCOME: JSON {"bitrate", "node", "t0_epoch", "behind_ms", "fd",
                  "data_bitrate"}
0x03   s -> c     ERROR: UTF-8 text (the server closes after an error in HELLO or framing)
0x10   c -> s     SEND: uint32 can_id, uint8 flags, uint8 dlc, data
0x11   s -> c     RX: uint64 t_ns (since t0), uint32 can_id, uint8 flags, uint8 dlc, data
0x12   s -> c     TXEND: uint8 ok, UTF-8 reason (one per SEND, in completion order)
0x13   s -> c     STATE: uint8 state (0 active, 1 warning, 2 passive, 3 bus off), uint16 tec, rec
0x14   c -> s     FILTERS: JSON list of python-can filters, or null
0x15   c -> s     BYE
0x16   s -> c     TXERROR: uint64 t_ns, uint16 tec, uint16 rec, UTF-8 reason: a transmission
                  failed (one-shot), sent before its TXEND; the client shows it as an error frame
0x17   c -> s     MODE: uint8 flags (1: listen-only): switch the node's mode at run time
0x18   c -> s     TIME: uint64 token: what time is it on the bus?
0x19   s -> c     NOW: uint64 token, uint64 bus t_ns when the bus handled TIME, uint64 ns
                  the bus is behind real time (`stack.io.clock.ClockOffset` reads it)
=====  =========  =====================================================================

Frame flags (SEND, RX): 1 extended, 2 remote, 4 the client's own frame (RX only), 8 CAN FD,
16 bit rate switch, 32 error state indicator. An FD frame's dlc is its DLC code (0..15).

Version 2 added the client's name, CAN FD (flags, HELLO's ``fd`` and ``data_bitrate``), TIME/NOW
and WELCOME's ``behind_ms``. A server refuses a HELLO of another version with an ERROR naming
both versions, so an old client learns that it must be upgraded (and a new client meeting an
old server shows that server's answer). A client ignores message types it does not know.
"""

from __future__ import annotations

import json
import struct
from typing import Any, NamedTuple

from stack.controller.confinement import ErrorState
from stack.wire.frame import Frame

__all__ = [
    "PROTOCOL_VERSION",
    "MAX_MESSAGE",
    "HELLO",
    "WELCOME",
    "ERROR",
    "SEND",
    "RX",
    "TXEND",
    "STATE",
    "FILTERS",
    "BYE",
    "TXERROR",
    "MODE",
    "TIME",
    "NOW",
    "F_EXT",
    "F_RTR",
    "F_OWN",
    "F_FD",
    "F_BRS",
    "F_ESI",
    "NODE_KEYS",
    "encode_message",
    "json_message",
    "Reader",
    "Hello",
    "Welcome",
    "encode_hello",
    "parse_hello",
    "encode_welcome",
    "parse_welcome",
    "encode_send",
    "decode_send",
    "encode_rx",
    "RxDecoder",
    "encode_txend",
    "decode_txend",
    "encode_state",
    "decode_state",
    "encode_tx_error",
    "decode_tx_error",
    "encode_mode",
    "decode_mode",
    "encode_time",
    "decode_time",
    "encode_now",
    "decode_now",
    "client_name",
    "parse_filters",
]

PROTOCOL_VERSION = 2
MAX_MESSAGE = 4096

HELLO, WELCOME, ERROR = 0x01, 0x02, 0x03
SEND, RX, TXEND, STATE, FILTERS, BYE, TXERROR, MODE = 0x10, 0x11, 0x12, 0x13, 0x14, 0x15, 0x16, 0x17
TIME, NOW = 0x18, 0x19

F_EXT, F_RTR, F_OWN, F_FD, F_BRS, F_ESI = 1, 2, 4, 8, 16, 32
_F_FRAME = F_EXT | F_RTR | F_OWN | F_FD | F_BRS | F_ESI
M_LISTEN_ONLY = 1

_STATES = [ErrorState.ACTIVE, ErrorState.WARNING, ErrorState.PASSIVE, ErrorState.BUS_OFF]
_STATE_INDEX = {s: i for i, s in enumerate(_STATES)}
_HDR = struct.Struct("!IB")
_SEND = struct.Struct("!IBB")
_RX = struct.Struct("!QIBB")
_STATE = struct.Struct("!BHH")
_TXERROR = struct.Struct("!QHH")
_TIME = struct.Struct("!Q")
_NOW = struct.Struct("!QQQ")

NODE_KEYS: dict[str, Any] = {
    "queue": str,
    "mailboxes": (int, type(None)),
    "abort": bool,
    "tx_queue_size": int,
    "listen_only": bool,
    "one_shot": bool,
}
"""The node options HELLO may carry, with their JSON types."""


def encode_message(mtype: int, payload: bytes = b"") -> bytes:
    """One protocol message: length, type, payload."""
    return _HDR.pack(len(payload) + 1, mtype) + payload


def json_message(mtype: int, obj: Any) -> bytes:
    """A message whose payload is ``obj`` as JSON."""
    return encode_message(mtype, json.dumps(obj).encode())


class Reader:
    """Splits a byte stream into (type, payload) messages; `ValueError` on a framing error."""

    def __init__(self) -> None:
        self.buf = bytearray()

    def feed(self, data: bytes) -> list[tuple[int, bytes]]:
        """Add ``data``; return the messages now complete, in order."""
        buf = self.buf
        buf += data
        out = []
        pos = 0
        n = len(buf)
        while n - pos >= 5:
            length, mtype = _HDR.unpack_from(buf, pos)
            if length < 1 or length > MAX_MESSAGE:
                raise ValueError(f"message length {length} outside 1..{MAX_MESSAGE}")
            if n - pos < 4 + length:
                break
            out.append((mtype, bytes(buf[pos + 5 : pos + 4 + length])))
            pos += 4 + length
        if pos:
            del buf[:pos]
        return out


def _json(payload: bytes) -> Any:
    try:
        return json.loads(payload.decode())
    except RecursionError:
        raise ValueError("JSON nested too deeply") from None
    except (ValueError, UnicodeDecodeError) as exc:
        raise ValueError(f"not JSON ({exc})") from None


# ---------------------------------------------------------------------------------- joining
class Hello(NamedTuple):
    """What a client asks for when it joins."""

    bus: str
    bitrate: int | None
    node_name: str | None
    config: dict[str, Any]
    receive_own_messages: bool
    client: str = ""
    fd: bool = False
    data_bitrate: int | None = None


def client_name() -> str:
    """This process as a server's log names it: its program and pid, e.g. ``candump[4242]``."""
    import os
    import sys

    argv = list(getattr(sys, "orig_argv", None) or sys.argv or ["python"])
    prog = os.path.basename(argv[0]) or "python"
    if "-m" in argv[1:-1]:  # python -m module: the module says more than the interpreter
        prog = argv[argv.index("-m", 1) + 1]
    elif prog.startswith("python") and len(argv) > 1 and argv[1].endswith(".py"):
        prog = os.path.basename(argv[1])
    return f"{''.join(c for c in prog if c.isprintable())[:48]}[{os.getpid()}]"


def encode_hello(
    bus: str,
    bitrate: int | None,
    node_name: str | None,
    config: dict[str, Any],
    receive_own_messages: bool,
    *,
    client: str | None = None,
    fd: bool = False,
    data_bitrate: int | None = None,
) -> bytes:
    """The HELLO message a client starts with (``config`` keeps only `NODE_KEYS`; ``client``
    defaults to `client_name`)."""
    return json_message(
        HELLO,
        {
            "v": PROTOCOL_VERSION,
            "bus": bus,
            "bitrate": bitrate,
            "node_name": node_name,
            "config": {k: v for k, v in config.items() if k in NODE_KEYS},
            "receive_own_messages": bool(receive_own_messages),
            "client": client_name() if client is None else client,
            "fd": bool(fd),
            "data_bitrate": data_bitrate,
        },
    )


def parse_hello(payload: bytes, bus: str, bitrate: int) -> Hello:
    """A HELLO payload checked against the served ``bus`` and ``bitrate``: ValueError names the
    field and the rule it breaks (version, bus name, bitrate, node name, client name, option
    types/ranges). FD and the data bit rate are read here and checked by the server."""
    hello = _json(payload)
    if not isinstance(hello, dict):
        raise ValueError("HELLO must be a JSON object")
    v = hello.get("v")
    if v != PROTOCOL_VERSION:
        if isinstance(v, int) and not isinstance(v, bool) and v < PROTOCOL_VERSION:
            raise ValueError(
                f"the client speaks canstack serve protocol {v}, this server speaks {PROTOCOL_VERSION}: "
                "upgrade canstack on the client (pip install -U canstack)"
            )
        raise ValueError(f"protocol version {v!r} not supported (server speaks {PROTOCOL_VERSION})")
    if hello.get("bus") != bus:
        raise ValueError(f"this server serves bus {bus!r}, not {hello.get('bus')!r}")
    br = hello.get("bitrate")
    if br is not None and br != bitrate:
        raise ValueError(f"bus {bus!r} runs at {bitrate} bit/s; a node cannot join it at {br!r} bit/s")
    name = hello.get("node_name")
    if name is not None and (not isinstance(name, str) or not 0 < len(name) <= 64):
        raise ValueError("node_name must be a string of 1..64 characters")
    client = hello.get("client", "")
    if not isinstance(client, str) or len(client) > 64 or not client.isprintable():
        raise ValueError("client must be a printable string of at most 64 characters (program[pid])")
    fd = hello.get("fd", False)
    if not isinstance(fd, bool):
        raise ValueError(f"fd {fd!r} must be true or false")
    dbr = hello.get("data_bitrate")
    if dbr is not None and (isinstance(dbr, bool) or not isinstance(dbr, int) or dbr <= 0):
        raise ValueError(f"data_bitrate {dbr!r} must be a positive integer (bit/s) or null")
    config = hello.get("config") or {}
    if not isinstance(config, dict):
        raise ValueError("config must be a JSON object")
    for k, val in config.items():
        if k not in NODE_KEYS:
            raise ValueError(f"unknown node option {k!r}")
        if not isinstance(val, NODE_KEYS[k]) or (isinstance(val, bool) and NODE_KEYS[k] is int):
            raise ValueError(f"node option {k}={val!r} has the wrong type")
    if not 1 <= config.get("tx_queue_size", 1024) <= 65536:
        raise ValueError("tx_queue_size must be 1..65536")
    if not 1 <= (config.get("mailboxes") or 1) <= 64:
        raise ValueError("mailboxes must be 1..64")
    return Hello(bus, br, name, config, bool(hello.get("receive_own_messages", False)), client, fd, dbr)


class Welcome(NamedTuple):
    """The server's answer to a good HELLO: the bus's bit rate(s), the node's name, the epoch
    (wall-clock s) of the bus's time 0, how far the bus is behind real time, whether it is FD."""

    bitrate: int
    node: str
    t0_epoch: float
    behind_ms: float = 0.0
    fd: bool = False
    data_bitrate: int | None = None


def encode_welcome(
    bitrate: int,
    node: str,
    t0_epoch: float,
    *,
    behind_ms: float = 0.0,
    fd: bool = False,
    data_bitrate: int | None = None,
) -> bytes:
    """The server's answer to a good HELLO."""
    return json_message(
        WELCOME,
        {
            "bitrate": bitrate,
            "node": node,
            "t0_epoch": t0_epoch,
            "behind_ms": round(behind_ms, 3),
            "fd": fd,
            "data_bitrate": data_bitrate,
        },
    )


def parse_welcome(payload: bytes) -> Welcome:
    """The `Welcome` of a WELCOME payload."""
    w = _json(payload)
    try:
        dbr = w.get("data_bitrate")
        return Welcome(
            int(w["bitrate"]),
            str(w["node"]),
            float(w["t0_epoch"]),
            float(w.get("behind_ms") or 0.0),
            bool(w.get("fd", False)),
            None if dbr is None else int(dbr),
        )
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ValueError(f"WELCOME malformed: {exc}") from None


# ---------------------------------------------------------------------------------- frames
def _flags(frame: Frame) -> int:
    f = (F_EXT if frame.extended else 0) | (F_RTR if frame.remote else 0)
    if frame.fd:
        f |= F_FD | (F_BRS if frame.brs else 0) | (F_ESI if frame.esi else 0)
    return f


def _frame(can_id: int, flags: int, dlc: int, data: bytes) -> Frame:
    if flags & ~_F_FRAME:
        raise ValueError(f"unknown frame flags 0x{flags & ~_F_FRAME:02X}")
    if flags & F_FD:
        return Frame(
            can_id,
            data,
            extended=bool(flags & F_EXT),
            remote=bool(flags & F_RTR),
            dlc=dlc,
            fd=True,
            brs=bool(flags & F_BRS),
            esi=bool(flags & F_ESI),
        )
    if flags & (F_BRS | F_ESI):
        raise ValueError("bit rate switch and error state indicator need the CAN FD flag")
    return Frame(can_id, data, extended=bool(flags & F_EXT), remote=bool(flags & F_RTR), dlc=dlc)


def encode_send(frame: Frame) -> bytes:
    """The SEND message of ``frame``."""
    return encode_message(SEND, _SEND.pack(frame.can_id, _flags(frame), frame.dlc) + frame.data)


def decode_send(payload: bytes) -> Frame:
    """The frame of a SEND payload; ValueError naming what is wrong (length, ID range, DLC,
    flags)."""
    if len(payload) < _SEND.size:
        raise ValueError(f"SEND payload of {len(payload)} bytes is too short")
    can_id, flags, dlc = _SEND.unpack_from(payload)
    if flags & F_OWN:
        raise ValueError("the own-frame flag (4) belongs to RX, not SEND")
    try:
        return _frame(can_id, flags, dlc, payload[_SEND.size :])
    except TypeError as exc:
        raise ValueError(str(exc)) from None


def encode_rx(t_ns: int, frame: Frame, own: bool) -> bytes:
    """The RX message of a frame received at ``t_ns`` (``own``: the client's own frame)."""
    return encode_message(
        RX, _RX.pack(t_ns, frame.can_id, _flags(frame) | (F_OWN if own else 0), frame.dlc) + frame.data
    )


class RxDecoder:
    """Decodes RX payloads to (t_ns, frame, is_rx); frames are cached by content, since a bus
    carries the same few frames again and again (building one costs far more than a dictionary
    hit)."""

    def __init__(self) -> None:
        self._cache: dict[bytes, Frame] = {}

    def decode(self, payload: bytes) -> tuple[int, Frame, bool]:
        """(t_ns, frame, is_rx) of an RX payload."""
        key = payload[8:]
        f = self._cache.get(key)
        if f is None:
            can_id, flags, dlc = _SEND.unpack_from(key)
            f = _frame(can_id, flags & ~F_OWN, dlc, key[_SEND.size :])
            if len(self._cache) > 4096:
                self._cache.clear()
            self._cache[key] = f
        return int.from_bytes(payload[:8], "big"), f, not (key[4] & F_OWN)


# ---------------------------------------------------------------------------------- status
def encode_txend(error: str | None) -> bytes:
    """TXEND: the frame was sent (None) or not, and why."""
    return encode_message(TXEND, b"\x01" if error is None else b"\x00" + error.encode()[: MAX_MESSAGE - 2])


def decode_txend(payload: bytes) -> str | None:
    """None for a sent frame, else the reason it was not."""
    return None if payload[:1] == b"\x01" else payload[1:].decode(errors="replace")


def encode_state(state: ErrorState, tec: int, rec: int) -> bytes:
    """STATE: the node's fault-confinement state and counters."""
    return encode_message(STATE, _STATE.pack(_STATE_INDEX.get(state, 0), min(tec, 65535), min(rec, 65535)))


def decode_state(payload: bytes) -> tuple[ErrorState, int, int]:
    """(state, tec, rec) of a STATE payload."""
    st, tec, rec = _STATE.unpack(payload)
    return _STATES[st], tec, rec


def encode_tx_error(t_ns: int, reason: str, tec: int, rec: int) -> bytes:
    """TXERROR: a transmission failed at ``t_ns`` (one-shot), with the counters after it."""
    return encode_message(
        TXERROR,
        _TXERROR.pack(t_ns, min(tec, 65535), min(rec, 65535)) + reason.encode()[: MAX_MESSAGE - 1 - _TXERROR.size],
    )


def decode_tx_error(payload: bytes) -> tuple[int, str, int, int]:
    """(t_ns, reason, tec, rec) of a TXERROR payload."""
    t_ns, tec, rec = _TXERROR.unpack_from(payload)
    return t_ns, payload[_TXERROR.size :].decode(errors="replace"), tec, rec


def encode_mode(listen_only: bool) -> bytes:
    """MODE: switch the node to listen-only or back."""
    return encode_message(MODE, bytes([M_LISTEN_ONLY if listen_only else 0]))


def decode_mode(payload: bytes) -> bool:
    """True for listen-only; ValueError for a payload that is not one flags byte."""
    if len(payload) != 1 or payload[0] & ~M_LISTEN_ONLY:
        raise ValueError(f"MODE payload {payload!r}: expected one byte, 0 (normal) or 1 (listen-only)")
    return bool(payload[0] & M_LISTEN_ONLY)


def encode_time(token: int) -> bytes:
    """TIME: ask the bus for its time (``token`` comes back in NOW; the client's clock)."""
    return encode_message(TIME, _TIME.pack(token))


def decode_time(payload: bytes) -> int:
    """The token of a TIME payload; ValueError for a payload that is not 8 bytes."""
    if len(payload) != _TIME.size:
        raise ValueError(f"TIME payload of {len(payload)} bytes: expected 8 (a token)")
    return int(_TIME.unpack(payload)[0])


def encode_now(token: int, t_ns: int, behind_ns: int) -> bytes:
    """NOW: the answer to TIME with the bus time when it was handled and how far behind real
    time the bus is."""
    return encode_message(NOW, _NOW.pack(token, max(0, t_ns), max(0, behind_ns)))


def decode_now(payload: bytes) -> tuple[int, int, int]:
    """(token, bus t_ns, behind ns) of a NOW payload."""
    token, t_ns, behind = _NOW.unpack(payload)
    return int(token), int(t_ns), int(behind)


def parse_filters(payload: bytes) -> Any:
    """The JSON value of a FILTERS payload (checked by `stack.io.port.check_filters` after)."""
    return _json(payload)
