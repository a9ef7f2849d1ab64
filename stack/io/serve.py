"""`canstack serve`: one simulated bus in real time shared by several processes.

The server runs a `SimBus` paced to the wall clock (`stack.io.runner.RealTimeRunner`) and accepts
clients over TCP (loopback only unless ``--allow-remote``) or a unix socket. Each client is a
node with its own controller on that bus; arbitration, ACK and timing are done by the server, so
ECU prototypes in several processes contend as on a real bus. A client joins with
``can.Bus(interface="canstack", channel="tcp://127.0.0.1:PORT/bus0")`` or
``channel="unix:///path/to/socket/bus0"``.

Protocol (binary, length-prefixed): every message is ``uint32 length (big endian) | uint8 type |
payload`` where length counts the type byte and the payload (at most `MAX_MESSAGE`).

=====  =========  =====================================================================
type   direction  payload
=====  =========  =====================================================================
0x01   c -> s     HELLO: JSON {"v": 1, "bus", "bitrate" | null, "node_name" | null,
                  "receive_own_messages", "config": {queue, mailboxes, abort,
                  tx_queue_size, listen_only, one_shot}}; must be the first message
0x02   s -> c     WELCOME: JSON {"bitrate", "node", "t0_epoch"}
0x03   s -> c     ERROR: UTF-8 text (the server closes after an error in HELLO or framing)
0x10   c -> s     SEND: uint32 can_id, uint8 flags (1 extended, 2 remote), uint8 dlc, data
0x11   s -> c     RX: uint64 t_ns (since t0), uint32 can_id, uint8 flags (4: own frame), dlc, data
0x12   s -> c     TXEND: uint8 ok, UTF-8 reason (one per SEND, in completion order)
0x13   s -> c     STATE: uint8 state (0 active, 1 warning, 2 passive, 3 bus off), uint16 tec, rec
0x14   c -> s     FILTERS: JSON list of python-can filters, or null
0x15   c -> s     BYE
=====  =========  =====================================================================

Robustness: a malformed message is answered with ERROR (or TXEND not ok for a bad SEND) and
logged; framing errors and a missing HELLO close that connection only. A client that dies leaves
the bus (its node goes off the wire); the others keep every frame, exactly once, in order.
A client that stops reading is disconnected once `MAX_BACKLOG` messages wait for it.
"""

from __future__ import annotations

import ipaddress
import json
import logging
import os
import queue
import socket
import struct
import threading
import time
from typing import Any

import can

from stack.controller.events import Received, TxDone, TxFailed
from stack.controller.filters import validate_filters
from stack.wire.frame import Frame
from stack.controller.node import ErrorState, Node, NodeError, QueueFull

__all__ = ["BusServer", "RemotePort", "MAX_MESSAGE", "MAX_BACKLOG",
           "encode_message", "PROTOCOL_VERSION"]

LOG = logging.getLogger("stack.io.serve")

PROTOCOL_VERSION = 1
MAX_MESSAGE = 4096
MAX_BACKLOG = 200_000
HELLO_TIMEOUT_S = 5.0

HELLO, WELCOME, ERROR = 0x01, 0x02, 0x03
SEND, RX, TXEND, STATE, FILTERS, BYE = 0x10, 0x11, 0x12, 0x13, 0x14, 0x15

F_EXT, F_RTR, F_OWN = 1, 2, 4
_STATES = [ErrorState.ACTIVE, ErrorState.WARNING, ErrorState.PASSIVE, ErrorState.BUS_OFF]
_STATE_INDEX = {s: i for i, s in enumerate(_STATES)}
_HDR = struct.Struct("!IB")
_SEND = struct.Struct("!IBB")
_RX = struct.Struct("!QIBB")
_STATE = struct.Struct("!BHH")
_NODE_KEYS = {"queue": str, "mailboxes": (int, type(None)), "abort": bool, "tx_queue_size": int,
              "listen_only": bool, "one_shot": bool}


def encode_message(mtype: int, payload: bytes = b"") -> bytes:
    """One protocol message: length, type, payload."""
    return _HDR.pack(len(payload) + 1, mtype) + payload


def _json_msg(mtype: int, obj: Any) -> bytes:
    return encode_message(mtype, json.dumps(obj).encode())


def _frame_payload(frame: Frame) -> bytes:
    return _SEND.pack(frame.can_id, (F_EXT if frame.extended else 0) | (F_RTR if frame.remote else 0),
                      frame.dlc) + frame.data


class _Reader:
    """Splits a byte stream into (type, payload) messages; `ValueError` on a framing error."""

    def __init__(self) -> None:
        self.buf = bytearray()

    def feed(self, data: bytes) -> list[tuple[int, bytes]]:
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
            out.append((mtype, bytes(buf[pos + 5:pos + 4 + length])))
            pos += 4 + length
        if pos:
            del buf[:pos]
        return out


# ---------------------------------------------------------------------------------- server
class _Session:
    """One connected client: its node on the bus, a reader thread and a writer thread."""

    def __init__(self, server: "BusServer", sock: socket.socket, peer: str) -> None:
        self.server = server
        self.sock = sock
        self.peer = peer
        self.node: Node | None = None
        self.own = False
        self.out: queue.SimpleQueue[bytes | None] = queue.SimpleQueue()
        self.closed = threading.Event()
        self._last_state: tuple[int, int, int] | None = None
        self._credit: set[Any] = set()
        self.rejected = 0
        threading.Thread(target=self._read_loop, name=f"serve-rd-{peer}", daemon=True).start()
        threading.Thread(target=self._write_loop, name=f"serve-wr-{peer}", daemon=True).start()

    # -- output -------------------------------------------------------------------------
    def push(self, data: bytes) -> None:
        if self.closed.is_set():
            return
        if self.out.qsize() > MAX_BACKLOG:
            LOG.warning("client %s does not read (%d messages waiting): disconnected", self.peer, MAX_BACKLOG)
            self.close()
            return
        self.out.put(data)

    def _write_loop(self) -> None:
        out = self.out
        try:
            while True:
                item = out.get()
                if item is None:
                    break
                chunks = [item]
                size = len(item)
                while size < 65536:
                    try:
                        nxt = out.get_nowait()
                    except queue.Empty:
                        break
                    if nxt is None:
                        self.sock.sendall(b"".join(chunks))
                        return
                    chunks.append(nxt)
                    size += len(nxt)
                self.sock.sendall(b"".join(chunks))
        except OSError:
            pass
        finally:
            self.close()
            try:
                self.sock.close()
            except OSError:
                pass

    # -- runner-thread callbacks ----------------------------------------------------------
    def _on_rx(self, ev: Received) -> None:
        f = ev.frame
        self.push(encode_message(RX, _RX.pack(ev.time, f.can_id, (F_EXT if f.extended else 0)
                                              | (F_RTR if f.remote else 0), f.dlc) + f.data))

    def _on_txdone(self, ev: TxDone) -> None:
        if self.own and self.node is not None and self.node.acceptance.accepts(ev.frame):
            f = ev.frame
            self.push(encode_message(RX, _RX.pack(ev.time, f.can_id, (F_EXT if f.extended else 0)
                                                  | (F_RTR if f.remote else 0) | F_OWN, f.dlc) + f.data))
        if ev.request in self._credit:
            self._credit.discard(ev.request)
            self.push(encode_message(TXEND, b"\x01"))

    def _on_txfailed(self, ev: TxFailed) -> None:
        if ev.request in self._credit:
            self._credit.discard(ev.request)
            self.push(encode_message(TXEND, b"\x00" + ev.reason.encode()))

    def _mirror_state(self) -> None:
        n = self.node
        if n is None:
            return
        st = (_STATE_INDEX.get(n.state, 0), min(n.tec, 65535), min(n.rec, 65535))
        if st != self._last_state:
            self._last_state = st
            self.push(encode_message(STATE, _STATE.pack(*st)))

    def _closed_by_runner(self, reason: str) -> None:
        self.push(encode_message(ERROR, reason.encode()))
        self.close()

    # -- input ----------------------------------------------------------------------------
    def _reject(self, reason: str, fatal: bool = False) -> None:
        self.rejected += 1
        self.server.rejected += 1
        LOG.warning("client %s: %s%s", self.peer, reason, " (disconnected)" if fatal else "")
        self.push(encode_message(ERROR, reason.encode()[:MAX_MESSAGE - 1]))
        if fatal:
            self.out.put(None)
            self.closed.set()

    def _read_loop(self) -> None:
        reader = _Reader()
        sock = self.sock
        try:
            sock.settimeout(HELLO_TIMEOUT_S)
            while not self.closed.is_set():
                try:
                    data = sock.recv(65536)
                except socket.timeout:
                    if self.node is None:
                        self._reject(f"no HELLO within {HELLO_TIMEOUT_S} s", fatal=True)
                        return
                    continue
                if not data:
                    return
                try:
                    msgs = reader.feed(data)
                except ValueError as exc:
                    self._reject(f"framing error: {exc}", fatal=True)
                    return
                for mtype, payload in msgs:
                    if self.node is None:
                        if mtype != HELLO:
                            self._reject(f"first message must be HELLO (0x01), got type 0x{mtype:02X}", fatal=True)
                            return
                        if not self._hello(payload):
                            return
                        sock.settimeout(None)
                        continue
                    self._handle(mtype, payload)
        except OSError:
            pass
        except Exception:  # never let a client take the server down
            LOG.exception("client %s: unexpected failure; disconnected", self.peer)
        finally:
            self.close()

    def _hello(self, payload: bytes) -> bool:
        try:
            hello = json.loads(payload.decode())
            if not isinstance(hello, dict):
                raise ValueError("HELLO must be a JSON object")
            if hello.get("v") != PROTOCOL_VERSION:
                raise ValueError(f"protocol version {hello.get('v')!r} not supported (server speaks {PROTOCOL_VERSION})")
            if hello.get("bus") != self.server.name:
                raise ValueError(f"this server serves bus {self.server.name!r}, not {hello.get('bus')!r}")
            br = hello.get("bitrate")
            if br is not None and br != self.server.bitrate:
                raise ValueError(f"bus {self.server.name!r} runs at {self.server.bitrate} bit/s; a node cannot "
                                 f"join it at {br!r} bit/s")
            name = hello.get("node_name")
            if name is not None and (not isinstance(name, str) or not 0 < len(name) <= 64):
                raise ValueError("node_name must be a string of 1..64 characters")
            config = hello.get("config") or {}
            if not isinstance(config, dict):
                raise ValueError("config must be a JSON object")
            for k, v in config.items():
                if k not in _NODE_KEYS:
                    raise ValueError(f"unknown node option {k!r}")
                if not isinstance(v, _NODE_KEYS[k]) or (isinstance(v, bool) and _NODE_KEYS[k] is int):
                    raise ValueError(f"node option {k}={v!r} has the wrong type")
            if not 1 <= config.get("tx_queue_size", 1024) <= 65536:
                raise ValueError("tx_queue_size must be 1..65536")
            if not 1 <= (config.get("mailboxes") or 1) <= 64:
                raise ValueError("mailboxes must be 1..64")
            self.own = bool(hello.get("receive_own_messages", False))
            node = self.server.runner.call(lambda: self.server._attach(self, name, config))
        except RecursionError:
            self._reject("HELLO refused: JSON nested too deeply", fatal=True)
            return False
        except (ValueError, TypeError, UnicodeDecodeError, can.CanError) as exc:
            self._reject(f"HELLO refused: {exc}", fatal=True)
            return False
        self.push(_json_msg(WELCOME, {"bitrate": self.server.bitrate, "node": node.name,
                                      "t0_epoch": self.server.runner.epoch0}))
        return True

    def _handle(self, mtype: int, payload: bytes) -> None:
        if mtype == SEND:
            try:
                if len(payload) < _SEND.size:
                    raise ValueError(f"SEND payload of {len(payload)} bytes is too short")
                can_id, flags, dlc = _SEND.unpack_from(payload)
                data = payload[_SEND.size:]
                frame = Frame(can_id, data, extended=bool(flags & F_EXT), remote=bool(flags & F_RTR), dlc=dlc)
                frame.bits  # noqa: B018 - stuffed on this thread, not the runner's
            except (ValueError, TypeError) as exc:
                self.rejected += 1
                self.server.rejected += 1
                LOG.warning("client %s: SEND rejected: %s", self.peer, exc)
                self.push(encode_message(TXEND, b"\x00" + f"rejected: {exc}".encode()[:512]))
                return
            self.server.runner.post(lambda: self._send(frame))
        elif mtype == FILTERS:
            try:
                filters = json.loads(payload.decode())
                validate_filters(filters)
            except (ValueError, UnicodeDecodeError) as exc:
                self._reject(f"FILTERS rejected: {exc}")
                return
            except RecursionError:
                self._reject("FILTERS rejected: JSON nested too deeply")
                return
            node = self.node
            self.server.runner.post(lambda: node.set_filters(filters or None))
        elif mtype == BYE:
            self.close()
        else:
            self._reject(f"unknown message type 0x{mtype:02X} ignored")

    def _send(self, frame: Frame) -> None:
        node = self.node
        if node is None or self.closed.is_set():
            return
        try:
            req = node.send(frame)
        except (QueueFull, NodeError) as exc:
            self.push(encode_message(TXEND, b"\x00" + str(exc).encode()))
            return
        if req.state == "queued":
            self._credit.add(req)
        else:
            self.push(encode_message(TXEND, b"\x01" if req.state == "sent" else b"\x00" + req.reason.encode()))

    def close(self) -> None:
        """Leave the bus and close the connection (idempotent)."""
        if getattr(self, "_closing", False):
            return
        self._closing = True
        self.closed.set()
        self.out.put(None)
        self.server._detach(self)


def _claim_unix_path(path: str) -> None:
    """Make ``path`` free for a new unix socket: a stale socket (nobody listening) is removed;
    anything else — a regular file, a directory, a socket a running server listens on — is an
    error, never deleted."""
    import stat

    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if not stat.S_ISSOCK(st.st_mode):
        raise ValueError(f"unix socket path {path!r} exists and is not a socket: not replacing it")
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        probe.settimeout(0.5)
        probe.connect(path)
    except OSError:
        os.unlink(path)  # stale: left by a server that did not close
        return
    finally:
        probe.close()
    raise ValueError(f"unix socket path {path!r} is in use by a running server")


class BusServer:
    """A simulated bus in real time served to python-can clients over TCP or a unix socket.

    ``listen`` is ``(host, port)`` (port 0 picks a free one); non-loopback hosts are refused
    unless ``allow_remote``. ``unix`` is a socket path. `url` is the channel clients use.
    """

    def __init__(self, bitrate: int = 500_000, *, name: str = "bus0", listen: tuple[str, int] | None = None,
                 unix: str | None = None, allow_remote: bool = False) -> None:
        from stack.io.runner import BUS_NAME_RE, RealTimeRunner

        if not BUS_NAME_RE.match(name):
            raise ValueError(f"bus name {name!r}: use 1..64 of A-Z a-z 0-9 _ . -")
        if (listen is None) == (unix is None):
            raise ValueError("give exactly one of a TCP listen address and a unix socket path")
        if listen is not None:
            host, port = listen
            if not allow_remote and not _is_loopback(host):
                raise ValueError(f"listen address {host!r} is not loopback: the simulated bus has no "
                                 "authentication; pass --allow-remote to serve other machines")
            fam = socket.AF_INET6 if ":" in host else socket.AF_INET
            self.sock = socket.socket(fam, socket.SOCK_STREAM)
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self.sock.bind((host, port))
            h, p = self.sock.getsockname()[:2]
            self.url = f"tcp://{'[' + h + ']' if ':' in h else h}:{p}/{name}"
            self.address: Any = (h, p)
        else:
            if not hasattr(socket, "AF_UNIX"):
                raise ValueError("unix sockets are not available on this system")
            if not os.path.isabs(unix):
                raise ValueError(f"unix socket path {unix!r} must be absolute")
            _claim_unix_path(unix)
            self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            self.sock.bind(unix)
            self._socket_ino = os.stat(unix).st_ino  # close() removes only its own socket
            self.url = f"unix://{unix}/{name}"
            self.address = unix
        self.sock.listen(64)
        self.sock.settimeout(0.2)
        self.name = name
        self.runner = RealTimeRunner(name, bitrate)
        self.bitrate = bitrate
        self.sessions: set[_Session] = set()
        self.rejected = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._accept_loop, name=f"serve-{name}", daemon=True)
        self._thread.start()

    @property
    def sim(self) -> Any:
        """The served `SimBus` (read it only from the runner thread, e.g. via ``runner.call``)."""
        return self.runner.sim

    def _accept_loop(self) -> None:
        while not self._stop.is_set():
            try:
                conn, addr = self.sock.accept()
            except socket.timeout:
                continue
            except OSError:
                break
            if conn.family != getattr(socket, "AF_UNIX", None):
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            peer = f"{addr[0]}:{addr[1]}" if isinstance(addr, tuple) else f"unix#{len(self.sessions)}"
            with self._lock:
                self.sessions.add(_Session(self, conn, peer))

    def _attach(self, session: _Session, name: str | None, config: dict[str, Any]) -> Node:
        sim = self.runner.sim
        if name is None:
            name = sim.free_name("client")
        elif name in {n.name for n in sim.nodes}:
            raise ValueError(f"a node named {name!r} is already on bus {self.name!r}")
        node = sim.node(name, receive_own_messages=False, rx_fifo_size=1, **config)
        session.node = node
        node.subscribe(session._on_rx)
        node.listen(TxDone, session._on_txdone)
        node.listen(TxFailed, session._on_txfailed)
        self.runner._ports.append(session)
        return node

    def _detach(self, session: _Session) -> None:
        def leave() -> None:
            node = session.node
            if session in self.runner._ports:
                self.runner._ports.remove(session)
            if node is not None and node.connected:
                for req in node.pending():
                    node.abort(req)
                self.runner.sim.disconnect(node)
        self.runner.post(leave)
        with self._lock:
            self.sessions.discard(session)
        try:
            session.sock.shutdown(socket.SHUT_RD)
        except OSError:
            pass

    def close(self) -> None:
        """Disconnect every client and stop serving."""
        self._stop.set()
        self._thread.join(2.0)
        with self._lock:
            sessions = list(self.sessions)
        for s in sessions:
            s.close()
            try:
                s.sock.close()
            except OSError:
                pass
        self.sock.close()
        if isinstance(self.address, str):
            try:
                if os.stat(self.address).st_ino == self._socket_ino:
                    os.unlink(self.address)
            except OSError:
                pass
        self.runner.stop()
        self.runner.join(2.0)

    def __enter__(self) -> "BusServer":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


# ---------------------------------------------------------------------------------- client
class RemotePort:
    """A `CanstackBus`'s connection to a `canstack serve` bus (client side of the protocol)."""

    native_periodic = False

    def __init__(self, owner: Any, kind: str, addr: Any, name: str, bitrate: int | None,
                 node_name: str | None, config: dict[str, Any]) -> None:
        self.owner = owner
        config = {k: v for k, v in config.items() if k in _NODE_KEYS}
        try:
            if kind == "tcp":
                self.sock = socket.create_connection(addr, timeout=5.0)
                self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            else:
                self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
                self.sock.settimeout(5.0)
                self.sock.connect(addr)
        except OSError as exc:
            raise can.CanInitializationError(f"cannot reach canstack server at {owner.channel if hasattr(owner, 'channel') else addr}: {exc}") from None
        self._wlock = threading.Lock()
        self._reader = _Reader()
        self._pending: list[tuple[int, bytes]] = []
        self._closing = False
        try:
            self._write(_json_msg(HELLO, {"v": PROTOCOL_VERSION, "bus": name, "bitrate": bitrate,
                                          "node_name": node_name, "config": config,
                                          "receive_own_messages": bool(owner.receive_own_messages)}))
            welcome = self._await_welcome()
        except (OSError, ValueError) as exc:
            self.sock.close()
            raise can.CanInitializationError(f"canstack server: {exc}") from None
        self.bitrate = int(welcome["bitrate"])
        self.node_name = str(welcome["node"])
        self.epoch0 = float(welcome["t0_epoch"])
        self.sock.settimeout(None)
        self._thread = threading.Thread(target=self._read_loop, name="canstack-client", daemon=True)
        self._thread.start()

    def _write(self, data: bytes) -> None:
        with self._wlock:
            self.sock.sendall(data)

    def _await_welcome(self) -> dict[str, Any]:
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:
            data = self.sock.recv(65536)
            if not data:
                raise ValueError("the server closed the connection")
            for mtype, payload in self._reader.feed(data):
                if mtype not in (WELCOME, ERROR):
                    self._pending.append((mtype, payload))
                elif mtype == ERROR:
                    raise ValueError(payload.decode(errors="replace"))
                else:
                    return json.loads(payload.decode())
        raise ValueError("no answer to HELLO within 5 s")

    def _read_loop(self) -> None:
        owner = self.owner
        deliver = owner._deliver
        cache: dict[bytes, Frame] = {}
        reason = "the server closed the connection"
        try:
            msgs = self._pending
            while True:
                for mtype, payload in msgs:
                    if mtype == RX:
                        key = payload[8:]
                        f = cache.get(key)
                        if f is None:
                            can_id, flags, dlc = _SEND.unpack_from(key)
                            f = Frame(can_id, key[_SEND.size:], extended=bool(flags & F_EXT),
                                      remote=bool(flags & F_RTR), dlc=dlc)
                            if len(cache) > 4096:
                                cache.clear()
                            cache[key] = f
                        deliver(int.from_bytes(payload[:8], "big"), f, not (key[4] & F_OWN))
                    elif mtype == TXEND:
                        owner._tx_finished(None if payload[:1] == b"\x01" else payload[1:].decode(errors="replace"))
                    elif mtype == STATE:
                        st, tec, rec = _STATE.unpack(payload)
                        owner._set_state(_STATES[st], tec, rec)
                    elif mtype == ERROR:
                        LOG.warning("canstack server: %s", payload.decode(errors="replace"))
                data = self.sock.recv(262144)
                if not data:
                    break
                msgs = self._reader.feed(data)
        except (OSError, ValueError) as exc:
            reason = f"connection lost: {exc}"
        if not self._closing:
            owner._port_lost(reason)

    def send(self, frame: Frame) -> None:
        """Send a frame to the server's node queue."""
        try:
            self._write(encode_message(SEND, _frame_payload(frame)))
        except OSError as exc:
            self.owner._tx_finished(str(exc))
            raise can.CanOperationError(f"canstack server connection lost: {exc}") from None

    def set_filters(self, filters: Any) -> None:
        """Set the node's acceptance filters on the server."""
        try:
            self._write(_json_msg(FILTERS, filters))
        except OSError as exc:
            raise can.CanOperationError(f"canstack server connection lost: {exc}") from None

    def close(self) -> None:
        """Say BYE and close the connection."""
        self._closing = True
        try:
            self._write(encode_message(BYE))
            self.sock.shutdown(socket.SHUT_WR)
        except OSError:
            pass
        self._thread.join(2.0)
        self.sock.close()
