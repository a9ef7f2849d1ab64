"""Errors of the DBC layer and the loader that turns cantools' parse errors into them.

Every error is a `ValueError`, so the `canstack` command line prints it as one line and exits 2.
Unknown names carry the closest names (difflib), a malformed DBC carries its line and reason.
"""

from __future__ import annotations

import difflib
import re
from pathlib import Path
from typing import Iterable

import cantools

__all__ = [
    "DbcError",
    "DbcLoadError",
    "UnknownNameError",
    "SignalRangeError",
    "ChoiceError",
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
    cantools' parse error when it names one, otherwise the line of the message the reason names
    (``BO_ <id> <name>:``) found in the text, otherwise none.
    """
    p = str(path)
    try:
        db = cantools.database.load_file(p, strict=strict)
    except FileNotFoundError:
        raise DbcLoadError(p, None, "no such file") from None
    except IsADirectoryError:
        raise DbcLoadError(p, None, "is a directory, not a database file") from None
    except (cantools.database.errors.Error, cantools.errors.Error, ValueError, UnicodeDecodeError) as exc:
        reason = " ".join(str(exc).split())
        if reason.startswith('DBC: "') and reason.endswith('"'):
            reason = reason[6:-1]
        line: int | None = None
        m = _LINE_RE.search(reason)
        if m:
            line = int(m.group(1))
        else:
            mm = _MSG_RE.search(reason)
            if mm:
                line = _find_message_line(p, mm.group(1))
        raise DbcLoadError(p, line, reason) from None
    if not isinstance(db, cantools.database.can.Database):
        raise DbcLoadError(p, None, f"not a CAN database ({type(db).__name__})")
    return db


def _find_message_line(path: str, message: str) -> int | None:
    pat = re.compile(rf"^\s*BO_\s+\d+\s+{re.escape(message)}\s*:")
    try:
        with open(path, encoding="cp1252", errors="replace") as fh:
            for i, text in enumerate(fh, 1):
                if pat.match(text):
                    return i
    except OSError:  # pragma: no cover
        return None
    return None
