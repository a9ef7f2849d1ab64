"""Keys of a scenario file named on the command line — ``canstack experiment --set KEY=VALUE``,
``canstack sweep --vary KEY=V1,V2`` — found in the file as TOML reads it and typed by its schema.

A key is a dotted path: tables by name (``bus.bitrate``, ``analysis.t_error_ms``), nodes and
messages by their ``name`` (``nodes.engine.queue``, ``nodes.engine.messages.EngineData.period_ms``),
other lists by index from 0 (``faults.0.rate``). A value is written as in TOML (``500000``,
``2.5``, ``0x100``, ``true``, ``"quoted"``) or as a bare word for a string (``fifo``,
``mailboxes:2``). The changed scenario is checked by its own schema afterwards
(`profiles.pipeline.scenario.parse_scenario`), so a value that breaks a rule gets the usual
message; a key the file does not have is a `KeyPathError` naming the option and what exists.
"""

from __future__ import annotations

import copy
import sys
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from profiles.pipeline.faults import FAULT_KEYS
from profiles.pipeline.scenario import ANALYSIS_KEYS, BUS_KEYS, MESSAGE_KEYS, NODE_KEYS, PLOT_KEYS
from profiles.registry import profile_kind, profile_kinds
from profiles.schema import Key

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = ["KeyPathError", "resolve_key", "typed_value", "apply_values", "parse_assignment", "override"]


class KeyPathError(ValueError):
    """A key that is not in the scenario (or holds a table or list): one line naming the option."""


def _schema_for(raw: Mapping[str, Any], path: Sequence[str | int]) -> Mapping[str, Key] | None:
    """The keys the scenario schema allows in the table at ``path`` (None: a table the spine does
    not know, such as a profile's own; then only keys the file has can be set)."""
    if len(path) == 1 and path[0] in ("bus", "analysis", "plot"):
        return {"bus": BUS_KEYS, "analysis": ANALYSIS_KEYS, "plot": PLOT_KEYS}[str(path[0])]
    if len(path) in (2, 4) and path[0] == "nodes":
        node = raw["nodes"][path[1]]
        profile = node.get("profile", "csma")
        extra: Mapping[str, Key] = {}
        if isinstance(profile, str) and profile in profile_kinds():
            kind = profile_kind(profile)
            extra = kind.node_keys if len(path) == 2 else kind.message_keys
        if len(path) == 2:
            return {**NODE_KEYS, **extra}
        if path[2] == "messages":
            return {**MESSAGE_KEYS, **extra}
    if len(path) == 2 and path[0] == "faults":
        kind = raw["faults"][path[1]].get("kind")
        if isinstance(kind, str) and kind in FAULT_KEYS:
            return {**FAULT_KEYS[kind], "kind": Key(str)}
    return None


def _verb(option: str) -> str:
    return "vary" if option == "--vary" else "set"


def _element(items: list[Any], seg: str, where: str, key: str, option: str) -> int:
    """The index of the list element named ``seg`` (its ``name`` key), else ``seg`` as an index."""
    for i, item in enumerate(items):
        if isinstance(item, Mapping) and item.get("name") == seg:
            return i
    if seg.isascii() and seg.isdigit() and int(seg) < len(items):
        return int(seg)
    names = [str(it["name"]) for it in items if isinstance(it, Mapping) and "name" in it]
    have = (f"names: {', '.join(names)}" if names else f"indices 0..{len(items) - 1}") if items else "it is empty"
    raise KeyPathError(f"{option} {key}: {where} has no element {seg!r} ({have})")


def resolve_key(
    raw: Mapping[str, Any], key: str, option: str = "--set"
) -> tuple[tuple[str | int, ...], tuple[type, ...] | None]:
    """Find dotted ``key`` in the raw scenario: its concrete path (names replaced by list
    indices) and the types its schema allows (None: a key of a table the schema does not know).

    Every segment but the last must exist (a table, or a list element by name or index; the
    optional tables ``analysis`` and ``plot`` may be absent); the last must be a key the schema
    allows there (or, in a table the schema does not know, a key the file has). Raises
    `KeyPathError` naming ``option``, the key and what exists instead."""
    segs = key.split(".")
    if not key or any(c.isspace() for c in key) or not all(segs):
        raise KeyPathError(f"{option} {key!r}: not a dotted key (e.g. nodes.engine.queue)")
    cur: Any = raw
    path: list[str | int] = []
    where = "the scenario"
    for seg in segs[:-1]:
        if isinstance(cur, list):
            idx = _element(cur, seg, where, key, option)
            path.append(idx)
            cur = cur[idx]
            where = f"{where}.{seg}"
        elif isinstance(cur, Mapping):
            if seg not in cur:
                if not path and seg in ("analysis", "plot"):
                    cur = {}
                    path.append(seg)
                    where = seg
                    continue
                have = ", ".join(str(k) for k in cur) or "nothing"
                raise KeyPathError(f"{option} {key}: {where} has no {seg!r} (it has: {have})")
            path.append(seg)
            cur = cur[seg]
            where = seg if where == "the scenario" else f"{where}.{seg}"
        else:
            raise KeyPathError(f"{option} {key}: {where} is a value, not a table or list")
    leaf = segs[-1]
    if isinstance(cur, list):
        raise KeyPathError(f"{option} {key}: {where} is a list: name an element and a key in it (e.g. {key}.<key>)")
    if not isinstance(cur, Mapping):
        raise KeyPathError(f"{option} {key}: {where} is a value, not a table")
    schema = _schema_for(raw, path)
    if isinstance(cur.get(leaf), (Mapping, list)):
        what = "table" if isinstance(cur[leaf], Mapping) else "list"
        raise KeyPathError(f"{option} {key}: is a {what}; {_verb(option)} a single value (a key inside it)")
    if leaf not in cur and (schema is None or leaf not in schema):
        allowed = sorted(schema) if schema is not None else [str(k) for k in cur]
        raise KeyPathError(f"{option} {key}: {where} has no key {leaf!r} (keys: {', '.join(allowed)})")
    if schema is not None and leaf in schema and schema[leaf].type in (list, dict):
        what = "list" if schema[leaf].type is list else "table"
        raise KeyPathError(f"{option} {key}: {leaf!r} holds a {what}; {_verb(option)} a single value")
    types: tuple[type, ...] | None = None
    if schema is not None and leaf in schema:
        t = schema[leaf].type
        types = t if isinstance(t, tuple) else (t,)
    elif leaf in cur:
        types = (type(cur[leaf]),)
    path.append(leaf)
    return tuple(path), types


def typed_value(token: Any, types: tuple[type, ...] | None) -> Any:
    """A value given on the command line as the scenario's schema expects it: kept as text for
    string keys, else read as a TOML value (``10``, ``2.5``, ``0x100``, ``true``, ``"quoted"``),
    else the word itself (the schema then says what is wrong with it)."""
    if not isinstance(token, str):
        return token  # a range: already numbers
    if types is not None and set(types) <= {str}:
        return token
    try:
        return tomllib.loads(f"v = {token}")["v"]
    except (tomllib.TOMLDecodeError, RecursionError, ValueError):
        return token


def apply_values(raw: Mapping[str, Any], assignments: Iterable[tuple[Sequence[str | int], Any]]) -> dict[str, Any]:
    """A deep copy of ``raw`` with each (path, value) set; missing tables on a path are created."""
    out = copy.deepcopy(dict(raw))
    for path, value in assignments:
        cur: Any = out
        for seg in path[:-1]:
            if isinstance(cur, dict) and seg not in cur:
                cur[seg] = {}
            cur = cur[seg]
        cur[path[-1]] = value
    return out


def parse_assignment(spec: str, option: str = "--set") -> tuple[str, str]:
    """``KEY=VALUE`` as (key, value text)."""
    key, eq, text = spec.partition("=")
    key = key.strip()
    if not eq or not key:
        raise KeyPathError(f"{option} {spec!r}: expected KEY=VALUE (e.g. bus.bitrate=250000)")
    if not text.strip():
        raise KeyPathError(f"{option} {key}: no value after '='")
    return key, text.strip()


def override(raw: Mapping[str, Any], specs: Iterable[str], option: str = "--set") -> dict[str, Any]:
    """``raw`` with every ``KEY=VALUE`` of ``specs`` set (see the module docstring); a key given
    twice is refused."""
    seen: set[str] = set()
    assignments = []
    for spec in specs:
        key, text = parse_assignment(spec, option)
        if key in seen:
            raise KeyPathError(f"{option} {key}: given twice")
        seen.add(key)
        path, types = resolve_key(raw, key, option)
        assignments.append((path, typed_value(text, types)))
    return apply_values(raw, assignments)
