"""A node's own oscillator: local time against the bus (driver) time, with an offset and a drift.

Real ECUs do not share a clock: each counts time with its own crystal, off by tens to thousands of
ppm. A node given a `LocalClock` speaks its local time in `now()`, `call_at`, `call_later` and the
times of the events it reports; the driver keeps the bus time and converts. This is what makes a
time-triggered schedule (TTCAN) drift between reference messages, and what its level-2 clock
correction is for.

    local(t) = offset + t + t · drift_ppm · 1e-6      (t: bus time in ns)

Conversions round to the nearest ns; `bus` returns the first bus time whose local time is at or
after the one asked for, so a timer never fires before its local time.
"""

from __future__ import annotations

import math

__all__ = ["LocalClock", "MAX_DRIFT_PPM"]

MAX_DRIFT_PPM = 100_000.0
"""10 %: far beyond any oscillator a CAN controller could work with (ISO 11898-1 tolerances are
at most 1.58 %); larger values are refused as a units mistake."""


class LocalClock:
    """Local time = ``offset_ns`` + bus time × (1 + ``drift_ppm`` · 1e-6) (see the module)."""

    __slots__ = ("offset_ns", "drift_ppm", "_rate")

    def __init__(self, offset_ns: int = 0, drift_ppm: float = 0.0) -> None:
        if isinstance(offset_ns, bool) or not isinstance(offset_ns, int):
            raise ValueError(f"clock offset {offset_ns!r}: an integer number of ns")
        if (
            isinstance(drift_ppm, bool)
            or not isinstance(drift_ppm, (int, float))
            or not math.isfinite(drift_ppm)
            or abs(drift_ppm) > MAX_DRIFT_PPM
        ):
            raise ValueError(f"clock drift {drift_ppm!r} ppm: a finite number within +-{MAX_DRIFT_PPM:g} ppm")
        self.offset_ns = offset_ns
        self.drift_ppm = float(drift_ppm)
        self._rate = 1.0 + self.drift_ppm * 1e-6

    def local(self, t_bus: int) -> int:
        """The local time (ns) at bus time ``t_bus``."""
        return self.offset_ns + t_bus + round(t_bus * self.drift_ppm * 1e-6)

    def bus(self, t_local: int) -> int:
        """The first bus time (ns, >= 0) at which the local time has reached ``t_local``."""
        t = max(0, math.ceil((t_local - self.offset_ns) / self._rate))
        while t > 0 and self.local(t - 1) >= t_local:  # rounding: step back to the first one
            t -= 1
        while self.local(t) < t_local:
            t += 1
        return t

    def duration_bus(self, d_local: int) -> int:
        """A local duration (ns) as bus ns (for delays measured on the local clock)."""
        return round(d_local / self._rate)

    def __repr__(self) -> str:
        return f"LocalClock(offset_ns={self.offset_ns}, drift_ppm={self.drift_ppm:g})"
