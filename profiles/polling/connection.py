"""What both ends of a DeviceNet I/O connection keep: the inactivity/watchdog timer of a
consumer, and the producer of a change-of-state / cyclic connection.

DeviceNet's rules (CIP Networks Library Vol. 3, the Connection object, as device manuals reprint
its attributes — e.g. Rockwell 193-UM002, Table 103; the 1769-SDN scanner manual, "Expected
Packet Rate"; Horner HE800DNS600 manual §4.10 — and the Acknowledge Handler object, class 0x2B):

- Every I/O connection has an expected packet rate (EPR, attribute 9, ms). A consumer's
  inactivity/watchdog timer is 4 × EPR and restarts with every packet it consumes on the
  connection; when it expires the connection times out.
- A cyclic connection produces every EPR (its transmission trigger timer). A change-of-state
  connection produces when the data change, and — its heartbeat — when the transmission trigger
  timer (the EPR, restarted at every production) expires without one; new data are never
  produced sooner than the production inhibit time (attribute 17) after the last production: a
  change during it goes out, with the data of that moment, when it ends.
- An acknowledged COS/cyclic message is sent again when its acknowledgement has not come within
  the Acknowledge Timer (attribute 1, default 16 ms), at most Retry Limit times (attribute 2,
  default 1); then the producer is told (RetryLimit_Reached) and the connection stays — it is
  the consumer's watchdog that drops a connection, not the producer's retries (the 1769-SDN
  manual: "the connection is not necessarily dropped as a result of reaching the retry limit").

The production inhibit time of a canstack COS message is its ``sporadic_ms`` (the minimum
inter-arrival the analysis uses), so the heartbeats and the coalesced changes keep that minimum.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover
    from profiles.declarations import MessageDecl
    from stack import NodeAPI, Timer, TxRequest

__all__ = ["Watchdog", "CosProducer"]


class Watchdog:
    """A consumer's inactivity/watchdog timer of ``timeout_ns`` on ``node``'s clock:
    ``on_expire(now)`` when ``timeout_ns`` pass after the last `kick`. One timer at a time: it
    re-arms itself at the latest deadline when it fires early, instead of a cancel and a new timer
    per packet."""

    def __init__(self, node: NodeAPI, timeout_ns: int, on_expire: Callable[[int], Any]) -> None:
        self.node = node
        self.timeout_ns = timeout_ns
        self.on_expire = on_expire
        self.deadline = 0
        self.running = False
        self.expired = False
        self._timer: Timer | None = None

    def start(self, t: int) -> None:
        """The connection is established at ``t``: the timer runs from there."""
        self.running = True
        self.expired = False
        self._set(t)

    def stop(self) -> None:
        """The consumer stops watching (its node stopped)."""
        self.running = False
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def kick(self, t: int) -> bool:
        """A packet consumed at ``t``: restart the timer. True when the connection had timed out
        (the packet brings it back)."""
        if not self.running:
            return False
        back = self.expired
        self.expired = False
        self._set(t)
        return back

    def _set(self, t: int) -> None:
        self.deadline = t + self.timeout_ns
        if self._timer is None:
            self._timer = self.node.call_at(self.deadline, self._fire)

    def _fire(self) -> None:
        self._timer = None
        if not self.running or self.expired:
            return
        now = self.node.now()
        if now < self.deadline:
            self._timer = self.node.call_at(self.deadline, self._fire)
            return
        self.expired = True
        self.on_expire(now)


class CosProducer:
    """The producing end of a COS/cyclic connection for one message (see the module docstring).

    ``send(m)`` queues the message's frame and returns its request (None when the node refused
    it); ``change()`` is the application's new data (a COS message's sporadic source, or a cyclic
    message's period). With ``acked`` each transmission waits ``ack_timeout_ns`` (from its end,
    `sent`) for `acked`, and is sent again up to ``retry_limit`` times; ``on_retry_limit(t,
    retries)`` reports the limit reached. Counters: ``productions`` (changes and heartbeats
    sent), ``heartbeats``, ``retransmissions``, ``retry_limits``."""

    def __init__(
        self,
        node: NodeAPI,
        m: MessageDecl,
        epr_ns: int,
        send: Callable[[MessageDecl], TxRequest | None],
        *,
        acked: bool = False,
        ack_timeout_ns: int = 16_000_000,
        retry_limit: int = 1,
        on_retry_limit: Callable[[int, int], Any] | None = None,
    ) -> None:
        self.node = node
        self.message = m
        self.epr_ns = epr_ns
        self.send = send
        self.acknowledged = acked
        self.ack_timeout_ns = ack_timeout_ns
        self.retry_limit = retry_limit
        self.on_retry_limit = on_retry_limit
        self.cyclic = m.period_ns is not None
        self.inhibit_ns = 0 if self.cyclic else (m.sporadic_ns or 0)
        self.last: int | None = None  # the last production (node clock)
        self.running = False
        self.awaiting: TxRequest | None = None  # the transmission whose acknowledgement is due
        self.retries = 0
        self._heartbeat: Timer | None = None
        self._inhibited: Timer | None = None
        self._ack_timer: Timer | None = None
        self.productions = 0
        self.heartbeats = 0
        self.retransmissions = 0
        self.retry_limits = 0

    def start(self) -> None:
        """The connection is established: a COS message's transmission trigger timer starts."""
        self.running = True
        if not self.cyclic:
            self._arm_heartbeat(self.node.now())

    def stop(self) -> None:
        """Stop producing (every timer off)."""
        self.running = False
        for t in (self._heartbeat, self._inhibited, self._ack_timer):
            if t is not None:
                t.cancel()
        self._heartbeat = self._inhibited = self._ack_timer = None
        self.awaiting = None

    # ------------------------------------------------------------------ production
    def change(self, *_: Any) -> None:
        """New data: produced now, or when the production inhibit time since the last production
        ends (one production for every change during it)."""
        if not self.running:
            return
        now = self.node.now()
        if self.last is not None and now < self.last + self.inhibit_ns:
            if self._inhibited is None:
                self._inhibited = self.node.call_at(self.last + self.inhibit_ns, self._inhibit_over)
            return
        self._produce(now, heartbeat=False)

    def _inhibit_over(self) -> None:
        self._inhibited = None
        if self.running:
            self._produce(self.node.now(), heartbeat=False)

    def _beat(self) -> None:
        self._heartbeat = None
        if self.running:
            self._produce(self.node.now(), heartbeat=True)

    def _arm_heartbeat(self, now: int) -> None:
        if self._heartbeat is not None:
            self._heartbeat.cancel()
        self._heartbeat = self.node.call_at(now + self.epr_ns, self._beat)

    def _produce(self, now: int, *, heartbeat: bool) -> None:
        self.last = now
        if not self.cyclic:
            self._arm_heartbeat(now)
        if self._ack_timer is not None:  # new data: the old message's acknowledgement no longer matters
            self._ack_timer.cancel()
            self._ack_timer = None
        self.retries = 0
        req = self.send(self.message)
        self.awaiting = req if self.acknowledged else None
        if req is not None:
            self.productions += 1
            self.heartbeats += heartbeat

    # ------------------------------------------------------------------ acknowledgement
    def sent(self, req: TxRequest, t: int) -> None:
        """A frame of this connection went out (ended at ``t``): the Acknowledge Timer starts."""
        if req is self.awaiting and self.running:
            if self._ack_timer is not None:
                self._ack_timer.cancel()
            self._ack_timer = self.node.call_at(t + self.ack_timeout_ns, self._ack_timeout)

    def acked(self) -> None:
        """The consumer's acknowledgement came."""
        self.awaiting = None
        self.retries = 0
        if self._ack_timer is not None:
            self._ack_timer.cancel()
            self._ack_timer = None

    def _ack_timeout(self) -> None:
        self._ack_timer = None
        if not self.running or self.awaiting is None:
            return
        if self.retries < self.retry_limit:
            self.retries += 1
            self.retransmissions += 1
            self.awaiting = self.send(self.message)
            return
        self.awaiting = None
        self.retry_limits += 1
        if self.on_retry_limit is not None:
            self.on_retry_limit(self.node.now(), self.retries)
