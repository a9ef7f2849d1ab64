"""The node API: everything a layer above the controller may use — a scheduling profile, a
CANopen device, a DBC ECU — written as a typing Protocol.

Code written against `NodeAPI` runs unchanged on the simulated bus and on any python-can bus,
because both give a `stack.controller.node.Node` a driver (see `stack.controller.contract`).
What a given driver can know (exact start-of-frame times, arbitration losses, error counters) is
in ``node.capabilities``.

Times: ``now()``, ``call_at``/``call_later`` and the times of every event the node reports are the
node's local clock in integer ns — the bus time itself unless the node was given a
`LocalClock` with an offset or a drift. `TxRequest` keeps bus times (``t_queued``, ``sof``,
``t_done``) for measurements across nodes.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:  # pragma: no cover
    from stack.controller.confinement import ErrorState
    from stack.controller.contract import Timer
    from stack.controller.events import Received
    from stack.controller.node import PeriodicTask, Subscription
    from stack.controller.queues import TxRequest
    from stack.wire.frame import Frame, MessageLike

__all__ = ["NodeAPI"]


class NodeAPI(Protocol):
    """A CAN node as the layers above see it."""

    name: str

    # -- transmit
    def send(
        self, frame: Frame | MessageLike, *, one_shot: bool | None = None, not_after: int | None = None
    ) -> TxRequest:
        """Queue a frame (or a `can.Message`, read by its attributes); ``one_shot`` overrides the
        node's retransmission mode for this frame, ``not_after`` (local ns) is its latest start
        time: not started by then, it is withdrawn and reported as `TxFailed`."""
        ...

    def send_periodic(
        self, frame: Frame | Callable[[], Frame], period: int, *, offset: int = 0, count: int | None = None
    ) -> PeriodicTask:
        """Queue ``frame`` every ``period`` ns of the node's clock."""
        ...

    def abort(self, req: TxRequest) -> bool:
        """Take back a request that has not started."""
        ...

    def pending(self) -> list[TxRequest]:
        """Requests still queued."""
        ...

    def set_remote_reply(self, frame: Frame | None, *, can_id: int | None = None, extended: bool = False) -> None:
        """A mailbox that answers remote frames for ``frame``'s identifier."""
        ...

    # -- receive and events
    def subscribe(
        self, callback: Callable[[Received], Any], filters: Iterable[Mapping[str, Any]] | None = None
    ) -> Subscription:
        """Call ``callback(Received)`` for each frame received (``.time``, ``.frame``, ``.sof``)."""
        ...

    def listen(self, event_type: type, callback: Callable[[Any], Any]) -> None:
        """Call ``callback(event)`` for TxDone, TxFailed, ArbitrationLost, ErrorStateChanged."""
        ...

    def unlisten(self, event_type: type, callback: Callable[[Any], Any]) -> bool:
        """Stop calling ``callback`` for ``event_type``."""
        ...

    def recv(self) -> tuple[int, Frame] | None:
        """The oldest frame of the receive FIFO (when nothing is subscribed)."""
        ...

    # -- time
    def now(self) -> int:
        """The node's local time, ns."""
        ...

    def call_at(self, time: int, callback: Callable[..., Any], *args: Any) -> Timer:
        """Run ``callback(*args)`` at local time ``time`` ns."""
        ...

    def call_later(self, delay: int, callback: Callable[..., Any], *args: Any) -> Timer:
        """Run ``callback(*args)`` ``delay`` local ns from now."""
        ...

    @property
    def bit_ns(self) -> float | None:
        """The bus's bit time in ns (None when the driver does not know the bitrate)."""
        ...

    @property
    def capabilities(self) -> frozenset[str]:
        """What the driver underneath can know (`stack.controller.contract.CAPABILITIES`)."""
        ...

    # -- state
    @property
    def state(self) -> ErrorState:
        """The fault-confinement state."""
        ...

    def counters(self) -> dict[str, int]:
        """tx/rx frames, arbitration losses, retransmissions, overruns, failures, TEC/REC."""
        ...
