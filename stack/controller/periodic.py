"""Cyclic transmission on a node's clock (what a controller's periodic task or an ECU's cyclic
message does), written against the node API only."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

from stack.controller.exceptions import NodeError, QueueFull
from stack.wire.frame import Frame

if TYPE_CHECKING:  # pragma: no cover
    from stack.controller.api import NodeAPI

__all__ = ["PeriodicTask"]


class PeriodicTask:
    """A frame sent every ``period`` ns on the node's clock (a cyclic transmission).

    ``frame`` may be a `Frame` or a callable returning the next frame (alive counters, changing
    signals). ``count`` limits the number of transmissions; `stop()` ends it.
    """

    def __init__(
        self,
        node: NodeAPI,
        frame: Frame | Callable[[], Frame],
        period: int,
        *,
        offset: int = 0,
        count: int | None = None,
    ) -> None:
        if isinstance(period, bool) or not isinstance(period, int) or period <= 0:
            raise ValueError(f"period {period!r} ns must be a positive int")
        self.node = node
        self.frame = frame
        self.period = period
        self.count = count
        self.sent = 0
        self.overflows = 0
        self.skipped = 0
        self._stopped = False
        self._next = node.now() + max(0, int(offset))
        self._timer = node.call_at(self._next, self._fire)

    def _fire(self) -> None:
        if self._stopped:
            return
        f = self.frame() if callable(self.frame) else self.frame
        try:
            self.node.send(f)
        except QueueFull:
            self.overflows += 1
        except NodeError:
            self.skipped += 1  # bus off: a controller drops what the application writes
        self.sent += 1
        if self.count is not None and self.sent >= self.count:
            self._stopped = True
            return
        self._next += self.period
        self._timer = self.node.call_at(self._next, self._fire)

    def stop(self) -> None:
        """Stop sending."""
        self._stopped = True
        self._timer.cancel()
