"""The python-can side of a canstack node's port (`Inbox`): received frames waiting for ``recv``,
transmit credits, the node's fault-confinement state; and `config_value`, the reading of the
options python-can's config files give as strings."""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from typing import Any

from stack.controller.confinement import ErrorState
from stack.wire.frame import Frame

__all__ = ["Inbox", "config_value", "BOOL_OPTIONS"]

#: the boolean options of the interface (python-can config files give them as words)
BOOL_OPTIONS = ("abort", "listen_only", "one_shot", "receive_own_messages", "ignore_rx_error_frames", "fd")
_BOOL_WORDS = {"true": True, "yes": True, "on": True, "1": True, "false": False, "no": False, "off": False, "0": False}


class Inbox:
    """The python-can side of a port (a `stack.io.port.PortOwner`): received frames wait in a
    queue for ``recv``, transmit credits in a counter, the node's state in attributes.

    A credit is one frame in the controller's transmit queue: ``send`` takes one, the port's
    ``tx_finished`` gives it back, so ``send`` waits for room as on a real controller, and
    ``shutdown`` knows how many frames are still to go out.
    """

    def __init__(self, rx_fifo_size: int, credits: int, error_frames: bool, fd: bool = False) -> None:
        self.rxq: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self.fd = fd  # False: FD frames on the bus are not shown (a CAN 2.0 socket of an FD controller)
        self.rx_fifo_size = rx_fifo_size
        self.rx_overruns = 0
        self.error_frames = error_frames
        self.state = ErrorState.ACTIVE
        self.tec = 0
        self.rec = 0
        self.last_tx_error: str | None = None
        self.lost_reason: str | None = None
        self.size = credits
        self.free = credits
        self.cond = threading.Condition()

    # PortOwner (runner or socket thread)
    def deliver(self, t_ns: int, frame: Frame, is_rx: bool) -> None:
        """Queue a received frame for ``recv`` (counted as an overrun when the FIFO is full)."""
        if frame.fd and not self.fd:
            return
        if self.rxq.qsize() >= self.rx_fifo_size:
            self.rx_overruns += 1
            return
        self.rxq.put((t_ns, frame, is_rx))

    def tx_finished(self, error: str | None) -> None:
        """Give a transmit credit back; remember why the frame was not sent, if it was not."""
        if error is not None:
            self.last_tx_error = error
        with self.cond:
            self.free += 1
            self.cond.notify_all()

    def tx_error(self, t_ns: int, reason: str, tec: int, rec: int) -> None:
        """Queue the error frame of a failed one-shot transmission for ``recv``."""
        self.last_tx_error = reason
        if self.error_frames and self.rxq.qsize() < self.rx_fifo_size:
            self.rxq.put((t_ns, None, (reason, tec, rec)))

    def set_state(self, state: ErrorState, tec: int, rec: int) -> None:
        """Mirror the node's fault-confinement state."""
        self.state = state
        self.tec = tec
        self.rec = rec

    def lost(self, reason: str) -> None:
        """The bus is gone: wake ``recv``."""
        self.lost_reason = reason
        self.rxq.put(None)

    # caller threads
    def take(self, timeout: float | None) -> bool:
        """Take a transmit credit, waiting up to ``timeout`` s (None: forever)."""
        with self.cond:
            if self.free > 0:
                self.free -= 1
                return True
            if timeout is not None and timeout <= 0:
                return False
            if not self.cond.wait_for(lambda: self.free > 0, timeout):
                return False
            self.free -= 1
            return True

    def drain(self, can_drain: Callable[[], bool], timeout: float) -> int:
        """Wait for every credit to come back, as long as frames keep going out: up to
        ``timeout`` s for each next one, and only while ``can_drain()``. Returns the frames
        still queued (0: all went out, or failed for reasons of their own)."""
        last = -1
        deadline = 0.0
        while True:
            # asked outside the lock: the answer comes from the runner thread, which needs the
            # lock to give credits back
            if not can_drain():
                return self.size - self.free
            with self.cond:
                if self.free >= self.size:
                    return 0
                if self.free != last:  # progress: a frame completed
                    last = self.free
                    deadline = time.monotonic() + timeout
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return self.size - self.free
                self.cond.wait(min(remaining, 0.05))
                if self.free >= self.size:
                    return 0


def config_value(key: str, value: Any) -> Any:
    """python-can config files give every option as a string: read flags and counts."""
    if not isinstance(value, str):
        return value
    if key in BOOL_OPTIONS and value.lower() in _BOOL_WORDS:
        return _BOOL_WORDS[value.lower()]
    if key in ("mailboxes", "tx_queue_size", "rx_fifo_size") and value.strip().isdigit():
        return int(value)
    if key == "flush_timeout":
        try:
            return float(value)
        except ValueError:
            return value
    return value
