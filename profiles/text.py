"""Text tables as the experiment and the profiles print them: columns as wide as their widest
cell, a name longer than its column's limit cut with a visible mark (``…``), never silently;
identifiers as every canstack output writes them (`stack.wire.frame.id_text`: ``0x0C1``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from stack.wire.frame import id_text

__all__ = ["table", "cut", "ms", "id_text", "intervals_ms", "CUT_MARK"]

CUT_MARK = "…"
"""What ends a name that was cut to fit its column."""


def cut(text: Any, most: int) -> str:
    """``text`` as it is when it has at most ``most`` characters, else cut to ``most`` with
    `CUT_MARK` as its last character."""
    s = str(text)
    return s if len(s) <= most else s[: max(0, most - 1)] + CUT_MARK


def ms(v: float | None, digits: int = 3, mark: str = "") -> str:
    """A time in ms with ``digits`` decimals (``-`` for none), ``mark`` appended."""
    return "-" if v is None else f"{v:.{digits}f}{mark}"


def intervals_ms(spans: Sequence[Sequence[float | None]], most: int = 3) -> str:
    """Intervals [start, end] in ms as ``312.3-710.7`` (``from 312.3`` while still open), the
    first ``most`` and how many more; ``no`` for none."""
    if not spans:
        return "no"
    parts = []
    for span in spans[:most]:
        a = span[0]
        b = span[1] if len(span) > 1 else None
        parts.append(f"from {a:.1f}" if b is None else f"{a:.1f}-{b:.1f}")
    more = len(spans) - most
    return ", ".join(parts) + (f" (+{more} more)" if more > 0 else "")


def table(
    headers: Sequence[str],
    rows: Sequence[Sequence[Any]],
    *,
    left: int | set[int] = 1,
    widest: dict[int, int] | None = None,
) -> list[str]:
    """The lines of a table: ``headers`` over ``rows`` (cells as text), the first ``left``
    columns (or the columns in the set ``left``) left-aligned and the rest right-aligned, each
    column as wide as its widest cell or header; column ``i`` is cut at ``widest[i]``
    characters (`cut`, with its mark)."""
    limits = widest or {}
    lefts = set(range(left)) if isinstance(left, int) else left
    cells = [[cut(c, limits[i]) if i in limits else str(c) for i, c in enumerate(r)] for r in rows]
    widths = [max([len(h)] + [len(r[i]) for r in cells]) for i, h in enumerate(headers)]

    def line(values: Sequence[str]) -> str:
        return " ".join(
            v.ljust(w) if i in lefts else v.rjust(w) for i, (v, w) in enumerate(zip(values, widths))
        ).rstrip()

    return [line(headers)] + [line(r) for r in cells]
