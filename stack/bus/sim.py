"""The simulated bus: a deterministic discrete-event engine with an integer-nanosecond clock.

Model (CAN 2.0 / ISO 11898-1, at frame granularity with bit-exact lengths):
- When the bus is idle (3 bits of intermission after EOF or after an error delimiter) every node
  with a pending frame starts; bitwise arbitration picks the lowest arbitration key (data beats
  remote, standard beats extended with the same base ID); losers retry at the next idle.
- The winning frame occupies the bus for its exact stuffed length (SOF..EOF), then intermission.
- Every other node on the bus that is not listen-only acknowledges; a transmitter without any
  acknowledging node gets an ACK error and retransmits (fault confinement hooks in `stack.bus.attempt`).
- Two nodes sending the same arbitration field but different frames (for example two remote
  frames with the same ID and different DLC) collide after arbitration: the one sending
  recessive where the other sends dominant sees a bit error and the attempt ends in an error
  frame. The engine reports it (`collisions`, trace records of kind 'collision').

CAN FD (ISO 11898-1:2015), on a bus made with a data bit rate (``data_bitrate``):
- A node is FD enabled, tolerant or classic (`stack.controller.node.Node.fd`); only an FD-enabled
  node sends FD frames, and only FD-enabled nodes receive and acknowledge them.
- An FD frame arbitrates as a classical data frame of its identifier (RRS is dominant, FDF comes
  after arbitration) and lasts its exact length at the nominal rate, except with BRS the bits
  after BRS up to the CRC delimiter at the data rate (`frame_ns`); error flags, delimiters,
  overload frames and intermission are always at the nominal rate, and an error in the data phase
  ends it (`stack.bus.attempt`). Its ESI is recessive when its transmitter is error passive at SOF.
- A tolerant node goes bus integrating at FDF (the protocol exception): no error, no counter. A
  classic (CAN 2.0) node answers an FD frame with an error frame (`stack.bus.fdnodes`).

Determinism: events at the same time run in the order they were scheduled; arbitration at an
instant runs after every timer due at that instant; nothing reads the wall clock or an unseeded
random source, so a scenario with the same seed gives the same trace.

Hot path, hand-written on purpose (DESIGN.md allows it for the event loop): the current
transmission and the next arbitration are two slots compared with the timer heap instead of
heap events, contenders sit in their own heap (O(log n) per round for 1000 nodes), runs of clean
frames go through one loop with local variables (`stack.bus.fastpath`), and receivers that only
buffer frames (no callbacks) read a shared delivery log lazily — batched when the log is flushed
— instead of being visited per frame (`stack.bus.delivery`). See `python -m stack.bench` for the
figures.

`SimBus` is assembled from parts, each a mixin in a module of its own: arbitration and the
completion of clean frames (`stack.bus.arbitration`), the fast loop (`stack.bus.fastpath`), the
delivery log (`stack.bus.delivery`), bit-level attempts (`stack.bus.bitlevel`) and statistics
(`stack.bus.stats`). This module holds the fields, the nodes' bookkeeping, the clock, the run
loop and rule 12's recovery count.
"""

from __future__ import annotations

import heapq
import itertools
import random
from collections.abc import Callable
from typing import Any

from stack.bus.arbitration import Arbitration
from stack.bus.attempt import AttemptResult, brs_position
from stack.bus.bitlevel import BitLevelAttempts
from stack.bus.delivery import LazyDelivery
from stack.bus.fastpath import FastFrames
from stack.bus.stats import BusStatistics, IdStats
from stack.bus.trace import DiscardedTrace, TraceRecord
from stack.controller.confinement import BUS_OFF, PASSIVE, RECOVERY_OCCURRENCES, RECOVERY_RECESSIVE_BITS, ErrorState
from stack.controller.node import CLASSIC, FD, Node, Timer
from stack.controller.queues import QUEUED, TxRequest
from stack.wire.coding import INTERMISSION_BITS
from stack.wire.frame import Frame

__all__ = ["SimBus", "TraceRecord", "IdStats", "SUSPEND_BITS", "MAX_DATA_BITRATE"]

_heappush = heapq.heappush
INF = float("inf")
SUSPEND_BITS = 8
# ISO 11898-1:2015 sets no upper limit to the data phase; transceivers of ISO 11898-2:2016 are
# specified for 2 and 5 Mbit/s, SIC ones up to 8 (the limit of `canstack frame --data-bitrate`)
MAX_DATA_BITRATE = 16_000_000
FD_DURATION_CACHE = 4096  # FD frame durations kept per bus (by the frame's bits)


class SimBus(Arbitration, FastFrames, LazyDelivery, BitLevelAttempts, BusStatistics):
    """A simulated CAN bus with a virtual clock (ns) and a bitrate (1 kbit/s .. 1 Mbit/s).

    ``data_bitrate`` makes it a CAN FD bus: the bit rate of the data phase of FD frames with BRS
    (from the nominal bit rate to 16 Mbit/s). Without it the bus is a classical CAN bus: its nodes
    are CAN 2.0 controllers unless made otherwise (`Node.fd`), none of which sends FD frames.
    ``record`` keeps a `TraceRecord` per bus event in ``trace`` — or, with ``keep=False``, only
    hands each to the `on_trace` listeners (a trace streamed to a file, receptions counted: memory
    stays flat however long the run); ``seed`` seeds ``rng`` (used by
    fault injection and by scenario code that asks for randomness). It is a driver for nodes in
    the sense of `stack.controller.contract` and knows everything a node can be told.
    """

    capabilities = frozenset({"bus-time", "sof", "arbitration-lost", "error-confinement", "one-shot", "latest-start"})

    # the fields as slots: the engine reads them once a frame (a dict of over 30 keys is slower)
    __slots__ = (
        "bitrate",
        "data_bitrate",
        "name",
        "seed",
        "rng",
        "record",
        "trace",
        "nodes",
        "_dur",
        "_ifs_ns",
        "_suspend_ns",
        "bit_ns",
        "now_ns",
        "_timers",
        "seqs",
        "_contenders",
        "_suspended",
        "rounds",
        "_idle_at",
        "_tx",
        "_tx_end",
        "_log",
        "_log_base",
        "delivered",
        "_lazy",
        "_eager",
        "_arb_watch",
        "_rtr",
        "_key_receivers",
        "_ack_count",
        "frames_ok",
        "error_frames",
        "collisions",
        "busy_ns",
        "id_stats",
        "_bus_listeners",
        "_rec_nonzero",
        "_faults",
        "_recessive_events",
        "_busoff",
        "_busoff_marks",
        "_idle_bits",
        "_unacked",
        "_fd_ns",
        "_non_fd",
        "_classic",
        "_eager_fd",
        "_fd_ack_count",
        "__dict__",
        "__weakref__",
    )

    def __init__(
        self,
        bitrate: int = 500_000,
        *,
        data_bitrate: int | None = None,
        seed: int = 0,
        name: str = "bus0",
        record: bool = True,
        keep: bool = True,
    ) -> None:
        if isinstance(bitrate, bool) or not isinstance(bitrate, int) or not 1_000 <= bitrate <= 1_000_000:
            raise ValueError(f"bitrate {bitrate!r}: a CAN bus arbitrates at 1000..1000000 bit/s")
        if data_bitrate is not None and (
            isinstance(data_bitrate, bool)
            or not isinstance(data_bitrate, int)
            or not bitrate <= data_bitrate <= MAX_DATA_BITRATE
        ):
            raise ValueError(
                f"data bit rate {data_bitrate!r}: a whole number of bit/s from the nominal bit rate ({bitrate}) "
                f"to {MAX_DATA_BITRATE} (the data phase is never slower than arbitration)"
            )
        self.bitrate = bitrate
        self.data_bitrate = data_bitrate
        self.name = name
        self.seed = seed
        self.rng = random.Random(seed)
        self.record = record
        self.trace: list[TraceRecord] = [] if keep else DiscardedTrace()
        self.nodes: list[Node] = []
        self._dur = [n * 1_000_000_000 // bitrate for n in range(1024)]
        self._ifs_ns = self._dur[INTERMISSION_BITS]
        self._suspend_ns = self._dur[SUSPEND_BITS]
        self.bit_ns = 1_000_000_000 / bitrate
        self.now_ns = 0
        self._timers: list[tuple[int, int, Timer]] = []
        self.seqs = itertools.count(1)  # requests and timers: ties order by it (the contract's `seqs`)
        self._contenders: list[tuple[int, int, TxRequest]] = []  # (key, seq, request): a heap
        self._suspended: list[Node] = []
        self.rounds = 0
        self._idle_at = 0
        # the attempt on the wire: transmitters, start, its bit-level result (None: a clean frame)
        # and the clean frame as sent
        self._tx: tuple[tuple[TxRequest, ...], int, AttemptResult | None, Frame | None] | None = None
        self._tx_end: int = 0
        # reception
        self._log: list[tuple[int, Frame, Node]] = []
        self._log_base = 0  # receptions before the first entry of _log
        self.delivered = 0  # receptions ever logged (_log_base + len(_log)): the contract's counter
        self._lazy: list[Node] = []
        self._eager: list[Node] = []
        self._arb_watch: list[Node] = []
        self._rtr: dict[tuple[int, bool], list[Node]] = {}
        self._key_receivers: dict[int, tuple[Node, ...]] = {}
        self._ack_count = 0
        # statistics
        self.frames_ok = 0
        self.error_frames = 0
        self.collisions = 0
        self.busy_ns = 0
        self.id_stats: dict[int, IdStats] = {}
        self._bus_listeners: list[Callable[[TraceRecord], Any]] = []
        # receivers whose REC rule 8 must decrement; a dict as an ordered set (insertion order)
        # so that state changes and what their listeners do happen in a deterministic order
        self._rec_nonzero: dict[Node, None] = {}
        self._faults: Any = None  # fault injection (stack.bus.faults), consulted per attempt
        self._recessive_events = 0  # occurrences of 11 recessive bits at frame ends (rule 12)
        self._busoff: set[Node] = set()  # rule 12 counting runs only while someone is bus off
        self._busoff_marks: dict[Node, int] = {}  # recessive-run count when each started recovering
        self._idle_bits = 0  # idle bits between frames, for rule 12 on an idle bus
        self._unacked: dict[Any, Any] = {}  # replays of unacknowledged attempts (`BitLevelAttempts`)
        # CAN FD: durations of frames with BRS by their bits (`frame_ns`); the nodes on the bus that
        # are not FD enabled, the CAN 2.0 ones among them; the buffering-free receivers and the
        # acknowledging nodes that are FD enabled (the only ones an FD frame reaches)
        self._fd_ns: dict[str, int] = {}
        self._non_fd: list[Node] = []
        self._classic: list[Node] = []
        self._eager_fd: list[Node] = []
        self._fd_ack_count = 0

    # ------------------------------------------------------------------ nodes
    def add(self, node: Node) -> Node:
        """Attach a node to the bus (it starts receiving and may transmit at the next idle).

        A node made FD enabled (``fd='fd'``) needs a bus with a data bit rate, as an FD
        controller needs its data bit timing (Linux refuses to bring one up without); a node whose
        ``fd`` was not given is FD enabled on such a bus and classic on one without (`Node.fd`)."""
        if node.bus is not None:
            raise ValueError(f"node {node.name!r} is already attached to a bus")
        if any(n.name == node.name for n in self.nodes):
            raise ValueError(f"a node named {node.name!r} is already on bus {self.name!r}")
        node.check_listeners(self.capabilities)
        if node.fd_declared and node.fd == FD and self.data_bitrate is None:
            raise ValueError(
                f"node {node.name!r} is FD enabled (fd='fd') but bus {self.name!r} has no data bit rate: "
                "give SimBus(bitrate, data_bitrate=...) (equal to bitrate for FD frames without bit rate switching)"
            )
        node.bus = self
        self.nodes.append(node)
        node.rx_cursor = self.delivered
        self.filters_changed(node)
        self.node_changed(node)
        node.update_head()
        return node

    def node(self, name: str, **config: Any) -> Node:
        """Create a `Node` with ``config`` (see Node) and attach it."""
        return self.add(Node(name, **config))

    def free_name(self, prefix: str = "node") -> str:
        """A node name not yet used on this bus: ``prefix`` followed by a number."""
        names = {n.name for n in self.nodes}
        i = len(self.nodes)
        while f"{prefix}{i}" in names:
            i += 1
        return f"{prefix}{i}"

    def __getitem__(self, name: str) -> Node:
        for n in self.nodes:
            if n.name == name:
                return n
        raise KeyError(
            f"no node named {name!r} on bus {self.name!r}: {', '.join(n.name for n in self.nodes) or 'none'}"
        )

    # -- what a fault injector (stack.bus.faults) works with ------------------------------------
    @property
    def faults(self) -> Any:
        """The `stack.bus.faults.FaultInjector` consulted on every attempt, or None."""
        return self._faults

    def attach_faults(self, injector: Any) -> None:
        """Consult ``injector`` on every attempt from now on (``FaultInjector(bus)`` calls this;
        one a bus): its ``attempt(bus, now, txs)`` says what goes wrong in an attempt, its
        ``unacknowledging(now)`` which nodes cannot drive the ACK slot."""
        if self._faults is not None:
            raise ValueError(f"bus {self.name!r} already has a fault injector")
        self._faults = injector

    @property
    def transmitting(self) -> bool:
        """True while an attempt is on the wire (until its completion has run)."""
        return self._tx is not None

    @property
    def idle_at(self) -> int:
        """When the bus is idle, ns: the end of the intermission after the attempt on the wire, or
        after the last one (in the past when the bus has been idle since)."""
        return self._tx_end + self._ifs_ns if self._tx is not None else self._idle_at

    def arbitration_due(self, now: int) -> bool:
        """True when a node offers a frame it may start at ``now``: an arbitration starts then."""
        return any(self._valid(e[2]) and e[2].node.ready_at <= now for e in self._contenders)

    def disconnect(self, node: Node) -> None:
        """Take a node off the wire: it neither receives, acknowledges nor transmits."""
        self.sync(node)
        node.connected = False
        self.node_changed(node)

    def remove(self, node: Node) -> None:
        """Detach a node for good (a client that left): it goes off the wire at once, its queued
        frames are aborted (`TxFailed` 'aborted'), and its name is free again. A frame of its
        own already on the wire finishes first (a controller cannot take back bits it sent);
        the node leaves the bus's lists when that transmission ends."""
        if node.bus is not self or node not in self.nodes:
            raise ValueError(f"node {node.name!r} is not on bus {self.name!r}")
        if node.connected:
            self.disconnect(node)
        for req in node.pending():
            node.abort(req)
        if self._tx is not None and any(q.node is node for q in self._tx[0]):
            self.call_at(self._tx_end + 1, self._detach, (node,))  # after the completion at _tx_end
        else:
            self._detach(node)

    def _detach(self, node: Node) -> None:
        if node not in self.nodes:
            return
        self.nodes.remove(node)
        self._rec_nonzero.pop(node, None)
        self._busoff.discard(node)
        if node.suspended:
            self._suspended = [n for n in self._suspended if n is not node]
            node.suspended = False
        self.node_changed(node)  # not connected: out of the delivery and arbitration lists
        self.filters_changed(node)
        node.on_bus = False
        node.bus = None

    def reconnect(self, node: Node) -> None:
        """Put a disconnected node back on the wire; it receives from now on."""
        node.connected = True
        node.rx_cursor = self.delivered
        self.node_changed(node)
        if node.offered is not None:
            node.offered.head_since = self.rounds
            self.offer(node, node.offered)
        else:
            node.update_head()

    def node_changed(self, node: Node) -> None:
        """Subscriptions, listeners or modes of ``node`` changed (the contract's notification),
        or its connection or state did: put the node in the lists the engine walks (buffering, callbacks, arbitration
        watchers). The lists are replaced, never changed in place: a loop delivering a frame
        keeps the list it started with even if a callback subscribes or unsubscribes."""
        was_lazy = node in self._lazy
        lazy = [n for n in self._lazy if n is not node]
        eager = [n for n in self._eager if n is not node]
        watch = [n for n in self._arb_watch if n is not node]
        on = node.connected and node.state is not BUS_OFF
        node.on_bus = on
        if on:
            # a node that is not FD enabled receives no FD frame: it is given each frame it gets
            # (`Node.deliver`) rather than reading the shared log, which every FD frame enters
            if node.subscribed or (self.data_bitrate is not None and node.fd != FD):
                self.sync(node)
                eager.append(node)
            else:
                if not was_lazy:  # frames delivered while it was eager or off the bus are not its
                    node.rx_cursor = self.delivered
                lazy.append(node)
            if node.watches_arbitration:
                watch.append(node)
        # keep the delivery order deterministic: attach order
        order = {n: i for i, n in enumerate(self.nodes)}
        self._lazy = sorted(lazy, key=order.__getitem__)
        self._eager = sorted(eager, key=order.__getitem__)
        self._arb_watch = sorted(watch, key=order.__getitem__)
        ackers = [n for n in self.nodes if n.connected and not n.listen_only and n.state is not BUS_OFF]
        self._ack_count = len(ackers)
        if self.data_bitrate is not None:
            self._fd_lists(ackers)

    def _fd_lists(self, ackers: list[Node]) -> None:
        """The nodes an FD frame treats apart: those on the bus that are not FD enabled (the
        CAN 2.0 ones among them destroy it), and the FD-enabled receivers and acknowledgers."""
        self._non_fd[:] = [n for n in self.nodes if n.on_bus and n.fd != FD]  # in place: the fast loop holds it
        self._classic = [n for n in self._non_fd if n.fd == CLASSIC]
        self._eager_fd = [n for n in self._eager if n.fd == FD]
        self._fd_ack_count = sum(1 for n in ackers if n.fd == FD)

    def filters_changed(self, node: Node) -> None:
        """Acceptance filters or remote replies of ``node`` changed (the contract's
        notification): the receivers per identifier and the reply mailboxes are looked up anew."""
        self._key_receivers = {}
        self._rtr = {}
        for n in self.nodes:
            for k in n.remote_replies:
                self._rtr.setdefault(k, []).append(n)

    # ------------------------------------------------------------------ clock
    def now(self) -> int:
        """Virtual time in ns."""
        return self.now_ns

    def call_at(self, time: int, callback: Callable[..., Any], args: tuple[Any, ...] = ()) -> Timer:
        """Schedule ``callback(*args)`` at virtual time ``time`` ns (not before now)."""
        if time < self.now_ns:
            time = self.now_ns
        t = Timer(time, callback, args)
        heapq.heappush(self._timers, (time, next(self.seqs), t))
        return t

    def call_later(self, delay: int, callback: Callable[..., Any], *args: Any) -> Timer:
        """Schedule ``callback(*args)`` ``delay`` ns from now."""
        return self.call_at(self.now_ns + int(delay), callback, args)

    def bits_to_ns(self, bits: int) -> int:
        """Duration of ``bits`` bit times in ns (at the nominal bit rate, floored to the ns)."""
        return bits * 1_000_000_000 // self.bitrate

    def frame_ns(self, frame: Frame) -> int:
        """The time ``frame`` takes on this bus from the start of SOF to the end of EOF, ns: its
        exact stuffed length at the nominal bit rate — except, in a CAN FD frame with BRS, the
        bits after BRS up to the CRC delimiter (`FrameBits.data_bits`) at the data bit rate
        (ISO 11898-1:2015) — floored to the ns as `bits_to_ns` is.

        FD durations are kept by the frame's bits (a dict hit on a string whose hash is cached);
        `FrameBits.duration_ns` gives the same to the nearest ns (equal whenever both bit times
        are whole ns)."""
        fb = frame.encoded or frame.bits
        if not fb.brs:
            return self._dur[len(fb.bits)]
        key = fb.bits
        t = self._fd_ns.get(key)
        if t is None:
            if len(self._fd_ns) >= FD_DURATION_CACHE:
                self._fd_ns.clear()
            t = self._fd_ns[key] = self.attempt_ns(len(key), (brs_position(frame) + 1, fb.crc_delim))
        return t

    # ------------------------------------------------------------------ engine
    def offer(self, node: Node, req: TxRequest) -> None:
        """``req`` is ``node``'s new offered request: it enters the next arbitration."""
        if node.on_bus and not node.suspended:  # a suspended node joins again in _wake
            _heappush(self._contenders, (req.key, req.seq, req))  # (once a frame: a module global)

    def counters_changed(self, node: Node) -> None:
        """TEC/REC of ``node`` changed: it is in the set rule 8 visits while its REC is above 0."""
        if node.rec > 0:
            self._rec_nonzero[node] = None
        else:
            self._rec_nonzero.pop(node, None)

    def run(self, until: int | None = None, *, duration: int | None = None, frames: int | None = None) -> SimBus:
        """Advance the simulation to virtual time ``until`` (ns), for ``duration`` ns, or until
        ``frames`` more frames were transmitted successfully — whichever comes first. With no
        bound it runs until nothing is left to do."""
        if duration is not None:
            until = self.now_ns + int(duration)
        limit = INF if until is None else until
        stop = INF if frames is None else self.frames_ok + frames
        if until is None and self._unbounded_risk():
            raise ValueError(
                "run() without until/duration would never end: a node keeps "
                "retransmitting without acknowledgement; give a time bound"
            )
        timers = self._timers
        heappop = heapq.heappop
        while self.frames_ok < stop:
            tt = timers[0][0] if timers else INF
            tb: float
            if self._tx is not None:
                tb = self._tx_end
            elif self._contenders:
                tb = self._idle_at if self._idle_at > self.now_ns else self.now_ns
            elif self._suspended:
                tb = max(self._idle_at, self.now_ns, min(n.ready_at for n in self._suspended))
            else:
                tb = INF
            if tt <= tb:
                if tt > limit or tt == INF:
                    break
                t, _, timer = heappop(timers)
                if timer.cancelled:
                    continue
                self.now_ns = t
                timer.callback(*timer.args)
            else:
                if tb > limit:
                    break
                self.now_ns = tb  # type: ignore[assignment]  # an int here: tb < tt, so it is not INF
                if self._tx is not None:
                    self._complete()
                elif self.fast and not (
                    self._suspended or self._arb_watch or self._faults is not None or self._ack_count < 2
                ):
                    if not self._fast_frames(tt, limit, stop):
                        self._arbitrate()
                else:
                    self._arbitrate()
        if until is not None and self.now_ns < until and self.frames_ok < stop:
            self.now_ns = until
        return self

    def next_event_time(self) -> float:
        """Virtual time (ns) of the next thing the engine will do: a timer, the end of the
        current transmission, or the next arbitration; ``inf`` when idle with nothing queued.
        A real-time driver sleeps until the wall clock reaches it."""
        tt = self._timers[0][0] if self._timers else INF
        tb: float
        if self._tx is not None:
            tb = self._tx_end
        elif self._contenders:
            tb = max(self._idle_at, self.now_ns)
        elif self._suspended:
            tb = max(self._idle_at, self.now_ns, min(n.ready_at for n in self._suspended))
        else:
            tb = INF
        return min(tt, tb)

    def _unbounded_risk(self) -> bool:
        """True when a node on the bus has a frame nobody can acknowledge: a run without a time
        bound would retransmit for ever (exception 1 of rule 3 keeps TEC at 128)."""
        pending = [n for n in self.nodes if n.on_bus and n.head is not None]
        if not pending:
            return False
        deaf: set[Node] = self._faults.unacknowledging(self.now_ns) if self._faults is not None else set()
        ackers = [n for n in self.nodes if n.on_bus and not n.listen_only and n not in deaf]
        if self.data_bitrate is None:  # (run() asks each time: kept as cheap as before FD)
            return all(not any(a is not p for a in ackers) for p in pending)

        def acknowledged(p: Node) -> bool:  # an FD frame by FD-enabled nodes only
            fd = p.head is not None and p.head.frame.fd
            return any(a is not p and (not fd or a.fd == FD) for a in ackers)

        return not any(acknowledged(p) for p in pending)

    # ------------------------------------------------------------------ fault confinement
    def state_changed(self, node: Node, old: ErrorState, new: ErrorState, t: int) -> None:
        """Fault confinement moved ``node`` from ``old`` to ``new`` (the contract's notification):
        bus off takes it off the bus (and starts rule 12's count if it recovers by itself),
        leaving bus off puts it back, leaving error passive ends suspend transmission."""
        if new is BUS_OFF:
            self._busoff.add(node)
            self.sync(node)
            self.node_changed(node)
            self._rec_nonzero.pop(node, None)
            if node.auto_recovery:
                self.start_recovery(node)
        elif old is BUS_OFF:
            self._busoff.discard(node)
            self._busoff_marks.pop(node, None)
            node.ready_at = 0
            node.rx_cursor = self.delivered
            self.node_changed(node)
            h = node.offered
            if h is not None and h.state is QUEUED:
                h.head_since = self.rounds
                self.offer(node, h)
            else:
                node.update_head()
        elif old is PASSIVE and new is not PASSIVE:
            node.ready_at = 0

    def _recessive_count(self, now: int) -> int:
        n = self._recessive_events
        if self._tx is None and now > self._idle_at:
            n += (now - self._idle_at) * self.bitrate // 11_000_000_000
        return n

    def start_recovery(self, node: Node) -> None:
        """Rule 12: bus off ends after 128 occurrences of 11 consecutive recessive bits."""
        self._busoff_marks[node] = self._recessive_count(self.now_ns)
        self.call_at(
            self.now_ns + self.bits_to_ns(RECOVERY_OCCURRENCES * RECOVERY_RECESSIVE_BITS), self._check_recovery, (node,)
        )

    def _check_recovery(self, node: Node) -> None:
        if node.state is not BUS_OFF:
            return
        done = self._recessive_count(self.now_ns) - self._busoff_marks[node]
        if done >= RECOVERY_OCCURRENCES:
            node.recovered(self.now_ns)  # back to error active: state_changed puts it on the bus
        else:
            self.call_at(
                self.now_ns + self.bits_to_ns((RECOVERY_OCCURRENCES - done) * RECOVERY_RECESSIVE_BITS),
                self._check_recovery,
                (node,),
            )
