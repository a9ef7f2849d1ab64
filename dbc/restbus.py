"""Rest-bus simulation: every node of a DBC but the device under test, on one bus.

`RestBus(db, bus, dut="IPC")` puts an `Ecu` for each other node on ``bus`` (anything with
``.node(name)``: a `stack.bus.sim.SimBus`, or the python-can driver's bus object), each sending its
messages with their initial values and interaction-layer timing, plus a monitor node that
decodes every frame on the bus into a `BusRecord`. Without a DUT every node is simulated.

The monitor matches a frame to its message as the ECUs do (`RestBus.lookup`: by identifier and
format; a 29-bit frame also to a J1939 message by PGN, whatever its priority and source address)
and names its sender: the simulated ECU that sends that message, else the DUT if the DBC lists it
as a sender, else the DBC's first sender, else ``"?"`` (also for a frame the database does not
know).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import cantools

from stack import Frame, Received

from .ecu import NO_NODE, SKIP_KINDS, Ecu, j1939_pgn, node_names, senderless, unsupported_reason
from .errors import UnknownNameError, load_database
from .interaction import message_timing

__all__ = ["RestBus", "BusRecord", "json_value", "MONITOR_NAME"]

MONITOR_NAME = "restbus-monitor"


def json_value(value: Any) -> Any:
    """A decoded signal value for JSON: choice values as their names (str), numbers as they
    are (int or float)."""
    name = getattr(value, "name", None)
    if name is not None and hasattr(value, "value"):
        return str(name)
    if isinstance(value, (bytes, bytearray)):
        return value.hex()
    return value


@dataclass(frozen=True, slots=True)
class BusRecord:
    """One frame seen on the bus: ``time`` ns, ``sender``, message ``name`` (None if the
    database does not know the identifier), ``frame`` and decoded ``signals``."""

    time: int
    sender: str
    name: str | None
    frame: Frame
    signals: dict[str, Any]

    def as_json(self) -> dict[str, Any]:
        """The record as the JSON object `canstack restbus --json` prints: t (s), sender,
        name, id (int), extended, for a CAN FD frame fd (true) and brs, data (hex), signals
        (choice values as names). A classical frame has no fd key (false, as the JSONL frame
        reader of `stack.phy.waveform` takes it)."""
        f = self.frame
        obj: dict[str, Any] = {"t": self.time / 1e9, "sender": self.sender, "name": self.name, "id": f.can_id}
        obj["extended"] = f.extended
        if f.fd:
            obj["fd"] = True
            obj["brs"] = f.brs
        obj["data"] = f.data.hex()
        obj["signals"] = {k: json_value(v) for k, v in self.signals.items()}
        return obj


class RestBus:
    """Simulate every node of ``db`` except ``dut`` on ``bus``; decode all traffic.

    ``nodes`` restricts the simulated nodes (default: all but the DUT); ``checks`` are passed
    to each `Ecu` (None: those the DBC declares); ``monitor`` adds the decoding monitor node;
    ``records`` keeps every `BusRecord` in ``self.records`` (callbacks from `on_record` run
    either way); ``default_cycle_ms`` sends every message the DBC gives neither send type nor
    cycle time with that period, and the messages no node sends (no sender, or ``Vector__XXX``
    only) from a simulated node ``Vector__XXX``; ``node_options`` are given to ``bus.node`` for
    every node made (``{"fd": "fd"}``: FD-enabled controllers on a python-can FD bus).
    """

    def __init__(
        self,
        db: cantools.database.can.Database | str,
        bus: Any,
        *,
        dut: str | None = None,
        nodes: Iterable[str] | None = None,
        checks: Iterable[Any] | None = None,
        monitor: bool = True,
        records: bool = True,
        start: bool = True,
        default_cycle_ms: int | None = None,
        node_options: Mapping[str, Any] | None = None,
    ) -> None:
        if not isinstance(db, cantools.database.can.Database):
            db = load_database(db)
        self.db = db
        names = node_names(db)
        if dut is not None and dut not in names:
            raise UnknownNameError("node", dut, names, f"(--dut; the database's nodes: {_listing(names)})")
        chosen = list(dict.fromkeys(nodes)) if nodes is not None else [n for n in names if n != dut]
        for n in chosen:
            if n not in names:
                raise UnknownNameError("node", n, names, f"(the database's nodes: {_listing(names)})")
        if (
            default_cycle_ms is not None
            and nodes is None
            and any(senderless(m) and unsupported_reason(m) is None for m in db.messages)
        ):
            chosen.append(NO_NODE)
        self.dut = dut
        self.bus = bus
        #: messages of the database that are no CAN frame: name -> kind (one of
        #: dbc.ecu.SKIP_KINDS: classical and longer than 8 bytes, FD and longer than 64, container)
        self.skipped: dict[str, str] = {}
        for m in db.messages:
            why = unsupported_reason(m)
            if why is not None:
                self.skipped[m.name] = why[0]
        self.ecus: dict[str, Ecu] = {}
        for n in chosen:
            node = bus.node(n, **(node_options or {}))
            self.ecus[n] = Ecu(db, n, node, checks=checks, start=False, default_cycle_ms=default_cycle_ms)
        self.keep = records
        self.records: list[BusRecord] = []
        self._callbacks: list[Callable[[BusRecord], Any]] = []
        self._sender_of: dict[str, str] = {}
        self._messages: dict[tuple[int, bool], Any] = {}
        self._by_pgn: dict[int, Any] = {}
        for m in db.messages:
            key = (m.frame_id, bool(m.is_extended_frame))
            self._messages[key] = m  # as cantools and the Ecu: the last one of a repeated identifier
            if m.protocol == "j1939" and m.is_extended_frame:
                self._by_pgn.setdefault(j1939_pgn(m.frame_id), m)
            sim = [s for s in m.senders if s in self.ecus]
            if NO_NODE in self.ecus and senderless(m):
                self._sender_of[m.name] = NO_NODE
            elif sim:
                self._sender_of[m.name] = sim[0]
            elif dut is not None and dut in m.senders:
                self._sender_of[m.name] = dut
            elif m.senders:
                self._sender_of[m.name] = m.senders[0]
        self.monitor = None
        if monitor:
            self.monitor = bus.node(MONITOR_NAME, **(node_options or {}))
            self.monitor.subscribe(self._on_frame)
        if start:
            self.start()

    @property
    def sent_messages(self) -> int:
        """How many database messages the simulated ECUs send (each message once per sender)."""
        return sum(len(e.tx_messages) for e in self.ecus.values())

    def silent(self) -> str | None:
        """None when a simulated ECU sends a message by itself (cyclic, or cyclic if active and
        active from the start); else one sentence saying why nothing would be sent: messages
        without sender, without send type or cycle time, sent by the DUT, or skipped."""
        for e in self.ecus.values():
            for name in e.tx_messages:
                t = e.timing(name)
                if t.cyclic or (t.if_active and e.would_be_active(name)):
                    return None
        total = len(self.db.messages)
        if not total:
            return "the database has no messages"
        counts = {"no sender": 0, "no cycle time or send type": 0, "spontaneous only": 0, "sent by the DUT": 0}
        for m in self.db.messages:
            if m.name in self.skipped:
                continue
            if senderless(m) and NO_NODE not in self.ecus:
                counts["no sender"] += 1
            elif not any(s in self.ecus for s in m.senders) and not (NO_NODE in self.ecus and senderless(m)):
                counts["sent by the DUT"] += 1
            elif message_timing(self.db, m).on_request_only:
                counts["no cycle time or send type"] += 1
            else:
                counts["spontaneous only"] += 1
        parts = [f"{n} {k}" for k, n in counts.items() if n]
        if self.skipped:
            parts.append(f"{len(self.skipped)} skipped")
        return f"no message would be sent: {total} message{'s' if total != 1 else ''}: {', '.join(parts)}"

    def skipped_summary(self) -> str | None:
        """One sentence saying how many of the database's messages were skipped and why
        (``"1 of 3 messages skipped: 1 longer than 8 bytes"``); None when none was."""
        if not self.skipped:
            return None
        counts = [(k, sum(1 for v in self.skipped.values() if v == k)) for k in SKIP_KINDS]
        why = ", ".join(f"{n} {k}" for k, n in counts if n)
        total = len(self.db.messages)
        return (
            f"{len(self.skipped)} of {total} message{'s' if total != 1 else ''} skipped: {why} "
            "(a classical frame carries at most 8 bytes, a CAN FD frame 64)"
        )

    def start(self) -> None:
        """Start every simulated ECU's interaction layer."""
        for e in self.ecus.values():
            e.start()

    def stop(self) -> None:
        """Stop every simulated ECU."""
        for e in self.ecus.values():
            e.stop()

    def on_record(self, callback: Callable[[BusRecord], Any]) -> None:
        """Call ``callback(BusRecord)`` for each frame the monitor sees."""
        self._callbacks.append(callback)

    def set(self, node: str, signal: str, value: Any, *, message: str | None = None) -> None:
        """Write a signal of a simulated node (see `Ecu.set`)."""
        ecu = self.ecus.get(node)
        if ecu is None:
            raise UnknownNameError("simulated node", node, self.ecus)
        ecu.set(signal, value, message=message)

    def lookup(self, frame: Frame) -> Any:
        """The database message of a frame, as the ECUs match it: by identifier and format,
        then, for a 29-bit frame, a J1939 message by PGN (any priority and source address);
        None if the database does not know it."""
        m = self._messages.get((frame.can_id, frame.extended))
        if m is None and frame.extended and self._by_pgn:
            m = self._by_pgn.get(j1939_pgn(frame.can_id))
        return m

    def _on_frame(self, ev: Received) -> None:
        f = ev.frame
        m = self.lookup(f)
        signals: Mapping[str, Any] = {}
        if m is not None and not f.remote:
            try:  # without the padding after the DBC's length (a CAN FD frame's)
                signals = m.decode(f.data[: m.length], decode_choices=True, scaling=True)
            except Exception:
                signals = {}
        if m is None:
            rec = BusRecord(ev.time, "?", None, f, {})
        else:
            rec = BusRecord(ev.time, self._sender_of.get(m.name, "?"), m.name, f, dict(signals))
        if self.keep:
            self.records.append(rec)
        for cb in self._callbacks:
            cb(rec)

    def from_dut(self) -> list[BusRecord]:
        """Records of frames the DUT sent (messages whose DBC sender is the DUT and that no
        simulated node sends)."""
        return [r for r in self.records if self.dut is not None and r.sender == self.dut]


def _listing(names: list[str], most: int = 40) -> str:
    """Names joined for one line: the first ``most``, then how many more."""
    shown = ", ".join(names[:most]) or "none"
    return shown + (f" and {len(names) - most} more" if len(names) > most else "")
