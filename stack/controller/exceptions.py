"""What a controller refuses to do, as exceptions the layers above catch."""

from __future__ import annotations

__all__ = ["NodeError", "QueueFull"]


class NodeError(Exception):
    """An operation the node cannot do in its current mode (listen-only, detached, bus off)."""


class QueueFull(Exception):
    """The controller's transmit queue has no room for another frame."""
