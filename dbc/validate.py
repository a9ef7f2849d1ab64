"""What cantools loads but a rest bus or an ECU cannot run: checked once, before anything runs.

cantools accepts some databases that make no sense to simulate, or reads less than the file
holds without saying so. `validate_database` refuses them with one `DbcLoadError` naming the
file, the line where it can be found, the message and the signal, and the rule broken:

- no message at all (nothing to simulate);
- a file that stops in the middle: fewer ``BO_``/``SG_`` entries read than the text has (a
  truncated file, or a line cantools' parser stopped at);
- two messages with one frame identifier (cantools keeps one of them for decoding);
- a signal scale of 0 (a physical value cannot be turned back into raw bits), a negative start
  bit, or bits outside the message's length;
- a start value (``GenSigStartValue``) outside what the signal's raw bits hold;
- a negative ``GenMsgCycleTime``/``GenMsgCycleTimeFast``/``GenMsgDelayTime``/
  ``GenMsgStartDelayTime``;
- a ``CanstackCheck`` attribute naming no known check (`dbc.checks`).
"""

from __future__ import annotations

import re
from typing import Any

from stack.wire.frame import id_text

from .checks import hook_from_spec
from .errors import DbcError, DbcLoadError
from .interaction import attribute

__all__ = ["validate_database"]

_BO = re.compile(r"^\s*BO_\s+(\d+)\s+(\w+)\s*:")
_BO_START = re.compile(r"^\s*BO_\s")
_SG_START = re.compile(r"^\s*SG_\s")

#: cantools' pseudo-message for signals that belong to no message (Vector's convention)
_INDEPENDENT = "VECTOR__INDEPENDENT_SIG_MSG"

_TIMES = ("GenMsgCycleTime", "GenMsgCycleTimeFast", "GenMsgDelayTime", "GenMsgStartDelayTime")


def validate_database(db: Any, path: str) -> None:
    """Refuse a database (a cantools `Database` read from ``path``) that cannot be simulated:
    `DbcLoadError` with the file, the line if one is found, the message and signal, and the
    rule (see the module docstring)."""
    p = str(path)
    lines = _text_lines(p)
    seen: dict[tuple[int, bool], str] = {}
    for m in db.messages:
        key = (m.frame_id, bool(m.is_extended_frame))
        if key in seen:
            dbc_id = m.frame_id | (0x80000000 if m.is_extended_frame else 0)
            raise DbcLoadError(
                p,
                _line(lines, rf"^\s*BO_\s+{dbc_id}\s+{re.escape(m.name)}\b"),
                f"message {m.name}: frame identifier {id_text(m.frame_id, bool(m.is_extended_frame))} is already message {seen[key]}'s "
                "(a frame identifier names one message)",
            )
        seen[key] = m.name
    if lines is not None and p.lower().endswith(".dbc"):
        _check_complete(db, p, lines)
    if not db.messages:
        raise DbcLoadError(p, None, "the database has no messages (no BO_): nothing to simulate")
    for m in db.messages:
        for name in _TIMES:
            v = attribute(db, m, name)
            if isinstance(v, (int, float)) and v < 0:
                raise DbcLoadError(
                    p,
                    _line(lines, rf'^\s*BA_\s+"{name}"\s+BO_\s+\d+\s+-'),
                    f"message {m.name}: {name} {v:g} ms is negative (a time is >= 0 ms)",
                )
        for s in m.signals:
            _check_signal(db, p, lines, m, s)
    for m in db.messages:
        for s in m.signals:
            spec = attribute(db, s, "CanstackCheck")
            if not spec:
                continue
            try:
                hook_from_spec(m.name, s.name, str(spec))
            except (DbcError, ValueError) as exc:
                line = _line(lines, rf'^\s*BA_\s+"CanstackCheck"\s+SG_\s+\d+\s+{re.escape(s.name)}\b')
                raise DbcLoadError(p, line, str(exc)) from None


def _check_signal(db: Any, p: str, lines: list[str] | None, m: Any, s: Any) -> None:
    where = f"message {m.name} signal {s.name}"

    def line() -> int | None:  # looked up only for an error: a scan of the text per signal is slow
        return _line(lines, rf"^\s*SG_\s+{re.escape(s.name)}\b")

    if s.conversion.scale == 0:
        raise DbcLoadError(p, line(), f"{where}: scale 0 (a physical value could not be turned back into raw bits)")
    if s.start < 0:
        raise DbcLoadError(p, line(), f"{where}: start bit {s.start} is negative")
    if s.length <= 0:
        raise DbcLoadError(p, line(), f"{where}: length {s.length} bits (a signal has at least 1 bit)")
    start = attribute(db, s, "GenSigStartValue")
    if s.raw_initial is not None:
        start = s.raw_initial
    if isinstance(start, (int, float)) and not s.is_float:
        lo, hi = (-(1 << (s.length - 1)), (1 << (s.length - 1)) - 1) if s.is_signed else (0, (1 << s.length) - 1)
        if not lo <= start <= hi:
            raise DbcLoadError(
                p,
                _line(lines, rf'^\s*BA_\s+"GenSigStartValue"\s+SG_\s+\d+\s+{re.escape(s.name)}\b') or line(),
                f"{where}: start value (GenSigStartValue) {start:g} is outside its {s.length}-bit raw range "
                f"[{lo} .. {hi}]",
            )


def _check_complete(db: Any, p: str, lines: list[str]) -> None:
    """Every ``BO_`` entry of the text was read, with as many signals as it has ``SG_`` lines:
    cantools' parser stops quietly at a truncated entry and returns what came before. Messages
    are matched by their identifier (names may be shortened: ``SystemMessageLongSymbol``)."""
    by_id = {(m.frame_id | (0x80000000 if m.is_extended_frame else 0)): m for m in db.messages}
    entries: list[tuple[int, str, int | None, int]] = []  # (line, text, dbc id, SG_ lines)
    for n, text in enumerate(lines, 1):
        if _BO_START.match(text):
            mb = _BO.match(text)
            entries.append((n, text, int(mb.group(1)) if mb else None, 0))
        elif _SG_START.match(text) and entries:
            n0, t0, i0, count = entries[-1]
            entries[-1] = (n0, t0, i0, count + 1)
    read = 0
    for n, text, ident, signals in entries:
        m = by_id.get(ident) if ident is not None else None
        if m is None:
            mb = _BO.match(text)
            if mb is not None and mb.group(2) == _INDEPENDENT:
                continue
            what = f"message {mb.group(2)}" if mb else f"entry {text.strip()[:40]!r}"
            raise DbcLoadError(
                p,
                n,
                f"{what}: not read (the file is truncated or malformed here; "
                f"{read} message{'s' if read != 1 else ''} read before it)",
            )
        read += 1
        if len(m.signals) < signals:
            raise DbcLoadError(
                p,
                n + len(m.signals) + 1,
                f"message {m.name}: {len(m.signals)} of its {signals} signals read (the file is truncated or "
                "malformed here)",
            )


def _text_lines(path: str) -> list[str] | None:
    try:
        with open(path, encoding="cp1252", errors="replace") as fh:
            return fh.read().splitlines()
    except OSError:
        return None


def _line(lines: list[str] | None, pattern: str) -> int | None:
    if not lines:
        return None
    pat = re.compile(pattern)
    for i, text in enumerate(lines, 1):
        if pat.match(text):
            return i
    return None
