"""What a master or a slave reports (h11 style: small immutable values), in its own node's
clock (ns). A profile keeps every event in ``events`` and calls the callbacks given to
``listen``."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

__all__ = [
    "Reporter",
    "CycleOverrun",
    "SlaveLost",
    "SlaveBack",
    "MasterStopped",
    "MasterResumed",
    "MasterLost",
    "MasterBack",
]


class CycleOverrun(NamedTuple):
    """A poll cycle ended after the next one was due: the next starts now, not on time (no
    silent drift). ``length`` is the cycle's length from its first request's SOF."""

    time: int
    master: str
    cycle: int
    length: int


class SlaveLost(NamedTuple):
    """A slave missed ``missed`` polls in a row (each with its retries): from now on it is polled
    at the slower rate until it answers."""

    time: int
    master: str
    slave: str
    missed: int


class SlaveBack(NamedTuple):
    """A lost slave answered again."""

    time: int
    master: str
    slave: str


class MasterStopped(NamedTuple):
    """The master stopped polling (``reason``: 'bus off')."""

    time: int
    master: str
    reason: str


class MasterResumed(NamedTuple):
    """The master's controller recovered (rule 12) and polling starts again."""

    time: int
    master: str


class MasterLost(NamedTuple):
    """A slave's watchdog expired: no request from its master for ``watchdog`` ns."""

    time: int
    slave: str
    master: str
    watchdog: int


class MasterBack(NamedTuple):
    """A slave that had lost its master is addressed by it again."""

    time: int
    slave: str
    master: str


class Reporter:
    """What masters and slaves share: every event kept in ``events``, and the callbacks given to
    `listen` called with it."""

    def __init__(self) -> None:
        self.events: list[Any] = []
        self._listeners: list[Callable[[Any], Any]] = []

    def listen(self, callback: Callable[[Any], Any]) -> None:
        """Call ``callback(event)`` for every event reported from now on (the classes above)."""
        self._listeners.append(callback)

    def _emit(self, event: Any) -> None:
        self.events.append(event)
        for cb in self._listeners:
            cb(event)
