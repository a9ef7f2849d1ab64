"""Signal changes that drive a rest bus: ``--set Message.Signal=VALUE`` and stimulus files.

A `Change` writes one signal of a simulated node at a time after the start. Values are physical
values in the DBC's unit, or choice names of the signal's value table. A stimulus file lists
timed changes, as CSV with the header ``time,message,signal,value`` (time in seconds)::

    time,message,signal,value
    0.5,EngineData,EngineSpeed,2000
    1.0,GearboxData,GearSelected,D

or as TOML, one ``[[changes]]`` table per row with the same keys::

    [[changes]]
    time = 0.5
    message = "EngineData"
    signal = "EngineSpeed"
    value = 2000

`check_changes` resolves every change against the rest bus before anything runs: an unknown
message, signal or choice, a message no simulated node sends, or a value outside the signal's
range is a `DbcError` naming the signal (and its range) and where the change came from.
"""

from __future__ import annotations

import csv
import functools
import math
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any, NamedTuple

from .errors import DbcError, UnknownNameError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = ["Change", "parse_assignment", "parse_value", "read_stimulus", "check_changes", "schedule"]

#: The columns of a stimulus file, in order.
COLUMNS = ("time", "message", "signal", "value")


class Change(NamedTuple):
    """Write ``value`` to ``message.signal`` at ``time`` ns after the start; ``source`` says
    where it came from (``--set`` or ``file, line n``) for error messages."""

    time: int
    message: str
    signal: str
    value: float | int | str
    source: str


def parse_value(text: str) -> float | int | str:
    """A value as given on the command line or in a CSV cell: an integer, a number, else a
    choice name (``D``, ``Open``)."""
    t = text.strip()
    for number in (int, _int_prefixed, float):
        try:
            return number(t)
        except ValueError:
            pass
    return t


def _int_prefixed(text: str) -> int:
    return int(text, 0)  # 0x1F, 0b101


def parse_assignment(text: str, source: str = "--set") -> Change:
    """``Message.Signal=VALUE`` as a `Change` at time 0."""
    target, eq, value = text.partition("=")
    message, dot, signal = target.strip().partition(".")
    if not eq or not dot or not message or not signal or not value.strip():
        raise DbcError(f"{source} {text!r}: give Message.Signal=VALUE (a physical value or a choice name)")
    return Change(0, message, signal.strip(), parse_value(value), source)


def _seconds(value: Any, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise DbcError(f"{where}: time: {value!r} is not a number of seconds")
    try:
        t = float(value)
    except ValueError:
        raise DbcError(f"{where}: time: {value!r} is not a number of seconds") from None
    if not (math.isfinite(t) and t >= 0):
        raise DbcError(f"{where}: time: {value!r} must be a finite number of seconds >= 0")
    return round(t * 1e9)


def read_stimulus(path: str | Path) -> list[Change]:
    """The changes of a stimulus file (``.toml``: ``[[changes]]`` tables; anything else: CSV
    with the header ``time,message,signal,value``), sorted by time (stable)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise DbcError(f"{p}: no such stimulus file") from None
    except IsADirectoryError:
        raise DbcError(f"{p}: is a directory, not a stimulus file") from None
    except UnicodeDecodeError:
        raise DbcError(f"{p}: not a text file (a stimulus is CSV or TOML in UTF-8)") from None
    except OSError as exc:
        raise DbcError(f"{p}: cannot read it ({exc.strerror})") from None
    changes = _read_toml(p, text) if p.suffix.lower() == ".toml" else _read_csv(p, text)
    return sorted(changes, key=lambda c: c.time)


def _read_csv(p: Path, text: str) -> list[Change]:
    rows = list(csv.reader(text.splitlines()))
    if not rows or [c.strip().lower() for c in rows[0]] != list(COLUMNS):
        got = ",".join(rows[0]) if rows else "an empty file"
        raise DbcError(f"{p}, line 1: the header must be {','.join(COLUMNS)} (got {got!r})")
    out = []
    for n, row in enumerate(rows[1:], 2):
        if not row or all(not c.strip() for c in row):
            continue
        where = f"{p}, line {n}"
        if len(row) != len(COLUMNS):
            raise DbcError(f"{where}: {len(row)} columns, expected 4 ({','.join(COLUMNS)})")
        t, message, signal, value = (c.strip() for c in row)
        if not message or not signal or not value:
            raise DbcError(f"{where}: message, signal and value must not be empty")
        out.append(Change(_seconds(t, where), message, signal, parse_value(value), where))
    return out


def _read_toml(p: Path, text: str) -> list[Change]:
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise DbcError(f"{p}: not valid TOML: {exc}") from None
    extra = sorted(set(raw) - {"changes"})
    if extra:
        raise DbcError(f"{p}: unknown table or key {extra[0]!r} (a stimulus file has [[changes]] tables)")
    rows = raw.get("changes", [])
    if not isinstance(rows, list):
        raise DbcError(f"{p}: changes: give [[changes]] tables (time, message, signal, value)")
    out = []
    for i, row in enumerate(rows, 1):
        where = f"{p}, [[changes]] #{i}"
        if not isinstance(row, dict):
            raise DbcError(f"{where}: expected a table")
        unknown = sorted(set(row) - set(COLUMNS))
        if unknown:
            raise DbcError(f"{where}: unknown key {unknown[0]!r} (keys: {', '.join(COLUMNS)})")
        missing = [k for k in COLUMNS if k not in row]
        if missing:
            raise DbcError(f"{where}: key {missing[0]!r} is required")
        message, signal, value = row["message"], row["signal"], row["value"]
        for key, v in (("message", message), ("signal", signal)):
            if not isinstance(v, str) or not v:
                raise DbcError(f"{where}: {key}: {v!r} must be a name")
        if isinstance(value, bool) or not isinstance(value, (int, float, str)):
            raise DbcError(f"{where}: value: {value!r} must be a number or a choice name")
        out.append(Change(_seconds(row["time"], where), message, signal, value, where))
    return out


def check_changes(restbus: Any, changes: Iterable[Change]) -> list[tuple[Change, Any]]:
    """Each change with the ECU that sends its message, its value checked (`Ecu.check_value`:
    the choice exists, the number is inside the signal's range); `DbcError` naming the source,
    the signal and the rule otherwise."""
    db = restbus.db
    out = []
    for c in changes:
        try:
            m = db.get_message_by_name(c.message)
        except KeyError:
            raise UnknownNameError("message", c.message, [m.name for m in db.messages], f"({c.source})") from None
        names = [s.name for s in m.signals]
        if c.signal not in names:
            raise UnknownNameError("signal", c.signal, names, f"in message {c.message} ({c.source})")
        ecu = next((e for e in restbus.ecus.values() if c.message in e.tx_messages), None)
        if ecu is None:
            senders = ", ".join(m.senders) or "no node"
            why = f"the DUT {restbus.dut}" if restbus.dut in m.senders else senders
            raise DbcError(
                f"{c.source}: message {c.message} is not sent by a simulated node (sent by {why}): "
                "only the rest bus's own messages can be set"
            )
        try:
            value = ecu.check_value(c.message, c.signal, c.value, clamp=False)
        except DbcError as exc:
            raise DbcError(f"{c.source}: {exc}") from None
        out.append((c._replace(value=value), ecu))
    return out


def schedule(checked: Iterable[tuple[Change, Any]], start: int) -> None:
    """Write the changes at time 0 now and schedule the others on their ECU's node at
    ``start`` + their time (the node's clock), in order."""
    for c, ecu in checked:
        if c.time == 0:
            ecu.set(c.signal, c.value, message=c.message)
        else:
            ecu.node.call_at(start + c.time, functools.partial(ecu.set, c.signal, c.value, message=c.message))
