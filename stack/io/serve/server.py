"""The server side of `canstack serve`: `BusServer` accepts clients, one `_Session` per client.

A session is the socket half of a client only: it reads and checks protocol messages
(`stack.io.serve.protocol`) and writes the answers; the client's node, its credits, its error
state and its leaving the bus are a `stack.io.port.Port`, the same class the in-process
interface uses.

Robustness: a malformed message is answered with ERROR (or TXEND not ok for a bad SEND) and
logged; framing errors and a missing HELLO close that connection only. A client that dies leaves
the bus (its node is removed and its name is free again); the others keep every frame, exactly
once, in order. A client that stops reading is disconnected once `MAX_BACKLOG` messages wait
for it. Clients joining and leaving are logged at INFO with the name they give (program and
pid), their node name and peer.

The server keeps accepting whatever ``accept()`` or a new thread does: out of file descriptors
(EMFILE) or threads, it logs once, backs off and tries again, and a connection it cannot serve is
closed at once. At most `MAX_UNJOINED` connections may wait for their HELLO (each for at most
`HELLO_TIMEOUT_S`); more are refused with an ERROR. A bus that cannot keep up with real time
still answers joins (`stack.io.runner.SLICE_NS`), says in WELCOME how far behind it is, and logs
it once per episode.
"""

from __future__ import annotations

import errno
import ipaddress
import logging
import os
import queue
import socket
import struct
import threading
from itertools import count
from typing import Any

import can

from stack.controller.confinement import ErrorState
from stack.io.discovery import Announcement
from stack.io.port import Port, check_filters
from stack.io.runner import BUS_NAME_RE, RealTimeRunner
from stack.io.serve import protocol as P
from stack.wire.frame import Frame

__all__ = ["BusServer", "MAX_BACKLOG", "HELLO_TIMEOUT_S", "MAX_UNJOINED", "BEHIND_WARN_NS"]

LOG = logging.getLogger("stack.io.serve")

MAX_BACKLOG = 200_000
HELLO_TIMEOUT_S = 5.0
MAX_UNJOINED = 64
BEHIND_WARN_NS = 500_000_000  # a bus this far behind real time is logged (once per episode)
_ACCEPT_BACKOFF_S = (0.05, 1.0)  # first and longest wait after accept() failed
_unix_peers = count(1)


class _Session:
    """One connected client: a reader thread, a writer thread and, once joined, its `Port`."""

    def __init__(self, server: BusServer, sock: socket.socket, peer: str) -> None:
        self.server = server
        self.sock = sock
        self.peer = peer
        self.port: Port | None = None
        self.out: queue.SimpleQueue[bytes | None] = queue.SimpleQueue()
        self.closed = threading.Event()
        self._closing = False
        self._close_lock = threading.Lock()
        self.rejected = 0
        self.client = ""  # the name the client gives (program[pid])
        self.fd = False  # the client joined as a CAN FD node

    @property
    def who(self) -> str:
        """The client as the log names it: its own name and its peer."""
        return f"{self.client} from {self.peer}" if self.client else self.peer

    def start(self) -> None:
        """Start reading and writing (after the server registered the session, so that a client
        that leaves at once is also removed from it). RuntimeError when a thread cannot start
        (the caller closes the session)."""
        threading.Thread(target=self._write_loop, name=f"serve-wr-{self.peer}", daemon=True).start()
        threading.Thread(target=self._read_loop, name=f"serve-rd-{self.peer}", daemon=True).start()

    @property
    def node_name(self) -> str | None:
        """The client's node on the bus (None before it joined)."""
        return self.port.node_name if self.port is not None else None

    # -- output -------------------------------------------------------------------------
    def push(self, data: bytes) -> None:
        """Queue ``data`` for the client (dropped once closed; a client that does not read is
        disconnected at `MAX_BACKLOG` waiting messages)."""
        if self.closed.is_set():
            return
        if self.out.qsize() > MAX_BACKLOG:
            LOG.warning("client %s does not read (%d messages waiting): disconnected", self.who, MAX_BACKLOG)
            self.close(f"did not read ({MAX_BACKLOG} messages waiting)")
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
                while size < 65536:  # one sendall for what is waiting: fewer system calls
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
        except OSError as exc:
            self.close(f"connection error: {exc}")
        finally:
            self.close("connection closed")
            try:
                # shut down before closing: a reader thread blocked in recv on this socket is
                # woken (closing the descriptor alone leaves it blocked, and the connection
                # open: the client would never hear that the server is gone)
                self.sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            try:
                self.sock.close()
            except OSError:
                pass

    # -- PortOwner: the runner thread reports here ----------------------------------------
    def deliver(self, t_ns: int, frame: Frame, is_rx: bool) -> None:
        """A frame for the client (RX)."""
        self.push(P.encode_rx(t_ns, frame, not is_rx))

    def tx_finished(self, error: str | None) -> None:
        """One SEND done (TXEND)."""
        self.push(P.encode_txend(error))

    def tx_error(self, t_ns: int, reason: str, tec: int, rec: int) -> None:
        """A one-shot transmission failed (TXERROR)."""
        self.push(P.encode_tx_error(t_ns, reason, tec, rec))

    def set_state(self, state: ErrorState, tec: int, rec: int) -> None:
        """The node's error state changed (STATE)."""
        self.push(P.encode_state(state, tec, rec))

    def lost(self, reason: str) -> None:
        """The bus stopped: tell the client and close."""
        self.push(P.encode_message(P.ERROR, reason.encode()))
        self.close(f"bus stopped: {reason}")

    # -- input ----------------------------------------------------------------------------
    def _reject(self, reason: str, fatal: bool = False) -> None:
        self.rejected += 1
        self.server.rejected += 1
        LOG.warning("client %s: %s%s", self.who, reason, " (disconnected)" if fatal else "")
        self.push(P.encode_message(P.ERROR, reason.encode()[: P.MAX_MESSAGE - 1]))
        if fatal:
            self.out.put(None)
            self.closed.set()

    def _read_loop(self) -> None:
        reader = P.Reader()
        sock = self.sock
        reason = "closed the connection"
        try:
            sock.settimeout(HELLO_TIMEOUT_S)
            while not self.closed.is_set():
                try:
                    data = sock.recv(65536)
                except TimeoutError:
                    if self.port is None:
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
                    if self.port is None:
                        if mtype != P.HELLO:
                            self._reject(f"first message must be HELLO (0x01), got type 0x{mtype:02X}", fatal=True)
                            return
                        if not self._hello(payload):
                            return
                        sock.settimeout(None)
                        continue
                    self._handle(mtype, payload)
        except OSError as exc:
            reason = f"connection error: {exc}"
        except Exception:  # never let a client take the server down
            LOG.exception("client %s: unexpected failure; disconnected", self.who)
            reason = "server-side failure (see log)"
        finally:
            self.close(reason)

    def _hello(self, payload: bytes) -> bool:
        srv = self.server
        try:
            hello = P.parse_hello(payload, srv.name, srv.bitrate)
            self.client = hello.client
            srv.check_fd(hello)
            self.fd = hello.fd
            self.port = Port(
                srv.runner,
                self,
                node_name=hello.node_name,
                prefix="client",
                config=hello.config,
                receive_own_messages=hello.receive_own_messages,
            )
        except (ValueError, TypeError, can.CanError) as exc:
            self._reject(f"HELLO refused: {exc}", fatal=True)
            return False
        if self._closing:  # the server closed while the node was attached: leave again
            self.port.close(wait=False)
            return False
        behind = srv.runner.behind_ns
        LOG.info(
            "client %s joined bus %r as node %r%s",
            self.who,
            srv.name,
            self.port.node_name,
            f" (the bus is {behind / 1e9:.3f} s behind real time)" if behind >= BEHIND_WARN_NS else "",
        )
        self.push(
            P.encode_welcome(
                srv.bitrate,
                self.port.node_name,
                srv.runner.epoch0,
                behind_ms=behind / 1e6,
                fd=srv.fd,
                data_bitrate=srv.data_bitrate,
            )
        )
        return True

    def _handle(self, mtype: int, payload: bytes) -> None:
        port = self.port
        assert port is not None
        if mtype == P.SEND:
            try:
                frame = P.decode_send(payload)
                frame.bits  # noqa: B018 - stuffed on this thread, not the runner's
            except ValueError as exc:
                self.rejected += 1
                self.server.rejected += 1
                LOG.warning("client %s: SEND rejected: %s", self.who, exc)
                self.push(P.encode_txend(f"rejected: {exc}"[:512]))
                return
            if frame.fd and not self.fd:
                self.rejected += 1
                self.server.rejected += 1
                self.push(P.encode_txend("rejected: a CAN FD frame from a client that joined without fd=True"))
                return
            port.send(frame)
        elif mtype == P.TIME:
            try:
                token = P.decode_time(payload)
            except ValueError as exc:
                self._reject(f"TIME rejected: {exc}")
                return
            runner = self.server.runner
            # answered on the runner thread, with the bus time at which it handles it: the
            # client's lower bound of the offset (`stack.io.clock`) holds for frames queued there
            runner.post(lambda: self.push(P.encode_now(token, runner.sim.now(), runner.behind_ns)))
        elif mtype == P.FILTERS:
            try:
                filters = check_filters(P.parse_filters(payload))
            except ValueError as exc:
                self._reject(f"FILTERS rejected: {exc}")
                return
            port.set_filters(filters, wait=False)
        elif mtype == P.MODE:
            try:
                listen_only = P.decode_mode(payload)
            except ValueError as exc:
                self._reject(f"MODE rejected: {exc}")
                return
            port.set_listen_only(listen_only, wait=False)
        elif mtype == P.BYE:
            self.close("said BYE")
        else:
            self._reject(f"unknown message type 0x{mtype:02X} ignored")

    def close(self, reason: str = "closed") -> None:
        """Leave the bus and close the connection (idempotent); logs the client leaving."""
        with self._close_lock:
            if self._closing:
                return
            self._closing = True
        self.closed.set()
        self.out.put(None)
        if self.port is not None:
            LOG.info("client %s (node %r) left bus %r: %s", self.who, self.port.node_name, self.server.name, reason)
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


def _bind_error(exc: OSError, where: str, tcp: bool) -> ValueError:
    """A bind failure as one line naming the address or path and what to do."""
    if exc.errno == errno.EADDRINUSE:
        hint = (
            (
                "another server (perhaps another canstack serve) listens there: stop it, or pick another port "
                "(--listen HOST:0 picks a free one)"
            )
            if tcp
            else "another server uses it"
        )
        return ValueError(f"{where} is already in use: {hint}")
    if exc.errno == errno.ENOENT:
        return ValueError(
            f"{where}: the directory {os.path.dirname(where)!r} does not exist; create it or choose another path"
        )
    if exc.errno in (errno.EACCES, errno.EPERM):
        what = (
            "ports below 1024 need privileges; choose a port above 1023"
            if tcp
            else "choose a path in a directory you may write"
        )
        return ValueError(f"{where}: permission denied ({what})")
    if exc.errno == errno.EADDRNOTAVAIL:
        return ValueError(f"{where}: that address belongs to no interface of this machine")
    return ValueError(f"cannot listen on {where}: {exc.strerror or exc}")


def _peer_name(conn: socket.socket, addr: Any) -> str:
    if isinstance(addr, tuple):
        return f"{addr[0]}:{addr[1]}"
    # a unix socket's peer has no address: name it by its process where the system tells
    peercred = getattr(socket, "SO_PEERCRED", None)
    if peercred is not None:
        try:
            pid, _, _ = struct.unpack("3i", conn.getsockopt(socket.SOL_SOCKET, peercred, struct.calcsize("3i")))
            return f"unix(pid {pid})#{next(_unix_peers)}"
        except OSError:
            pass
    return f"unix#{next(_unix_peers)}"


class BusServer:
    """A simulated bus in real time served to python-can clients over TCP or a unix socket.

    ``listen`` is ``(host, port)`` (port 0 picks a free one); non-loopback hosts are refused
    unless ``allow_remote``. ``data_bitrate`` makes it a CAN FD bus (clients join with
    ``fd=True``; others see no FD frames). ``unix`` is a socket path. `url` is the channel clients use. A
    server announces itself on this machine (`stack.io.discovery`) while it runs. ValueError
    names the address or path when it cannot listen there (in use, missing directory, ...).
    """

    def __init__(
        self,
        bitrate: int = 500_000,
        *,
        name: str = "bus0",
        listen: tuple[str, int] | None = None,
        unix: str | None = None,
        allow_remote: bool = False,
        data_bitrate: int | None = None,
    ) -> None:
        if not BUS_NAME_RE.match(name):
            raise ValueError(f"bus name {name!r}: use 1..64 of A-Z a-z 0-9 _ . -")
        if (listen is None) == (unix is None):
            raise ValueError("give exactly one of a TCP listen address and a unix socket path")
        if listen is not None:
            self.sock, self.address, self.url = self._bind_tcp(listen, name, allow_remote)
        else:
            assert unix is not None
            self.sock, self.address, self.url = self._bind_unix(unix, name)
        self.sock.listen(64)
        self.sock.settimeout(0.2)
        self.name = name
        try:
            self.runner = RealTimeRunner(name, bitrate, data_bitrate)
        except ValueError:  # no CAN FD in this engine: nothing is left listening
            self.sock.close()
            if unix is not None:
                os.unlink(unix)
            raise
        self.bitrate = bitrate
        self.fd = data_bitrate is not None  # a CAN FD bus: its clients may join with fd=True
        self.data_bitrate = data_bitrate
        self._refusing: str | None = None
        self._behind_logged = False
        self.sessions: set[_Session] = set()
        self.rejected = 0
        self._lock = threading.Lock()
        self._changed = threading.Condition(self._lock)  # notified when a session comes or goes
        self._stop = threading.Event()
        self._announcement = Announcement(name, self.url)
        self._thread = threading.Thread(target=self._accept_loop, name=f"serve-{name}", daemon=True)
        self._thread.start()

    @staticmethod
    def _bind_tcp(listen: tuple[str, int], name: str, allow_remote: bool) -> tuple[socket.socket, Any, str]:
        host, port = listen
        if not allow_remote and not _is_loopback(host):
            raise ValueError(
                f"listen address {host!r} is not loopback: the simulated bus has no "
                "authentication; pass --allow-remote to serve other machines"
            )
        where = f"{'[' + host + ']' if ':' in host else host}:{port}"
        fam = socket.AF_INET6 if ":" in host else socket.AF_INET
        sock = socket.socket(fam, socket.SOCK_STREAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind((host, port))
        except socket.gaierror as exc:
            sock.close()
            raise ValueError(f"listen address {host!r}: unknown host ({exc.strerror})") from exc
        except OSError as exc:
            sock.close()
            raise _bind_error(exc, where, tcp=True) from exc
        h, p = sock.getsockname()[:2]
        return sock, (h, p), f"tcp://{'[' + h + ']' if ':' in h else h}:{p}/{name}"

    def _bind_unix(self, path: str, name: str) -> tuple[socket.socket, Any, str]:
        if not hasattr(socket, "AF_UNIX"):
            raise ValueError("unix sockets are not available on this system")
        if not os.path.isabs(path):
            raise ValueError(f"unix socket path {path!r} must be absolute")
        _claim_unix_path(path)
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            sock.bind(path)
        except OSError as exc:
            sock.close()
            raise _bind_error(exc, path, tcp=False) from exc
        self._socket_ino = os.stat(path).st_ino  # close() removes only its own socket
        return sock, path, f"unix://{path}/{name}"

    @property
    def sim(self) -> Any:
        """The served `SimBus` (read it only from the runner thread, e.g. via ``runner.call``)."""
        return self.runner.sim

    def check_fd(self, hello: P.Hello) -> None:
        """ValueError when a client asks for CAN FD that this bus does not carry, or for another
        data bit rate than the bus's."""
        if hello.fd and not self.fd:
            raise ValueError(
                f"bus {self.name!r} is served without a data bit rate: it carries no CAN FD frames (serve it with "
                "--data-bitrate, or open the bus without fd=True)"
            )
        if hello.fd and hello.data_bitrate is not None and hello.data_bitrate != self.data_bitrate:
            raise ValueError(
                f"bus {self.name!r} runs its data phase at {self.data_bitrate} bit/s; a node cannot join it at "
                f"{hello.data_bitrate} bit/s"
            )

    def _accept_loop(self) -> None:
        backoff = 0.0
        failing: str | None = None  # the failure logged last: each kind once per episode
        while not self._stop.is_set():
            self._watch_behind()
            try:
                conn, addr = self.sock.accept()
            except TimeoutError:
                continue
            except OSError as exc:
                if self._stop.is_set() or exc.errno in (errno.EBADF, errno.EINVAL):
                    break  # the listening socket was closed
                # out of file descriptors (EMFILE, ENFILE), memory, or a connection reset before
                # it was accepted: the server stays up and tries again
                what = f"accept() failed: {exc.strerror or exc}"
                if what != failing:
                    LOG.warning("bus %r: %s; retrying (clients are refused meanwhile)", self.name, what)
                    failing = what
                backoff = min(max(backoff * 2, _ACCEPT_BACKOFF_S[0]), _ACCEPT_BACKOFF_S[1])
                self._stop.wait(backoff)
                continue
            if failing is not None:
                LOG.info("bus %r: accepting clients again", self.name)
                failing, backoff = None, 0.0
            self._serve(conn, addr)

    def _serve(self, conn: socket.socket, addr: Any) -> None:
        """Start a session for an accepted connection, or refuse it cleanly (an ERROR, then
        close) when too many wait for their HELLO or no thread can be started for it."""
        try:
            if conn.family != getattr(socket, "AF_UNIX", None):
                conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            peer = _peer_name(conn, addr)
        except OSError:
            conn.close()
            return
        with self._lock:
            unjoined = sum(1 for s in self.sessions if s.port is None)
        if unjoined >= MAX_UNJOINED:
            self._refuse(conn, peer, f"too many connections waiting to join ({MAX_UNJOINED}): try again later")
            return
        session = _Session(self, conn, peer)
        with self._changed:
            self.sessions.add(session)
            self._changed.notify_all()
        try:
            session.start()
        except RuntimeError as exc:  # can't start new thread
            with self._changed:
                self.sessions.discard(session)
                self._changed.notify_all()
            session.closed.set()
            session.out.put(None)
            self._refuse(conn, peer, f"the server cannot start a thread for this client ({exc}): try again later")
            return
        self._refusing = None

    def _refuse(self, conn: socket.socket, peer: str, reason: str) -> None:
        """Tell a connection why it is refused and close it (logged once per reason and episode)."""
        if reason != self._refusing:
            LOG.warning("bus %r: client %s refused: %s", self.name, peer, reason)
            self._refusing = reason
        self.rejected += 1
        try:
            conn.settimeout(0.2)
            conn.sendall(P.encode_message(P.ERROR, reason.encode()))
        except OSError:
            pass
        finally:
            conn.close()

    def _watch_behind(self) -> None:
        """Log once when the bus falls behind real time and once when it caught up."""
        behind = self.runner.behind_ns
        if behind >= BEHIND_WARN_NS and not self._behind_logged:
            self._behind_logged = True
            LOG.warning(
                "bus %r is %.3f s behind real time: this machine cannot simulate its traffic as fast as it happens",
                self.name,
                behind / 1e9,
            )
        elif behind == 0 and self._behind_logged:
            self._behind_logged = False
            LOG.info("bus %r caught up with real time", self.name)

    def _detach(self, session: _Session) -> None:
        if session.port is not None:
            session.port.close(wait=False)  # the node leaves the bus; its name is free again
        with self._changed:
            self.sessions.discard(session)
            self._changed.notify_all()
        try:
            session.sock.shutdown(socket.SHUT_RD)
        except OSError:
            pass

    def wait_sessions(self, count: int, timeout: float | None = None) -> bool:
        """Wait until exactly ``count`` clients are connected; False if ``timeout`` seconds pass
        first. A session is registered when its connection is accepted, before the client can
        hear anything from the server (a client whose ``can.Bus`` is open is in `sessions`), and
        removed after its leaving is logged."""
        with self._changed:
            return self._changed.wait_for(lambda: len(self.sessions) == count, timeout)

    def close(self) -> None:
        """Disconnect every client and stop serving."""
        self._stop.set()
        self._thread.join(2.0)
        self._announcement.close()
        with self._lock:
            sessions = list(self.sessions)
        for s in sessions:
            s.close("server closing")
            try:  # the client hears it at once, even when its writer is stuck (the writer closes)
                s.sock.shutdown(socket.SHUT_RDWR)
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

    def __enter__(self) -> BusServer:
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
