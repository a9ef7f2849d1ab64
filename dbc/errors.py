"""Errors of the DBC layer and the loader that turns cantools' parse errors into them.

Every error is a `ValueError`, so the `canstack` command line prints it as one line and exits 2.
Unknown names carry the closest names (difflib), a malformed DBC carries its line and reason.
"""

from __future__ import annotations

import contextlib
import difflib
import logging
import re
from collections.abc import Iterable, Iterator
from pathlib import Path

import cantools

__all__ = [
    "DbcError",
    "DbcLoadError",
    "UnknownNameError",
    "SignalRangeError",
    "ChoiceError",
    "FdNotCarriedError",
    "closest",
    "load_database",
]


class DbcError(ValueError):
    """Base class of every error the `dbc` package raises on bad input."""


class DbcLoadError(DbcError):
    """A database cantools rejects: ``path``, ``line`` (None when cantools gives none) and
    ``reason``."""

    def __init__(self, path: str, line: int | None, reason: str) -> None:
        self.path = path
        self.line = line
        self.reason = reason
        where = f"{path}, line {line}" if line is not None else path
        super().__init__(f"{where}: {reason}")


class UnknownNameError(DbcError, KeyError):
    """A node, message, signal or choice name that is not in the database; ``suggestions``
    holds the closest existing names."""

    def __init__(self, kind: str, name: str, candidates: Iterable[str], context: str = "") -> None:
        self.kind = kind
        self.name = name
        self.suggestions = closest(name, candidates)
        hint = f"; did you mean {', '.join(map(repr, self.suggestions))}?" if self.suggestions else ""
        ctx = f" {context}" if context else ""
        ValueError.__init__(self, f"unknown {kind} {name!r}{ctx}{hint}")

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0])


class SignalRangeError(DbcError):
    """A physical value outside the signal's range (DBC minimum/maximum, or what its raw bits
    can hold)."""


class ChoiceError(UnknownNameError):
    """A choice (value table) name the signal does not define."""


class FdNotCarriedError(DbcError):
    """An ECU would send a CAN FD ``message`` from a node that is not FD enabled (a bus without a
    data bit rate: ISO 11898-1:2015 lets only an FD-enabled controller send FD frames)."""

    def __init__(self, message: str, node: str, kind: str, length: int) -> None:
        self.message = message
        self.node = node
        super().__init__(
            f"message {message} is a CAN FD frame ({length} bytes) but node {node} is {kind!r}, not FD enabled: "
            "a bus without a data bit rate carries classical frames only"
        )


def closest(name: str, candidates: Iterable[str], n: int = 3) -> list[str]:
    """Up to ``n`` candidates closest to ``name`` (difflib ratio >= 0.5; case-insensitive)."""
    cands = list(dict.fromkeys(candidates))
    lower = {c.lower(): c for c in cands}
    hits = difflib.get_close_matches(name.lower(), list(lower), n=n, cutoff=0.5)
    return [lower[h] for h in hits]


_LINE_RE = re.compile(r"line (\d+)(?:, column (\d+))?")
_MSG_RE = re.compile(r"in message (\w+)")


def load_database(path: str | Path, *, strict: bool = True) -> cantools.database.can.Database:
    """Load a DBC (or any format cantools reads) into a cantools `Database`.

    A file cantools rejects raises `DbcLoadError` with the line and reason: the line from
    cantools' parse error when it names one; otherwise the line is found in the text: the
    ``BA_``/``BA_REL_`` using an attribute no ``BA_DEF_`` defines (cantools only says the
    attribute's name), the first ``VAL_``/``SIG_VALTYPE_`` that names a signal its message does
    not have (cantools lists them without lines), or the ``BO_ <id> <name>:`` of the message
    the reason names; otherwise none.
    """
    p = str(path)
    _refuse_binary(p)
    try:
        with _quiet_cantools():
            db = cantools.database.load_file(p, strict=strict)
    except FileNotFoundError:
        raise DbcLoadError(p, None, "no such file") from None
    except IsADirectoryError:
        raise DbcLoadError(p, None, "is a directory, not a database file") from None
    except NotADirectoryError:
        raise DbcLoadError(p, None, f"{_file_on_the_way(p)!r} is a file, not a directory") from None
    except (cantools.database.errors.Error, cantools.errors.Error, ValueError, UnicodeDecodeError) as exc:
        reason = _printable(" ".join(str(exc).split()))
        if reason.startswith('DBC: "') and reason.endswith('"'):
            reason = reason[6:-1]
        line: int | None = None
        m = _LINE_RE.search(reason)
        if m:
            line = int(m.group(1))
        else:
            found = _explain(p, exc, reason)
            if found is not None:
                line, reason = found
            else:
                mm = _MSG_RE.search(reason)
                if mm:
                    line = _find_message_line(p, mm.group(1))
        raise DbcLoadError(p, line, reason) from None
    if not isinstance(db, cantools.database.can.Database):
        raise DbcLoadError(p, None, f"not a CAN database ({type(db).__name__})")
    return db


@contextlib.contextmanager
def _quiet_cantools() -> Iterator[None]:
    """cantools logs what it overwrites (two messages with one frame identifier) as warnings,
    which Python prints on stderr as a second line; `dbc.validate` reports them as errors."""
    logger = logging.getLogger("cantools")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(level)


def _file_on_the_way(path: str) -> str:
    """The part of ``path`` that is a file where a directory should be."""
    parent = Path(path).parent
    while parent != parent.parent and not parent.is_file():
        parent = parent.parent
    return str(parent)


def _refuse_binary(path: str) -> None:
    """Every format cantools reads (DBC, KCD, ARXML, SYM) is text: a NUL byte means a binary
    file, whose parse error would quote raw bytes to the terminal."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(65536)
    except OSError:
        return  # cantools' own open reports it (no such file, a directory, ...)
    nul = head.find(b"\0")
    if nul >= 0:
        raise DbcLoadError(
            path,
            None,
            f"not a database file: binary content (a NUL byte at offset {nul}); DBC, KCD, ARXML and SYM files are text",
        )


def _printable(text: str, limit: int = 300) -> str:
    """A parser's message made safe for one terminal line: control characters escaped, and cut
    to ``limit`` characters (it may quote a long stretch of the file)."""
    out = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)
    return out if len(out) <= limit else out[:limit] + "..."


def _lines(path: str) -> list[str]:
    """The file's lines as cantools reads a DBC (cp1252), or none if it cannot be read."""
    try:
        with open(path, encoding="cp1252", errors="replace") as fh:
            return fh.read().splitlines()
    except OSError:  # pragma: no cover
        return []


def _find_line(lines: list[str], pattern: str) -> int | None:
    pat = re.compile(pattern)
    for i, text in enumerate(lines, 1):
        if pat.match(text):
            return i
    return None


def _find_message_line(path: str, message: str) -> int | None:
    return _find_line(_lines(path), rf"^\s*BO_\s+\d+\s+{re.escape(message)}\s*:")


_KEY_RE = re.compile(r"^'([^']*)'$")
_UNUSED_RE = re.compile(r"unused (VAL_|SIG_VALTYPE_) entries in DBC: (.*)$")
_ENTRY_RE = re.compile(r"(VAL_|SIG_VALTYPE_) (\d+) (\S+)")


def _explain(path: str, exc: BaseException, reason: str) -> tuple[int | None, str] | None:
    """(line, reason) for the cantools errors that carry no line: a ``KeyError`` for an
    attribute used without definition, and unused ``VAL_``/``SIG_VALTYPE_`` entries; None for
    any other error."""
    cause = exc.__cause__ if exc.__cause__ is not None else exc.__context__
    key: str | None = None
    if isinstance(cause, KeyError) and cause.args:
        key = str(cause.args[0])
    else:
        mk = _KEY_RE.match(reason)
        if mk:
            key = mk.group(1)
    if key is not None:
        lines = _lines(path)
        q = re.escape(key)
        for use, define in (("BA_", "BA_DEF_"), ("BA_REL_", "BA_DEF_REL_")):
            line = _find_line(lines, rf'^\s*{use}\s+"{q}"')
            if line is not None and _find_line(lines, rf'^\s*{define}\s+(?:\w+\s+)*"{q}"') is None:
                return line, f'attribute "{key}" is used ({use}) but never defined (no {define} "{key}")'
        return _find_line(lines, rf".*\b{q}\b"), f"undefined name {key!r} referenced"
    mu = _UNUSED_RE.search(reason)
    if mu:
        kind = mu.group(1)
        entries = _ENTRY_RE.findall(mu.group(2))
        if not entries:
            return None
        lines = _lines(path)
        _, frame_id, signal = entries[0]
        line = _find_line(lines, rf"^\s*{kind}\s+{frame_id}\s+{re.escape(signal)}\b")
        bo = _find_line(lines, rf"^\s*BO_\s+{frame_id}\s")
        if bo is None:
            why = f"no message has identifier {frame_id} (no BO_ {frame_id})"
        else:
            mm = re.match(r"^\s*BO_\s+\d+\s+(\w+)", lines[bo - 1])
            name = mm.group(1) if mm else frame_id
            why = f"message {name} (BO_ {frame_id}, line {bo}) has no signal {signal}"
        more = f" (and {len(entries) - 1} more unused {kind} entries)" if len(entries) > 1 else ""
        return line, f"{kind} {frame_id} {signal}: {why}{more}"
    return None
