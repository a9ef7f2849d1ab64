"""The master of a master/slave network: it runs its poll list as a cycle and is the only node
that starts a transaction.

`PollMaster` is the sans-IO master, built from its `MasterConfig` (as the TDMA FSE is built from
its `Schedule`): its states and what each event does in each are the transition table of
`profiles.polling._state` (``idle``, ``sending``, ``waiting``, ``stopped``), what it measures is
kept apart in `profiles.polling.stats`, and it sends through the callable it is given. `Master`
is the scenario profile that builds one on its node, with the node's frames and tracks.

A cycle starts ``cycle_ms`` after the previous one started, or — an *overrun*, reported as
`CycleOverrun` — as soon as the previous one ends if that is later: the schedule moves, openly,
rather than piling up or drifting silently. In a cycle the master runs each transaction of the
poll list in order:

1. It queues the request with a latest start of now + timeout (a request the bus cannot take in
   time is withdrawn, ``unsent``, and counts as a timeout).
2. From the request's SOF (`TxDone.sof`) the slave(s) have ``timeout_ms`` to answer, up to the end
   of the response: the response time measured is the same interval (request SOF to response
   end), so a response is counted exactly when its response time is within the timeout.
   A poll command longer than 8 bytes goes out in DeviceNet fragments, queued back to back
   (`profiles.polling.fragment`): the timeout runs from the first fragment's SOF, and an answer
   longer than 8 bytes counts when its last fragment completes it.
3. An answer ends the transaction (a bit-strobe: the answers of every strobed slave); the next
   request is queued at once. A timeout repeats a polled or remote request ``retries`` times;
   then the slave has *missed* the poll. After ``lost_after`` missed polls in a row the slave is
   *lost* (`SlaveLost`) and polled only every ``lost_poll_every`` cycles until it answers
   (`SlaveBack`; any answer of a lost slave, even a late one, brings it back).

A slave's change-of-state / cyclic messages are consumed whenever they arrive and acknowledged at
once when the link says so; the master's watchdog over each COS/cyclic connection (4 × its
expected packet rate, restarted by every message of it) reports the connection timed out
(`SlaveLost`, connection "cos") and back at its next message (`SlaveBack`). Bus off stops the master (`MasterStopped`; its slaves' watchdogs
fire); with ``restart_after_bus_off`` it starts a new cycle when its controller is error active
again (rule 12; `MasterResumed`).

With ``dup_mac_check`` the master first runs DeviceNet's duplicate MAC ID check
(`profiles.polling.dupmac`) and starts its first cycle ``offset_ms`` after going online (2 s
after power-up); a duplicate of its MAC ID is a communication fault (`CommunicationFault`,
`MasterStopped`): it stops for good.

Everything is timed on the node's clock (a drifting master runs a drifting cycle) and happens in
callbacks of the node API, so the master runs unchanged on the simulated bus and on python-can.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import TYPE_CHECKING, Any

from profiles.base import Context, Profile, frame_of
from profiles.polling._state import MasterEvent, MasterState, next_state
from profiles.polling.config import NETWORK_TABLE
from profiles.polling.connection import Watchdog
from profiles.polling.dupmac import DupMacCheck
from profiles.polling.events import (
    COS,
    CommunicationFault,
    CycleOverrun,
    MasterResumed,
    MasterStopped,
    Reporter,
    SlaveBack,
    SlaveLost,
)
from profiles.polling.fragment import Reassembler, fragment, io_frames
from profiles.polling.stats import CycleStats, SlaveLink
from stack import ErrorStateChanged, Frame, TxDone, TxFailed

if TYPE_CHECKING:  # pragma: no cover
    from profiles.declarations import MessageDecl, NodeDecl
    from profiles.polling.config import CosLink, MasterConfig, Transaction
    from profiles.responses import ResponseStats
    from stack import NodeAPI, Received, Timer, TxRequest

__all__ = ["PollMaster", "Master", "Send", "rx_filters"]

Send = Callable[..., "TxRequest | None"]
"""``send(message, not_after)``: queue one of the master's messages (a request with its latest
start, an acknowledgement with None) and return its request, or None when the node could not
take it (queue full, bus off); ``send(message, not_after, data)`` queues one fragment of a
fragmented request (the frame's ``data``, `profiles.polling.fragment`)."""


def rx_filters(messages: list[MessageDecl]) -> list[dict[str, Any]]:
    """python-can acceptance filters that pass exactly these messages' identifiers."""
    return [
        {"can_id": m.can_id, "can_mask": 0x1FFFFFFF if m.extended else 0x7FF, "extended": m.extended} for m in messages
    ]


class PollMaster(Reporter):
    """A poll-list master on ``node``, built from its ``config`` (see the module docstring);
    ``send`` queues its frames. ``state`` follows `profiles.polling._state`; ``stats`` and
    ``links`` hold what it measured."""

    def __init__(
        self, node: NodeAPI, config: MasterConfig, *, send: Send, plot_window: tuple[int, int] | None = None
    ) -> None:
        Reporter.__init__(self)
        self.node = node
        self.config = config
        self.send = send
        self.state = MasterState.IDLE
        self.links = {s: SlaveLink(s) for s in config.slaves}
        self.stats = CycleStats(config, plot_window)
        self._answers: dict[int, tuple[Transaction, str]] = {}
        self._reassembly: dict[int, Reassembler] = {}  # fragmented answers, by identifier
        self.fragments = {tx.request.name: io_frames(tx.request) for tx in config.transactions}
        watched: list[MessageDecl] = []
        for tx in config.transactions:
            for s, r in zip(tx.slaves, tx.responses):
                self._answers[frame_of(r).key] = (tx, s)
                watched.append(r)
                io = r.options.get("io_data")
                if io is not None:
                    self._reassembly[frame_of(r).key] = Reassembler(len(io))
        self._cos: dict[int, CosLink] = {}
        self.cos_watchdogs: dict[str, Watchdog] = {}
        for link in config.cos:
            for m in link.messages:
                self._cos[frame_of(m).key] = link
                watched.append(m)
            self.cos_watchdogs[link.slave] = Watchdog(node, link.watchdog_ns, partial(self._cos_lost, link.slave))
        self._filters = rx_filters(watched)
        # the cycle
        self.cycle = 0
        self.cycle_start = 0
        self.first_sof: int | None = None
        self.first_sof_bus: int | None = None
        self.ran = 0  # transactions run in this cycle
        self.clean = True  # every slave due answered in time so far
        # the transaction in progress
        self._idx = 0
        self._tx: Transaction | None = None
        self._attempt = 0
        self._req: TxRequest | None = None
        self._rest: list[TxRequest] = []  # the request's further fragments
        self._queued_at = 0
        self._sof = 0
        self._awaiting: set[str] = set()
        self._timer: Timer | None = None
        self._cycle_timer: Timer | None = None
        self.dup_mac: DupMacCheck | None = None
        if config.dup_mac is not None:
            vendor, serial = config.dup_mac
            self.dup_mac = DupMacCheck(
                node,
                config.mac_id,
                vendor_id=vendor,
                serial_number=serial,
                on_online=self._online,
                on_fault=self._comm_fault,
            )

    def _to(self, event: MasterEvent) -> bool:
        """Take ``event`` through the transition table; False (and no change) when the state
        ignores it."""
        nxt = next_state(self.state, event)
        if nxt is None:
            return False
        self.state = nxt
        return True

    # ------------------------------------------------------------------ wiring
    def start(self) -> None:
        """Subscribe to the answers and COS messages, watch the requests and the error state, and
        arm the first cycle at ``offset_ms`` — after the duplicate MAC ID check, when it has one."""
        if self._filters:
            self.node.subscribe(self._on_frame, self._filters)
        self.node.listen(TxDone, self._on_done)
        self.node.listen(TxFailed, self._on_failed)
        self.node.listen(ErrorStateChanged, self._on_state)
        if self.dup_mac is not None:
            self.dup_mac.start()
        else:
            self._online(self.node.now())

    def _online(self, t: int) -> None:
        """The master may use the network from ``t`` on: its connections start."""
        if self.state is MasterState.FAULTED:
            return
        for w in self.cos_watchdogs.values():
            w.start(t)
        self._cycle_timer = self.node.call_at(t + self.config.offset_ns, self._begin_cycle)

    def _comm_fault(self, t: int, reason: str) -> None:
        """The duplicate MAC ID check heard our MAC ID: communication fault, for good."""
        if not self._to(MasterEvent.COMM_FAULT):
            return
        self._halt()
        self._emit(CommunicationFault(t, self.config.name, self.config.mac_id, reason))
        self._emit(MasterStopped(t, self.config.name, "duplicate MAC ID"))

    # ------------------------------------------------------------------ the cycle
    def _begin_cycle(self) -> None:
        self._cycle_timer = None
        if not self._to(MasterEvent.CYCLE_START):
            return
        self.cycle += 1
        self.cycle_start = self.node.now()
        self.first_sof = self.first_sof_bus = None
        self.ran = 0
        self.clean = True
        self._idx = 0
        self._next(self.cycle_start)

    def _next(self, t: int) -> None:
        """Run the next transaction that has a slave due in this cycle, or end the cycle."""
        txs = self.config.transactions
        every = self.config.lost_poll_every
        while self._idx < len(txs):
            tx = txs[self._idx]
            self._idx += 1
            due = [s for s in tx.slaves if self.links[s].due(self.cycle, every)]
            if due:
                self._tx = tx
                self._attempt = 0
                self.ran += 1
                self._send(tx, set(due))
                return
        self._end_cycle(t)

    def _send(self, tx: Transaction, awaiting: set[str]) -> None:
        self._awaiting = awaiting
        now = self._queued_at = self.node.now()
        self._to(MasterEvent.REQUEST)
        self._drop_rest()
        frames = self.fragments[tx.request.name]
        if len(frames) == 1:
            self._req = self.send(tx.request, now + tx.timeout_ns)
        else:  # DeviceNet I/O fragments, back to back: the first one carries the latest start
            self._req = self.send(tx.request, now + tx.timeout_ns, frames[0])
            if self._req is not None:
                self._rest = [r for f in frames[1:] if (r := self.send(tx.request, None, f)) is not None]
        if self._req is None:  # queue full, or bus off (then the state listener stops the master)
            self.stats.unsent += 1
            self.clean = False
            if self.state is not MasterState.STOPPED:
                self._arm(now + tx.timeout_ns)

    def _drop_rest(self) -> None:
        """Take back the fragments of an earlier attempt still queued."""
        for r in self._rest:
            self.node.abort(r)
        self._rest = []

    def _arm(self, at: int) -> None:
        if self._timer is not None:
            self._timer.cancel()
        self._timer = self.node.call_at(at, self._timeout)

    def _on_done(self, ev: TxDone) -> None:
        req, tx = self._req, self._tx
        if self._rest and ev.request is self._rest[-1] and tx is not None:
            self.stats.request_end(tx.request.name, ev.time - self.cycle_start)  # the last fragment
            return
        if req is None or ev.request is not req or tx is None or not self._to(MasterEvent.SENT):
            return
        self._sof = ev.sof if ev.sof >= 0 else self._queued_at
        if self.first_sof is None:
            self.first_sof = self._sof
            self.first_sof_bus = req.sof if req.sof >= 0 else None
        for s in self._awaiting:
            self.links[s].polls += 1
        if not self._rest:
            self.stats.request_end(tx.request.name, ev.time - self.cycle_start)
        self._arm(self._sof + tx.timeout_ns)

    def _on_failed(self, ev: TxFailed) -> None:
        if ev.request is not self._req or not self._to(MasterEvent.UNSENT):
            return
        # not started by its latest start time (a bus too busy), or dropped: no answer can come
        self._drop_rest()
        self.stats.unsent += 1
        self.clean = False
        self._req = None
        self._timeout()

    def _on_frame(self, ev: Received) -> None:
        key = ev.frame.key
        hit = self._answers.get(key)
        reassembly = self._reassembly.get(key)
        if reassembly is not None and reassembly.feed(ev.frame.data) is None:
            return  # a fragment of an answer: it counts when its last fragment completes it
        if hit is not None:
            tx, slave = hit
            link = self.links[slave]
            # only an answer to the request that went out counts; one that comes while a retry is
            # still queued, or that ended before the retry started (a wall-clock bus whose reader
            # thread handed it over late), answers the attempt that timed out: late
            if tx is self._tx and slave in self._awaiting and ev.time > self._sof and self._to(MasterEvent.ANSWER):
                link.responses += 1
                link.response.add(ev.time - self._sof)
                link.answered(ev.time)
                link.in_a_row = 0
                if link.lost:
                    self._back(link, ev.time)
                self._awaiting.discard(slave)
                if not self._awaiting:
                    self.stats.answers_end(tx.request.name, ev.time - self.cycle_start)
                    if self._timer is not None:
                        self._timer.cancel()
                        self._timer = None
                    self._req = None
                    self._next(ev.time)
            else:
                link.late += 1
                if link.lost:
                    self._back(link, ev.time)
            return
        cos = self._cos.get(key)
        if cos is not None:
            link = self.links[cos.slave]
            link.cos += 1
            if self.cos_watchdogs[cos.slave].kick(ev.time):
                link.cos_back(ev.time)
                self._emit(SlaveBack(ev.time, self.config.name, link.name, COS))
            if cos.ack is not None and self._to(MasterEvent.COS):
                if self.send(cos.ack, None) is not None:
                    link.acks += 1

    def _timeout(self) -> None:
        self._timer = None
        tx = self._tx
        if tx is None or not self._to(MasterEvent.TIMEOUT):
            return
        for s in self._awaiting:
            self.links[s].timeouts += 1
        self.clean = False
        if self._attempt < tx.retries:
            self._attempt += 1
            self._send(tx, set(self._awaiting))
            return
        now = self.node.now()
        for s in sorted(self._awaiting):
            self._miss(self.links[s], now)
        self._awaiting = set()
        self._req = None
        self._next(now)

    def _miss(self, link: SlaveLink, t: int) -> None:
        link.last_end = None
        link.missed += 1
        link.in_a_row += 1
        if not link.lost and link.in_a_row >= self.config.lost_after:
            link.lost = True
            link.lost_cycle = self.cycle
            link.lost_periods.append([t, None])
            self._emit(SlaveLost(t, self.config.name, link.name, link.in_a_row))

    def _cos_lost(self, slave: str, t: int) -> None:
        """The watchdog of ``slave``'s COS/cyclic connection expired: the connection timed out."""
        self.links[slave].cos_lost_at(t)
        self._emit(SlaveLost(t, self.config.name, slave, 0, COS))

    def _back(self, link: SlaveLink, t: int) -> None:
        link.lost = False
        link.in_a_row = 0
        if link.lost_periods and link.lost_periods[-1][1] is None:
            link.lost_periods[-1][1] = t
        self._emit(SlaveBack(t, self.config.name, link.name))

    def _end_cycle(self, t: int) -> None:
        self._tx = None
        self._to(MasterEvent.CYCLE_END)
        start = self.first_sof if self.first_sof is not None else self.cycle_start
        due = self.cycle_start + self.config.cycle_ns
        overrun = t > due
        if self.ran:
            self.stats.cycle(t - start, self.clean, self.first_sof_bus, overrun)
        if overrun:
            self.stats.overruns += 1
            self._emit(CycleOverrun(t, self.config.name, self.cycle, t - start))
        self._cycle_timer = self.node.call_at(max(due, t), self._begin_cycle)

    # ------------------------------------------------------------------ fault confinement
    def _halt(self) -> None:
        """Stop: timers off, the request in progress taken back, no watchdog verdicts (a stopped
        master consumes nothing)."""
        self.stats.stopped_at.append(self.node.now())
        for timer in (self._timer, self._cycle_timer):
            if timer is not None:
                timer.cancel()
        self._timer = self._cycle_timer = None
        req, self._req, self._tx = self._req, None, None
        if req is not None:
            self.node.abort(req)
        for w in self.cos_watchdogs.values():
            w.stop()

    def _on_state(self, ev: ErrorStateChanged) -> None:
        if ev.new == "bus-off" and self._to(MasterEvent.BUS_OFF):
            self._halt()
            self._emit(MasterStopped(ev.time, self.config.name, "bus off"))
        elif ev.new == "error-active" and self.config.restart_after_bus_off and self._to(MasterEvent.RECOVERED):
            self._emit(MasterResumed(ev.time, self.config.name))
            for w in self.cos_watchdogs.values():
                w.start(ev.time)
            self._begin_cycle()

    # ------------------------------------------------------------------ results
    def figures(self) -> dict[str, Any]:
        """The master's figures (`CycleStats.figures`): its cycles, its state and its events (and
        its duplicate MAC ID check's, when it has one)."""
        out = self.stats.figures(self.cycle, self.state.value, self.events)
        if self.dup_mac is not None:
            out["dup_mac_check"] = self.dup_mac.figures()
        return out


class Master(Profile):
    """The ``master`` profile: a `PollMaster` on the node, built from the scenario's network,
    sending the node's declared frames (requests, acknowledgements) through its tracks."""

    kind = "master"

    def __init__(self, node: NodeAPI, decl: NodeDecl, context: Context) -> None:
        super().__init__(node, decl, context)
        self.config: MasterConfig = context.scenario.tables[NETWORK_TABLE].masters[decl.name]
        self.frames = {m.name: frame_of(m) for m in decl.messages}
        self._track = {m.name: context.recorder.track(m) for m in decl.messages}
        w = context.scenario.plot.get("window_ms")
        # the cycles the poll-cycle plot draws: its window ([plot] window_ms, else the first 50 ms)
        window = (round(w[0] * 1e6), round(w[1] * 1e6)) if w else (0, 50_000_000)
        self.poller = PollMaster(node, self.config, send=self._send, plot_window=window)

    def _send(self, m: MessageDecl, not_after: int | None, data: bytes | None = None) -> TxRequest | None:
        frame = self.frames[m.name] if data is None else Frame(m.can_id, data, extended=m.extended)
        if not_after is None:
            return self.queue(frame, self._track[m.name])
        return self.queue(frame, self._track[m.name], not_after=not_after)

    def start(self) -> None:
        """Start polling (`PollMaster.start`)."""
        self.poller.start()

    def set_data(self, name: str, data: bytes) -> None:
        """Application hook: the output data the next requests of message ``name`` carry (the
        whole I/O message of a fragmented one, of its connection's size)."""
        frags = self.poller.fragments.get(name)
        if frags is not None and len(frags) > 1:
            size = sum(len(f) - 1 for f in frags)
            if len(data) != size:
                raise ValueError(f"{name}: {len(data)} bytes for a {size}-byte fragmented I/O connection")
            self.poller.fragments[name] = fragment(data)
            return
        old = self.frames[name]
        self.frames[name] = type(old)(old.can_id, data, extended=old.extended)

    @property
    def state(self) -> MasterState:
        """The master's state (`profiles.polling._state.MasterState`)."""
        return self.poller.state

    @property
    def events(self) -> list[Any]:
        """Every event the master reported, in order (`profiles.polling.events`)."""
        return self.poller.events

    def listen(self, callback: Callable[[Any], Any]) -> None:
        """Call ``callback(event)`` for every event the master reports from now on."""
        self.poller.listen(callback)

    @property
    def links(self) -> dict[str, SlaveLink]:
        """The master's view of each slave."""
        return self.poller.links

    @property
    def stats(self) -> CycleStats:
        """What the master measured of its cycles."""
        return self.poller.stats

    @property
    def cycle_ns(self) -> ResponseStats:
        """The measured length of every cycle (ns: count, min, max, mean, p99; each value while
        the run is short)."""
        return self.poller.stats.cycle_ns

    @property
    def clean_ns(self) -> ResponseStats:
        """The measured length of the cycles in which every slave due answered in time (ns)."""
        return self.poller.stats.clean_ns

    def summary(self) -> dict[str, Any]:
        """The master's own figures (the runner's per-node ``summary``)."""
        return {"state": self.state.value, "cycles": self.poller.cycle, "overruns": self.stats.overruns}

    def figures(self) -> dict[str, Any]:
        """The master's figures (`PollMaster.figures`)."""
        return self.poller.figures()

    def link_figures(self, slave: str) -> dict[str, Any]:
        """The master's view of one slave (see `SlaveLink`) as JSON."""
        return self.links[slave].figures()
