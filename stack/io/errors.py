"""The errors a python-can bus of this package raises beyond python-can's own."""

from __future__ import annotations

import can

__all__ = ["BusLost"]


class BusLost(can.CanOperationError):
    """The bus is gone for good (its server stopped, its engine failed): every later `send` and
    `recv` raises it too. A `stack.io.driver.PyCanDriver` that sees it stops at once instead of
    retrying; python-can code that catches `can.CanOperationError` catches it as before.
    ``reason`` says why without the bus's name (the message has both)."""

    def __init__(self, message: str, reason: str | None = None) -> None:
        super().__init__(message)
        self.reason = reason or message
