"""Acceptance filtering with python-can's filter semantics.

A filter is a mapping ``{"can_id": int, "can_mask": int, "extended": bool (optional)}``; a frame
matches when ``frame.can_id & can_mask == can_id & can_mask`` and, if ``extended`` is given, its
format matches. A frame is accepted when any filter matches; no filters (None or empty) accept
everything. Results are cached per arbitration key, since a node sees the same identifiers again
and again (a dictionary hit is cheaper than evaluating the filters).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from stack.wire.frame import EXTENDED_ID_MAX, Frame

__all__ = ["AcceptanceFilter", "validate_filters"]


def validate_filters(filters: Iterable[Mapping[str, Any]] | None) -> list[tuple[int, int, bool | None]]:
    """Check a python-can filter list; ValueError names the bad entry and the rule it breaks."""
    out: list[tuple[int, int, bool | None]] = []
    if filters is None:
        return out
    if isinstance(filters, Mapping):
        raise ValueError("filters must be a list of {'can_id', 'can_mask'[, 'extended']} mappings, got one mapping")
    if isinstance(filters, (str, bytes)) or not isinstance(filters, Iterable):
        raise ValueError(
            f"filters {filters!r} must be a list of {{'can_id', 'can_mask'[, 'extended']}} mappings, or None"
        )
    for i, f in enumerate(filters):
        if not isinstance(f, Mapping):
            raise ValueError(f"filter {i} ({f!r}) is not a mapping with can_id and can_mask")
        unknown = set(f) - {"can_id", "can_mask", "extended"}
        if unknown:
            raise ValueError(f"filter {i} has unknown key(s) {sorted(unknown)}: allowed are can_id, can_mask, extended")
        try:
            can_id, can_mask = f["can_id"], f["can_mask"]
        except KeyError as exc:
            raise ValueError(f"filter {i} ({dict(f)!r}) lacks {exc.args[0]!r}") from None
        for name, v in (("can_id", can_id), ("can_mask", can_mask)):
            if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= EXTENDED_ID_MAX:
                raise ValueError(f"filter {i}: {name} {v!r} must be an int in 0..0x1FFFFFFF")
        ext = f.get("extended")
        if ext is not None and not isinstance(ext, bool):
            raise ValueError(f"filter {i}: extended {ext!r} must be True, False or absent")
        out.append((can_id & can_mask, can_mask, ext))
    return out


class AcceptanceFilter:
    """A compiled filter list; `accepts(frame)` implements python-can's matching rule.

    ``cache`` maps an arbitration key to the verdict once computed (the controller reads it
    directly on its receive path)."""

    __slots__ = ("filters", "_rules", "cache")

    def __init__(self, filters: Iterable[Mapping[str, Any]] | None = None) -> None:
        self._rules = validate_filters(filters)
        self.filters = [dict(f) for f in filters] if filters else None
        self.cache: dict[int, bool] = {}

    @property
    def accepts_all(self) -> bool:
        """True when no filter is set (everything passes)."""
        return not self._rules

    def accepts(self, frame: Frame) -> bool:
        """True if any filter matches the frame (or none is set)."""
        r = self.cache.get(frame.key)
        if r is None:
            r = self._match(frame.can_id, frame.extended)
            self.cache[frame.key] = r
        return r

    def _match(self, can_id: int, extended: bool) -> bool:
        if not self._rules:
            return True
        return any(can_id & mask == fid and (ext is None or ext == extended) for fid, mask, ext in self._rules)
