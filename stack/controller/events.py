"""Events a node reports to the layers above (h11 style: small immutable values).

They are NamedTuples rather than frozen dataclasses: one is made per received frame on the hot
path, and a NamedTuple is built several times faster (the benchmarks page has the figure).

Times are integer nanoseconds on the node's clock: the driver's (virtual in simulation, wall
clock on a python-can bus), shifted and scaled when the node has a `LocalClock`. ``sof`` is the
start of frame of the frame in question, on the same clock (the bus time of its SOF bit — what a
time-triggered node's hard synchronisation sees; on a python-can bus an estimate, see
``node.capabilities``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NamedTuple

from stack.wire.frame import Frame

if TYPE_CHECKING:  # pragma: no cover
    from stack.controller.queues import TxRequest

__all__ = ["Received", "TxDone", "TxFailed", "ArbitrationLost", "ErrorStateChanged", "Event"]


class Received(NamedTuple):
    """A frame passed the acceptance filters and was received (valid at the end of EOF)."""

    time: int
    frame: Frame
    sof: int = -1


class TxDone(NamedTuple):
    """A queued frame was transmitted successfully (no error up to the end of EOF)."""

    time: int
    frame: Frame
    request: TxRequest
    sof: int = -1


class TxFailed(NamedTuple):
    """A queued frame will not be sent: one-shot failure, abort, its latest start time passed
    (reason "not started by ..."), bus off, or shutdown."""

    time: int
    frame: Frame
    request: TxRequest
    reason: str
    kind: str = ""
    """Why, in one word: 'arbitration' (lost, one-shot), 'bit', 'stuff', 'form', 'crc', 'ack'
    (the error that destroyed a one-shot attempt), 'expired' (latest start time passed),
    'aborted', 'send' (the python-can bus refused it)."""


class ArbitrationLost(NamedTuple):
    """The node's pending frame lost bitwise arbitration to ``winner`` in the round at ``time``."""

    time: int
    frame: Frame
    winner: Frame


class ErrorStateChanged(NamedTuple):
    """Fault confinement moved the node to another state (rules 9-12, warning at 96)."""

    time: int
    node: str
    old: str
    new: str
    tec: int
    rec: int


Event = Any
