"""The simulated bus as a python-can interface: ``can.Bus(interface="canstack", channel=...)``.

Each `CanstackBus` is a node with its own software controller on a simulated bus that runs in
real time (`stack.io.runner.RealTimeRunner`: virtual ns = wall ns since the bus started), so a
frame arrives after its real wire time, contending frames are arbitrated bit by bit and
acknowledged by the other nodes. The node's engine side is a `stack.io.port.Port` (in process)
or a `stack.io.serve.RemotePort` (a served bus); this module is the python-can plugin only:
messages and frames are converted in `stack.io.pycan_frames`, channels read in
`stack.io.pycan_channel`, received frames wait in a `stack.io.pycan_inbox.Inbox`.

Channel forms:

- ``"bus0"`` — a bus **private to this process** (created by the first Bus that names it, gone
  when the last one shuts down). Another process that opens ``"bus0"`` gets a bus of its own and
  sees nothing of this one. When a ``canstack serve`` runs on this machine, opening a plain-named
  bus warns once per process (`PrivateBusWarning`) and names the served channel;
- ``"tcp://127.0.0.1:PORT/bus0"`` and ``"unix:///path/to/socket/bus0"`` — a bus served by
  ``canstack serve``, shared by every process that connects to it (see `stack.io.serve`).

python-can behaviour kept as on SocketCAN: ``shutdown()`` delivers what was sent (it waits for
queued frames, see `CanstackBus`); a failed one-shot transmission arrives at the sender's
``recv`` as an error frame with SocketCAN's error classes; ``bus.state = can.BusState.PASSIVE``
makes the node listen-only at run time (``ACTIVE`` undoes it).

python-can finds the interface through the ``can.interface`` entry point of the installed
distribution (``pip install -e .`` in a checkout); importing this module changes nothing in
python-can.
"""

from __future__ import annotations

import logging
import queue
from collections.abc import Callable, Sequence
from typing import Any, cast

import can
from can.broadcastmanager import (
    LimitedDurationCyclicSendTaskABC,
    ModifiableCyclicTaskABC,
    RestartableCyclicTaskABC,
)

from stack.controller.confinement import BUS_OFF, PASSIVE, ErrorState
from stack.io.errors import BusLost
from stack.io.message import to_message
from stack.io.port import NODE_OPTIONS, Port, check_filters
from stack.io.pycan_channel import PrivateBusWarning, parse_channel, warn_if_served
from stack.io.pycan_frames import InvalidFrame, error_frame_of, frame_of
from stack.io.pycan_inbox import Inbox, config_value
from stack.io.runner import DEFAULT_BITRATE, RealTimeRunner, acquire_runner, release_runner, running_buses
from stack.io.serve.client import RemotePort
from stack.wire.frame import Frame

__all__ = [
    "CanstackBus",
    "RealTimeRunner",
    "CanstackCyclicTask",
    "InvalidFrame",
    "PrivateBusWarning",
    "running_buses",
    "frame_of",
    "error_frame_of",
]

LOG = logging.getLogger("stack.io.pycan")

_PASSED_TO_EVERY_INTERFACE = ("app_name", "serial", "poll_interval", "single_handle")


class CanstackBus(can.BusABC):
    """A node with a software CAN controller on a canstack simulated bus (real time).

    :param channel: ``"bus0"`` (a bus private to this process), ``"tcp://HOST:PORT/NAME"`` or
        ``"unix:///PATH/NAME"`` (a bus served by ``canstack serve``, shared between processes).
    :param bitrate: bit/s; the first node starts the bus at this rate (default 500000), later
        nodes must give the same or none. ``timing`` (a `can.BitTiming`, or a `can.BitTimingFd`
        with ``fd``) may be given instead.
    :param fd: a CAN FD node (``protocol`` is `can.CanProtocol.CAN_FD`): it sends and receives FD
        messages (``is_fd``, ``bitrate_switch``, ``error_state_indicator``). The first FD node
        makes the bus an FD bus; a node without ``fd`` may join it and sees no FD frames (as a
        SocketCAN socket without CAN_RAW_FD_FRAMES), and an FD message sent without ``fd`` is
        refused with `InvalidFrame`.
    :param data_bitrate: the data phase's bit/s of an FD bus (default 2000000 for a new one).
    :param receive_own_messages: also receive the frames this node sent (``is_rx`` False).
    :param can_filters: python-can filters; applied by the node's acceptance filter.
    :param queue: transmit queue policy, 'priority' (default), 'fifo' or 'mailbox'.
    :param mailboxes, abort: for the mailbox policy (see `stack.controller.queues`).
    :param tx_queue_size: frames the controller queues (default 1024); ``send`` waits for room.
    :param rx_fifo_size: received frames buffered until ``recv`` (default 65536); more are
        dropped and counted in ``rx_overruns``.
    :param listen_only: no transmission and no ACK (``state`` PASSIVE; settable at run time).
    :param one_shot: no retransmission; a failed frame arrives at ``recv`` as an error frame
        (SocketCAN's classes, see `error_frame_of`) unless ``ignore_rx_error_frames``, and is
        named in ``last_tx_error``.
    :param flush_timeout: ``shutdown`` waits for queued frames to go out while they keep going
        out: up to this many seconds for each next one (default 1.0; 0 drops them at once). It
        stops early when no other node could acknowledge them.
    :param node_name: the node's name on the bus (default ``nodeN``, or ``clientN`` served).
    """

    def __init__(
        self,
        channel: Any = "bus0",
        can_filters: Any = None,
        *,
        bitrate: int | None = None,
        fd: bool = False,
        data_bitrate: int | None = None,
        receive_own_messages: bool = False,
        rx_fifo_size: int = 65536,
        node_name: str | None = None,
        timing: Any = None,
        flush_timeout: float = 1.0,
        ignore_rx_error_frames: bool = False,
        **kwargs: Any,
    ) -> None:
        opts = {
            k: config_value(k, v)
            for k, v in dict(
                kwargs,
                receive_own_messages=receive_own_messages,
                rx_fifo_size=rx_fifo_size,
                flush_timeout=flush_timeout,
                ignore_rx_error_frames=ignore_rx_error_frames,
                fd=fd,
            ).items()
        }
        fd = opts.pop("fd")
        if not isinstance(fd, bool):
            raise can.CanInitializationError(f"fd {fd!r} must be True or False")
        bitrate, data_bitrate = self._check_bitrate(bitrate, timing, fd, data_bitrate)
        self.fd = fd
        config = self._check_options(opts)
        try:
            filters = check_filters(can_filters)
        except ValueError as exc:
            raise can.CanInitializationError(f"can_filters: {exc}") from None
        kind, name, addr = parse_channel(channel)
        self.channel = channel
        self.channel_info = f"canstack {channel}"
        self.receive_own_messages = bool(opts["receive_own_messages"])
        self.rx_fifo_size: int = opts["rx_fifo_size"]
        self.flush_timeout: float = opts["flush_timeout"]
        self._listen_only = bool(config.get("listen_only", False))
        self._inbox = Inbox(
            self.rx_fifo_size,
            config.get("tx_queue_size", 1024),
            error_frames=not opts["ignore_rx_error_frames"],
            fd=fd,
        )
        self._runner: RealTimeRunner | None = None
        self._port: Any = self._open_port(kind, name, addr, bitrate, node_name, config, data_bitrate)
        self.bitrate = self._port.bitrate
        self.data_bitrate: int | None = getattr(self._port, "data_bitrate", None) if fd else None
        self.node_name = self._port.node_name
        try:
            # check_filters gave python-can's own filter dicts back, checked
            super().__init__(channel, can_filters=cast("can.typechecking.CanFilters | None", filters))
        except BaseException:
            self._leave()
            raise
        self._can_protocol = can.CanProtocol.CAN_FD if fd else can.CanProtocol.CAN_20

    @staticmethod
    def _check_bitrate(bitrate: Any, timing: Any, fd: bool, data_bitrate: Any) -> tuple[int | None, int | None]:
        if timing is not None:
            if isinstance(timing, can.BitTimingFd) and fd:
                if data_bitrate is not None and data_bitrate != timing.data_bitrate:
                    raise can.CanInitializationError(
                        f"data_bitrate {data_bitrate} and timing ({timing.data_bitrate} bit/s) disagree"
                    )
                data_bitrate = timing.data_bitrate
                timing_bitrate = timing.nom_bitrate
            elif isinstance(timing, can.BitTiming):
                timing_bitrate = timing.bitrate
            else:
                raise can.CanInitializationError(
                    f"timing {timing!r}: a can.BitTiming, or a can.BitTimingFd on a bus opened with fd=True"
                )
            if bitrate is not None and bitrate != timing_bitrate:
                raise can.CanInitializationError(f"bitrate {bitrate} and timing ({timing_bitrate} bit/s) disagree")
            bitrate = timing_bitrate
        if bitrate is not None:
            if isinstance(bitrate, bool) or not isinstance(bitrate, int) or not 1_000 <= bitrate <= 1_000_000:
                raise can.CanInitializationError(f"bitrate {bitrate!r}: a CAN bus arbitrates at 1000..1000000 bit/s")
        if data_bitrate is not None:
            if not fd:
                raise can.CanInitializationError(
                    f"data_bitrate {data_bitrate!r}: a data phase is CAN FD's; open the bus with fd=True"
                )
            if isinstance(data_bitrate, str) and data_bitrate.strip().isdigit():
                data_bitrate = int(data_bitrate)  # from a python-can config file
            if isinstance(data_bitrate, bool) or not isinstance(data_bitrate, int) or data_bitrate <= 0:
                raise can.CanInitializationError(f"data_bitrate {data_bitrate!r} must be a positive int (bit/s)")
        return bitrate, data_bitrate

    @staticmethod
    def _check_options(opts: dict[str, Any]) -> dict[str, Any]:
        """The node options out of ``opts`` (python-can's generic ones dropped); the rest checked."""
        for k in _PASSED_TO_EVERY_INTERFACE:  # options python-can's config files pass to every interface
            opts.pop(k, None)
        config = {k: opts.pop(k) for k in NODE_OPTIONS if k in opts}
        known = {"receive_own_messages", "rx_fifo_size", "flush_timeout", "ignore_rx_error_frames"}
        unknown = sorted(set(opts) - known)
        if unknown:
            raise can.CanInitializationError(
                f"unknown canstack option(s) {unknown}: allowed are bitrate, fd, data_bitrate, timing, node_name, "
                f"{', '.join(sorted(known))}, {', '.join(NODE_OPTIONS)}"
            )
        fifo = opts["rx_fifo_size"]
        if isinstance(fifo, bool) or not isinstance(fifo, int) or fifo < 1:
            raise can.CanInitializationError(f"rx_fifo_size {fifo!r} must be a positive int")
        qsize = config.get("tx_queue_size", 1024)
        if isinstance(qsize, bool) or not isinstance(qsize, int) or qsize < 1:
            raise can.CanInitializationError(f"tx_queue_size {qsize!r} must be a positive int")
        ft = opts["flush_timeout"]
        if isinstance(ft, bool) or not isinstance(ft, (int, float)) or not 0 <= ft <= 3600:
            raise can.CanInitializationError(f"flush_timeout {ft!r} must be a number of seconds in 0..3600")
        for k in ("receive_own_messages", "ignore_rx_error_frames"):
            if not isinstance(opts[k], bool):
                raise can.CanInitializationError(f"{k} {opts[k]!r} must be True or False")
        return config

    def _open_port(
        self,
        kind: str,
        name: str,
        addr: Any,
        bitrate: int | None,
        node_name: str | None,
        config: dict[str, Any],
        data_bitrate: int | None,
    ) -> Any:
        if kind != "local":
            return RemotePort(
                self._inbox,
                kind,
                addr,
                name,
                bitrate,
                node_name,
                config,
                channel=self.channel,
                receive_own_messages=self.receive_own_messages,
                fd=self.fd,
                data_bitrate=data_bitrate,
            )
        warn_if_served(name)
        runner = acquire_runner(name, bitrate, data_bitrate, fd=self.fd)
        try:
            port = Port(
                runner,
                self._inbox,
                node_name=node_name,
                prefix="node",
                config=config,
                receive_own_messages=self.receive_own_messages,
            )
        except ValueError as exc:
            release_runner(runner)
            raise can.CanInitializationError(
                f"canstack {exc}" if str(exc).startswith("node options") else str(exc)
            ) from None
        except BaseException:
            release_runner(runner)
            raise
        self._runner = runner
        return port

    def _leave(self) -> None:
        self._port.close()
        if self._runner is not None:
            release_runner(self._runner)
        self._inbox.rxq.put(None)

    # -- state mirrored from the node -----------------------------------------------------
    @property
    def tec(self) -> int:
        """The node's transmit error counter (as Linux's txerr)."""
        return self._inbox.tec

    @property
    def rec(self) -> int:
        """The node's receive error counter (as Linux's rxerr)."""
        return self._inbox.rec

    @property
    def rx_overruns(self) -> int:
        """Frames dropped because ``rx_fifo_size`` frames were waiting for ``recv``."""
        return self._inbox.rx_overruns

    @property
    def last_tx_error(self) -> str | None:
        """Why the last frame that was not sent was not (None until one failed)."""
        return self._inbox.last_tx_error

    @property
    def error_state(self) -> ErrorState:
        """The node's fault-confinement state (error-active, -warning, -passive, bus-off)."""
        return self._inbox.state

    # -- python-can API ----------------------------------------------------------------
    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Queue ``msg`` for transmission; wait up to ``timeout`` s (None: forever) for room in
        the controller's transmit queue. Raises `InvalidFrame` for an FD message without ``fd``
        or > 8 bytes in a classical one and
        `can.CanOperationError` when shut down, listen-only, bus off or the queue stays full."""
        if self._is_shutdown:
            raise can.CanOperationError(f"canstack bus {self.channel!r} is shut down: cannot send")
        inbox = self._inbox
        if inbox.lost_reason is not None:
            raise BusLost(f"canstack bus {self.channel!r} is gone: {inbox.lost_reason}", inbox.lost_reason)
        frame = frame_of(msg, self.fd)
        if self._listen_only:
            raise can.CanOperationError("the node is listen-only (BusState.PASSIVE): it cannot transmit")
        if inbox.state is BUS_OFF:
            raise can.CanOperationError(f"the node is bus off (TEC {inbox.tec}): it cannot transmit until it recovers")
        if not inbox.take(timeout):
            raise can.CanOperationError(
                f"transmit queue full ({inbox.size} frames) for {timeout} s: the bus is busier than "
                "this node's traffic allows"
            )
        self._port.send(frame)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        # after shutdown recv returns None (a Notifier thread still polling while its bus is
        # shut down, as cantools' Tester does at teardown, must not die with an exception)
        inbox = self._inbox
        try:
            item = inbox.rxq.get(timeout=timeout) if timeout is None or timeout > 0 else inbox.rxq.get_nowait()
        except queue.Empty:
            return None, True
        if item is None:
            if inbox.lost_reason is not None:
                inbox.rxq.put(None)  # every later recv says so too
                raise BusLost(f"canstack bus {self.channel!r} is gone: {inbox.lost_reason}", inbox.lost_reason)
            return None, True
        t_ns, frame, extra = item
        timestamp = self._port.timestamp(t_ns)
        if frame is None:  # a failed one-shot transmission: (reason, TEC, REC)
            reason, tec, rec = extra
            return error_frame_of(reason, tec, rec, timestamp=timestamp, channel=self.channel), True
        msg = to_message(frame, timestamp=timestamp, channel=self.channel)
        msg.is_rx = extra
        return msg, True

    def _apply_filters(self, filters: Any) -> None:
        try:
            checked = check_filters(filters)
        except ValueError as exc:
            raise can.CanInitializationError(f"filters: {exc}") from None
        self._port.set_filters(checked)

    @property
    def state(self) -> can.BusState:
        """ERROR when bus off; PASSIVE when listen-only or error passive; else ACTIVE."""
        st = self._inbox.state
        if st is BUS_OFF:
            return can.BusState.ERROR
        if self._listen_only or st is PASSIVE:
            return can.BusState.PASSIVE
        return can.BusState.ACTIVE

    @state.setter
    def state(self, new_state: can.BusState) -> None:
        """PASSIVE makes the node listen-only (no ACK, no transmission; frames still queued are
        aborted), ACTIVE makes it a normal node again; both apply at run time, from the next frame
        on the bus. ERROR (bus off) is the controller's to reach, not the host's to set."""
        if new_state not in (can.BusState.ACTIVE, can.BusState.PASSIVE):
            raise can.CanOperationError(
                f"bus state {new_state!r} cannot be set: use BusState.ACTIVE (normal) or BusState.PASSIVE "
                "(listen-only); bus off is reached by fault confinement only"
            )
        if self._is_shutdown:
            raise can.CanOperationError(f"canstack bus {self.channel!r} is shut down")
        on = new_state is can.BusState.PASSIVE
        self._port.set_listen_only(on)
        self._listen_only = on

    def _send_periodic_internal(
        self,
        msgs: Sequence[can.Message] | can.Message,
        period: float,
        duration: float | None = None,
        autostart: bool = True,
        modifier_callback: Callable[[can.Message], None] | None = None,
    ) -> can.broadcastmanager.CyclicSendTaskABC:
        if not getattr(self._port, "native_periodic", True):
            return super()._send_periodic_internal(msgs, period, duration, autostart, modifier_callback)
        return CanstackCyclicTask(self, msgs, period, duration, autostart, modifier_callback)

    def shutdown(self) -> None:
        """Stop periodic tasks, let the frames still queued go out (see ``flush_timeout``), then
        leave the bus: the node is removed and its name is free again."""
        if self._is_shutdown:
            return
        super().shutdown()
        inbox = self._inbox
        left = inbox.size - inbox.free
        if left and inbox.lost_reason is None and self.flush_timeout > 0:
            left = inbox.drain(self._port.can_drain, self.flush_timeout)
        if left and inbox.lost_reason is None:  # a lost bus was reported as such: not one more line
            LOG.warning(
                "canstack bus %r: %d queued frame(s) dropped at shutdown (%s)",
                self.channel,
                left,
                "not acknowledged or not sent in time" if self.flush_timeout > 0 else "flush_timeout=0",
            )
        self._leave()

    @staticmethod
    def _detect_available_configs() -> list[can.typechecking.AutoDetectedConfig]:
        buses = running_buses() or {"bus0": DEFAULT_BITRATE}
        return [
            {"interface": "canstack", "channel": name, "bitrate": br}  # type: ignore[typeddict-item]
            for name, br in sorted(buses.items())
        ]


class CanstackCyclicTask(ModifiableCyclicTaskABC, RestartableCyclicTaskABC, LimitedDurationCyclicSendTaskABC):
    """A cyclic transmission driven by the simulation clock (`Node.send_periodic`).

    Each period's frame is queued by the engine at its exact virtual time, so the period on the
    wire deviates only by arbitration, not by a Python thread's sleep jitter.
    """

    def __init__(
        self,
        bus: CanstackBus,
        msgs: Sequence[can.Message] | can.Message,
        period: float,
        duration: float | None,
        autostart: bool,
        modifier_callback: Callable[[can.Message], None] | None,
    ) -> None:
        super().__init__(msgs, period, duration)
        self.bus = bus
        self._frames = tuple(frame_of(m, bus.fd) for m in self.messages)
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
            return frame_of(msg, self.bus.fd)
        return self._frames[i]

    def modify_data(self, messages: Sequence[can.Message] | can.Message) -> None:
        """Replace the messages sent (same identifier and count)."""
        messages = self._check_and_convert_messages(messages)
        self._check_modified_messages(messages)
        self._frames = tuple(frame_of(m, self.bus.fd) for m in messages)
        self.messages = messages

    def start(self) -> None:
        """Start (or restart) the transmission."""
        if self._task is not None:
            return
        count = None if self.duration is None else max(1, round(self.duration / self.period))
        self._task = self.bus._port.start_periodic(self._next, self.period_ns, count)

    def stop(self) -> None:
        """Stop the transmission."""
        if self._task is not None:
            self.bus._port.stop_periodic(self._task)
            self._task = None
