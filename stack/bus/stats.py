"""Statistics the simulated bus keeps as it runs (streaming: constant memory per identifier)."""

from __future__ import annotations

__all__ = ["IdStats"]


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
