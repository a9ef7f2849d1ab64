"""Native CSMA/CR: plain CAN. Each node queues its messages when they are released and the bus
arbitrates; the order a node offers its own frames in is its controller's queue policy
(priority, FIFO or mailboxes — see `stack.controller.queues`).

This is the profile the response-time analysis (`profiles.analysis.rta`) describes when every
node uses a priority queue.

A node may be *gated* by a time-triggered schedule on the same bus (see the TDMA profile): then
``gate`` is set, and each release asks it when the frame may start and by when it must have
started; ungated (``tdma_gated = false`` in the scenario), the node sends at once whatever the
schedule says.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from profiles.base import Context, Profile, frame_of, source_for

if TYPE_CHECKING:  # pragma: no cover
    from profiles.analysis.rta import MessageSpec
    from profiles.declarations import MessageDecl, NodeDecl
    from stack import Frame, NodeAPI

__all__ = ["CsmaProfile", "Gate", "message_specs"]

Gate = Callable[["Frame", int], "tuple[int, int | None] | None"]
"""``gate(frame, now) -> (start_at, not_after)``: when a frame released at ``now`` (node clock)
may be queued and its latest start; None to send at once."""


class CsmaProfile(Profile):
    """Plain CAN on one node: periodic and sporadic messages queued at their release times."""

    kind = "csma"

    def __init__(self, node: NodeAPI, decl: NodeDecl, context: Context) -> None:
        super().__init__(node, decl, context)
        self.gate: Gate | None = None
        self.frames = {m.name: frame_of(m) for m in decl.messages}
        self._track_of = {m.name: context.recorder.track(m) for m in decl.messages}
        self.sources = [
            s
            for m in decl.messages
            if (s := source_for(node, m, self.release, context.rng("release", decl.name, m.name)))
        ]
        self._source_of = {s.decl.name: s for s in self.sources}

    def start(self) -> None:
        """Arm every message's first release."""
        for s in self.sources:
            s.start()

    def release(self, m: MessageDecl) -> None:
        """An instance of ``m`` is released: queue it now (or, gated, when the schedule lets it).
        Its deadline counts from its nominal release (its source's, when a source released it)."""
        frame = self.frames[m.name]
        src = self._source_of.get(m.name)
        nominal = None if src is None else src.releasing
        if self.gate is not None:
            slot = self.gate(frame, self.node.now())
            if slot is not None:
                start_at, not_after = slot
                self.node.call_at(start_at, self._queue_gated, m, not_after, nominal)
                return
        self.queue(frame, self._track_of[m.name], nominal=nominal)

    def _queue_gated(self, m: MessageDecl, not_after: int | None, nominal: int | None = None) -> None:
        self.queue(self.frames[m.name], self._track_of[m.name], nominal=nominal, not_after=not_after)

    def set_data(self, name: str, data: bytes) -> None:
        """Application hook: the payload the next instances of message ``name`` carry."""
        old = self.frames[name]
        if old.fd:
            self.frames[name] = type(old)(old.can_id, data, extended=old.extended, fd=True, brs=old.brs)
        else:
            self.frames[name] = type(old)(old.can_id, data, extended=old.extended)

    def summary(self) -> dict[str, Any]:
        """Per node: the queue policy and whether a schedule gates it."""
        return {"queue": self.decl.queue, "gated": self.gate is not None}


def message_specs(decl: NodeDecl, exact: bool = False) -> list[MessageSpec]:
    """The node's messages as the response-time analysis models them: period (or minimum
    inter-arrival) and release jitter on the node's clock (its drift goes with them), deadline
    from the nominal release, CAN FD and BRS as declared; with ``exact``, each frame's own length
    (its payload is fixed; with BRS, the part of it at the data rate) instead of worst-case
    stuffing."""
    from profiles.analysis.rta import MessageSpec
    from stack.wire.coding import INTERMISSION_BITS

    out = []
    for m in decl.messages:
        if m.interval_ns is None:
            continue
        bits = frame_of(m).bits if exact else None
        out.append(
            MessageSpec(
                m.name,
                m.can_id,
                m.extended,
                m.dlc,
                m.interval_ns,
                m.deadline_ns or m.interval_ns,
                m.jitter_ns,
                None if bits is None else bits.length + INTERMISSION_BITS,
                node=decl.name,
                drift_ppm=decl.drift_ppm,
                fd=m.fd,
                brs=m.brs,
                # an exact frame with BRS: how many of its bits go at the data rate
                data_bits=bits.data_bits if bits is not None and m.brs else None,
            )
        )
    return out
