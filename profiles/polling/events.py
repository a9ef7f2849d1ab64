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
    "RetryLimitReached",
    "CommunicationFault",
    "POLL",
    "COS",
]

POLL = "poll"
"""The ``connection`` of events about the poll / bit-strobe connection."""
COS = "cos"
"""The ``connection`` of events about the change-of-state / cyclic connection."""


class CycleOverrun(NamedTuple):
    """A poll cycle ended after the next one was due: the next starts now, not on time (no
    silent drift). ``length`` is the cycle's length from its first request's SOF."""

    time: int
    master: str
    cycle: int
    length: int


class SlaveLost(NamedTuple):
    """The master lost a slave's connection: on the poll connection, the slave missed ``missed``
    polls in a row (each with its retries) and is polled at the slower rate from now on until it
    answers; on the COS/cyclic connection (``connection`` "cos", ``missed`` 0), nothing came for
    4 × its expected packet rate (the connection timed out)."""

    time: int
    master: str
    slave: str
    missed: int
    connection: str = POLL


class SlaveBack(NamedTuple):
    """A lost slave answered again (``connection``: the one that had been lost)."""

    time: int
    master: str
    slave: str
    connection: str = POLL


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
    """A slave's watchdog expired: nothing of its master on ``connection`` for ``watchdog`` ns
    (the poll connection: no request; an acknowledged COS/cyclic connection: no acknowledgement)."""

    time: int
    slave: str
    master: str
    watchdog: int
    connection: str = POLL


class MasterBack(NamedTuple):
    """A slave that had lost its master is addressed by it again on ``connection``."""

    time: int
    slave: str
    master: str
    connection: str = POLL


class RetryLimitReached(NamedTuple):
    """An acknowledged COS/cyclic message was sent ``retries`` times more without an
    acknowledgement (DeviceNet's Acknowledge Handler: RetryLimit_Reached); the slave waits for its
    next production. The connection itself stays (its watchdog decides)."""

    time: int
    slave: str
    message: str
    retries: int


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


class CommunicationFault(NamedTuple):
    """A node's duplicate MAC ID check heard another node with its MAC ID (``reason``): it went
    to DeviceNet's communication fault state and stays silent."""

    time: int
    node: str
    mac_id: int
    reason: str
