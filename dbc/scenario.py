"""A scheduling scenario from a network description (``canstack scenario from-dbc``).

`scenario_from_dbc` turns a DBC into the scenario file the experiment pipeline reads
(`profiles.pipeline.scenario`): one node per sending ECU, and one message per message that the
ECU sends by itself — cyclic (``GenMsgCycleTime``; cyclic-and-spontaneous counted at its cycle),
or cyclic if active (at ``GenMsgCycleTimeFast``, its period while active: the worst case) — with
its identifier, length and period; ``GenMsgStartDelayTime`` becomes the offset. The deadline is
the period unless the message has the ``CanstackDeadline`` attribute (ms). Every node queues by
priority, the controller model the response-time analysis assumes.

CAN FD messages (cantools' ``Message.is_fd``) become FD messages of the scenario: ``fd = true``,
``brs`` from the DBC's ``CANFD_BRS`` (`dbc.transmit.fd_format`) and ``length`` in bytes, the DBC's
length padded to the next CAN FD length as the ECUs send it; classical messages keep ``dlc``. A
database with FD messages makes the bus a CAN FD bus: ``[bus] data_bitrate`` is ``--data-bitrate``,
else `DEFAULT_DATA_BITRATE` with a note.

What a scenario cannot hold is left out, each with a comment line in the file and a line on
stderr: classical messages longer than 8 bytes, containers, and messages sent only on request or
spontaneously (no period). A message with several senders is given to the first (one sender per
identifier on a bus). The bit rate is ``--bitrate``, else the database's ``Baudrate`` attribute,
else 500 kbit/s.

``canstack scenario from-dbc`` (`dbc.scenario_cli`) reads the text back with the pipeline's own
reader before it writes it, so a file it writes is one ``canstack experiment`` runs.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

from stack.wire.frame import FD_LENGTHS

from .ecu import NO_NODE, senderless, unsupported_reason
from .errors import DbcError
from .interaction import attribute, message_timing
from .transmit import fd_format

__all__ = ["ScenarioText", "scenario_from_dbc", "DEFAULT_BITRATE", "DEFAULT_DATA_BITRATE"]

DEFAULT_BITRATE = 500_000

#: ``[bus] data_bitrate`` of a scenario from a database with CAN FD messages when no
#: ``--data-bitrate`` is given: 2 Mbit/s, the rate ISO 11898-2:2016 transceivers are first
#: specified for.
DEFAULT_DATA_BITRATE = 2_000_000


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
    data_bitrate: int | None = None,
) -> ScenarioText:
    """The scenario of a cantools database (see the module docstring); ``default_cycle_ms`` is
    the period of the messages the DBC gives neither send type nor cycle time (as
    ``canstack restbus --default-cycle``), ``data_bitrate`` the CAN FD data phase's bit/s (None:
    `DEFAULT_DATA_BITRATE` when the database has FD messages, else a classical bus). `DbcError`
    when no message is sent periodically, or the data bit rate is below the bit rate."""
    nodes: dict[str, list[str]] = {}
    notes: list[str] = []
    count = defaulted = fd_count = 0
    for m in db.messages:
        why = unsupported_reason(m)
        if why is not None:
            notes.append(f"{m.name}: left out: {why[1]}")
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
        fd, brs = fd_format(db, m)
        if fd:
            fd_count += 1
            length = next(n for n in FD_LENGTHS if n >= m.length)
            padded = f"  # {m.length} bytes in the DBC, padded" if length != m.length else ""
            lines += ["fd = true", f"brs = {'true' if brs else 'false'}", f"length = {length}{padded}"]
        else:
            lines.append(f"dlc = {m.length}")
        lines.append(f"period_ms = {_number(period)}")
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
    nominal = _bitrate(db, bitrate)
    bus = ["", "[bus]", f"bitrate = {nominal}"]
    if fd_count or data_bitrate is not None:
        if data_bitrate is None:
            data_bitrate = DEFAULT_DATA_BITRATE
            notes.insert(
                0,
                f"{fd_count} CAN FD message{'s' if fd_count != 1 else ''}: a CAN FD bus with a data phase at "
                f"{data_bitrate} bit/s (give --data-bitrate for another)",
            )
        if data_bitrate < nominal:
            raise DbcError(
                f"data bit rate {data_bitrate} is below the bit rate {nominal}: a CAN FD data phase is at least as "
                "fast as the arbitration phase"
            )
        bus.append(f"data_bitrate = {data_bitrate}")
    head = [
        f"# A scenario from the network description {source}, written by canstack scenario from-dbc:",
        "# one node per sending ECU, one message per cyclic message; deadlines are the periods.",
    ]
    head += [f"# {n}" for n in notes]
    body = [*bus, f"duration = {_number(duration)}", f"seed = {seed}"]
    for name, msgs in nodes.items():
        body += ["", "[[nodes]]", f"name = {json.dumps(name)}", 'queue = "priority"']
        for text in msgs:
            body += ["", text]
    return ScenarioText("\n".join(head + body) + "\n", notes, count, len(nodes))
