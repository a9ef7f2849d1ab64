"""Converters: a `MessageSet` in one profile's terms, for the profiles study
(`profiles.sweeps.comparison.profiles_study`).

The study runs one message set in each registered profile (`profiles.registry.profile_kinds`)
that knows how to express it: a *converter* takes the `MessageSet` and
returns a scenario dictionary (what a TOML file reads as) in that profile's terms. CSMA/CR's is
`csma_scenario`. Another profile provides its own in one of two ways:

- a module-level function ``express_message_set(mset: MessageSet) -> dict`` in the profile's module
  (the module of its ``ProfileKind.build``; found the way the experiment command finds a module's
  ``PLOTS``), or
- ``register_converter("name", fn)`` from anywhere imported before the study runs.

The scenario it returns keeps every message's ``name`` (the table lines up by name), runs on the
set's ``bitrate`` for ``duration_s`` with ``seed``, and may add its own nodes (a master, a time
master) and tables (a schedule). The study reports per message the worst response, the
start-to-start jitter and the deadline misses, the bus load, and the profile's own figures.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

from profiles.message_set import MessageSet, StudyMessage
from profiles.registry import profile_kinds

__all__ = [
    "Converter",
    "register_converter",
    "converter_for",
    "csma_scenario",
    "csma_fifo_scenario",
    "message_set_from_scenario",
]

Converter = Callable[[MessageSet], dict]
"""``fn(mset) -> dict``: the message set as a scenario dictionary (what `tomllib` gives for a
scenario file) in one profile's terms."""

_CONVERTERS: dict[str, Converter] = {}


def register_converter(profile: str, fn: Converter) -> Converter:
    """Make ``fn`` the way the profiles study expresses a message set in profile ``profile``."""
    _CONVERTERS[profile] = fn
    return fn


def converter_for(profile: str) -> Converter | None:
    """The converter of ``profile``: registered, else the ``express_message_set`` function of
    the profile's module, else None (the study skips the profile and says so)."""
    if profile in _CONVERTERS:
        return _CONVERTERS[profile]
    kind = profile_kinds().get(profile)
    if kind is None:
        return None
    mod = importlib.import_module(kind.build.__module__)
    fn = getattr(mod, "express_message_set", None)
    return fn if callable(fn) else None


def _csma(mset: MessageSet, queue: str) -> dict:
    nodes: dict[str, list[dict[str, Any]]] = {n: [] for n in mset.nodes}
    for m in mset.messages:
        msg: dict[str, Any] = {
            "name": m.name,
            "id": m.can_id,
            "extended": m.extended,
            "dlc": m.dlc,
            "period_ms": m.period_ns / 1e6,
            "deadline_ms": m.deadline_ns / 1e6,
        }
        if m.fd:
            msg.update(fd=True, brs=m.brs)
        nodes[m.node].append(msg)
    bus: dict[str, Any] = {"bitrate": mset.bitrate, "duration": mset.duration_s, "seed": mset.seed}
    if mset.data_bitrate is not None or mset.fd:
        # an FD frame needs an FD bus: without BRS its data phase is at the nominal rate
        bus["data_bitrate"] = mset.data_bitrate if mset.data_bitrate is not None else mset.bitrate
    return {
        "bus": bus,
        "nodes": [{"name": n, "profile": "csma", "queue": queue, "messages": ms} for n, ms in nodes.items()],
    }


def csma_scenario(mset: MessageSet) -> dict:
    """CSMA/CR's converter: every node sends its messages periodically from offset 0 (all
    released together: the analysis' critical instant) through a priority queue; CAN FD
    messages as FD frames (BRS as the set says) on a bus with the set's data bit rate (its
    bit rate when it has none: FD frames without BRS)."""
    return _csma(mset, "priority")


def csma_fifo_scenario(mset: MessageSet) -> dict:
    """The same with FIFO transmit queues (a node sends its frames in release order)."""
    return _csma(mset, "fifo")


register_converter("csma", csma_scenario)


def message_set_from_scenario(scenario: Any) -> MessageSet:
    """The periodic and sporadic messages of a checked scenario as a `MessageSet` (a sporadic
    message at its minimum inter-arrival time; messages without either are left out), CAN FD
    and BRS as declared, with the bus's data bit rate."""
    msgs = tuple(
        StudyMessage(
            m.name,
            m.node,
            m.can_id,
            m.dlc,
            m.interval_ns,
            m.deadline_ns or m.interval_ns,
            m.extended,
            fd=m.fd,
            brs=m.brs,
        )
        for m in scenario.messages
        if m.interval_ns is not None and not m.remote
    )
    if not msgs:
        raise ValueError(f"{scenario.source}: no periodic or sporadic data message to study")
    return MessageSet(
        scenario.bitrate,
        msgs,
        scenario.duration_ns / 1e9,
        scenario.seed,
        data_bitrate=getattr(scenario, "data_bitrate", None),
    )
