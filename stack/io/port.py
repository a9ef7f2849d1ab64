"""A python-can client's node on a real-time simulated bus: the engine side shared by the
in-process interface (`stack.io.pycan`) and the sessions of `canstack serve` (`stack.io.serve`).

A `Port` attaches a node with the client's options to a `RealTimeRunner`'s `SimBus`, hands the
node's receptions (and, if asked, its own frames) to its owner, counts transmit credits by
`TxDone`/`TxFailed`, reports one-shot failures, mirrors the node's error state, runs periodic
tasks on the simulation clock, switches listen-only at run time, and takes the node off the
bus when the client leaves (`SimBus.remove`: its name is free again).

The owner is what the client sees: `CanstackBus`'s inbox (a queue and a semaphore) in process,
or a session that writes protocol messages to a socket. Every owner callback runs on the runner
thread; every `Port` method may be called from any other thread.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from typing import Any, Protocol

from stack.controller.confinement import BUS_OFF, ErrorState
from stack.controller.events import TxDone, TxFailed
from stack.controller.filters import validate_filters
from stack.controller.node import Node, NodeError, QueueFull
from stack.wire.frame import Frame

__all__ = ["Port", "PortOwner", "NODE_OPTIONS", "check_filters"]

NODE_OPTIONS = ("queue", "mailboxes", "abort", "tx_queue_size", "listen_only", "one_shot")
"""The controller options a client may give for its node (see `stack.controller.node.Node`)."""


_WIRE_FAILURES = frozenset({"arbitration", "bit", "stuff", "form", "crc", "ack"})


class PortOwner(Protocol):
    """What a `Port` reports to (on the runner thread)."""

    def deliver(self, t_ns: int, frame: Frame, is_rx: bool) -> None:
        """A frame received at ``t_ns`` (``is_rx`` False: the node's own, sent successfully)."""

    def tx_finished(self, error: str | None) -> None:
        """One frame given to `Port.send` is done: sent (None) or not, and why."""

    def tx_error(self, t_ns: int, reason: str, tec: int, rec: int) -> None:
        """A one-shot transmission failed at ``t_ns`` (lost arbitration or an error), the case
        SocketCAN reports with an error frame; the counters are the node's after it."""

    def set_state(self, state: ErrorState, tec: int, rec: int) -> None:
        """The node's fault-confinement state or counters changed."""

    def lost(self, reason: str) -> None:
        """The bus is gone (engine failure): nothing more will come."""


def check_filters(filters: Any) -> list[Mapping[str, Any]] | None:
    """python-can acceptance filters checked: None (or empty) accepts everything, else a list of
    ``{"can_id", "can_mask"[, "extended"]}`` mappings. ValueError names the value and the rule,
    also for values that are no list at all (a number, a boolean, a string, one mapping)."""
    if filters is None:
        return None
    if isinstance(filters, (str, bytes, bytearray, Mapping)) or not isinstance(filters, Iterable):
        raise ValueError(
            f"filters {filters!r} must be a list of {{'can_id', 'can_mask'[, 'extended']}} "
            "mappings, or None for no filtering"
        )
    flist = list(filters)
    validate_filters(flist)
    return flist or None


class Port:
    """A client's node on ``runner``'s bus, reporting to ``owner`` (a `PortOwner`).

    ``node_name`` None picks a free name ``{prefix}N``; a name already on the bus, or options the
    node refuses (``config``: see `NODE_OPTIONS`), raise ValueError naming the value.
    ``receive_own_messages`` echoes the node's successful frames that pass its filters.
    """

    def __init__(
        self,
        runner: Any,
        owner: PortOwner,
        *,
        node_name: str | None = None,
        prefix: str = "node",
        config: Mapping[str, Any] | None = None,
        receive_own_messages: bool = False,
    ) -> None:
        self.runner = runner
        self.owner = owner
        self.own = bool(receive_own_messages)
        self.bitrate: int = runner.bitrate
        self.data_bitrate: int | None = getattr(runner, "data_bitrate", None)
        self.epoch0: float = runner.epoch0
        self.closed = False
        self._credit: set[Any] = set()
        self._tasks: set[Any] = set()
        self._last_state: tuple[ErrorState, int, int] | None = None
        self.node: Node = runner.call(lambda: self._attach(node_name, prefix, dict(config or {})))
        self.node_name: str = self.node.name

    def _attach(self, node_name: str | None, prefix: str, config: dict[str, Any]) -> Node:
        sim = self.runner.sim
        unknown = set(config) - set(NODE_OPTIONS)
        if unknown:
            raise ValueError(f"unknown node option(s) {sorted(unknown)}: allowed are {', '.join(NODE_OPTIONS)}")
        if node_name is None:
            node_name = sim.free_name(prefix)
        elif any(n.name == node_name for n in sim.nodes):
            raise ValueError(f"a node named {node_name!r} is already on bus {sim.name!r}")
        try:
            # frames go to the subscription callback, never to the node's FIFO; own frames
            # come from TxDone, so the node's self-reception stays off
            node = sim.node(node_name, receive_own_messages=False, rx_fifo_size=1, **config)
        except (ValueError, TypeError) as exc:
            raise ValueError(f"node options: {exc}") from None
        self.node = node
        deliver = self.owner.deliver
        node.subscribe(lambda ev: deliver(ev.time, ev.frame, True))
        node.listen(TxDone, self._on_txdone)
        node.listen(TxFailed, self._on_txfailed)
        self.runner.add_port(self)
        return node

    # -- runner thread ------------------------------------------------------------------
    def _on_txdone(self, ev: TxDone) -> None:
        if self.own and self.node.acceptance.accepts(ev.frame):
            self.owner.deliver(ev.time, ev.frame, False)
        if ev.request in self._credit:
            self._credit.discard(ev.request)
            self.owner.tx_finished(None)

    def _on_txfailed(self, ev: TxFailed) -> None:
        # a failed attempt on the wire (TxFailed.kind names the error); not the host's abort
        # nor a frame withdrawn at its latest start time: those never reached the wire
        if ev.kind in _WIRE_FAILURES and not self.closed:
            self.owner.tx_error(ev.time, ev.reason, self.node.tec, self.node.rec)
        if ev.request in self._credit:
            self._credit.discard(ev.request)
            self.owner.tx_finished(ev.reason)

    def mirror_state(self) -> None:
        """Report the node's state to the owner if it changed (the runner calls this)."""
        n = self.node
        st = (n.state, n.tec, n.rec)
        if st != self._last_state:
            self._last_state = st
            self.owner.set_state(*st)

    def closed_by_runner(self, reason: str) -> None:
        """The engine stopped (the runner calls this): tell the owner."""
        self.owner.lost(reason)

    def _send(self, frame: Frame) -> None:
        if self.closed:
            return
        try:
            req = self.node.send(frame)
        except (QueueFull, NodeError) as exc:
            self.owner.tx_finished(str(exc))
            return
        if req.state == "queued":
            self._credit.add(req)
        else:  # settled at once (a one-shot failure inside send)
            self.owner.tx_finished(None if req.state == "sent" else req.reason)

    # -- any thread ----------------------------------------------------------------------
    def send(self, frame: Frame) -> None:
        """Queue ``frame`` on the node; the owner's ``tx_finished`` reports its end."""
        self.runner.post(lambda: self._send(frame))

    def set_filters(self, filters: list[Mapping[str, Any]] | None, wait: bool = True) -> None:
        """Replace the node's acceptance filters (checked by `check_filters` first). With
        ``wait`` the call returns once they apply; frames queued after it see them either way."""

        def apply() -> None:
            if not self.closed:
                self.node.set_filters(filters)

        if wait:
            self.runner.call(apply)
        else:
            self.runner.post(apply)

    def set_listen_only(self, on: bool, wait: bool = True) -> None:
        """Switch the controller to listen-only (no ACK, no transmission, no error flags) or
        back, at run time, as a controller is re-initialised in the other mode: frames still
        queued are aborted when it goes listen-only (a frame already on the wire finishes);
        the mode applies from the next frame on the bus."""
        sim = self.runner.sim

        def abort_queued() -> None:
            node = self.node
            if self.closed or not node.listen_only:
                return
            on_wire = False
            for req in node.pending():
                if req.on_wire:
                    on_wire = True
                else:
                    node.abort(req)
            if on_wire:  # look again just after the bus's next event: the frame's end, at the latest
                sim.call_at(sim.next_event_time() + 1, abort_queued)

        def switch() -> None:
            node = self.node
            if self.closed or node.listen_only == on:
                return
            node.listen_only = on  # the node tells the bus, which re-reads who acknowledges
            if on:  # a frame on the wire that fails is not retransmitted: aborted at its end
                abort_queued()

        if wait:
            self.runner.call(switch)
        else:
            self.runner.post(switch)

    def timestamp(self, t_ns: int) -> float:
        """The wall-clock time (s since the epoch) of bus time ``t_ns``."""
        return self.epoch0 + t_ns / 1e9

    def can_drain(self) -> bool:
        """True while the node's queued frames can still go out: it is on the bus and another
        node there acknowledges (a lone transmitter retransmits for ever)."""

        def check() -> bool:
            node = self.node
            if self.closed or not node.connected or node.listen_only:
                return False
            return any(
                n is not node and n.connected and not n.listen_only and n.state is not BUS_OFF
                for n in self.runner.sim.nodes
            )

        try:
            return bool(self.runner.call(check, timeout=1.0))
        except Exception:  # the runner is gone: nothing drains any more
            return False

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

    def close(self, wait: bool = True, timeout: float = 2.0) -> None:
        """Leave the bus for good: periodic tasks stop, frames still queued are aborted, a
        frame already on the wire finishes, the node leaves the bus's list and its name is free
        again (`SimBus.remove`). Idempotent; with ``wait`` it returns once that is done (or the
        runner did not answer within ``timeout`` s)."""

        def leave() -> None:
            if self.closed:
                return
            self.closed = True
            for t in list(self._tasks):
                t.stop()
            self._tasks.clear()
            self.runner.remove_port(self)
            if self.node in self.runner.sim.nodes:  # not yet detached (its bus is the runner's)
                self.runner.sim.remove(self.node)

        if not wait:
            self.runner.post(leave)
            return
        try:
            self.runner.call(leave, timeout=timeout)
        except Exception:  # runner gone or stuck: nothing left to leave
            pass
