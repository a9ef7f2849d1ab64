"""The master of a master/slave network: it runs its poll list as a cycle and is the only node
that starts a transaction.

States (h11 style, ``state``): ``idle`` between cycles, ``sending`` while a request waits for the
bus, ``waiting`` for the answer(s) once it went out, ``stopped`` after bus off.

A cycle starts ``cycle_ms`` after the previous one started, or — an *overrun*, reported as
`CycleOverrun` — as soon as the previous one ends if that is later: the schedule moves, openly,
rather than piling up or drifting silently. In a cycle the master runs each transaction of the
poll list in order:

1. It queues the request with a latest start of now + timeout (a request the bus cannot take in
   time is withdrawn, ``unsent``, and counts as a timeout).
2. From the request's SOF (`TxDone.sof`) the slave(s) have ``timeout_ms`` to answer, up to the end
   of the response: the response time measured is the same interval (request SOF to response
   end), so a response is counted exactly when its response time is within the timeout.
3. An answer ends the transaction (a bit-strobe: the answers of every strobed slave); the next
   request is queued at once. A timeout repeats a polled or remote request ``retries`` times;
   then the slave has *missed* the poll. After ``lost_after`` missed polls in a row the slave is
   *lost* (`SlaveLost`) and polled only every ``lost_poll_every`` cycles until it answers
   (`SlaveBack`; any answer of a lost slave, even a late one, brings it back).

A slave's change-of-state / cyclic messages are consumed whenever they arrive and acknowledged at
once when the link says so. Bus off stops the master (`MasterStopped`; its slaves' watchdogs
fire); with ``restart_after_bus_off`` it starts a new cycle when its controller is error active
again (rule 12; `MasterResumed`).

Everything is timed on the node's clock (a drifting master runs a drifting cycle) and happens in
callbacks of the node API, so the master runs unchanged on the simulated bus and on python-can.
"""

from __future__ import annotations

from array import array
from typing import TYPE_CHECKING, Any

from profiles.base import Context, Profile, frame_of, stats_ms
from profiles.polling.config import NETWORK_TABLE
from profiles.polling.events import CycleOverrun, MasterResumed, MasterStopped, Reporter, SlaveBack, SlaveLost
from stack import ErrorStateChanged, TxDone, TxFailed

if TYPE_CHECKING:  # pragma: no cover
    from profiles.declarations import MessageDecl, NodeDecl
    from profiles.polling.config import CosLink, MasterConfig, Transaction
    from stack import NodeAPI, Received, Timer, TxRequest

__all__ = ["Master", "SlaveLink", "IDLE", "SENDING", "WAITING", "STOPPED"]

IDLE, SENDING, WAITING, STOPPED = "idle", "sending", "waiting", "stopped"


def rx_filters(messages: list[MessageDecl]) -> list[dict[str, Any]]:
    """python-can acceptance filters that pass exactly these messages' identifiers."""
    return [
        {"can_id": m.can_id, "can_mask": 0x1FFFFFFF if m.extended else 0x7FF, "extended": m.extended} for m in messages
    ]


class SlaveLink:
    """The master's view of one slave: polls sent (requests that reached the bus), answers and
    their response times (request SOF to response end, master's clock) and period jitter (max −
    min distance between the ends of answers to consecutive polls), timeouts (attempts
    without an answer in time), missed polls (all attempts of a transaction), the lost state with
    its periods, late answers (after the timeout, or from a lost slave between its slow polls),
    and COS/cyclic messages consumed and acknowledged."""

    __slots__ = (
        "name",
        "polls",
        "responses",
        "timeouts",
        "missed",
        "in_a_row",
        "lost",
        "lost_cycle",
        "lost_periods",
        "response_ns",
        "late",
        "cos",
        "acks",
        "last_end",
        "gap_min",
        "gap_max",
    )

    def __init__(self, name: str) -> None:
        self.name = name
        self.polls = 0
        self.responses = 0
        self.timeouts = 0
        self.missed = 0
        self.in_a_row = 0
        self.lost = False
        self.lost_cycle = 0
        self.lost_periods: list[list[int | None]] = []
        self.response_ns: array[int] = array("q")
        self.late = 0
        self.cos = 0
        self.acks = 0
        self.last_end: int | None = None  # end of the last answer, if the poll before it was answered
        self.gap_min: int | None = None
        self.gap_max: int | None = None

    def answered(self, t_end: int) -> None:
        """An answer ended at ``t_end``: the distance from the previous one (when that one answered
        the previous poll) makes the answers' period jitter."""
        if self.last_end is not None:
            gap = t_end - self.last_end
            self.gap_min = gap if self.gap_min is None else min(self.gap_min, gap)
            self.gap_max = gap if self.gap_max is None else max(self.gap_max, gap)
        self.last_end = t_end

    def due(self, cycle: int, every: int) -> bool:
        """Polled in this cycle: always, or every ``every`` cycles from the one it was lost in."""
        return not self.lost or (cycle - self.lost_cycle) % every == 0


class Master(Profile, Reporter):
    """A poll-list master on one node (see the module docstring)."""

    kind = "master"

    def __init__(self, node: NodeAPI, decl: NodeDecl, context: Context) -> None:
        super().__init__(node, decl, context)
        self.config: MasterConfig = context.scenario.tables[NETWORK_TABLE].masters[decl.name]
        self.frames = {m.name: frame_of(m) for m in decl.messages}
        self._track = {m.name: context.recorder.track(m) for m in decl.messages}
        self.links = {s: SlaveLink(s) for s in self.config.slaves}
        self._answers: dict[int, tuple[Transaction, str]] = {}
        watched: list[MessageDecl] = []
        for tx in self.config.transactions:
            for s, r in zip(tx.slaves, tx.responses):
                self._answers[frame_of(r).key] = (tx, s)
                watched.append(r)
        self._cos: dict[int, CosLink] = {}
        for link in self.config.cos:
            for m in link.messages:
                self._cos[frame_of(m).key] = link
                watched.append(m)
        self._filters = rx_filters(watched)
        self.state = IDLE
        Reporter.__init__(self)
        # the cycle
        self.cycle = 0
        self.cycle_start = 0
        self.first_sof: int | None = None
        self.first_sof_bus: int | None = None
        self.ran = 0  # transactions run in this cycle
        self.cycle_ns: array[int] = array("q")
        self.clean_ns: array[int] = array("q")  # cycles in which every slave due answered in time
        self.clean = True
        self.overruns = 0
        self.windows: list[tuple[int, int, bool]] = []  # (first SOF, end) bus ns, overrun — for the plot
        self.unsent = 0
        # per transaction, the latest end of its request and of its last answer after the cycle's start
        self.offsets: dict[str, list[int]] = {t.request.name: [0, 0] for t in self.config.transactions}
        # the transaction in progress
        self._idx = 0
        self._tx: Transaction | None = None
        self._attempt = 0
        self._req: TxRequest | None = None
        self._queued_at = 0
        self._sof: int | None = None
        self._awaiting: set[str] = set()
        self._timer: Timer | None = None
        self._cycle_timer: Timer | None = None
        self.stopped_at: list[int] = []

    # ------------------------------------------------------------------ wiring
    def start(self) -> None:
        """Subscribe to the answers and COS messages, watch the requests and the error state, and
        arm the first cycle at ``offset_ms``."""
        if self._filters:
            self.node.subscribe(self._on_frame, self._filters)
        self.node.listen(TxDone, self._on_done)
        self.node.listen(TxFailed, self._on_failed)
        self.node.listen(ErrorStateChanged, self._on_state)
        self._cycle_timer = self.node.call_at(self.node.now() + self.config.offset_ns, self._begin_cycle)

    def set_data(self, name: str, data: bytes) -> None:
        """Application hook: the output data the next requests of message ``name`` carry."""
        old = self.frames[name]
        self.frames[name] = type(old)(old.can_id, data, extended=old.extended)

    # ------------------------------------------------------------------ the cycle
    def _begin_cycle(self) -> None:
        self._cycle_timer = None
        if self.state == STOPPED:
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
                self._send(set(due))
                return
        self._end_cycle(t)

    def _send(self, awaiting: set[str]) -> None:
        tx = self._tx
        assert tx is not None
        self._awaiting = awaiting
        self._sof = None
        now = self._queued_at = self.node.now()
        self.state = SENDING
        self._req = self.queue(
            self.frames[tx.request.name], self._track[tx.request.name], not_after=now + tx.timeout_ns
        )
        if self._req is None:  # queue full, or bus off (then the state listener stops the master)
            self.unsent += 1
            self.clean = False
            if self.state != STOPPED:
                self._arm(now + tx.timeout_ns)

    def _arm(self, at: int) -> None:
        if self._timer is not None:
            self._timer.cancel()
        self._timer = self.node.call_at(at, self._timeout)

    def _on_done(self, ev: TxDone) -> None:
        if ev.request is not self._req or self.state != SENDING:
            return
        self._sof = ev.sof if ev.sof >= 0 else self._queued_at
        if self.first_sof is None:
            self.first_sof = self._sof
            self.first_sof_bus = ev.request.sof if ev.request.sof >= 0 else None
        for s in self._awaiting:
            self.links[s].polls += 1
        off = self.offsets[self._tx.request.name]  # type: ignore[union-attr]
        off[0] = max(off[0], ev.time - self.cycle_start)
        self.state = WAITING
        self._arm(self._sof + self._tx.timeout_ns)  # type: ignore[union-attr]

    def _on_failed(self, ev: TxFailed) -> None:
        if ev.request is not self._req or self.state != SENDING:
            return
        # not started by its latest start time (a bus too busy), or dropped: no answer can come
        self.unsent += 1
        self.clean = False
        self._req = None
        self._timeout()

    def _on_frame(self, ev: Received) -> None:
        key = ev.frame.key
        hit = self._answers.get(key)
        if hit is not None:
            tx, slave = hit
            link = self.links[slave]
            # only an answer to the request that went out counts; one that comes while a retry is
            # still queued answers the attempt that timed out: late
            if tx is self._tx and slave in self._awaiting and self.state == WAITING:
                link.responses += 1
                link.response_ns.append(ev.time - self._sof)  # type: ignore[operator]
                link.answered(ev.time)
                link.in_a_row = 0
                if link.lost:
                    self._back(link, ev.time)
                self._awaiting.discard(slave)
                if not self._awaiting:
                    off = self.offsets[tx.request.name]
                    off[1] = max(off[1], ev.time - self.cycle_start)
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
            if link.lost:
                self._back(link, ev.time)
            if cos.ack is not None and self.state != STOPPED:
                if self.queue(self.frames[cos.ack.name], self._track[cos.ack.name]) is not None:
                    link.acks += 1

    def _timeout(self) -> None:
        self._timer = None
        tx = self._tx
        if tx is None or self.state == STOPPED:
            return
        for s in self._awaiting:
            self.links[s].timeouts += 1
        self.clean = False
        if self._attempt < tx.retries:
            self._attempt += 1
            self._send(set(self._awaiting))
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
            self._emit(SlaveLost(t, self.decl.name, link.name, link.in_a_row))

    def _back(self, link: SlaveLink, t: int) -> None:
        link.lost = False
        link.in_a_row = 0
        if link.lost_periods and link.lost_periods[-1][1] is None:
            link.lost_periods[-1][1] = t
        self._emit(SlaveBack(t, self.decl.name, link.name))

    def _end_cycle(self, t: int) -> None:
        self._tx = None
        self.state = IDLE
        start = self.first_sof if self.first_sof is not None else self.cycle_start
        due = self.cycle_start + self.config.cycle_ns
        overrun = t > due
        if self.ran:
            self.cycle_ns.append(t - start)
            if self.clean:
                self.clean_ns.append(t - start)
            if self.first_sof_bus is not None:
                self.windows.append((self.first_sof_bus, self.first_sof_bus + (t - start), overrun))
        if overrun:
            self.overruns += 1
            self._emit(CycleOverrun(t, self.decl.name, self.cycle, t - start))
        self._cycle_timer = self.node.call_at(max(due, t), self._begin_cycle)

    # ------------------------------------------------------------------ fault confinement
    def _on_state(self, ev: ErrorStateChanged) -> None:
        if ev.new == "bus-off" and self.state != STOPPED:
            self.state = STOPPED
            self.stopped_at.append(ev.time)
            for timer in (self._timer, self._cycle_timer):
                if timer is not None:
                    timer.cancel()
            self._timer = self._cycle_timer = None
            req, self._req, self._tx = self._req, None, None
            if req is not None:
                self.node.abort(req)
            self._emit(MasterStopped(ev.time, self.decl.name, "bus off"))
        elif ev.new == "error-active" and self.state == STOPPED and self.config.restart_after_bus_off:
            self.state = IDLE
            self._emit(MasterResumed(ev.time, self.decl.name))
            self._begin_cycle()

    # ------------------------------------------------------------------ results
    def summary(self) -> dict[str, Any]:
        """The master's own figures (the runner's per-node ``summary``)."""
        return {"state": self.state, "cycles": self.cycle, "overruns": self.overruns}

    def figures(self) -> dict[str, Any]:
        """cycles started, the measured cycle (first request's SOF to the end of the last
        transaction: min/mean/p99/max ms) — of every cycle, and of the *clean* ones, in which
        every slave due answered in time (no timeout, no request the bus could not take) —
        overruns, requests the bus could not take, bus-off stops, and how many times each event
        happened."""
        counts: dict[str, int] = {}
        for e in self.events:
            counts[type(e).__name__] = counts.get(type(e).__name__, 0) + 1
        return {
            "cycles": self.cycle,
            "cycle_ms": stats_ms(self.cycle_ns),
            "clean_cycle_ms": stats_ms(self.clean_ns),
            "overruns": self.overruns,
            "unsent": self.unsent,
            "state": self.state,
            "stopped_ms": [t / 1e6 for t in self.stopped_at],
            "events": counts,
        }

    def link_figures(self, slave: str) -> dict[str, Any]:
        """The master's view of one slave (see `SlaveLink`) as JSON."""
        ln = self.links[slave]
        return {
            "polls": ln.polls,
            "responses": ln.responses,
            "timeouts": ln.timeouts,
            "missed": ln.missed,
            "lost": ln.lost,
            "lost_ms": [
                [a / 1e6 if a is not None else None, b / 1e6 if b is not None else None] for a, b in ln.lost_periods
            ],
            "late": ln.late,
            "response_ms": stats_ms(ln.response_ns),
            "jitter_ms": None if ln.gap_min is None else (ln.gap_max - ln.gap_min) / 1e6,  # type: ignore[operator]
            "cos": ln.cos,
            "acks": ln.acks,
        }
