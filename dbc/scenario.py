"""A scheduling scenario from a network description (``canstack scenario from-dbc``).

`scenario_from_dbc` turns a DBC into the scenario file the experiment pipeline reads
(`profiles.pipeline.scenario`): one node per sending ECU, and one message per message that the
ECU sends by itself — cyclic (``GenMsgCycleTime``; cyclic-and-spontaneous counted at its cycle),
or cyclic if active (at ``GenMsgCycleTimeFast``, its period while active: the worst case) — with
its identifier, length and period; ``GenMsgStartDelayTime`` becomes the offset. The deadline is
the period unless the message has the ``CanstackDeadline`` attribute (ms). Every node queues by
priority, the controller model the response-time analysis assumes.

What a CAN 2.0 scenario cannot hold is left out, each with a comment line in the file and a line
on stderr: CAN FD frames and messages longer than 8 bytes (the scenario format carries classical
frames only), containers, and messages sent only on request or spontaneously (no period). A
message with several senders is given to the first (one sender per identifier on a bus). The bit
rate is ``--bitrate``, else the database's ``Baudrate`` attribute, else 500 kbit/s.

``canstack scenario from-dbc`` (`dbc.scenario_cli`) reads the text back with the pipeline's own
reader before it writes it, so a file it writes is one ``canstack experiment`` runs.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

from .ecu import NO_NODE, senderless, unsupported_reason
from .errors import DbcError
from .interaction import attribute, message_timing

__all__ = ["ScenarioText", "scenario_from_dbc", "DEFAULT_BITRATE"]

DEFAULT_BITRATE = 500_000


@dataclass
class ScenarioText:
    """A scenario built from a DBC: the TOML ``text``, the ``notes`` on what was left out or
    changed (one line each), and how many ``messages`` and ``nodes`` it holds."""

    text: str
    notes: list[str] = field(default_factory=list)
    messages: int = 0
    nodes: int = 0


def _bitrate(db: Any, given: int | None) -> int:
    if given is not None:
        return given
    v = attribute(db, db, "Baudrate")
    if isinstance(v, (int, float)) and 1_000 <= v <= 1_000_000:
        return int(v)
    return DEFAULT_BITRATE


def _number(v: float) -> str:
    return str(int(v)) if float(v).is_integer() else repr(float(v))


def scenario_from_dbc(
    db: Any,
    source: str,
    *,
    bitrate: int | None = None,
    duration: float = 1.0,
    seed: int = 0,
    default_cycle_ms: int | None = None,
) -> ScenarioText:
    """The scenario of a cantools database (see the module docstring); ``default_cycle_ms`` is
    the period of the messages the DBC gives neither send type nor cycle time (as
    ``canstack restbus --default-cycle``). `DbcError` when no message is sent periodically."""
    nodes: dict[str, list[str]] = {}
    notes: list[str] = []
    count = defaulted = 0
    for m in db.messages:
        why = unsupported_reason(m)
        if why is not None:
            notes.append(f"{m.name}: left out: {why[1]} (the scenario format carries CAN 2.0 frames)")
            continue
        t = message_timing(db, m)
        if t.on_request_only and default_cycle_ms is not None:
            period = default_cycle_ms
            defaulted += 1
        elif t.cyclic:
            period = t.cycle_time
        elif t.if_active:
            period = t.cycle_time_fast or t.cycle_time
        else:
            kind = "sent on request only" if t.on_request_only else f"{t.send_type.value} without a period"
            notes.append(f"{m.name}: left out: {kind}")
            continue
        sender = NO_NODE if senderless(m) else next(s for s in m.senders if s != NO_NODE)
        if len([s for s in m.senders if s != NO_NODE]) > 1:
            notes.append(f"{m.name}: sent by {', '.join(m.senders)}: given to {sender} (one sender per identifier)")
        lines = [
            "[[nodes.messages]]",
            f"name = {json.dumps(m.name)}",
            f"id = {m.frame_id:#0{10 if m.is_extended_frame else 5}x}",
        ]
        if m.is_extended_frame:
            lines.append("extended = true")
        lines += [f"dlc = {m.length}", f"period_ms = {_number(period)}"]
        if t.start_delay:
            lines.append(f"offset_ms = {_number(t.start_delay)}  # GenMsgStartDelayTime")
        deadline = attribute(db, m, "CanstackDeadline")
        if isinstance(deadline, (int, float)) and deadline > 0:
            lines.append(f"deadline_ms = {_number(deadline)}  # CanstackDeadline")
        if t.if_active:
            lines[-1] += "  # cyclic if active: its period while active"
        nodes.setdefault(sender, []).append("\n".join(lines))
        count += 1
    if not count:
        raise DbcError(
            f"{source}: no message is sent periodically (cyclic or cyclic if active): nothing to put in a "
            f"scenario ({len(db.messages)} message{'s' if len(db.messages) != 1 else ''}"
            + (f"; {notes[0]}" if notes else "")
            + ")"
            + ("" if default_cycle_ms else "; give --default-cycle MS to send those without a cycle time every MS ms")
        )
    if defaulted:
        notes.insert(
            0,
            f"{defaulted} message{'s' if defaulted != 1 else ''} without send type or cycle time in the DBC: "
            f"every {default_cycle_ms} ms (--default-cycle)",
        )
    head = [
        f"# A scenario from the network description {source}, written by canstack scenario from-dbc:",
        "# one node per sending ECU, one message per cyclic message; deadlines are the periods.",
    ]
    head += [f"# {n}" for n in notes]
    body = [
        "",
        "[bus]",
        f"bitrate = {_bitrate(db, bitrate)}",
        f"duration = {_number(duration)}",
        f"seed = {seed}",
    ]
    for name, msgs in nodes.items():
        body += ["", "[[nodes]]", f"name = {json.dumps(name)}", 'queue = "priority"']
        for text in msgs:
            body += ["", text]
    return ScenarioText("\n".join(head + body) + "\n", notes, count, len(nodes))
