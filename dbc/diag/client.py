"""A udsoncan connection over an `IsoTpChannel` on the simulated bus (needs ``udsoncan``).

`SimConnection(bus, node, tx_id, rx_id)` lets udsoncan's ``Client`` talk to ECUs on a
`stack.bus.sim.SimBus` in the same process: ``send`` queues the request on the tester's ISO-TP
channel, and waiting for the response runs the simulated bus until the response is complete or
the timeout (simulated seconds) has passed. Nothing sleeps: a request costs the simulated time
it takes on the bus.
"""

from __future__ import annotations

from collections import deque
from typing import Any

from udsoncan.connections import BaseConnection
from udsoncan.exceptions import TimeoutException

from .isotp import IsoTpChannel

__all__ = ["SimConnection"]


class SimConnection(BaseConnection):
    """A udsoncan connection from a tester node on a simulated bus (see the module docstring);
    ``channel`` options (``stmin_ms``, ``block_size``, ``extended``) go to `IsoTpChannel`."""

    def __init__(self, bus: Any, node: Any, tx_id: int, rx_id: int, **channel: Any) -> None:
        super().__init__("canstack-sim")
        self.bus = bus
        self._rx: deque[bytes] = deque()
        self.channel = IsoTpChannel(node, rx_id, tx_id, self._rx.append, **channel)
        self._open = False

    def open(self) -> SimConnection:
        """Open (nothing to set up: the channel is on the bus already)."""
        self._open = True
        return self

    def close(self) -> None:
        """Close; the channel stops receiving."""
        self._open = False
        self.channel.close()

    def is_open(self) -> bool:
        """Whether `open` was called and not `close`."""
        return self._open

    def empty_rxqueue(self) -> None:
        """Drop responses not read yet."""
        self._rx.clear()

    def specific_send(self, payload: bytes, timeout: float | None = None) -> None:
        """Queue a request on the tester's ISO-TP channel."""
        self.channel.send(payload)

    def specific_wait_frame(self, timeout: float | None = None) -> bytes | None:
        """Run the simulated bus until a response is complete, at most ``timeout`` simulated
        seconds (default 1)."""
        end = self.bus.now() + round((1.0 if timeout is None else timeout) * 1e9)
        step = 100_000  # 0.1 ms of bus time per slice: a response ends at most this much late
        while not self._rx:
            now = self.bus.now()
            if now >= end:
                raise TimeoutException(f"no response in {timeout} s of simulated time")
            self.bus.run(until=min(end, now + step))
        return self._rx.popleft()
