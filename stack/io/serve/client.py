"""The client side of `canstack serve`: `RemotePort`, a `CanstackBus`'s connection to a served
bus. It speaks `stack.io.serve.protocol` and reports to its owner exactly as an in-process
`stack.io.port.Port` does (`stack.io.port.PortOwner`), so `CanstackBus` cannot tell them apart
except that periodic tasks run on python-can's threads (``native_periodic`` False).

Frames come stamped with the server's bus time. `RemotePort.timestamp` maps it onto this
process's clocks with the offset `stack.io.clock.ClockOffset` keeps from TIME requests: one at
join, then one every `CLOCK_REFRESH_S`. So a received message's ``timestamp`` is on the same
clock as ``time.time()`` here, never before the moment its frame was really on the bus.
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from collections.abc import Mapping
from typing import Any

import can

from stack.io.clock import BusClock
from stack.io.errors import BusLost
from stack.io.port import PortOwner
from stack.io.serve import protocol as P
from stack.wire.frame import Frame

__all__ = ["RemotePort", "CLOCK_REFRESH_S", "BEHIND_WARN_MS"]

LOG = logging.getLogger("stack.io.serve")

CLOCK_REFRESH_S = 1.0
BEHIND_WARN_MS = 500.0  # a served bus this far behind real time at join is worth a warning

_CLOCKS: dict[tuple[str, float], BusClock] = {}
_CLOCKS_LOCK = threading.Lock()


def _bus_clock(where: str, t0_epoch: float) -> BusClock:
    """The clock of the bus served at ``where`` that started at ``t0_epoch`` (one per process)."""
    with _CLOCKS_LOCK:
        clock = _CLOCKS.get((where, t0_epoch))
        if clock is None:
            if len(_CLOCKS) > 64:  # servers come and go: forget the old ones
                _CLOCKS.clear()
            clock = _CLOCKS[(where, t0_epoch)] = BusClock()
        return clock


class RemotePort:
    """The connection of ``owner`` to the bus ``name`` served at ``addr``: ``kind`` 'tcp' with
    ``(host, port)`` or 'unix' with a socket path. `can.CanInitializationError` names the
    channel when the server cannot be reached or refuses the HELLO (with its reason)."""

    native_periodic = False

    def __init__(
        self,
        owner: PortOwner,
        kind: str,
        addr: Any,
        name: str,
        bitrate: int | None,
        node_name: str | None,
        config: Mapping[str, Any],
        *,
        channel: str = "",
        receive_own_messages: bool = False,
        fd: bool = False,
        data_bitrate: int | None = None,
    ) -> None:
        self.owner = owner
        self.clock = BusClock()  # this connection's until WELCOME names the bus
        self.behind_ns = 0
        where = channel or str(addr)
        try:
            if kind == "tcp":
                self.sock = socket.create_connection(addr, timeout=5.0)
                self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            else:
                self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
                self.sock.settimeout(5.0)
                self.sock.connect(addr)
        except OSError as exc:
            what = (
                "nothing listens there"
                if isinstance(exc, (ConnectionRefusedError, FileNotFoundError))
                else (exc.strerror or str(exc))
            )
            raise can.CanInitializationError(
                f"cannot reach a canstack server at {where}: {what} (is `canstack serve` running there?)"
            ) from None
        self._wlock = threading.Lock()
        self._reader = P.Reader()
        self._pending: list[tuple[int, bytes]] = []
        self._closing = False
        try:
            self._write(
                P.encode_hello(
                    name, bitrate, node_name, dict(config), receive_own_messages, fd=fd, data_bitrate=data_bitrate
                )
            )
            welcome = P.parse_welcome(self._await(P.WELCOME))
            self.clock = _bus_clock(where, welcome.t0_epoch)
            self._ask_time()
            self._await(P.NOW)
        except (OSError, ValueError) as exc:
            self.sock.close()
            raise can.CanInitializationError(f"canstack server at {where}: {exc}") from None
        if fd and not welcome.fd:  # an older server that ignored the request
            self.sock.close()
            raise can.CanInitializationError(f"canstack server at {where}: its bus carries no CAN FD frames")
        self.bitrate, self.node_name, self.epoch0 = welcome.bitrate, welcome.node, welcome.t0_epoch
        self.fd, self.data_bitrate = welcome.fd, welcome.data_bitrate
        self.behind_ms = welcome.behind_ms
        if welcome.behind_ms >= BEHIND_WARN_MS:
            LOG.warning(
                "canstack server at %s: its bus is %.3f s behind real time (the server's machine is overloaded)",
                where,
                welcome.behind_ms / 1e3,
            )
        self.sock.settimeout(None)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read_loop, name="canstack-client", daemon=True)
        self._thread.start()
        self._clock_thread = threading.Thread(target=self._clock_loop, name="canstack-client-clock", daemon=True)
        self._clock_thread.start()

    def _write(self, data: bytes) -> None:
        with self._wlock:
            self.sock.sendall(data)

    def _await(self, wanted: int) -> bytes:
        """The payload of the next message of type ``wanted`` (WELCOME, NOW) during the join;
        what comes before it waits for the reader thread, a NOW is read on the way."""
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:
            data = self.sock.recv(65536)
            if not data:
                raise ValueError("the server closed the connection")
            found = None
            for mtype, payload in self._reader.feed(data):
                if mtype == P.ERROR:
                    raise ValueError(payload.decode(errors="replace"))
                if mtype == P.NOW:
                    self._now(payload)
                if mtype == wanted and found is None:
                    found = payload
                elif mtype != P.NOW:
                    self._pending.append((mtype, payload))
            if found is not None:
                return found
        raise ValueError(f"no answer within 5 s ({'HELLO' if wanted == P.WELCOME else 'TIME'})")

    def _ask_time(self) -> None:
        self._write(P.encode_time(time.monotonic_ns()))

    def _now(self, payload: bytes) -> None:
        """A NOW: one more sample of the bus clock's offset."""
        c1 = time.monotonic_ns()
        token, bus_ns, behind_ns = P.decode_now(payload)
        if token <= c1:
            self.clock.offset.sample(token, bus_ns, c1)
        self.behind_ns = behind_ns

    def _clock_loop(self) -> None:
        """Ask for the bus time every `CLOCK_REFRESH_S` while connected (the offset stays fresh)."""
        while not self._stop.wait(CLOCK_REFRESH_S):
            try:
                self._ask_time()
            except OSError:
                return

    def timestamp(self, t_ns: int) -> float:
        """The wall-clock time (s since the epoch, as ``time.time()`` here) of bus time ``t_ns``."""
        return self.clock.timestamp(t_ns)

    def _read_loop(self) -> None:
        owner = self.owner
        deliver = owner.deliver
        rx = P.RxDecoder().decode
        reason = "the server closed the connection"
        try:
            msgs = self._pending
            while True:
                for mtype, payload in msgs:
                    if mtype == P.RX:
                        deliver(*rx(payload))
                    elif mtype == P.TXEND:
                        owner.tx_finished(P.decode_txend(payload))
                    elif mtype == P.STATE:
                        owner.set_state(*P.decode_state(payload))
                    elif mtype == P.TXERROR:
                        owner.tx_error(*P.decode_tx_error(payload))
                    elif mtype == P.NOW:
                        self._now(payload)
                    elif mtype == P.ERROR:
                        LOG.warning("canstack server: %s", payload.decode(errors="replace"))
                    # other types: from a newer server, ignored
                data = self.sock.recv(262144)
                if not data:
                    break
                msgs = self._reader.feed(data)
        except (OSError, ValueError) as exc:
            reason = f"connection lost: {exc}"
        self._stop.set()
        if not self._closing:
            owner.lost(reason)

    def _send_message(self, data: bytes) -> None:
        try:
            self._write(data)
        except OSError as exc:
            raise BusLost(f"canstack server connection lost: {exc}", f"connection lost: {exc}") from None

    def send(self, frame: Frame) -> None:
        """Send a frame to the server's node queue (TXEND reports its end)."""
        try:
            self._write(P.encode_send(frame))
        except OSError as exc:
            self.owner.tx_finished(str(exc))
            raise BusLost(f"canstack server connection lost: {exc}", f"connection lost: {exc}") from None

    def set_filters(self, filters: list[Mapping[str, Any]] | None) -> None:
        """Set the node's acceptance filters on the server (checked before)."""
        self._send_message(P.json_message(P.FILTERS, filters))

    def set_listen_only(self, on: bool) -> None:
        """Switch the node to listen-only or back (see `stack.io.port.Port.set_listen_only`)."""
        self._send_message(P.encode_mode(on))

    def can_drain(self) -> bool:
        """Whether queued frames can still go out: the server decides; True while connected."""
        return not self._closing and self._thread.is_alive()

    def close(self) -> None:
        """Say BYE and close the connection."""
        self._closing = True
        self._stop.set()
        try:
            self._write(P.encode_message(P.BYE))
            self.sock.shutdown(socket.SHUT_WR)
        except OSError:
            pass
        self._thread.join(2.0)
        self.sock.close()
