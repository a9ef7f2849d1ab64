"""Latency figures as the metrics report them: min, mean, 99th percentile and max in ms.

The samples stay plain lists of integer ns on the objects that measure them (the experiments'
metrics recorder reads those); this only summarises.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

__all__ = ["summary", "percentile"]


def percentile(sorted_ns: list[int], q: float) -> int:
    """The nearest-rank ``q``-th percentile (0 < q <= 100) of ascending samples."""
    if not sorted_ns:
        raise ValueError("no samples")
    k = max(1, math.ceil(q / 100 * len(sorted_ns)))
    return sorted_ns[k - 1]


def summary(samples_ns: Iterable[int]) -> dict[str, float | int | None]:
    """{'count', 'min', 'mean', 'p99', 'max'}: times in ms (µs resolution); None without samples."""
    s = sorted(samples_ns)
    if not s:
        return {"count": 0, "min": None, "mean": None, "p99": None, "max": None}
    ms = 1e6
    return {
        "count": len(s),
        "min": round(s[0] / ms, 6),
        "mean": round(sum(s) / len(s) / ms, 6),
        "p99": round(percentile(s, 99) / ms, 6),
        "max": round(s[-1] / ms, 6),
    }
