"""Statistics the simulated bus keeps as it runs (streaming: constant memory per identifier) and
the results it reports (bus load, summary). The trace goes to a file through python-can's writers
with `stack.io.tracefile.save_trace`."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from stack.bus.trace import TraceRecord
from stack.wire.frame import arbitration_key, id_text

if TYPE_CHECKING:  # pragma: no cover
    from stack.controller.node import Node

__all__ = ["IdStats", "BusStatistics"]


class IdStats:
    """Per-identifier statistics: frames and latency (queued to end of EOF) min/mean/max in ns."""

    __slots__ = ("can_id", "extended", "count", "total", "min", "max", "losses")

    def __init__(self, can_id: int, extended: bool) -> None:
        self.can_id = can_id
        self.extended = extended
        self.count = 0
        self.total = 0
        self.min = 1 << 62
        self.max = 0
        self.losses = 0

    def add(self, latency: int, losses: int) -> None:
        """One frame sent: its latency (queued to end of EOF, ns) and arbitration rounds lost."""
        self.count += 1
        self.total += latency
        self.losses += losses
        if latency < self.min:
            self.min = latency
        if latency > self.max:
            self.max = latency

    @property
    def mean(self) -> float:
        """Mean latency in ns."""
        return self.total / self.count if self.count else 0.0


class BusStatistics:
    """The results of `stack.bus.sim.SimBus` (a mixin over the counters the bus keeps)."""

    if not TYPE_CHECKING:  # SimBus declares the fields (the annotations below are their types)
        __slots__ = ()

    bitrate: int
    data_bitrate: int | None
    name: str
    nodes: list[Node]
    trace: list[TraceRecord]
    frames_ok: int
    error_frames: int
    collisions: int
    busy_ns: int
    id_stats: dict[int, IdStats]
    now_ns: int
    _idle_at: int
    _bus_listeners: list[Callable[[TraceRecord], Any]]

    @property
    def elapsed(self) -> int:
        """Virtual time since the start of the simulation, ns."""
        return self.now_ns

    def bus_load(self) -> float:
        """Fraction of elapsed time the bus was not idle (frames and error frames with their
        intermission), 0..1: the intermission of the last frame counts only up to now (a run
        that ends inside it would otherwise count time it never reached)."""
        if not self.now_ns:
            return 0.0
        busy = self.busy_ns - max(0, self._idle_at - self.now_ns)
        return min(1.0, max(0, busy) / self.now_ns)

    def on_trace(self, callback: Callable[[TraceRecord], Any]) -> None:
        """Call ``callback(record)`` for each trace record as it is made (needs record=True)."""
        self._bus_listeners.append(callback)

    def summary(self) -> dict[str, Any]:
        """Bus load, frame and error counts, per-ID latency and per-node counters (and the data bit
        rate of a CAN FD bus)."""
        out: dict[str, Any] = {"bitrate": self.bitrate}
        if self.data_bitrate is not None:
            out["data_bitrate"] = self.data_bitrate
        return out | {
            "elapsed_s": self.now_ns / 1e9,
            "frames": self.frames_ok,
            "error_frames": self.error_frames,
            "collisions": self.collisions,
            "bus_load": self.bus_load(),
            # one entry per arbitration key: a remote frame and a data frame of one identifier
            # are two frames on the wire (labelled 'ID RTR' and 'ID'), so the counts add up
            "ids": {
                id_text(s.can_id, s.extended, key == arbitration_key(s.can_id, s.extended, True)): {
                    "id": s.can_id,
                    "extended": s.extended,
                    "remote": key == arbitration_key(s.can_id, s.extended, True),
                    "count": s.count,
                    "latency_min_us": s.min / 1e3,
                    "latency_mean_us": s.mean / 1e3,
                    "latency_max_us": s.max / 1e3,
                    "arbitration_losses": s.losses,
                }
                for key, s in sorted(self.id_stats.items())
            },
            "nodes": {n.name: n.counters() for n in self.nodes},
        }
