"""Helpers of the python-can tests, as fixtures."""

from __future__ import annotations

import io
import math
import time
from collections.abc import Callable
from pathlib import Path
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


FILLER_ID = 0x7FF  # the lowest priority: a filler never delays a frame under test


def _logged(path: Path) -> list[Any]:
    """The frames in the complete lines of an .asc file another process is still writing."""
    import can

    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except FileNotFoundError:
        return []
    complete = text[: text.rfind("\n") + 1]
    return list(can.ASCReader(io.StringIO(complete)))


@pytest.fixture
def fill_until_logged(wait_until: Callable[..., Any]) -> Callable[..., list[Any]]:
    """``fill_until_logged(tx, path, n)``: send filler frames (ID 0x7FF, 8 bytes) from ``tx`` until
    the .asc log ``path`` written by another process shows ``n`` frames that are no fillers; the
    frames logged so far (``fill_until_logged.filler_id`` is the fillers' ID). A log file is written through a buffer: the fillers push the frames
    under test through it, so the test knows the logger has them before it stops the logger
    (a logger stopped earlier loses what it had not read, and no fixed wait is long enough on a
    loaded machine)."""

    def fill(tx: Any, path: Path, n: int) -> list[Any]:
        import can

        filler = can.Message(arbitration_id=FILLER_ID, data=bytes(8), is_extended_id=False)

        def enough() -> list[Any] | None:
            got = _logged(path)
            if sum(1 for m in got if m.arbitration_id != FILLER_ID) >= n:
                return got
            for _ in range(16):  # a few lines' worth of the writer's buffer at a time
                tx.send(filler)
            return None

        return wait_until(enough, timeout=60.0, what=f"{n} frames in {path}")

    fill.filler_id = FILLER_ID  # type: ignore[attr-defined]
    return fill


@pytest.fixture
def settle(wait_until: Callable[..., Any]) -> Callable[[str], None]:
    """``settle(channel)``: wait until the in-process canstack bus ``channel`` has nothing left
    to do (no frame on the wire or queued, no timer: `SimBus.next_event_time` is infinite). Every
    frame sent before is then in its receivers' queues, and none can come after: ``recv(0)``
    reads exactly what the bus carried. (The check runs on the bus's runner thread, after the
    commands already posted, such as a frame just sent.)"""
    from stack.io.runner import get_runner

    def wait(channel: str) -> None:
        runner = get_runner(channel)
        assert runner is not None, f"no canstack bus {channel!r} in this process"
        wait_until(lambda: runner.call(lambda: runner.sim.next_event_time() == math.inf), what=f"bus {channel!r} idle")

    return wait
