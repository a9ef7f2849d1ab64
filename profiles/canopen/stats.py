"""Latency figures as the metrics report them: min, mean, 99th percentile and max in ms.

The objects that measure keep their samples in a `profiles.responses.ResponseStats` (exact
count, min, max, mean; the p99 exact while every value is kept, else from a sketch, so that a
long run stays in bounded memory); this only summarises.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

from profiles.responses import ResponseStats

__all__ = ["summary", "percentile"]


def percentile(sorted_ns: list[int], q: float) -> int:
    """The nearest-rank ``q``-th percentile (0 < q <= 100) of ascending samples."""
    if not sorted_ns:
        raise ValueError("no samples")
    k = max(1, math.ceil(q / 100 * len(sorted_ns)))
    return sorted_ns[k - 1]


def summary(samples_ns: ResponseStats | Iterable[int]) -> dict[str, float | int | None]:
    """{'count', 'min', 'mean', 'p99', 'max', 'p99_error'}: times in ms (µs resolution), the p99's
    relative error (0: exact); None without samples."""
    stats = samples_ns if isinstance(samples_ns, ResponseStats) else _stats(samples_ns)
    f = stats.figures()
    if f is None:
        return {"count": 0, "min": None, "mean": None, "p99": None, "max": None, "p99_error": None}
    n, lo, hi, mean, p99 = f
    ms = 1e6
    return {
        "count": n,
        "min": round(lo / ms, 6),
        "mean": round(mean / ms, 6),
        "p99": round(p99 / ms, 6),
        "max": round(hi / ms, 6),
        "p99_error": (stats.stats_ms() or {}).get("p99_error", 0.0),
    }


def _stats(values: Iterable[int]) -> ResponseStats:
    out = ResponseStats(keep_all=True)
    for v in values:
        out.add(v)
    return out
