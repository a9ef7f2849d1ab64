"""The edge of a working range found by bisection: the bus-length and loop-delay searches
(`stack.phy.propagation.max_bus_length_simulated`, `stack.phy.tdc.max_loop_delay`) both look for
the largest value at which an exchange still works, knowing that what works is an interval from
its low end."""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

F = TypeVar("F")


def last_working(
    failure: Callable[[float], F | None], lo: float, hi: float, bad: F, resolution: float
) -> tuple[float, float, F]:
    """Bisect [lo, hi] — ``failure(lo)`` is None (works), ``failure(hi)`` is ``bad`` — until the
    interval is at most ``resolution`` wide; return (the last value that worked, the first that
    failed, that failure). Valid when the values that work form an interval from ``lo``."""
    while hi - lo > resolution:
        mid = (lo + hi) / 2
        f = failure(mid)
        if f is None:
            lo = mid
        else:
            hi, bad = mid, f
    return lo, hi, bad
