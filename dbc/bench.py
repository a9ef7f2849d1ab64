"""Benchmark: ECU encoding + scheduling overhead per transmitted message vs cantools' encode.

``python -m dbc.bench`` prints the figures. Method, in one run:

- the sample network (`dbc/databases/powertrain_body.dbc`): one `Ecu` per node, each on a
  bare driver stub (a clock, a timer heap, a ``send`` that keeps the frame) — so what is timed
  is the ECU's own transmit path: interaction-layer timers, alive counters and checksums,
  cantools encode, building the `Frame` — and not the bus engine (measured by
  ``python -m stack.bench``) nor reception;
- ``ecu_us_per_msg`` = wall time of ``seconds`` of virtual time / frames sent;
- ``cantools_us_per_msg``: cantools' ``Message.encode(values)`` (its default, strict) of the same
  messages with the same values, in the same proportions; ``cantools_nonstrict_us_per_msg``
  the same with ``strict=False`` (what the ECU calls after checking values at write time).

The target is ``ratio`` = ecu / cantools <= 1.5.
"""

from __future__ import annotations

import heapq
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from .ecu import Ecu, node_names
from .errors import load_database

__all__ = ["benchmark", "SAMPLE_DBC"]

SAMPLE_DBC = Path(__file__).resolve().parent / "databases" / "powertrain_body.dbc"


class _Timer:
    __slots__ = ("cancelled",)

    def __init__(self) -> None:
        self.cancelled = False

    def cancel(self) -> None:
        self.cancelled = True


class _StubDriver:
    """The least a node offers an ECU: a virtual clock, timers, send."""

    def __init__(self) -> None:
        self.t = 0
        self.heap: list[tuple[int, int, _Timer, Callable[..., Any], tuple[Any, ...]]] = []
        self.seq = 0
        self.sent = 0

    def node(self, name: str) -> _StubNode:
        return _StubNode(self)

    def run(self, until: int) -> None:
        heap = self.heap
        pop = heapq.heappop
        while heap and heap[0][0] <= until:
            t, _, tm, cb, args = pop(heap)
            if tm.cancelled:
                continue
            self.t = t
            cb(*args)
        self.t = until


class _StubNode:
    def __init__(self, drv: _StubDriver) -> None:
        self.drv = drv
        self.last: Any = None

    def now(self) -> int:
        return self.drv.t

    def call_at(self, t: int, cb: Callable[..., Any], *args: Any) -> _Timer:
        d = self.drv
        d.seq += 1
        tm = _Timer()
        heapq.heappush(d.heap, (max(t, d.t), d.seq, tm, cb, args))
        return tm

    def call_later(self, delay: int, cb: Callable[..., Any], *args: Any) -> _Timer:
        return self.call_at(self.drv.t + delay, cb, *args)

    def send(self, frame: Any) -> Any:
        self.drv.sent += 1
        self.last = frame
        return frame

    def subscribe(self, cb: Callable[[Any], Any], filters: Any = None) -> None:
        return None


def _best(fn: Callable[[], float], repeat: int) -> float:
    return min(fn() for _ in range(repeat))


def benchmark(seconds: float = 20.0, repeat: int = 3) -> dict[str, float]:
    """Measure the ECU's per-message transmit overhead against cantools' encode (see the
    module docstring); returns {"ecu_us_per_msg", "cantools_us_per_msg", "ratio",
    "cantools_nonstrict_us_per_msg", "frames"}."""
    db = load_database(SAMPLE_DBC)
    until = int(seconds * 1e9)
    samples: list[tuple[Any, dict[str, Any], int]] = []
    frames = [0]

    def with_ecus() -> float:
        drv = _StubDriver()
        ecus = [Ecu(db, n, drv.node(n)) for n in node_names(db)]
        t0 = time.perf_counter()
        drv.run(until)
        dt = time.perf_counter() - t0
        frames[0] = drv.sent
        if not samples:
            for e in ecus:
                for name in e.tx_messages:
                    sent = e.sent(name)
                    if sent:
                        m = db.get_message_by_name(name)
                        samples.append((m, dict(m.gather_signals(e.values(name))), sent))
        return dt

    t_ecu = _best(with_ecus, repeat)
    total = sum(n for _, _, n in samples)

    def cantools_encode(strict: bool) -> float:
        t0 = time.perf_counter()
        for m, v, n in samples:
            enc = m.encode
            for _ in range(n):
                enc(v, strict=strict)
        return time.perf_counter() - t0

    t_ct = _best(lambda: cantools_encode(True), repeat)
    t_ns = _best(lambda: cantools_encode(False), repeat)
    ecu_us = t_ecu / frames[0] * 1e6
    ct_us = t_ct / total * 1e6
    return {
        "ecu_us_per_msg": round(ecu_us, 3),
        "cantools_us_per_msg": round(ct_us, 3),
        "ratio": round(ecu_us / ct_us, 3),
        "cantools_nonstrict_us_per_msg": round(t_ns / total * 1e6, 3),
        "frames": frames[0],
    }


if __name__ == "__main__":  # pragma: no cover
    import json

    print(json.dumps(benchmark(), indent=2))
