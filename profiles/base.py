"""The profile contract: what every scheduling layer shares — the base class, the context a
scenario gives it, message sources (periodic, sporadic, application) and the one metrics
recorder the scenario runner reads.

A profile is a sans-IO state machine on one `stack` node: it acts only through the node API
(`stack.NodeAPI`: ``send``, ``subscribe``, ``listen``, ``call_at``/``call_later``, ``now``), so it
runs unchanged on the simulated bus and on any python-can bus. Releases are timed on the node's
own clock (a drifting node releases on its drifting clock); measurements use the bus times the
node's `TxRequest` keeps, so they compare across nodes.
"""

from __future__ import annotations

import hashlib
import random
from array import array
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, NamedTuple

from profiles.responses import BATCH, ResponseStats, stats_ms
from stack import Frame, NodeError, QueueFull

if TYPE_CHECKING:  # pragma: no cover
    from profiles.declarations import MessageDecl, NodeDecl, Scenario
    from stack import NodeAPI, TxRequest

__all__ = [
    "Profile",
    "Context",
    "Recorder",
    "Track",
    "Instance",
    "PeriodicSource",
    "SporadicSource",
    "frame_of",
    "stats_ms",
    "stable_rng",
    "source_for",
]


def stable_rng(seed: int, *parts: object) -> random.Random:
    """A random source derived from ``seed`` and names (a node, a message): the same scenario and
    seed give the same draws whatever else the scenario holds, in any process (unlike `hash`)."""
    digest = hashlib.sha256(repr((seed,) + parts).encode()).digest()
    return random.Random(int.from_bytes(digest[:8], "big"))


def frame_of(m: MessageDecl) -> Frame:
    """The frame a declared message sends (its data, or zeros): a CAN FD frame (with BRS) when
    the message says so, its data ``m.length`` bytes."""
    if m.remote:
        return Frame(m.can_id, extended=m.extended, remote=True, dlc=m.dlc)
    data = m.data if m.data is not None else bytes(m.length)
    if m.fd:
        return Frame(m.can_id, data, extended=m.extended, fd=True, brs=m.brs)
    return Frame(m.can_id, data, extended=m.extended)


class Track:
    """What happened to one declared message: instances released (queued), sent, failed,
    dropped (queue full or node bus off at release), their response times (queued → end of EOF,
    bus ns: `ResponseStats`, exact min/max/mean and a p99 in bounded memory), the longest time
    from a nominal release to the end of EOF (``worst_release``), the start-to-start jitter from
    the SOF times of successful instances, and deadline misses — an instance that ends more than
    its deadline after its *nominal* release (the response-time analysis' reference: the release
    jitter counts against the deadline), fails, is dropped, or is still pending at the end of the
    run when its deadline has passed. An instance its source queued ``late_ns`` after its nominal
    release says so (`release`); one a profile queues on its own account is its own nominal
    release.

    It reads the outcome of each instance from its `TxRequest` (state, ``t_done``, ``sof``),
    lazily — at the next release of the message and at the end — rather than through `TxDone`
    listeners: a listener per frame would take the simulated bus off its fast path (the runner's
    figure in `python -m stack.bench`).

    ``responses`` and ``starts`` hold the values of the current batch (every value of a short
    run, or of a run that keeps all: ``keep_all``); ``sink``, when set, is called once per
    instance with an `Instance` (``canstack experiment --samples``), and ``clock`` gives the bus
    time of a drop.
    """

    __slots__ = (
        "decl",
        "released",
        "sent",
        "failed",
        "dropped",
        "misses",
        "stats",
        "starts",
        "pending",
        "worst_release",
        "received",
        "monitor",
        "awaiting",
        "sink",
        "clock",
        "_gap_lo",
        "_gap_hi",
        "_last_start",
    )

    def __init__(self, decl: MessageDecl, keep_all: bool = False) -> None:
        self.decl = decl
        self.released = 0
        self.sent = 0
        self.failed = 0
        self.dropped = 0
        self.misses = 0
        self.received: int | None = None  # set by the runner: instances that reached another node
        self.stats = ResponseStats(keep_all)
        self.starts: array[int] = array("q")
        # queued instances, in release order, with how late after its nominal release each was
        # queued (bus ns)
        self.pending: dict[TxRequest, int] = {}
        self.worst_release: int | None = None
        # on a python-can bus the end of a frame is the monitor's receive timestamp (`observed`),
        # not the moment the driver handed it over: sent instances wait for it here
        self.monitor = False
        self.awaiting: dict[TxRequest, int] = {}
        self.sink: Callable[[Instance], Any] | None = None
        self.clock: Callable[[], int] | None = None
        self._gap_lo: int | None = None  # start-to-start gaps of the folded batches
        self._gap_hi: int | None = None
        self._last_start: int | None = None

    @property
    def responses(self) -> array[int]:
        """The response times (ns) not yet folded into the statistics: all of them while
        ``stats.exact``."""
        return self.stats.values

    def release(self, req: TxRequest, late_ns: int = 0) -> None:
        """An instance was queued (``req.t_queued``), ``late_ns`` after its nominal release."""
        self.released += 1
        if self.pending:
            self.settle()
        self.pending[req] = late_ns

    def drop(self) -> None:
        """An instance could not be queued (transmit queue full, node bus off)."""
        self.released += 1
        self.dropped += 1
        self.misses += 1
        if self.sink is not None:
            t = self.clock() if self.clock is not None else None
            self.sink(Instance(self.decl.name, self.decl.node, "dropped", t, None, None, None, None, True))

    def settle(self, everything: bool = False) -> None:
        """Account for the pending instances that finished, in release order — up to the first
        still queued (instances of one message leave in order), or all with ``everything``."""
        done = []
        for req in self.pending:
            st = req.state
            if st == "queued":
                if everything:
                    continue
                break
            done.append(req)
        for req in done:
            late = self.pending.pop(req)
            if req.state == "sent":
                if self.monitor:
                    self.awaiting[req] = late
                else:
                    self._complete(req, req.t_done, req.sof, late)
            else:  # failed (one-shot, expired) or aborted
                self.failed += 1
                self.misses += 1
                if self.sink is not None:
                    q = req.t_queued
                    self.sink(Instance(self.decl.name, self.decl.node, "failed", q - late, q, None, None, None, True))

    def observed(self, t_end: int, sof: int) -> None:
        """A monitor on a python-can bus received this message at ``t_end`` (its SOF at ``sof``):
        the oldest instance handed to the bus ends there."""
        self.settle()
        if self.awaiting:
            req = next(iter(self.awaiting))
            late = self.awaiting.pop(req)
        elif self.pending:  # the monitor saw it before the driver reported it sent
            req = next(iter(self.pending))
            late = self.pending.pop(req)
        else:
            return
        self._complete(req, t_end, sof, late)

    def _complete(self, req: TxRequest, t_end: int, sof: int, late: int) -> None:
        self.sent += 1
        resp = t_end - req.t_queued
        values = self.stats.values
        values.append(resp)
        self.starts.append(sof)
        since = resp + late  # from the nominal release
        if self.worst_release is None or since > self.worst_release:
            self.worst_release = since
        d = self.decl.deadline_ns
        missed = d is not None and since > d
        if missed:
            self.misses += 1
        if self.sink is not None:
            q = req.t_queued
            self.sink(Instance(self.decl.name, self.decl.node, "sent", q - late, q, sof, t_end, resp, missed))
        if len(values) >= BATCH and not self.stats.keep_all:
            self._fold()

    def _fold(self) -> None:
        """Fold the current batch into the running figures (bounded memory: the module
        `profiles.responses`), the start-to-start gaps included."""
        st = self.starts
        if st:
            prev = self._last_start
            gaps = [b - a for a, b in zip(st, st[1:])]
            if prev is not None:
                gaps.append(st[0] - prev)
            if gaps:
                lo, hi = min(gaps), max(gaps)
                self._gap_lo = lo if self._gap_lo is None else min(self._gap_lo, lo)
                self._gap_hi = hi if self._gap_hi is None else max(self._gap_hi, hi)
            self._last_start = st[-1]
            self.starts = array("q")
        self.stats.fold()

    def finish(self, t_end: int) -> int:
        """At the end of the run: every finished instance is accounted for; those still pending
        whose deadline has passed are misses. Returns how many are still pending."""
        self.settle(everything=True)
        d = self.decl.deadline_ns
        left = list(self.pending.items()) + list(self.awaiting.items())
        for r, late in left:
            missed = d is not None and r.t_queued - late + d < t_end
            self.misses += missed
            if self.sink is not None:
                q = r.t_queued
                self.sink(Instance(self.decl.name, self.decl.node, "pending", q - late, q, None, None, None, missed))
        return len(left)

    def response_stats_ms(self) -> dict[str, Any] | None:
        """min, mean, p99, max of the response times in ms and ``p99_error`` (see
        `ResponseStats.stats_ms`); None when no instance was sent."""
        return self.stats.stats_ms()

    def jitter_ns(self) -> int | None:
        """Max − min of the start-to-start distance (SOF to SOF of consecutive instances),
        for a periodic message; None otherwise or with fewer than two instances."""
        if self.decl.period_ns is None:
            return None
        st = self.starts
        gaps = [b - a for a, b in zip(st, st[1:])]
        if st and self._last_start is not None:
            gaps.append(st[0] - self._last_start)
        if self._gap_lo is not None and self._gap_hi is not None:
            gaps += [self._gap_lo, self._gap_hi]
        if not gaps:
            return None
        return max(gaps) - min(gaps)


class Instance(NamedTuple):
    """One instance of a message as ``--samples`` writes it (bus ns; None where it has none):
    ``outcome`` sent, failed (one-shot, expired, aborted), dropped (not queued) or pending (at the
    end of the run); ``nominal`` its nominal release, ``queued``, ``sof`` and ``eof`` (end of
    EOF), ``response`` (queued to EOF), ``missed`` its deadline."""

    message: str
    node: str
    outcome: str
    nominal: int | None
    queued: int | None
    sof: int | None
    eof: int | None
    response: int | None
    missed: bool


class Recorder:
    """The one place profiles record what they measure; the runner reads it. Tracks are keyed by
    message name (unique in a scenario)."""

    def __init__(self, keep_all: bool = False) -> None:
        self.tracks: dict[str, Track] = {}
        self.keep_all = keep_all

    def track(self, decl: MessageDecl) -> Track:
        """The track of a declared message (made on first use; ``keep_all`` keeps every
        response time, see `Track`)."""
        t = self.tracks.get(decl.name)
        if t is None:
            t = self.tracks[decl.name] = Track(decl, self.keep_all)
        return t


@dataclass
class Context:
    """What a scenario gives its profiles: the scenario, the recorder, every node by name (for
    profiles that talk to each other), the profiles built so far, and the simulated bus (None on
    a python-can bus)."""

    scenario: Scenario
    recorder: Recorder
    nodes: dict[str, NodeAPI] = field(default_factory=dict)
    profiles: dict[str, Profile] = field(default_factory=dict)
    bus: Any = None

    def rng(self, *parts: object) -> random.Random:
        """A random source for one purpose (see `stable_rng`)."""
        return stable_rng(self.scenario.seed, *parts)


class Profile:
    """Base of the scheduling layers: a profile on ``node`` built from its scenario declaration.

    Subclasses release their messages through ``release`` or their own schedule, record through
    ``context.recorder`` and report their own figures in `summary`. ``start()`` is called once
    every profile of the scenario is built (so profiles may look each other up in
    ``context.profiles``).
    """

    kind = "profile"

    def __init__(self, node: NodeAPI, decl: NodeDecl, context: Context) -> None:
        self.node = node
        self.decl = decl
        self.context = context
        self.tracks: dict[int, Track] = {}  # by arbitration key: identifiers are unique on the bus
        for m in decl.messages:
            tr = context.recorder.track(m)
            self.tracks[frame_of(m).key] = tr

    def start(self) -> None:
        """Begin acting (timers, first releases)."""

    def summary(self) -> dict[str, Any]:
        """The profile's own figures for the results (JSON-ready)."""
        return {}

    def queue(
        self, frame: Frame, track: Track | None = None, *, nominal: int | None = None, **send: Any
    ) -> TxRequest | None:
        """Send ``frame`` (keyword arguments go to `send`: ``one_shot``, ``not_after``) and
        record the instance; a full queue or a bus-off node drops it (recorded as a miss).
        ``nominal`` is the instance's nominal release on the node's clock (its source's
        ``releasing``), when it is queued later than that (release jitter, a gate): the track
        counts its deadline from there."""
        try:
            req = self.node.send(frame, **send)
        except (QueueFull, NodeError):
            if track is not None:
                track.drop()
            return None
        if track is not None:
            late = 0
            if nominal is not None:
                # node-clock ns to bus ns: the node's oscillator runs 1 + drift_ppm·1e-6 as fast
                late = max(0, round((self.node.now() - nominal) / (1 + self.decl.drift_ppm * 1e-6)))
            track.release(req, late)
        return req


class PeriodicSource:
    """Releases ``on_release(decl)`` every ``period_ns`` of the node's clock, first at
    ``offset_ns``, each release late by a uniform draw in [0, ``jitter_ns``] (release jitter)
    from a seeded source; the nominal times do not drift with the jitter. While ``on_release``
    runs, ``releasing`` is the nominal release (node clock) of that instance, else None."""

    def __init__(
        self, node: NodeAPI, decl: MessageDecl, on_release: Callable[[MessageDecl], Any], rng: random.Random
    ) -> None:
        if decl.period_ns is None and type(self) is PeriodicSource:
            raise ValueError(f"message {decl.name!r} has no period")
        self.period = decl.period_ns or 0  # a sporadic source steps by its own gaps
        self.node = node
        self.decl = decl
        self.on_release = on_release
        self.rng = rng
        self.nominal = 0
        self.releasing: int | None = None

    def start(self) -> None:
        """Arm the first release."""
        self.nominal = self.node.now() + self.decl.offset_ns
        self._arm()

    def _arm(self) -> None:
        j = self.decl.jitter_ns
        self.node.call_at(self.nominal + (self.rng.randint(0, j) if j else 0), self._fire)

    def _fire(self) -> None:
        self.releasing = self.nominal
        try:
            self.on_release(self.decl)
        finally:
            self.releasing = None
        self.nominal += self.period
        self._arm()


class SporadicSource(PeriodicSource):
    """Releases a sporadic message: consecutive releases at least ``sporadic_ns`` apart, the
    extra gap exponentially distributed so that the mean inter-arrival is ``mean_ns`` (twice the
    minimum when not given), from a seeded source."""

    def __init__(
        self, node: NodeAPI, decl: MessageDecl, on_release: Callable[[MessageDecl], Any], rng: random.Random
    ) -> None:
        if decl.sporadic_ns is None:
            raise ValueError(f"message {decl.name!r} is not sporadic")
        super().__init__(node, decl, on_release, rng)
        self.gap = decl.sporadic_ns
        self.extra_mean = (decl.mean_ns if decl.mean_ns is not None else 2 * decl.sporadic_ns) - decl.sporadic_ns

    def start(self) -> None:
        """Arm the first release (at the offset plus a random gap)."""
        self.nominal = self.node.now() + self.decl.offset_ns + self._gap_extra()
        self._arm()

    def _gap_extra(self) -> int:
        return round(self.rng.expovariate(1 / self.extra_mean)) if self.extra_mean > 0 else 0

    def _fire(self) -> None:
        self.releasing = self.nominal
        try:
            self.on_release(self.decl)
        finally:
            self.releasing = None
        self.nominal += self.gap + self._gap_extra()
        self._arm()


def source_for(
    node: NodeAPI, decl: MessageDecl, on_release: Callable[[MessageDecl], Any], rng: random.Random
) -> PeriodicSource | None:
    """The source that releases ``decl`` (periodic or sporadic), or None for an untimed one."""
    if decl.period_ns is not None:
        return PeriodicSource(node, decl, on_release, rng)
    if decl.sporadic_ns is not None:
        return SporadicSource(node, decl, on_release, rng)
    return None
