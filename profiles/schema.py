"""Typed tables for scenario files: each key's type, default and rule, and errors that name the
file, the table and the key.

Scenario files are TOML (read with `tomllib`, `tomli` on Python 3.10); this module checks what
TOML gives (int, float, str, bool, lists, tables) against a schema, so that every profile reads
its own keys the same way and every error says where it is and which rule it breaks:

    scenario.toml: [[nodes]] #2 'engine' > [[nodes.messages]] #1 'EngineData': dlc: 9 is outside 0..8
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

__all__ = [
    "ScenarioError",
    "Key",
    "REQUIRED",
    "read_table",
    "where",
    "one_of",
    "in_range",
    "positive",
    "non_negative",
    "identifier_rule",
    "positive_time",
    "non_negative_time",
    "show",
    "MAX_TIME_S",
    "TIME_UNITS",
]

MAX_TIME_S = 1e6
"""The longest time a scenario may give (s): the longest run (11.6 simulated days); a time beyond
it is a units mistake, and would only overflow the engine's integer nanoseconds."""

TIME_UNITS = {"s": 1e9, "ms": 1e6, "us": 1e3, "µs": 1e3, "ns": 1.0}
"""Nanoseconds per unit of the time keys (``_ms``, ``_us``)."""

_BIG_INT = 1 << 64


class ScenarioError(ValueError):
    """A scenario file breaks a rule: the message names the file, the table, the key and the rule."""


class _Required:
    def __repr__(self) -> str:
        return "REQUIRED"


REQUIRED: Any = _Required()

_TYPE_NAMES = {
    int: "an integer",
    float: "a number",
    str: "a string",
    bool: "true or false",
    list: "a list",
    dict: "a table",
}


@dataclass(frozen=True)
class Key:
    """One key of a table: its TOML type (``float`` accepts integers too; ``int`` and ``float``
    refuse booleans), its default (`REQUIRED` when it must be given), a rule (a function that
    returns what is wrong with a value, or None) and a short description for the docs."""

    type: type | tuple[type, ...]
    default: Any = REQUIRED
    rule: Callable[[Any], str | None] | None = None
    doc: str = ""

    def check(self, value: Any) -> str | None:
        """What is wrong with ``value`` for this key, or None."""
        types = self.type if isinstance(self.type, tuple) else (self.type,)
        ok = False
        for t in types:
            if t in (int, float) and isinstance(value, bool):
                continue
            if t is float and isinstance(value, (int, float)):
                if isinstance(value, float) and not math.isfinite(value):
                    return f"{value!r} is not a finite number"
                ok = True
                break
            if isinstance(value, t):
                ok = True
                break
        if not ok:
            want = " or ".join(_TYPE_NAMES.get(t, t.__name__) for t in types)
            return f"{show(value)} is {_describe(value)}, expected {want}"
        if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= _BIG_INT:
            return f"{show(value)} is outside any range a scenario uses (at most 64 bits)"
        return self.rule(value) if self.rule is not None else None


def show(value: Any, most: int = 60) -> str:
    """``repr(value)`` for an error message, shortened: an integer of more digits than a message
    holds is given by its size (Python refuses to print one over 4,300 digits at all), a long
    string or list is cut with a mark."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10**30:
        digits = (
            len(str(abs(value))) if abs(value).bit_length() < 14_000 else int(abs(value).bit_length() * 0.30103) + 1
        )
        return f"{'-' if value < 0 else ''}an integer of {digits:,} digits"
    text = repr(value)
    if len(text) <= most:
        return text
    return text[: most - 3] + "..."


def _describe(value: Any) -> str:
    if isinstance(value, bool):
        return "a boolean"
    for t, name in _TYPE_NAMES.items():
        if type(value) is t:
            return name
    return type(value).__name__


def where(source: str, *parts: str) -> str:
    """The location prefix of an error: the file and the table path."""
    return f"{source}: " + " > ".join(p for p in parts if p) if parts else f"{source}:"


def read_table(
    raw: Any,
    schema: Mapping[str, Key],
    loc: str,
    *,
    extra: Mapping[str, Key] | None = None,
    allow_unknown: bool = False,
) -> dict[str, Any]:
    """Check ``raw`` (a TOML table) against ``schema`` (plus ``extra`` keys, e.g. a profile's)
    and return every key with its value or default. Unknown keys, missing required keys, wrong
    types and broken rules raise `ScenarioError` naming ``loc`` and the key."""
    if not isinstance(raw, Mapping):
        raise ScenarioError(f"{loc}: expected a table, got {_describe(raw)} {show(raw)}")
    keys = dict(schema)
    if extra:
        keys.update(extra)
    if not allow_unknown:
        unknown = sorted(set(raw) - set(keys))
        if unknown:
            raise ScenarioError(
                f"{loc}: unknown key{'s' if len(unknown) > 1 else ''} {', '.join(map(repr, unknown))}"
                f" (allowed: {', '.join(sorted(keys))})"
            )
    out: dict[str, Any] = {}
    for name, key in keys.items():
        if name not in raw:
            if key.default is REQUIRED:
                raise ScenarioError(f"{loc}: key {name!r} is required" + (f" ({key.doc})" if key.doc else ""))
            out[name] = key.default
            continue
        problem = key.check(raw[name])
        if problem is not None:
            raise ScenarioError(f"{loc}: {name}: {problem}")
        out[name] = raw[name]
    if allow_unknown:
        for name in raw:
            out.setdefault(name, raw[name])
    return out


def one_of(*choices: str) -> Callable[[Any], str | None]:
    """Rule: the value is one of ``choices``."""

    def rule(v: Any) -> str | None:
        return None if v in choices else f"{show(v)} is not one of {', '.join(map(repr, choices))}"

    return rule


def _num(v: float) -> str:
    return str(int(v)) if float(v).is_integer() and abs(v) < 1e15 else f"{v:g}"


def in_range(lo: float, hi: float, what: str = "") -> Callable[[Any], str | None]:
    """Rule: lo <= value <= hi."""

    def rule(v: Any) -> str | None:
        return (
            None if lo <= v <= hi else f"{show(v)} is outside {_num(lo)}..{_num(hi)}" + (f" ({what})" if what else "")
        )

    return rule


def positive(what: str = "") -> Callable[[Any], str | None]:
    """Rule: value > 0."""

    def rule(v: Any) -> str | None:
        return None if v > 0 else f"{show(v)} must be > 0" + (f" ({what})" if what else "")

    return rule


def non_negative(what: str = "") -> Callable[[Any], str | None]:
    """Rule: value >= 0."""

    def rule(v: Any) -> str | None:
        return None if v >= 0 else f"{show(v)} must be >= 0" + (f" ({what})" if what else "")

    return rule


def _time_rule(what: str, unit: str, zero: bool) -> Callable[[Any], str | None]:
    scale = TIME_UNITS[unit]
    most = MAX_TIME_S * 1e9 / scale

    def rule(v: Any) -> str | None:
        label = f" ({what})" if what else ""
        if v < 0 or (v == 0 and not zero):
            return f"{v!r} must be {'>= 0' if zero else '> 0'}{label}"
        if v > most:
            return f"{v!r} {unit} is longer than the longest run ({MAX_TIME_S:g} s){label}"
        if v and round(v * scale) < 1:
            return (
                f"{v!r} {unit} rounds to 0 ns: the engine counts whole nanoseconds, so a time is "
                f"0 or at least {1 / scale:g} {unit}{label}"
            )
        return None

    return rule


def positive_time(what: str = "", unit: str = "ms") -> Callable[[Any], str | None]:
    """Rule: a time > 0 in ``unit`` (``ms``, ``us``, ``s``) that the engine can represent: at
    least 1 ns once rounded to whole nanoseconds (the engine's unit; a period of 1e-7 ms would
    round to 0 and release without end at one instant) and at most `MAX_TIME_S`."""
    return _time_rule(what, unit, zero=False)


def non_negative_time(what: str = "", unit: str = "ms") -> Callable[[Any], str | None]:
    """Rule: a time >= 0 in ``unit``; when not 0, at least 1 ns once rounded, and at most
    `MAX_TIME_S` (see `positive_time`)."""
    return _time_rule(what, unit, zero=True)


def identifier_rule(extended: bool) -> Callable[[Any], str | None]:
    """Rule: an 11-bit (0..0x7FF) or 29-bit (0..0x1FFFFFFF) CAN identifier."""
    top = 0x1FFFFFFF if extended else 0x7FF

    def rule(v: Any) -> str | None:
        if 0 <= v <= top:
            return None
        kind = "an extended (29-bit)" if extended else "a standard (11-bit)"
        return f"0x{v:X} is not {kind} identifier 0..0x{top:X}" if v >= 0 else f"{v} is negative"

    return rule
