"""Response-time statistics in bounded memory: exact count, min, max and mean of every instance,
and the 99th percentile — exact while the values are kept, else from a DDSketch (Masson, Rim,
Lee 2019: a mergeable quantile sketch whose answer is within a stated *relative* error of the
true quantile), the ``ddsketch`` library.

A run of an hour holds millions of instances per message; keeping each (8 bytes) was most of an
experiment's memory. `ResponseStats` keeps the values of the current batch (`BATCH` of them) and
folds a full batch into the running figures: the exact ones (count, sum, min, max) and the
sketch. A run whose messages stay under one batch each — every run of a few seconds — keeps
every value and its p99 is exact; so is any run whose values are all kept (``keep_all``, as
``canstack experiment --samples`` asks).
"""

from __future__ import annotations

import math
from array import array
from collections import Counter
from collections.abc import Iterable
from typing import Any

__all__ = ["ResponseStats", "RELATIVE_ACCURACY", "BATCH", "nearest_rank", "stats_ms"]

RELATIVE_ACCURACY = 0.005
"""The sketch's relative accuracy: a p99 it gives is within ±0.5 % of the true p99."""

BATCH = 4096
"""Values kept before they are folded into the running figures (32 KB a message)."""


def nearest_rank(sorted_values: Any, q: float) -> Any:
    """The nearest-rank ``q`` quantile of sorted values: the value at rank ceil(q·n)."""
    n = len(sorted_values)
    return sorted_values[max(0, math.ceil(q * n) - 1)]


class ResponseStats:
    """Count, sum, min, max of every value added, and their 99th percentile (see the module
    docstring). ``values`` holds the values not yet folded (all of them while `exact`)."""

    __slots__ = ("values", "keep_all", "count", "total", "min", "max", "sketch")

    def __init__(self, keep_all: bool = False) -> None:
        self.values: array[int] = array("q")
        self.keep_all = keep_all
        self.count = 0  # folded values only; `n` adds the kept ones
        self.total = 0
        self.min: int | None = None
        self.max: int | None = None
        self.sketch: Any = None

    def add(self, value: int) -> None:
        """One value (integer ns)."""
        self.values.append(value)
        if len(self.values) >= BATCH and not self.keep_all:
            self.fold()

    def fold(self) -> None:
        """Fold the kept values into the exact figures and the sketch, and drop them. Repeated
        values (a periodic schedule repeats its response times) go in once, with their count."""
        v = self.values
        if not v:
            return
        from ddsketch import DDSketch

        self.count += len(v)
        self.total += sum(v)
        lo, hi = min(v), max(v)
        self.min = lo if self.min is None else min(self.min, lo)
        self.max = hi if self.max is None else max(self.max, hi)
        if self.sketch is None:
            self.sketch = DDSketch(RELATIVE_ACCURACY)
        for x, c in Counter(v).items():
            # the sketch maps values > 0 to its logarithmic bins: a 0 ns response (none is
            # possible on a bus, but a caller may add one) goes into its zero bin as 0
            self.sketch.add(float(x), float(c))
        self.values = array("q")

    @property
    def n(self) -> int:
        """How many values were added."""
        return self.count + len(self.values)

    @property
    def exact(self) -> bool:
        """True while every value is kept (the p99 is exact)."""
        return self.sketch is None

    def figures(self) -> tuple[int, int, float, float, float] | None:
        """(n, min, max, mean, p99) in ns, or None without values. The p99 is the nearest-rank
        99th percentile when `exact`, else the sketch's (within `RELATIVE_ACCURACY`)."""
        n = self.n
        if n == 0:
            return None
        if self.exact:
            s = sorted(self.values)
            return n, s[0], s[-1], sum(s) / n, float(nearest_rank(s, 0.99))
        self.fold()
        assert self.min is not None and self.max is not None
        p99 = float(self.sketch.get_quantile_value(0.99))
        # the sketch answers within its accuracy: never outside what was seen
        return n, self.min, self.max, self.total / n, min(float(self.max), max(float(self.min), p99))

    def quantiles(self, qs: Iterable[float]) -> list[float]:
        """The values at quantiles ``qs`` (ns): exact (nearest rank) or from the sketch."""
        if self.n == 0:
            return []
        if self.exact:
            s = sorted(self.values)
            return [float(nearest_rank(s, q)) for q in qs]
        self.fold()
        return [float(self.sketch.get_quantile_value(q)) for q in qs]

    def stats_ms(self) -> dict[str, Any] | None:
        """min, mean, p99 and max in ms, and ``p99_error``: 0 when exact, else the sketch's
        relative accuracy (None without values)."""
        f = self.figures()
        if f is None:
            return None
        _n, lo, hi, mean, p99 = f
        return {
            "min": lo / 1e6,
            "mean": mean / 1e6,
            "p99": p99 / 1e6,
            "max": hi / 1e6,
            # one value throughout leaves the sketch nothing to approximate
            "p99_error": 0.0 if self.exact or lo == hi else RELATIVE_ACCURACY,
        }


def stats_ms(values_ns: Iterable[int]) -> dict[str, float] | None:
    """min, mean, p99 (nearest rank) and max of ns values, in ms (None when there are none)."""
    s = sorted(values_ns)
    n = len(s)
    if n == 0:
        return None
    return {"min": s[0] / 1e6, "mean": sum(s) / n / 1e6, "p99": nearest_rank(s, 0.99) / 1e6, "max": s[-1] / 1e6}
