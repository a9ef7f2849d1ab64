"""Events a node reports to the layers above (h11 style: small immutable values).

Times are integer nanoseconds on the driver's clock (virtual in simulation, wall clock on a
python-can bus).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from .frame import Frame

if TYPE_CHECKING:  # pragma: no cover
    from .queues import TxRequest

__all__ = ["Received", "TxDone", "TxFailed", "ArbitrationLost", "Event"]


@dataclass(frozen=True, slots=True)
class Received:
    """A frame passed the acceptance filters and was received (valid at the end of EOF)."""

    time: int
    frame: Frame


@dataclass(frozen=True, slots=True)
class TxDone:
    """A queued frame was transmitted successfully (no error up to the end of EOF)."""

    time: int
    frame: Frame
    request: "TxRequest"


@dataclass(frozen=True, slots=True)
class TxFailed:
    """A queued frame will not be sent: one-shot failure, abort, bus off, or shutdown."""

    time: int
    frame: Frame
    request: "TxRequest"
    reason: str


@dataclass(frozen=True, slots=True)
class ArbitrationLost:
    """The node's pending frame lost bitwise arbitration to ``winner`` in the round at ``time``."""

    time: int
    frame: Frame
    winner: Frame


Event = Any
