"""The simulated bus as a python-can interface: ``can.Bus(interface="canstack", channel="bus0")``.

Each `CanstackBus` is a node with its own software controller on a shared `SimBus` named by the
channel. The `SimBus` runs in real time on one thread, the `RealTimeRunner`: virtual ns = wall ns
since the bus started, so a frame arrives after its real wire time, contending frames are
arbitrated bit by bit and acknowledged by the other nodes. All engine calls happen on the runner
thread (the engine is not thread-safe); `CanstackBus` instances post commands to it through a
deque and an event, and the runner hands received frames back through a queue per bus.

Channel forms:

- ``"bus0"`` — a bus in this process (created by the first Bus that names it, gone when the last
  one shuts down);
- ``"tcp://127.0.0.1:PORT/bus0"`` and ``"unix:///path/to/socket/bus0"`` — a bus served by
  ``canstack serve`` in another process (see `stack.serve`).

The interface is registered under the python-can entry point group ``can.interface`` by the
installed distribution; importing this module also registers it in python-can's table, so a
checkout that is not installed works too.
"""

from __future__ import annotations

import logging
import os
import queue
import re
import threading
from typing import Any, Callable, Sequence

import can
from can.broadcastmanager import (
    LimitedDurationCyclicSendTaskABC,
    ModifiableCyclicTaskABC,
    RestartableCyclicTaskABC,
)

from stack.controller.events import Received, TxDone, TxFailed
from stack.wire.frame import Frame
from stack.controller.node import ErrorState, Node, NodeError, QueueFull
from stack.io.runner import (BUS_NAME_RE, DEFAULT_BITRATE, RealTimeRunner, acquire_runner, release_runner,
                             running_buses)

__all__ = [
    "CanstackBus",
    "RealTimeRunner",
    "CanstackCyclicTask",
    "InvalidFrame",
    "register_interface",
    "running_buses",
    "frame_of",
]

LOG = logging.getLogger("stack.io.pycan")

_STATE_MAP = {
    ErrorState.ACTIVE: can.BusState.ACTIVE,
    ErrorState.WARNING: can.BusState.ACTIVE,
    ErrorState.PASSIVE: can.BusState.PASSIVE,
    ErrorState.BUS_OFF: can.BusState.ERROR,
}
_NODE_OPTIONS = ("queue", "mailboxes", "abort", "tx_queue_size", "listen_only", "one_shot")
_BOOL_OPTIONS = ("abort", "listen_only", "one_shot")
_BOOL_WORDS = {"true": True, "yes": True, "on": True, "1": True, "false": False, "no": False, "off": False, "0": False}


class InvalidFrame(can.CanOperationError):
    """A message python-can accepts but CAN 2.0 does not (FD, more than 8 bytes, error frame)."""


def register_interface() -> None:
    """Make ``interface="canstack"`` known to python-can in this process.

    The installed distribution registers it through the ``can.interface`` entry point; this adds
    it to python-can's tables for a checkout that is not installed (idempotent).
    """
    import can.interfaces
    import can.util

    can.interfaces.BACKENDS.setdefault("canstack", ("stack.io.pycan", "CanstackBus"))
    for mod in (can.interfaces, can.util, can):
        valid = getattr(mod, "VALID_INTERFACES", None)
        if valid is not None and "canstack" not in valid:
            setattr(mod, "VALID_INTERFACES", frozenset(valid | {"canstack"}))


# ---------------------------------------------------------------------------------- frames
_FRAME_CACHE: dict[tuple[int, bool, bool, int, bytes], Frame] = {}


def frame_of(msg: can.Message) -> Frame:
    """The CAN 2.0 frame of a message, or `InvalidFrame` naming why it is not one.

    Frames are cached by content: computing a frame's stuffed bits costs ~37 us, and a node
    usually sends the same few frames again and again (a dictionary hit is ~0.3 us).
    """
    if msg.is_fd:
        raise InvalidFrame("CAN FD message refused: a canstack bus is CAN 2.0 (classic) only")
    if msg.is_error_frame:
        raise InvalidFrame("an error frame cannot be sent: the controller signals errors itself")
    data = bytes(msg.data) if msg.data is not None else b""
    if len(data) > 8 or msg.dlc > 8:
        raise InvalidFrame(f"message with {max(len(data), msg.dlc)} bytes refused: a CAN 2.0 frame carries at most 8")
    key = (msg.arbitration_id, bool(msg.is_extended_id), bool(msg.is_remote_frame), msg.dlc, data)
    f = _FRAME_CACHE.get(key)
    if f is None:
        try:
            f = Frame.from_message(msg)
        except ValueError as exc:
            raise InvalidFrame(str(exc)) from None
        f.bits  # noqa: B018 - computed here, on the sender's thread, not on the runner's
        if len(_FRAME_CACHE) > 8192:
            _FRAME_CACHE.clear()
        _FRAME_CACHE[key] = f
    return f


# ---------------------------------------------------------------------------------- ports
class _LocalPort:
    """A `CanstackBus`'s node on an in-process real-time bus (engine side on the runner)."""

    native_periodic = True

    def __init__(self, owner: "CanstackBus", name: str, bitrate: int | None, node_name: str | None,
                 config: dict[str, Any]) -> None:
        self.owner = owner
        self.runner = acquire_runner(name, bitrate)
        self.bitrate = self.runner.bitrate
        self.epoch0 = self.runner.epoch0
        self.t0_ns = self.runner.t0_ns
        self._credit_reqs: set[Any] = set()
        self._tasks: set[Any] = set()
        try:
            self.node: Node = self.runner.call(lambda: self._attach(node_name, config))
        except BaseException:
            release_runner(self.runner)
            raise
        self.node_name = self.node.name

    def _attach(self, node_name: str | None, config: dict[str, Any]) -> Node:
        sim = self.runner.sim
        if node_name is None:
            node_name = sim.free_name("node")
        elif node_name in {n.name for n in sim.nodes}:
            raise can.CanInitializationError(f"a node named {node_name!r} is already on bus {sim.name!r}")
        try:
            node = sim.node(node_name, **config)
        except (ValueError, TypeError) as exc:
            raise can.CanInitializationError(f"canstack node options: {exc}") from None
        self.node = node
        node.subscribe(self._on_rx)
        node.listen(TxDone, self._on_txdone)
        node.listen(TxFailed, self._on_txfailed)
        self.runner._ports.append(self)
        return node

    # runner-thread callbacks
    def _on_rx(self, ev: Received) -> None:
        self.owner._deliver(ev.time, ev.frame, True)

    def _on_txdone(self, ev: TxDone) -> None:
        if self.owner.receive_own_messages and self.node.acceptance.accepts(ev.frame):
            self.owner._deliver(ev.time, ev.frame, False)
        if ev.request in self._credit_reqs:
            self._credit_reqs.discard(ev.request)
            self.owner._tx_finished(None)

    def _on_txfailed(self, ev: TxFailed) -> None:
        if ev.request in self._credit_reqs:
            self._credit_reqs.discard(ev.request)
            self.owner._tx_finished(ev.reason)

    def _mirror_state(self) -> None:
        n = self.node
        self.owner._set_state(n.state, n.tec, n.rec)

    def _closed_by_runner(self, reason: str) -> None:
        self.owner._port_lost(reason)

    # caller-thread API
    def send(self, frame: Frame) -> None:
        """Queue ``frame`` on the node (on the runner thread)."""
        def cmd() -> None:
            try:
                req = self.node.send(frame)
            except (QueueFull, NodeError) as exc:
                self.owner._tx_finished(str(exc))
                return
            if req.state == "queued":
                self._credit_reqs.add(req)
            else:
                self.owner._tx_finished(None if req.state == "sent" else req.reason)
        self.runner.post(cmd)

    def set_filters(self, filters: Any) -> None:
        """Set the node's acceptance filters (python-can format)."""
        self.runner.call(lambda: self.node.set_filters(filters))

    def start_periodic(self, make: Callable[[], Frame], period_ns: int, count: int | None) -> Any:
        """Start a cyclic transmission on the simulation clock; returns its engine task."""
        def start() -> Any:
            t = self.node.send_periodic(make, period_ns, count=count)
            self._tasks.add(t)
            return t
        return self.runner.call(start)

    def stop_periodic(self, task: Any) -> None:
        """Stop a cyclic transmission."""
        def stop() -> None:
            task.stop()
            self._tasks.discard(task)
        self.runner.post(stop)

    def close(self) -> None:
        """Leave the bus: the node is taken off the wire, its pending frames are dropped."""
        def leave() -> None:
            for t in list(self._tasks):
                t.stop()
            self._tasks.clear()
            sim = self.runner.sim
            for req in self.node.pending():
                self.node.abort(req)
            sim.disconnect(self.node)
            if self in self.runner._ports:
                self.runner._ports.remove(self)
        try:
            self.runner.call(leave, timeout=2.0)
        except can.CanError:  # runner gone: nothing to leave
            pass
        release_runner(self.runner)


def _is_socket(path: str) -> bool:
    import stat

    try:
        return stat.S_ISSOCK(os.stat(path).st_mode)
    except OSError:
        return False


def _parse_channel(channel: Any) -> tuple[str, str, Any]:
    """('local', name, None) | ('tcp', name, (host, port)) | ('unix', name, path)."""
    if not isinstance(channel, str) or not channel:
        raise can.CanInitializationError(
            f"canstack channel {channel!r}: give a bus name like 'bus0', 'tcp://127.0.0.1:PORT/bus0' "
            "or 'unix:///path/to/socket/bus0'")
    if "://" not in channel:
        if not BUS_NAME_RE.match(channel):
            raise can.CanInitializationError(
                f"canstack channel {channel!r}: a bus name is 1..64 of A-Z a-z 0-9 _ . - ; "
                "or use tcp://HOST:PORT/NAME or unix:///PATH/NAME")
        return "local", channel, None
    scheme, rest = channel.split("://", 1)
    if scheme == "tcp":
        m = re.match(r"^(\[[^\]]+\]|[^:/]+):(\d{1,5})/([A-Za-z0-9_.\-]{1,64})$", rest)
        if not m:
            raise can.CanInitializationError(f"canstack channel {channel!r}: expected tcp://HOST:PORT/NAME")
        host = m.group(1).strip("[]")
        port = int(m.group(2))
        if not 0 < port < 65536:
            raise can.CanInitializationError(f"canstack channel {channel!r}: port {port} out of range")
        return "tcp", m.group(3), (host, port)
    if scheme == "unix":
        if _is_socket(rest):
            raise can.CanInitializationError(
                f"canstack channel {channel!r}: {rest} is the socket itself; add the bus name: "
                f"unix://{rest}/NAME")
        path, _, name = rest.rpartition("/")
        if not path.startswith("/") or not BUS_NAME_RE.match(name):
            raise can.CanInitializationError(
                f"canstack channel {channel!r}: expected unix:///ABSOLUTE/SOCKET/PATH/NAME")
        return "unix", name, path
    raise can.CanInitializationError(
        f"canstack channel {channel!r}: unknown form {scheme + '://'!r}; use a bus name, tcp:// or unix://")


# ---------------------------------------------------------------------------------- the bus
class CanstackBus(can.BusABC):
    """A node with a software CAN controller on a canstack simulated bus (real time).

    :param channel: bus name (``"bus0"``), ``"tcp://HOST:PORT/NAME"`` or ``"unix:///PATH/NAME"``.
    :param bitrate: bit/s; the first node starts the bus at this rate (default 500000), later
        nodes must give the same or none. ``timing`` (a `can.BitTiming`) may be given instead.
    :param receive_own_messages: also receive the frames this node sent (``is_rx`` False).
    :param can_filters: python-can filters; applied by the node's acceptance filter.
    :param queue: transmit queue policy, 'priority' (default), 'fifo' or 'mailbox'.
    :param mailboxes, abort: for the mailbox policy (see `stack.queues`).
    :param tx_queue_size: frames the controller queues (default 1024); ``send`` waits for room.
    :param rx_fifo_size: received frames buffered until ``recv`` (default 65536); more are
        dropped and counted in ``rx_overruns``.
    :param listen_only: no transmission and no ACK. :param one_shot: no retransmission.
    :param node_name: the node's name on the bus (default ``nodeN``).
    """

    def __init__(self, channel: Any = "bus0", can_filters: Any = None, *, bitrate: int | None = None,
                 receive_own_messages: bool = False, rx_fifo_size: int = 65536,
                 node_name: str | None = None, timing: Any = None, **kwargs: Any) -> None:
        if timing is not None:
            if not isinstance(timing, can.BitTiming):
                raise can.CanInitializationError(f"timing {timing!r}: only a classic can.BitTiming fits a CAN 2.0 bus")
            if bitrate is not None and bitrate != timing.bitrate:
                raise can.CanInitializationError(f"bitrate {bitrate} and timing ({timing.bitrate} bit/s) disagree")
            bitrate = timing.bitrate
        if bitrate is not None:
            if isinstance(bitrate, bool) or not isinstance(bitrate, int) or not 1_000 <= bitrate <= 1_000_000:
                raise can.CanInitializationError(f"bitrate {bitrate!r}: a CAN 2.0 bus runs at 1000..1000000 bit/s")
        if kwargs.pop("fd", False):
            raise can.CanInitializationError("fd=True: a canstack bus is CAN 2.0 (classic) only")
        if isinstance(rx_fifo_size, bool) or not isinstance(rx_fifo_size, int) or rx_fifo_size < 1:
            raise can.CanInitializationError(f"rx_fifo_size {rx_fifo_size!r} must be a positive int")
        if kwargs.get("data_bitrate") is not None:
            raise can.CanInitializationError(
                f"data_bitrate {kwargs['data_bitrate']!r}: a canstack bus is CAN 2.0 (classic), no FD data phase")
        config = {k: kwargs.pop(k) for k in _NODE_OPTIONS if k in kwargs}
        for k, v in list(config.items()):  # python-can config files give every option as a string
            if isinstance(v, str) and k in _BOOL_OPTIONS and v.lower() in _BOOL_WORDS:
                config[k] = _BOOL_WORDS[v.lower()]
            elif isinstance(v, str) and k in ("mailboxes", "tx_queue_size") and v.strip().isdigit():
                config[k] = int(v)
        for k in list(kwargs):  # options python-can's config files pass to every interface
            if k in ("data_bitrate", "app_name", "serial", "poll_interval", "single_handle"):
                kwargs.pop(k)
        if kwargs:
            raise can.CanInitializationError(
                f"unknown canstack option(s) {sorted(kwargs)}: allowed are bitrate, receive_own_messages, "
                f"rx_fifo_size, node_name, {', '.join(_NODE_OPTIONS)}")
        kind, name, addr = _parse_channel(channel)
        self.channel = channel
        self.channel_info = f"canstack {channel}"
        self.receive_own_messages = bool(receive_own_messages)
        self.rx_fifo_size = rx_fifo_size
        self.rx_overruns = 0
        self._rxq: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._ns_state = ErrorState.ACTIVE
        self.tec = 0
        self.rec = 0
        self.last_tx_error: str | None = None
        self._closed_reason: str | None = None
        self._listen_only = bool(config.get("listen_only", False))
        qsize = config.get("tx_queue_size", 1024)
        if isinstance(qsize, bool) or not isinstance(qsize, int) or qsize < 1:
            raise can.CanInitializationError(f"tx_queue_size {qsize!r} must be a positive int")
        self._tx_queue_size = qsize
        self._credits = threading.Semaphore(qsize)
        config["receive_own_messages"] = False  # own frames come from TxDone (is_rx False)
        config["rx_fifo_size"] = 1  # frames go to subscription callbacks, never the node's FIFO
        if kind == "local":
            self._port: Any = _LocalPort(self, name, bitrate, node_name, config)
        else:
            from stack.io.serve import RemotePort

            self._port = RemotePort(self, kind, addr, name, bitrate, node_name, config)
        self.bitrate = self._port.bitrate
        self.node_name = self._port.node_name
        super().__init__(channel, can_filters=can_filters)

    # -- engine side (runner or socket thread) -------------------------------------------
    def _deliver(self, t_ns: int, frame: Frame, is_rx: bool) -> None:
        if self._rxq.qsize() >= self.rx_fifo_size:
            self.rx_overruns += 1
            return
        self._rxq.put((t_ns, frame, is_rx))

    def _tx_finished(self, error: str | None) -> None:
        if error is not None:
            self.last_tx_error = error
        self._credits.release()

    def _set_state(self, state: ErrorState, tec: int, rec: int) -> None:
        self._ns_state = state
        self.tec = tec
        self.rec = rec

    def _port_lost(self, reason: str) -> None:
        self._closed_reason = reason
        self._rxq.put(None)

    # -- python-can API ----------------------------------------------------------------
    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Queue ``msg`` for transmission; wait up to ``timeout`` s (None: forever) for room in
        the controller's transmit queue. Raises `InvalidFrame` for FD or > 8 bytes and
        `can.CanOperationError` when shut down, listen-only, bus off or the queue stays full."""
        if self._is_shutdown:
            raise can.CanOperationError(f"canstack bus {self.channel!r} is shut down: cannot send")
        if self._closed_reason is not None:
            raise can.CanOperationError(f"canstack bus {self.channel!r} is gone: {self._closed_reason}")
        frame = frame_of(msg)
        if self._listen_only:
            raise can.CanOperationError("the node is listen-only: it cannot transmit")
        if self._ns_state is ErrorState.BUS_OFF:
            raise can.CanOperationError(
                f"the node is bus off (TEC {self.tec}): it cannot transmit until it recovers")
        if timeout is None:
            ok = self._credits.acquire()
        elif timeout <= 0:
            ok = self._credits.acquire(blocking=False)
        else:
            ok = self._credits.acquire(timeout=timeout)
        if not ok:
            raise can.CanOperationError(
                f"transmit queue full ({self._tx_queue_size} frames) for {timeout} s: the bus is busier than "
                "this node's traffic allows")
        self._port.send(frame)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        # after shutdown recv returns None (a Notifier thread still polling while its bus is
        # shut down, as cantools' Tester does at teardown, must not die with an exception)
        try:
            item = self._rxq.get(timeout=timeout) if timeout is None or timeout > 0 else self._rxq.get_nowait()
        except queue.Empty:
            return None, True
        if item is None:
            if self._closed_reason is not None:
                raise can.CanOperationError(f"canstack bus {self.channel!r} is gone: {self._closed_reason}")
            return None, True
        t_ns, frame, is_rx = item
        msg = frame.to_message(timestamp=self._port.epoch0 + t_ns / 1e9, channel=self.channel)
        msg.is_rx = is_rx
        return msg, True

    def _apply_filters(self, filters: Any) -> None:
        from stack.controller.filters import validate_filters

        try:
            validate_filters(filters)
        except ValueError as exc:
            raise can.CanInitializationError(f"filters: {exc}") from None
        self._port.set_filters(list(filters) if filters else None)

    @property
    def state(self) -> can.BusState:
        """ACTIVE (error active or warning), PASSIVE (error passive) or ERROR (bus off)."""
        return _STATE_MAP[self._ns_state]

    @state.setter
    def state(self, new_state: can.BusState) -> None:
        if new_state is not can.BusState.ACTIVE or self._listen_only:
            raise NotImplementedError("a canstack node's mode is chosen when it is created (listen_only=True)")

    @property
    def error_state(self) -> ErrorState:
        """The node's fault-confinement state (error-active, -warning, -passive, bus-off)."""
        return self._ns_state

    def _send_periodic_internal(self, msgs: Sequence[can.Message] | can.Message, period: float,
                                duration: float | None = None, autostart: bool = True,
                                modifier_callback: Callable[[can.Message], None] | None = None,
                                ) -> can.broadcastmanager.CyclicSendTaskABC:
        if not getattr(self._port, "native_periodic", False):
            return super()._send_periodic_internal(msgs, period, duration, autostart, modifier_callback)
        return CanstackCyclicTask(self, msgs, period, duration, autostart, modifier_callback)

    def shutdown(self) -> None:
        """Leave the bus (the node goes off the wire) and stop periodic tasks."""
        if self._is_shutdown:
            return
        super().shutdown()
        self._port.close()
        self._rxq.put(None)

    @staticmethod
    def _detect_available_configs() -> list[can.typechecking.AutoDetectedConfig]:
        buses = running_buses() or {"bus0": DEFAULT_BITRATE}
        return [{"interface": "canstack", "channel": name, "bitrate": br}  # type: ignore[typeddict-item]
                for name, br in sorted(buses.items())]


class CanstackCyclicTask(ModifiableCyclicTaskABC, RestartableCyclicTaskABC, LimitedDurationCyclicSendTaskABC):
    """A cyclic transmission driven by the simulation clock (`Node.send_periodic`).

    Each period's frame is queued by the engine at its exact virtual time, so the period on the
    wire deviates only by arbitration, not by a Python thread's sleep jitter.
    """

    def __init__(self, bus: CanstackBus, msgs: Sequence[can.Message] | can.Message, period: float,
                 duration: float | None, autostart: bool,
                 modifier_callback: Callable[[can.Message], None] | None) -> None:
        super().__init__(msgs, period, duration)
        self.bus = bus
        self._frames = tuple(frame_of(m) for m in self.messages)
        self._modifier = modifier_callback
        self._i = 0
        self._task: Any = None
        if autostart:
            self.start()

    def _next(self) -> Frame:
        i = self._i
        self._i = (i + 1) % len(self.messages)
        if self._modifier is not None:
            msg = self.messages[i]
            self._modifier(msg)
            return frame_of(msg)
        return self._frames[i]

    def modify_data(self, messages: Sequence[can.Message] | can.Message) -> None:
        """Replace the messages sent (same identifier and count)."""
        messages = self._check_and_convert_messages(messages)
        self._check_modified_messages(messages)
        self._frames = tuple(frame_of(m) for m in messages)
        self.messages = messages

    def start(self) -> None:
        """Start (or restart) the transmission."""
        if self._task is not None:
            return
        count = None if self.duration is None else max(1, int(round(self.duration / self.period)))
        self._task = self.bus._port.start_periodic(self._next, self.period_ns, count)

    def stop(self) -> None:
        """Stop the transmission."""
        if self._task is not None:
            self.bus._port.stop_periodic(self._task)
            self._task = None


register_interface()
