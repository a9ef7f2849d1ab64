"""Clocks of the buses outside the process: one instant read on two clocks, and the offset of a
served bus's clock from this process's monotonic clock.

A client of `canstack serve` stamps releases on its own monotonic clock; the server stamps the
end of each frame on its bus clock. To compare them they must be one clock: `ClockOffset` maps
the bus's onto the client's from time requests (the NTP idea, kept causal): the client asks at
``c0``, the server answers with its bus time ``s`` as it handles the request, the answer comes
back at ``c1``. The bus read ``s`` somewhere between ``c0`` and ``c1``, so the true offset
(bus − client) lies in ``[s − c1, s − c0]``. Taking the lower bound ``s − c1`` makes every bus
time map to a client time no earlier than the instant it really happened: a frame the server
queued after the client released it can never end before its release (no negative response),
and whatever delays the answer — a loaded machine, a server behind real time — shows as
lateness, never as time running backwards. Every answer is such a bound, so the tightest one
(the largest) over a recent window is kept: the window lets the offset follow two machines'
clocks drifting apart.
"""

from __future__ import annotations

import time
from collections import deque

__all__ = ["clock_pair", "ClockOffset", "BusClock"]


def clock_pair(tries: int = 8) -> tuple[int, float]:
    """A monotonic time (ns) and the wall-clock time (s) of the same instant: the wall clock read
    between two monotonic reads, the tightest pair of ``tries`` kept. A thread preempted between
    the two reads (a loaded machine) would otherwise map every timestamp that far off."""
    best = (0, 0, 0.0)
    for i in range(tries):
        m0 = time.monotonic_ns()
        wall = time.time()
        m1 = time.monotonic_ns()
        if i == 0 or m1 - m0 < best[0]:
            best = (m1 - m0, (m0 + m1) // 2, wall)
    return best[1], best[2]


class ClockOffset:
    """The offset (bus ns − local monotonic ns) of a served bus, from time requests (see the
    module docstring): `sample` adds one answer, `offset` is the largest lower bound of the
    answers of the last ``window_ns``; `round_trip_ns` the shortest round trip among them."""

    def __init__(self, window_ns: int = 30_000_000_000) -> None:
        self.window_ns = window_ns
        self._samples: deque[tuple[int, int, int]] = deque()  # (c1, lower bound, round trip)
        self.samples = 0

    def sample(self, c0: int, bus_ns: int, c1: int) -> None:
        """One answer: asked at local ``c0``, the bus read ``bus_ns``, answered at local ``c1``."""
        if c1 < c0:
            raise ValueError(f"answer at {c1} before the question at {c0}")
        s = self._samples
        s.append((c1, bus_ns - c1, c1 - c0))
        while len(s) > 1 and s[0][0] < c1 - self.window_ns:
            s.popleft()
        self.samples += 1

    @property
    def offset(self) -> int:
        """bus ns − local ns (0 before any answer)."""
        return max((lb for _, lb, _ in self._samples), default=0)

    @property
    def round_trip_ns(self) -> int | None:
        """The shortest round trip in the window (the offset is exact to within it)."""
        return min((rt for _, _, rt in self._samples), default=None)


class BusClock:
    """A served bus's clock as seen from this process: the `ClockOffset` of its answers and one
    `clock_pair` of this process, to turn a bus time into a local monotonic time (`local_ns`)
    or a wall-clock time (`timestamp`). Every connection of a process to one server shares one
    (`stack.io.serve.client`), so they stamp a frame they all receive alike."""

    def __init__(self) -> None:
        self.offset = ClockOffset()
        self.mono0, self.wall0 = clock_pair()

    def local_ns(self, t_ns: int) -> int:
        """Bus time ``t_ns`` on this process's monotonic clock (``time.monotonic_ns()``)."""
        return t_ns - self.offset.offset

    def timestamp(self, t_ns: int) -> float:
        """The wall-clock time (s since the epoch, as ``time.time()`` here) of bus time ``t_ns``."""
        return self.wall0 + (t_ns - self.offset.offset - self.mono0) / 1e9
