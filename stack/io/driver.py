"""Run stack nodes on any python-can bus (socketcan/vcan, virtual, udp_multicast, hardware).

`PyCanDriver` is the second driver of the design: it gives each `Node` a wall clock and a
`can.BusABC` as its wire. The node's code — and every profile or DBC ECU above it — is the one
that runs on `SimBus`: it calls ``send``, ``subscribe``, ``listen``, ``call_at``, ``now``; the
driver turns received frames into `Received`, and frames handed to the bus into `TxDone`.

- One python-can connection per node (``can.Bus(interface, channel)`` each, or a bus you pass),
  so the nodes see each other's frames through the real bus (on vcan, through the kernel).
- The software controller still orders its own transmit queue: the driver hands the bus one
  frame per node at a time, the head of the node's queue; when several nodes of this driver
  have a frame ready at the same moment, the lowest arbitration key goes first. The bus itself
  does the real arbitration (hardware), or none (vcan, virtual).
- ``pace_bitrate`` makes the driver hand frames no faster than the wire would carry them at
  that bitrate (useful on ``virtual``, which has no wire time).
- A transmission counts as done (`TxDone`, stamped when ``bus.send`` returns — the earliest the
  driver knows the frame is on its way) ; a `can.CanError` from it is a retransmission 1 ms
  later (or `TxFailed` for a one-shot request). A request with a latest start time (``not_after``)
  that has not been handed to the bus by then is withdrawn (`TxFailed`).
- Timers run on one scheduler thread with the wall clock in ns since the driver started. Every
  node callback runs on that thread; from another thread use `submit` or hold `lock`.
- A bus that goes away is noticed at once and not retried for ever: a `stack.io.errors.BusLost`
  from ``send`` or ``recv`` (a canstack bus whose server stopped), a bus shut down under the
  driver, or a receive that keeps failing (`RECV_FAILURES_LOST` times in a row). The driver then
  stops handing frames to any bus, records what happened in ``lost`` (`BusGone`: which bus,
  when, why), sets the event ``gone`` and calls the ``on_lost`` callbacks; its owner stops.

What this driver can and cannot know (``capabilities``, see `stack.controller.contract`): received
frames carry the bus's receive timestamp when it is a wall-clock time (SocketCAN's kernel stamp,
canstack's end-of-frame time), and their start of frame is estimated from it minus the frame's
length at the bitrate given (``bitrate`` or ``pace_bitrate``; an FD frame with BRS needs ``data_bitrate``
too) — exact on the canstack interface, whose timestamps are the end of EOF. CAN FD frames go
both ways on a bus that carries them (python-can's ``fd=True``). Arbitration happens in the controller underneath, so no
`ArbitrationLost`. Error counters and states are the bus underneath's: when it reports them as
SocketCAN error frames (controller state, TEC/REC in data[6]/[7], bus off, restarted), the
node's TEC/REC follow and `ErrorStateChanged` fires with the same meaning as on the simulated
bus; otherwise they stay at 0.
"""

from __future__ import annotations

import heapq
import itertools
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any, NamedTuple

import can

from stack.controller.confinement import BUS_OFF, BUS_OFF_LIMIT, RECOVERY_OCCURRENCES, RECOVERY_RECESSIVE_BITS
from stack.controller.contract import Timer
from stack.controller.node import FD, Node
from stack.controller.queues import QUEUED
from stack.io.clock import clock_pair
from stack.io.errors import BusLost
from stack.io.message import to_message
from stack.wire.coding import INTERMISSION_BITS
from stack.wire.frame import Frame

__all__ = ["PyCanDriver", "BusGone", "RETRY_NS", "RECV_FAILURES_LOST", "decode_error_frame"]

# SocketCAN error frames (linux/can/error.h): class bits in the identifier, details in the data
CAN_ERR_CRTL = 0x004
CAN_ERR_BUSOFF = 0x040
CAN_ERR_RESTARTED = 0x100
CAN_ERR_CNT = 0x200
CAN_ERR_CRTL_ACTIVE = 0x40  # data[1]: back to error active

SEND_FAILURES_REPORTED = 20  # a request whose send failed this often is reported in `errors`
RETRY_NS = 1_000_000
RECV_FAILURES_LOST = 3  # receive failures in a row (50 ms apart) that mean the bus is gone
_BATCH = 256


class BusGone(NamedTuple):
    """A bus that went away under the driver: the node on it, the bus as python-can describes
    it (``channel_info``), the driver time (ns) and wall-clock time (s since the epoch) it was
    noticed, and why."""

    node: str
    bus: str
    t_ns: int
    wall: float
    reason: str

    def describe(self) -> str:
        """One line naming the bus and the time."""
        when = time.strftime("%H:%M:%S", time.localtime(self.wall))
        return f"bus {self.bus} lost at {self.t_ns / 1e9:.3f} s ({when}): {self.reason}"


class PyCanDriver:
    """Nodes on python-can buses with wall-clock timers (see the module docstring).

    Give ``interface``/``channel`` (and any python-can options in ``bus_kwargs``) to open one
    ``can.Bus`` per node, or ``bus_factory(node_name) -> can.BusABC``, or pass ``can_bus`` to
    `add`/`node` for each node.
    """

    def __init__(
        self,
        bus_factory: Callable[[str], can.BusABC] | None = None,
        *,
        interface: str | None = None,
        channel: Any = None,
        pace_bitrate: int | None = None,
        **bus_kwargs: Any,
    ) -> None:
        if bus_factory is None and interface is not None:

            def bus_factory(name: str) -> can.BusABC:
                return can.Bus(interface=interface, channel=channel, **bus_kwargs)

        if pace_bitrate is not None and not 1_000 <= pace_bitrate <= 1_000_000:
            raise ValueError(f"pace_bitrate {pace_bitrate!r}: a CAN 2.0 bus runs at 1000..1000000 bit/s")
        bitrate = bus_kwargs.get("bitrate")
        rate = pace_bitrate or (bitrate if isinstance(bitrate, int) and 1_000 <= bitrate <= 1_000_000 else None)
        self._factory = bus_factory
        self.pace_bitrate = pace_bitrate
        self.bit_ns: float | None = 1e9 / rate if rate else None
        self.bitrate: int | None = rate
        dbr = bus_kwargs.get("data_bitrate")
        dbr = dbr if isinstance(dbr, int) and not isinstance(dbr, bool) and dbr > 0 else None
        fd = bus_kwargs.get("fd") is True or bus_kwargs.get("protocol") is can.CanProtocol.CAN_FD
        # a bus that carries CAN FD (python-can's fd=True) has a data bit rate, the contract's sign
        # of an FD bus to its nodes; without one given, FD frames without bit rate switch only
        # have a known length in time
        self._brs_rate = dbr
        self.data_bitrate: int | None = dbr or (rate if fd else None)
        # python-can's fd=True says the bus carries CAN FD even when its rates are set outside the
        # program (SocketCAN's `ip link`): the nodes `node` makes on it are FD enabled then too
        self.carries_fd = fd or dbr is not None
        self.capabilities = frozenset(
            {"bus-time", "one-shot", "latest-start", "error-frames"} | ({"sof-estimate"} if rate else set())
        )
        self.nodes: list[Node] = []
        self.buses: dict[Node, can.BusABC] = {}
        self._owned: set[can.BusABC] = set()
        self.rounds = 0  # arbitration happens in the controller underneath: no rounds seen here
        self.delivered = 0  # receptions go straight to the node: no lazy log
        self.lock = threading.RLock()
        self._t0, self._epoch0 = clock_pair()  # _epoch0: the wall-clock time of _t0, to read the buses' timestamps
        self._timers: list[tuple[int, int, Timer]] = []
        self.seqs = itertools.count(1)  # requests and timers (the contract's `seqs`)
        self._ready: deque[Node] = deque()
        self._inbox: deque[tuple[int, Node, can.Message]] = deque()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._busy_until = 0
        self._retry: dict[Any, int] = {}
        self.rx_ignored = 0  # FD and error frames seen on the bus (not CAN 2.0 data/remote)
        self.rx_error_frames: dict[str, int] = {}  # error frames each node's bus reported, by node name
        self.errors: list[str] = []
        self.lost: BusGone | None = None
        self.gone = threading.Event()
        self.on_lost: list[Callable[[BusGone], Any]] = []

    # ------------------------------------------------------------------ nodes
    def node(self, name: str, *, can_bus: can.BusABC | None = None, **config: Any) -> Node:
        """Create a `Node` (``config`` as for `Node`) on its own python-can connection; on a bus
        opened for CAN FD (python-can's ``fd=True``) it is FD enabled unless ``fd`` says otherwise,
        whether or not the driver knows the bit rates."""
        if self.carries_fd:
            config.setdefault("fd", FD)
        return self.add(Node(name, **config), can_bus)

    def add(self, node: Node, can_bus: can.BusABC | None = None) -> Node:
        """Attach ``node``; ``can_bus`` is its wire (default: one from the factory)."""
        if node.bus is not None:
            raise ValueError(f"node {node.name!r} is already attached to a bus")
        if any(n.name == node.name for n in self.nodes):
            raise ValueError(f"a node named {node.name!r} is already on this driver")
        node.check_listeners(self.capabilities)
        if can_bus is None:
            if self._factory is None:
                raise ValueError("give can_bus, or create the driver with interface/channel or a bus_factory")
            can_bus = self._factory(node.name)
            self._owned.add(can_bus)
        with self.lock:
            node.bus = self
            self.nodes.append(node)
            self.buses[node] = can_bus
            node.on_bus = True
            node.update_head()
        if self._threads:
            self._start_reader(node)
        return node

    # ------------------------------------------------------------------ the node's driver protocol
    def now(self) -> int:
        """Wall-clock ns since the driver was created."""
        return time.monotonic_ns() - self._t0

    @property
    def now_ns(self) -> int:
        """`now` as the contract's attribute (computed here: the wall clock)."""
        return time.monotonic_ns() - self._t0

    def call_at(self, time_ns: int, callback: Callable[..., Any], args: tuple[Any, ...] = ()) -> Timer:
        """Run ``callback(*args)`` at driver time ``time_ns`` (thread-safe)."""
        t = Timer(int(time_ns), callback, args)
        with self.lock:
            heapq.heappush(self._timers, (t.time, next(self.seqs), t))
        self._wake.set()
        return t

    def call_later(self, delay: int, callback: Callable[..., Any], *args: Any) -> Timer:
        """Run ``callback(*args)`` ``delay`` ns from now."""
        return self.call_at(self.now() + int(delay), callback, args)

    def submit(self, fn: Callable[..., Any], *args: Any) -> Timer:
        """Run ``fn(*args)`` on the scheduler thread as soon as possible (thread-safe)."""
        return self.call_at(0, fn, args)

    def offer(self, node: Node, req: Any) -> None:
        """``node`` offers a new head: hand it to the bus at the next turn of the loop."""
        self._ready.append(node)
        self._wake.set()

    def sync(self, node: Node) -> None:
        """Nothing to catch up: receptions are delivered at once."""

    def node_changed(self, node: Node) -> None:
        """Nothing to reclassify: every node is read and written the same way."""

    def filters_changed(self, node: Node) -> None:
        """Nothing to do: acceptance filtering is the node's (software), as in simulation."""

    def counters_changed(self, node: Node) -> None:
        """Nothing to do: the counters come from the bus's error frames."""

    def state_changed(self, node: Node, old: Any, new: Any, t: int) -> None:
        """A node bus off hands no frames to its bus until it recovers."""
        if new is BUS_OFF:
            node.on_bus = False
        elif old is BUS_OFF:
            node.on_bus = True
            if node.head is not None:
                self.offer(node, node.head)

    def start_recovery(self, node: Node) -> None:
        """Rule 12 as far as this driver can time it: 128 × 11 bit times from now (at the
        bitrate given; 1 ms without one), unless the bus reports the restart first."""
        bits = RECOVERY_OCCURRENCES * RECOVERY_RECESSIVE_BITS
        delay = int(bits * self.bit_ns) if self.bit_ns else 1_000_000
        self.call_at(self.now() + delay, self._recover, (node,))

    def _recover(self, node: Node) -> None:
        if node.state is BUS_OFF:
            node.recovered(self.now())

    # ------------------------------------------------------------------ running
    def start(self) -> PyCanDriver:
        """Start the scheduler thread and one reader thread per node."""
        if self._threads:
            return self
        self._stop.clear()
        th = threading.Thread(target=self._loop, name="canstack-driver", daemon=True)
        self._threads.append(th)
        for node in self.nodes:
            self._start_reader(node)
        th.start()
        return self

    def run(self, duration_s: float) -> None:
        """Run for ``duration_s`` wall-clock seconds, then stop."""
        self.start()
        time.sleep(duration_s)
        self.stop()

    def stop(self) -> None:
        """Stop the threads (the buses stay open; `close` shuts down the ones it opened)."""
        self._stop.set()
        self._wake.set()
        for th in self._threads:
            th.join(2.0)
        self._threads = []

    def close(self) -> None:
        """Stop, then shut down the python-can buses this driver opened."""
        self.stop()
        for b in self._owned:
            b.shutdown()
        self._owned.clear()

    def __enter__(self) -> PyCanDriver:
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def _start_reader(self, node: Node) -> None:
        th = threading.Thread(
            target=self._read, args=(node, self.buses[node]), name=f"canstack-rx-{node.name}", daemon=True
        )
        self._threads.append(th)
        th.start()

    def _read(self, node: Node, bus: can.BusABC) -> None:
        inbox = self._inbox
        failures = 0
        while not self._stop.is_set() and self.lost is None:
            try:
                msg = bus.recv(0.05)
            except can.CanError as exc:
                failures += 1
                if isinstance(exc, BusLost) or getattr(bus, "_is_shutdown", False):
                    self._lose(node, bus, getattr(exc, "reason", str(exc)))
                    return
                if failures == 1:
                    self.errors.append(f"{node.name}: receive failed: {exc}")
                if failures >= RECV_FAILURES_LOST:
                    self._lose(node, bus, f"receive keeps failing ({failures} tries): {exc}")
                    return
                self._stop.wait(0.05)
                continue
            failures = 0
            if msg is not None:
                inbox.append((self._stamp(msg), node, msg))
                self._wake.set()
            elif getattr(bus, "_is_shutdown", False):  # shut down under the driver: recv says nothing more
                self._lose(node, bus, "the bus was shut down")
                return

    def _lose(self, node: Node, bus: can.BusABC, reason: str) -> None:
        """``node``'s bus is gone: stop handing frames to any bus, say so once, wake the owner."""
        with self.lock:
            if self.lost is not None:
                return
            desc = getattr(bus, "channel_info", None) or str(getattr(bus, "channel", "")) or type(bus).__name__
            self.lost = BusGone(node.name, str(desc), self.now(), time.time(), " ".join(reason.split()))
            for n in self.nodes:
                n.on_bus = False
            self._ready.clear()
        self.errors.append(f"{node.name}: {self.lost.describe()}")  # for owners that read errors only
        self.gone.set()
        self._wake.set()
        for cb in list(self.on_lost):
            self._guard(cb, self.lost)

    def _stamp(self, msg: can.Message) -> int:
        """A received frame's time on this driver's clock: the bus's own timestamp (the kernel's
        for SocketCAN, the wire time for canstack) when it is a wall-clock time near now, else
        the time it reached this thread."""
        now = self.now()
        ts = msg.timestamp
        if ts:
            t = int((ts - self._epoch0) * 1e9)
            if now - 2_000_000_000 < t <= now + 1_000_000:
                return t
        return now

    def _loop(self) -> None:
        timers = self._timers
        inbox = self._inbox
        while not self._stop.is_set():
            with self.lock:
                now = self.now()
                while timers and timers[0][0] <= now:
                    _, _, t = heapq.heappop(timers)
                    if not t.cancelled:
                        self._guard(t.callback, *t.args)
                while inbox:
                    t_rx, node, msg = inbox.popleft()
                    self._guard(self._receive, t_rx, node, msg)
                retry_at = self._transmit()
                nxt = timers[0][0] if timers else now + 50_000_000
                if retry_at is not None:
                    nxt = min(nxt, retry_at)
            if self._ready and retry_at is None:
                continue
            delay = (nxt - self.now()) / 1e9
            if delay > 0 and not inbox:
                self._wake.wait(min(delay, 0.05))
            self._wake.clear()

    def _guard(self, fn: Callable[..., Any], *args: Any) -> None:
        try:
            fn(*args)
        except Exception as exc:  # a failing callback must not stop the other nodes
            self.errors.append(f"{getattr(fn, '__qualname__', fn)}: {type(exc).__name__}: {exc}")

    def _receive(self, t: int, node: Node, msg: can.Message) -> None:
        if msg.is_error_frame:
            self.rx_error_frames[node.name] = self.rx_error_frames.get(node.name, 0) + 1
            self._error_frame(t, node, msg)
            return
        try:
            frame = Frame.from_message(msg)
        except ValueError:
            self.rx_ignored += 1
            return
        node.deliver(t, frame, None, self._sof(t, frame))
        reply = node.remote_reply(frame)
        if reply is not None and node.on_bus:
            node.send(reply)

    def _sof(self, t_end: int, frame: Frame) -> int:
        """Start of frame estimated from its end: the frame's stuffed length at the bit rate (an
        FD frame with BRS: its data phase at the data bit rate, the rest at the nominal one)."""
        if self.bit_ns is None or self.bitrate is None:
            return -1
        if frame.fd and frame.brs:
            if self._brs_rate is None:
                return -1  # its length in time is unknown without the data bit rate
            return t_end - (frame.encoded or frame.bits).duration_ns(self.bitrate, self._brs_rate)
        return t_end - round(frame.bits.length * self.bit_ns)

    def _error_frame(self, t: int, node: Node, msg: can.Message) -> None:
        """The bus underneath reports its controller's error state: the node's counters and
        state follow it (rules 9-11 through `Node.set_counters`, rule 12 through `recovered`)."""
        info = decode_error_frame(msg)
        if info is None:
            self.rx_ignored += 1
            return
        if info["restarted"] or info["active"]:
            if node.state is BUS_OFF:
                node.recovered(t)
        if info["counters"] is not None:
            tec, rec = info["counters"]
            if info["bus_off"]:
                tec = max(tec, BUS_OFF_LIMIT)
            node.set_counters(tec, rec, t)
        elif info["bus_off"]:
            node.set_counters(max(node.tec, BUS_OFF_LIMIT), node.rec, t)

    def _transmit(self) -> int | None:
        """Hand the heads of ready nodes to their buses, lowest arbitration key first; returns
        the time to try again when pacing or a retry holds them back."""
        ready = self._ready
        waiting: list[Node] = []  # nodes whose head waits for its retry time: offered again after it
        sent = 0
        while ready and sent < _BATCH and self.lost is None:
            nodes = dict.fromkeys(ready)  # dedupe, keep order
            ready.clear()
            heads = sorted((n.head.key, n.head.seq, n) for n in nodes if n.head is not None)
            for i, (_, _, node) in enumerate(heads):
                req = node.head
                if req is None or req.state is not QUEUED or req.on_wire or not node.on_bus:
                    continue
                now = self.now()
                if req.not_after is not None and now > req.not_after:
                    continue  # its latest start passed: the node's expiry timer withdraws it
                if self.pace_bitrate is not None and now < self._busy_until:
                    ready.extend(h[2] for h in heads[i:])
                    ready.extend(waiting)
                    return self._busy_until
                if self._retry.get(req, 0) > now:
                    waiting.append(node)
                    continue
                self._send_one(node, req, now)
                sent += 1
        ready.extend(waiting)
        if ready and self.lost is None:
            pending = [self._retry.get(n.head, 0) for n in ready if n.head is not None]
            return max(self.now(), min(pending)) if pending else self.now()
        ready.clear()
        return None

    def _send_one(self, node: Node, req: Any, now: int) -> None:
        frame: Frame = req.frame
        bus = self.buses[node]
        try:
            bus.send(to_message(frame, timestamp=time.time()), timeout=0.1)
        except can.CanError as exc:
            if isinstance(exc, BusLost) or getattr(bus, "_is_shutdown", False):
                self._lose(node, bus, getattr(exc, "reason", str(exc)))
                return
            if req.one_shot:
                self._retry.pop(req, None)
                node.fail(req, self.now(), f"send failed (one-shot): {exc}", "send")
            else:
                self._retry[req] = now + RETRY_NS
                node.retry(req)  # counted as a retransmission and offered again
                if req.retries == SEND_FAILURES_REPORTED:  # not congestion any more: say so, once
                    self.errors.append(f"{node.name}: send keeps failing ({req.retries} tries): {exc}")
            return
        if self.pace_bitrate is not None:
            self._busy_until = (
                max(now, self._busy_until)
                + (frame.bits.length + INTERMISSION_BITS) * 1_000_000_000 // self.pace_bitrate
            )
        self._retry.pop(req, None)
        done = self.now()  # bus.send returned: the earliest the driver knows the frame left
        nxt = node.confirm(req, done, self._sof(done, frame))
        if nxt is not None:
            self.offer(node, nxt)


def decode_error_frame(msg: can.Message) -> dict[str, Any] | None:
    """What a SocketCAN error frame (linux/can/error.h) says about the controller's state: the
    counters (``CAN_ERR_CNT``: TEC in data[6], REC in data[7]), bus off (``CAN_ERR_BUSOFF``),
    restarted after bus off (``CAN_ERR_RESTARTED``), back to error active (``CAN_ERR_CRTL`` with
    ``CAN_ERR_CRTL_ACTIVE`` in data[1]). None when it carries none of these."""
    if not msg.is_error_frame:
        return None
    cls = msg.arbitration_id
    data = bytes(msg.data or b"")
    counters = (data[6], data[7]) if cls & CAN_ERR_CNT and len(data) >= 8 else None
    info = {
        "counters": counters,
        "bus_off": bool(cls & CAN_ERR_BUSOFF),
        "restarted": bool(cls & CAN_ERR_RESTARTED),
        "active": bool(cls & CAN_ERR_CRTL and len(data) >= 2 and data[1] & CAN_ERR_CRTL_ACTIVE),
    }
    if counters is None and not (info["bus_off"] or info["restarted"] or info["active"]):
        return None
    return info
