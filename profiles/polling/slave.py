"""A slave of a master/slave network: it speaks when its master asks, and watches that it does.

- A request addressed to it (a poll command, a bit-strobe command that names it) is answered
  after the slave's processing delay (a poll command or answer longer than 8 bytes goes in
  DeviceNet fragments, `profiles.polling.fragment`: the answer is due once the request's last
  fragment completed it; ``outputs`` keeps the last output data received per request), drawn uniformly from [``processing_min_ms``,
  ``processing_ms``] by a seeded source, from the end of the request (its reception) to queuing
  the answer — so the response time the master measures includes it.
- A remote frame for a message of its remote-reply mailbox is answered by the controller itself
  (`NodeAPI.set_remote_reply`), without the application and so without its delay.
- Its change-of-state / cyclic messages are produced outside the poll by a `CosProducer` each
  (`profiles.polling.connection`): a cyclic message every period, a COS message at each change
  of its sporadic source (never sooner than ``sporadic_ms``, its production inhibit time, after
  the last) and, when nothing changed for the connection's expected packet rate, again (the
  heartbeat). An acknowledged one is sent again ``retry_limit`` times ``ack_timeout_ms`` after it
  went out without its acknowledgement (`RetryLimitReached` after the last).
- Watchdogs, one per connection it consumes on (DeviceNet's inactivity/watchdog timer): the poll
  connection's — restarted by every request addressed to it, ``watchdog_ms`` (default 4 × the
  master's ``epr_ms``) — and, when its COS/cyclic connection is acknowledged, that connection's —
  restarted by every acknowledgement, 4 × its EPR. When one expires the slave reports loss of
  master on that connection (`MasterLost`) and, at its next frame, that the master is back
  (`MasterBack`). A slave with only an unacknowledged COS/cyclic connection consumes nothing and
  so cannot notice its master's loss. It keeps answering throughout (what an I/O device does with
  its outputs meanwhile is its own business; DeviceNet's connection would stay timed out until
  the master allocates it again — see the package docstring).

- With ``dup_mac_check`` it first runs DeviceNet's duplicate MAC ID check (`profiles.polling.dupmac`):
  it answers nothing and produces nothing until it is online, 2 s after power-up; a duplicate
  sends it to communication fault, silent for good.

States (``state``): ``running``, ``master lost`` while a watchdog has expired, ``communication
fault``.
"""

from __future__ import annotations

from functools import partial
from typing import TYPE_CHECKING, Any

from profiles.base import Context, Profile, frame_of, source_for
from profiles.polling.config import NETWORK_TABLE
from profiles.polling.connection import CosProducer, Watchdog
from profiles.polling.dupmac import COMMUNICATION_FAULT, DupMacCheck
from profiles.polling.events import (
    COS,
    POLL,
    CommunicationFault,
    MasterBack,
    MasterLost,
    Reporter,
    RetryLimitReached,
)
from profiles.polling.fragment import Reassembler, fragment
from profiles.polling.master import rx_filters
from stack import Frame, TxDone

if TYPE_CHECKING:  # pragma: no cover
    from profiles.declarations import MessageDecl, NodeDecl
    from profiles.polling.config import SlaveConfig
    from stack import NodeAPI, Received, TxRequest

__all__ = ["Slave", "RUNNING", "MASTER_LOST", "COMMUNICATION_FAULT"]

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
        cfg = self.config
        link = cfg.cos_link
        self.producers: dict[str, CosProducer] = {}
        for m in cfg.cos:
            epr = link.epr_ns.get(m.name, m.interval_ns or 0) if link is not None else (m.interval_ns or 0)
            self.producers[m.name] = CosProducer(
                node,
                m,
                epr,
                self._produce,
                acked=link is not None and link.ack is not None,
                ack_timeout_ns=cfg.ack_timeout_ns,
                retry_limit=cfg.retry_limit,
                on_retry_limit=partial(self._retry_limit, m.name),
            )
        self.sources = [
            s
            for m in cfg.cos
            if (s := source_for(node, m, self.producers[m.name].change, context.rng("release", decl.name, m.name)))
        ]
        self._producing = {frame_of(m).key: self.producers[m.name] for m in cfg.cos}
        self.state = RUNNING
        Reporter.__init__(self)
        # one watchdog per connection the slave consumes on
        self.watchdogs: dict[str, Watchdog] = {}
        if cfg.polls:
            self.watchdogs[POLL] = Watchdog(node, cfg.watchdog_ns, partial(self._lost, POLL))
        if link is not None and link.ack is not None:
            self.watchdogs[COS] = Watchdog(node, link.watchdog_ns, partial(self._lost, COS))
        self.requests = 0
        self.acks = 0
        self.master_lost_at: list[int] = []
        self.master_back_at: list[int] = []
        self.online = False
        # fragmented I/O: the master's poll commands longer than 8 bytes, and our answers
        self._reassembly = {
            frame_of(m).key: Reassembler(len(m.options["io_data"]))
            for m in context.scenario.node(cfg.master).messages
            if frame_of(m).key in cfg.polls and "io_data" in m.options
        }
        self.io = {m.name: m.options["io_data"] for m in decl.messages if "io_data" in m.options}
        self.outputs: dict[int, bytes] = {}
        self.dup_mac: DupMacCheck | None = None
        if cfg.dup_mac is not None and cfg.mac_id is not None:
            vendor, serial = cfg.dup_mac
            self.dup_mac = DupMacCheck(
                node, cfg.mac_id, vendor_id=vendor, serial_number=serial, on_online=self._online, on_fault=self._fault
            )

    def start(self) -> None:
        """Listen to the master's frames addressed to this slave, start the COS/cyclic sources,
        and go online — after the duplicate MAC ID check, when it has one."""
        keys = self.config.requests
        wanted = [m for m in self.context.scenario.node(self.config.master).messages if frame_of(m).key in keys]
        if wanted:
            self.node.subscribe(self._on_frame, rx_filters(wanted))
        # the controller queues a mailbox's reply itself (accounted for when it is sent); an
        # acknowledged COS/cyclic message's Acknowledge Timer runs from its end
        self.node.listen(TxDone, self._on_done)
        for s in self.sources:
            s.start()
        if self.dup_mac is not None:
            self.dup_mac.start()
        else:
            self._online(self.node.now())

    def _online(self, t: int) -> None:
        """The slave may use the network from ``t`` on: the remote-reply mailbox is loaded, the
        connections start (watchdogs, COS/cyclic producers)."""
        if self.state == COMMUNICATION_FAULT:
            return
        self.online = True
        for m in self.config.mailbox:
            self.node.set_remote_reply(self.frames[m.name])
        for w in self.watchdogs.values():
            w.start(t)
        for p in self.producers.values():
            p.start()

    def _fault(self, t: int, reason: str) -> None:
        """A duplicate of its MAC ID: communication fault — silent for good (no answers, no
        production, no mailbox, no watchdog verdicts)."""
        self.online = False
        self.state = COMMUNICATION_FAULT
        for m in self.config.mailbox:
            self.node.set_remote_reply(None, can_id=m.can_id, extended=m.extended)
        for w in self.watchdogs.values():
            w.stop()
        for p in self.producers.values():
            p.stop()
        for req in list(self.node.pending()):
            self.node.abort(req)
        self._emit(CommunicationFault(t, self.decl.name, self.config.mac_id or 0, reason))

    def set_data(self, name: str, data: bytes) -> None:
        """Application hook: the payload the next instances of message ``name`` carry (a mailbox
        message is reloaded into the controller; a fragmented message takes its whole I/O data, of
        its ``size``)."""
        if name in self.io:
            if len(data) != len(self.io[name]):
                raise ValueError(f"{name}: {len(data)} bytes for a {len(self.io[name])}-byte fragmented message")
            self.io[name] = bytes(data)
            return
        old = self.frames[name]
        self.frames[name] = new = type(old)(old.can_id, data, extended=old.extended)
        if new.key in self._mailbox and self.online:
            self.node.set_remote_reply(new)

    # ------------------------------------------------------------------ requests
    def _on_frame(self, ev: Received) -> None:
        key = ev.frame.key
        cfg = self.config
        if key not in cfg.requests or not self.online:
            return
        if key in cfg.acks:  # the acknowledgement of the COS/cyclic connection
            self.acks += 1
            self._kick(COS, ev.time)
            for p in self.producers.values():
                p.acked()
            return
        self._kick(POLL, ev.time)
        reassembly = self._reassembly.get(key)
        if reassembly is not None:
            message = reassembly.feed(ev.frame.data)
            if message is None:
                return  # a fragment: the request is complete with its last one
            self.outputs[key] = message
        elif not ev.frame.remote:
            self.outputs[key] = ev.frame.data
        self.requests += 1
        name = self._answer_of.get(key)
        if name is None:
            return  # a remote frame: the controller's mailbox answers it
        cfg = self.config
        lo, hi = cfg.processing_min_ns, cfg.processing_max_ns
        delay = hi if lo == hi else self._rng.randint(lo, hi)
        if delay:
            self.node.call_later(delay, self._answer, name)
        else:
            self._answer(name)

    def _answer(self, name: str) -> None:
        io = self.io.get(name)
        if io is None:
            self.queue(self.frames[name], self._track[name])
            return
        f = self.frames[name]
        for data in fragment(io):  # DeviceNet I/O fragments, back to back
            self.queue(Frame(f.can_id, data, extended=f.extended), self._track[name])

    def _on_done(self, ev: TxDone) -> None:
        key = ev.frame.key
        name = self._mailbox.get(key)
        if name is not None and ev.request.state == "sent":
            self._track[name].release(ev.request)
        producer = self._producing.get(key)
        if producer is not None:
            producer.sent(ev.request, ev.time)

    def _produce(self, m: MessageDecl) -> TxRequest | None:
        return self.queue(self.frames[m.name], self._track[m.name])

    # ------------------------------------------------------------------ watchdogs
    def _kick(self, connection: str, t: int) -> None:
        """A frame of the master on ``connection``: restart its watchdog (the master is back on
        it if it had expired)."""
        w = self.watchdogs.get(connection)
        if w is not None and w.kick(t):
            self.master_back_at.append(t)
            self._emit(MasterBack(t, self.decl.name, self.config.master, connection))
            if not any(x.expired for x in self.watchdogs.values()) and self.state == MASTER_LOST:
                self.state = RUNNING

    def _retry_limit(self, message: str, t: int, retries: int) -> None:
        self._emit(RetryLimitReached(t, self.decl.name, message, retries))

    def _lost(self, connection: str, now: int) -> None:
        if self.state == COMMUNICATION_FAULT:
            return
        self.state = MASTER_LOST
        self.master_lost_at.append(now)
        timeout = self.watchdogs[connection].timeout_ns
        self._emit(MasterLost(now, self.decl.name, self.config.master, timeout, connection))

    # ------------------------------------------------------------------ results
    def summary(self) -> dict[str, Any]:
        """The slave's own figures."""
        return self.figures()

    def figures(self) -> dict[str, Any]:
        """Requests and acknowledgements received, watchdog expiries (loss of master, on any
        connection) and returns, the processing delay it was given, its watchdogs (ms, by
        connection), and what its COS/cyclic producers sent: heartbeats (productions without a
        change), retransmissions for want of an acknowledgement, retry limits reached."""
        ps = self.producers.values()
        return {
            "state": self.state,
            "requests": self.requests,
            "acks_received": self.acks,
            "master_lost": len(self.master_lost_at),
            "master_lost_ms": [t / 1e6 for t in self.master_lost_at],
            "master_back_ms": [t / 1e6 for t in self.master_back_at],
            "processing_ms": [self.config.processing_min_ns / 1e6, self.config.processing_max_ns / 1e6],
            "watchdog_ms": {c: w.timeout_ns / 1e6 for c, w in self.watchdogs.items()},
            "heartbeats": sum(p.heartbeats for p in ps),
            "retransmissions": sum(p.retransmissions for p in ps),
            "retry_limit_reached": sum(p.retry_limits for p in ps),
            **({} if self.dup_mac is None else {"dup_mac_check": self.dup_mac.figures()}),
        }
