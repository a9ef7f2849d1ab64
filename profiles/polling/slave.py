"""A slave of a master/slave network: it speaks when its master asks, and watches that it does.

- A request addressed to it (a poll command, a bit-strobe command that names it) is answered
  after the slave's processing delay, drawn uniformly from [``processing_min_ms``,
  ``processing_ms``] by a seeded source, from the end of the request (its reception) to queuing
  the answer — so the response time the master measures includes it.
- A remote frame for a message of its remote-reply mailbox is answered by the controller itself
  (`NodeAPI.set_remote_reply`), without the application and so without its delay.
- Its change-of-state / cyclic messages are released by their own periodic or sporadic source,
  outside the poll; the master may acknowledge them.
- Watchdog: every frame of its master addressed to it (requests, acknowledgements) restarts it;
  when ``watchdog_ms`` passes without one the slave reports loss of master (`MasterLost`) and, at
  the next request, that the master is back (`MasterBack`). It keeps answering throughout (what an
  I/O device does with its outputs meanwhile is its own business).

States (``state``): ``running``, or ``master lost`` while the watchdog has expired.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from profiles.base import Context, Profile, frame_of, source_for
from profiles.polling.config import NETWORK_TABLE
from profiles.polling.events import MasterBack, MasterLost, Reporter
from profiles.polling.master import rx_filters
from stack import TxDone

if TYPE_CHECKING:  # pragma: no cover
    from profiles.declarations import MessageDecl, NodeDecl
    from profiles.polling.config import SlaveConfig
    from stack import Frame, NodeAPI, Received

__all__ = ["Slave", "RUNNING", "MASTER_LOST"]

RUNNING, MASTER_LOST = "running", "master lost"


class Slave(Profile, Reporter):
    """A polled slave on one node (see the module docstring)."""

    kind = "slave"

    def __init__(self, node: NodeAPI, decl: NodeDecl, context: Context) -> None:
        super().__init__(node, decl, context)
        self.config: SlaveConfig = context.scenario.tables[NETWORK_TABLE].slaves[decl.name]
        self.frames: dict[str, Frame] = {m.name: frame_of(m) for m in decl.messages}
        self._track = {m.name: context.recorder.track(m) for m in decl.messages}
        self._answer_of = {k: m.name for k, m in self.config.answers.items()}
        self._mailbox = {frame_of(m).key: m.name for m in self.config.mailbox}
        self._rng = context.rng("processing", decl.name)
        self.sources = [
            s
            for m in self.config.cos
            if (s := source_for(node, m, self._produce, context.rng("release", decl.name, m.name)))
        ]
        self.state = RUNNING
        Reporter.__init__(self)
        self._deadline = 0
        self._armed = False
        self.requests = 0
        self.acks = 0
        self.master_lost_at: list[int] = []
        self.master_back_at: list[int] = []

    def start(self) -> None:
        """Listen to the master's frames addressed to this slave, load the remote-reply mailbox,
        start the COS/cyclic sources and the watchdog."""
        keys = self.config.requests
        wanted = [m for m in self.context.scenario.node(self.config.master).messages if frame_of(m).key in keys]
        if wanted:
            self.node.subscribe(self._on_frame, rx_filters(wanted))
        for m in self.config.mailbox:
            self.node.set_remote_reply(self.frames[m.name])
        if self._mailbox:
            # the controller queues the reply itself: account for it when it is sent
            self.node.listen(TxDone, self._on_done)
        for s in self.sources:
            s.start()
        self._kick(self.node.now())

    def set_data(self, name: str, data: bytes) -> None:
        """Application hook: the payload the next instances of message ``name`` carry (a mailbox
        message is reloaded into the controller)."""
        old = self.frames[name]
        self.frames[name] = new = type(old)(old.can_id, data, extended=old.extended)
        if new.key in self._mailbox:
            self.node.set_remote_reply(new)

    # ------------------------------------------------------------------ requests
    def _on_frame(self, ev: Received) -> None:
        key = ev.frame.key
        if key not in self.config.requests:
            return
        self.requests += 1
        self._kick(ev.time)
        name = self._answer_of.get(key)
        if name is None:
            if not ev.frame.remote:
                self.acks += 1  # a COS/cyclic acknowledgement
            return  # a remote frame: the controller's mailbox answers it
        cfg = self.config
        lo, hi = cfg.processing_min_ns, cfg.processing_max_ns
        delay = hi if lo == hi else self._rng.randint(lo, hi)
        if delay:
            self.node.call_later(delay, self._answer, name)
        else:
            self._answer(name)

    def _answer(self, name: str) -> None:
        self.queue(self.frames[name], self._track[name])

    def _on_done(self, ev: TxDone) -> None:
        name = self._mailbox.get(ev.frame.key)
        if name is not None and ev.request.state == "sent":
            self._track[name].release(ev.request)

    def _produce(self, m: MessageDecl) -> None:
        self.queue(self.frames[m.name], self._track[m.name])

    # ------------------------------------------------------------------ watchdog
    def _kick(self, t: int) -> None:
        """Restart the watchdog. One timer at a time: it re-arms itself at the latest deadline
        when it fires early, instead of a cancel and a new timer per request."""
        self._deadline = t + self.config.watchdog_ns
        if self.state == MASTER_LOST:
            self.state = RUNNING
            self.master_back_at.append(t)
            self._emit(MasterBack(t, self.decl.name, self.config.master))
        if not self._armed:
            self._armed = True
            self.node.call_at(self._deadline, self._watchdog)

    def _watchdog(self) -> None:
        now = self.node.now()
        if now < self._deadline:
            self.node.call_at(self._deadline, self._watchdog)
            return
        self._armed = False
        self.state = MASTER_LOST
        self.master_lost_at.append(now)
        self._emit(MasterLost(now, self.decl.name, self.config.master, self.config.watchdog_ns))

    # ------------------------------------------------------------------ results
    def summary(self) -> dict[str, Any]:
        """The slave's own figures."""
        return self.figures()

    def figures(self) -> dict[str, Any]:
        """Requests and acknowledgements received, watchdog expiries (loss of master) and returns,
        and the processing delay it was given."""
        return {
            "state": self.state,
            "requests": self.requests,
            "acks_received": self.acks,
            "master_lost": len(self.master_lost_at),
            "master_lost_ms": [t / 1e6 for t in self.master_lost_at],
            "master_back_ms": [t / 1e6 for t in self.master_back_at],
            "processing_ms": [self.config.processing_min_ns / 1e6, self.config.processing_max_ns / 1e6],
            "watchdog_ms": self.config.watchdog_ns / 1e6,
        }
