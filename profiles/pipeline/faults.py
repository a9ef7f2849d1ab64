"""The ``[[faults]]`` of a scenario: one table of fault kinds (`FAULTS`), each with its scenario
keys, the rules its values keep beyond the keys' own, and how the simulated bus's fault injector
(`stack.bus.faults.FaultInjector`) applies it. Reading (`read_fault`) and injecting
(`inject_faults`) both dispatch on that table, so a new kind is one entry.

    [[faults]]
    kind = "bit_errors"       # bit_errors | flip | stuck | disconnect | babbling_idiot | never_ack
    rate = 1e-5

Times are given in ms from the start of the run, as everywhere in scenario files.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from profiles.declarations import FaultDecl, ms_to_ns
from profiles.schema import (
    REQUIRED,
    Key,
    ScenarioError,
    identifier_rule,
    in_range,
    non_negative,
    non_negative_time,
    one_of,
    positive,
    read_table,
    show,
    where,
)

if TYPE_CHECKING:  # pragma: no cover
    from stack import FaultInjector, SimBus

__all__ = ["FaultKind", "FAULTS", "FAULT_KINDS", "FAULT_KEYS", "read_fault", "inject_faults"]


@dataclass(frozen=True)
class FaultKind:
    """One kind of ``[[faults]]``: its keys (besides ``kind``), ``check(values, loc)`` for the
    rules across its values (raises `ScenarioError`), and ``inject(injector, bus, values)``, which
    applies it to a simulated bus (the checked values, times in ms)."""

    keys: Mapping[str, Key]
    inject: Callable[[FaultInjector, SimBus, dict[str, Any]], None]
    check: Callable[[dict[str, Any], str], None] | None = None


def _ns(ms: float | None) -> int | None:
    return None if ms is None else ms_to_ns(ms)


def _bit_errors(fi: FaultInjector, bus: SimBus, p: dict[str, Any]) -> None:
    """A bit-error rate from ``start_ms`` (at once when 0) until ``end_ms``: the injector's rate
    is set and cleared by bus timers."""
    nodes, start, end = p["nodes"], ms_to_ns(p["start_ms"]), _ns(p["end_ms"])
    if start:
        bus.call_at(start, lambda: fi.bit_errors(p["rate"], nodes=nodes))
    else:
        fi.bit_errors(p["rate"], nodes=nodes)
    if end is not None:
        bus.call_at(end, lambda: fi.bit_errors(0.0, nodes=nodes))


def _flip(fi: FaultInjector, bus: SimBus, p: dict[str, Any]) -> None:
    fi.flip(
        can_id=p["id"],
        extended=p["extended"],
        occurrence=p["occurrence"],
        field=p["field"],
        bit=p["bit"],
        nodes=p["nodes"],
        every=p["every"],
    )


def _flip_fields() -> list[str]:
    """The names a flip's ``field`` may take: the field groups of the fault injector, the wire
    layer's field names, and 'raw' (a position from SOF, stuff bits counted)."""
    from stack.bus.faults import FIELD_GROUPS
    from stack.wire.coding import Field

    return [*FIELD_GROUPS, *(f.value for f in Field), "raw"]


def _check_flip(p: dict[str, Any], loc: str) -> None:
    if p["id"] is not None:
        rule = identifier_rule(bool(p["extended"]))(p["id"])
        if rule is not None:
            raise ScenarioError(f"{loc}: id: {rule}")
    names = _flip_fields()
    if p["field"].lower() not in {n.lower() for n in names}:
        raise ScenarioError(f"{loc}: field: {show(p['field'])} is not one of {', '.join(names)}")


def _stuck(fi: FaultInjector, bus: SimBus, p: dict[str, Any]) -> None:
    fi.stuck(p["node"], p["level"], start=ms_to_ns(p["start_ms"]), end=_ns(p["end_ms"]))


def _disconnect(fi: FaultInjector, bus: SimBus, p: dict[str, Any]) -> None:
    fi.disconnect(p["node"], at=ms_to_ns(p["at_ms"]), reconnect_at=_ns(p["reconnect_ms"]))


def _babbling_idiot(fi: FaultInjector, bus: SimBus, p: dict[str, Any]) -> None:
    fi.babbling_idiot(
        p["node"],
        can_id=p["id"],
        data=bytes.fromhex(p["data"]),
        start=ms_to_ns(p["start_ms"]),
        end=_ns(p["end_ms"]),
    )


def _check_babbling_idiot(p: dict[str, Any], loc: str) -> None:
    rule = identifier_rule(False)(p["id"])
    if rule is not None:
        raise ScenarioError(f"{loc}: id: {rule} (a babbling idiot sends a standard frame)")
    try:
        data = bytes.fromhex(p["data"])
    except ValueError:
        raise ScenarioError(f"{loc}: data: {show(p['data'])} is not hex bytes") from None
    if len(data) > 8:
        raise ScenarioError(f"{loc}: data: {len(data)} bytes: a CAN 2.0 frame carries at most 8")


def _never_ack(fi: FaultInjector, bus: SimBus, p: dict[str, Any]) -> None:
    fi.never_ack(p["node"])


FAULTS: dict[str, FaultKind] = {
    "bit_errors": FaultKind(
        {
            "rate": Key(float, REQUIRED, in_range(0, 0.5, "a bit-error rate")),
            "nodes": Key(list, None),
            "start_ms": Key(float, 0.0, non_negative_time()),
            "end_ms": Key(float, None, non_negative_time()),
        },
        _bit_errors,
    ),
    "flip": FaultKind(
        {
            "id": Key(int, None, non_negative()),
            "extended": Key(bool, None),
            "occurrence": Key(int, 1, positive()),
            "field": Key(str, "data"),
            "bit": Key(int, 0, non_negative()),
            "nodes": Key(list, None),
            "every": Key(bool, False),
        },
        _flip,
        _check_flip,
    ),
    "stuck": FaultKind(
        {
            "node": Key(str, REQUIRED),
            "level": Key(str, REQUIRED, one_of("dominant", "recessive")),
            "start_ms": Key(float, 0.0, non_negative_time()),
            "end_ms": Key(float, None, non_negative_time()),
        },
        _stuck,
    ),
    "disconnect": FaultKind(
        {
            "node": Key(str, REQUIRED),
            "at_ms": Key(float, REQUIRED, non_negative_time()),
            "reconnect_ms": Key(float, None, non_negative_time()),
        },
        _disconnect,
    ),
    "babbling_idiot": FaultKind(
        {
            "node": Key(str, REQUIRED),
            "id": Key(int, 0, non_negative()),
            "data": Key(str, "ffffffffffffffff"),
            "start_ms": Key(float, 0.0, non_negative_time()),
            "end_ms": Key(float, None, non_negative_time()),
        },
        _babbling_idiot,
        _check_babbling_idiot,
    ),
    "never_ack": FaultKind({"node": Key(str, REQUIRED)}, _never_ack),
}
"""Every fault kind a scenario may name, by its ``kind`` value."""

FAULT_KINDS = tuple(FAULTS)
"""The names of the fault kinds, in the table's order (the order errors list them in)."""

FAULT_KEYS: dict[str, Mapping[str, Key]] = {name: kind.keys for name, kind in FAULTS.items()}
"""Each kind's keys (besides ``kind``), as the sweeps look keys up."""

# (start, end) pairs of keys whose end must come after its start
_INTERVALS = (("start_ms", "end_ms"), ("at_ms", "reconnect_ms"))


def read_fault(rf: Any, i: int, source: str, node_names: set[str]) -> FaultDecl:
    """Check the ``i``-th ``[[faults]]`` table against its kind's keys and rules: the nodes it
    names are nodes of the scenario, an interval ends after it starts, and the kind's own
    ``check``."""
    loc = where(source, f"[[faults]] #{i}")
    if not isinstance(rf, Mapping):
        raise ScenarioError(f"{loc}: expected a table, got {rf!r}")
    kind = rf.get("kind")
    if not isinstance(kind, str) or kind not in FAULTS:
        raise ScenarioError(f"{loc}: kind: {show(kind)} is not one of {', '.join(map(repr, FAULT_KINDS))}")
    fault = FAULTS[kind]
    d = read_table(rf, {**fault.keys, "kind": Key(str, REQUIRED)}, loc)
    if "node" in d and d["node"] not in node_names:
        raise ScenarioError(f"{loc}: node: {show(d['node'])} is not a node of this scenario")
    if d.get("nodes") is not None:
        bad = [x for x in d["nodes"] if not isinstance(x, str) or x not in node_names]
        if bad:
            raise ScenarioError(f"{loc}: nodes: {show(bad[0])} is not a node of this scenario (a list of node names)")
    for a, b in _INTERVALS:
        if d.get(b) is not None and d.get(a) is not None and d[b] <= d[a]:
            raise ScenarioError(f"{loc}: {b}: {d[b]!r} must be after {a} {d[a]!r}")
    if fault.check is not None:
        fault.check(d, loc)
    del d["kind"]
    return FaultDecl(kind=kind, params=d, index=i)


def inject_faults(bus: SimBus, faults: list[FaultDecl], source: str = "scenario") -> None:
    """Apply the scenario's ``[[faults]]`` with the simulated bus's fault injector, each by its
    kind's ``inject``; a value the injector refuses is a `ScenarioError` naming ``source`` and
    the entry."""
    if not faults:
        return
    from stack import FaultInjector

    fi = FaultInjector(bus)
    for f in faults:
        try:
            FAULTS[f.kind].inject(fi, bus, f.params)
        except ValueError as exc:  # a rule the injector keeps beyond the scenario's checks
            raise ScenarioError(f"{where(source, f'[[faults]] #{f.index}')}: {exc}") from None
