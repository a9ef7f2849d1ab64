"""Helpers of the python-can tests, as fixtures."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import pytest


def _drain(bus: Any, n: int, timeout: float = 3.0) -> list[Any]:
    got: list[Any] = []
    end = time.monotonic() + timeout
    while len(got) < n and time.monotonic() < end:
        m = bus.recv(0.1)
        if m is not None:
            got.append(m)
    return got


@pytest.fixture
def drain() -> Callable[..., list[Any]]:
    """``drain(bus, n, timeout=3.0)``: up to ``n`` messages from a python-can bus, waiting at most
    ``timeout`` seconds of wall clock for them."""
    return _drain
