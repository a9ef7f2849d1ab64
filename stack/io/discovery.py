"""Where running `canstack serve` buses announce themselves on this machine.

A plain channel name (``channel="bus0"``) is a bus private to the process, and ``canstack serve``
serves a bus named ``bus0`` by default: two processes that both open ``"bus0"`` see nothing of
each other, silently. So each `BusServer` writes a small JSON file (bus name, channel URL, pid)
into a per-user directory while it runs, and the python-can interface reads that directory when
a process opens a plain-named bus, to warn that a served bus may have been meant.

The directory is ``$XDG_RUNTIME_DIR/canstack`` or ``<tempdir>/canstack-<uid>`` (mode 0700, only
used when it belongs to this user). Files of processes that no longer run are removed on sight.
"""

from __future__ import annotations

import json
import os
import tempfile
import threading
from itertools import count
from pathlib import Path
from typing import Any

__all__ = ["Announcement", "announce_dir", "local_servers"]

_ids = count()
_lock = threading.Lock()


def announce_dir() -> Path:
    """The per-user directory the announcements live in (not created here)."""
    base = os.environ.get("XDG_RUNTIME_DIR")
    if base and os.path.isdir(base):
        return Path(base) / "canstack"
    uid = os.getuid() if hasattr(os, "getuid") else os.environ.get("USERNAME", "user")
    return Path(tempfile.gettempdir()) / f"canstack-{uid}"


def _own_dir(create: bool) -> Path | None:
    d = announce_dir()
    try:
        if create:
            d.mkdir(mode=0o700, exist_ok=True)
        st = d.stat()
    except OSError:
        return None
    # a directory another user made in a shared /tmp is not trusted (nor written)
    if hasattr(os, "getuid") and st.st_uid != os.getuid():
        return None
    return d


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True  # exists, owned by someone else
    return True


class Announcement:
    """This process serves ``bus`` at ``url``: a file in `announce_dir` until `close()`.

    Best effort: a directory that cannot be written leaves the server unannounced (it serves
    anyway; only the warning for plain-named buses is lost).
    """

    def __init__(self, bus: str, url: str) -> None:
        self.path: Path | None = None
        d = _own_dir(create=True)
        if d is None:
            return
        with _lock:
            n = next(_ids)
        path = d / f"serve-{os.getpid()}-{n}.json"
        try:
            tmp = path.with_suffix(".tmp")
            tmp.write_text(json.dumps({"bus": bus, "url": url, "pid": os.getpid()}))
            os.replace(tmp, path)  # readers never see half a file
        except OSError:
            return
        self.path = path

    def close(self) -> None:
        """Withdraw the announcement (idempotent)."""
        if self.path is not None:
            try:
                self.path.unlink()
            except OSError:
                pass
            self.path = None


def local_servers() -> list[dict[str, Any]]:
    """The buses served on this machine by running processes of this user: dicts with
    ``bus``, ``url`` and ``pid``, oldest file first."""
    d = _own_dir(create=False)
    if d is None:
        return []
    out = []
    try:
        files = sorted(d.glob("serve-*.json"), key=lambda p: p.stat().st_mtime)
    except OSError:  # a file vanished while listing: its server closed
        files = sorted(d.glob("serve-*.json"))
    for p in files:
        try:
            info = json.loads(p.read_text())
            pid = int(info["pid"])
            entry = {"bus": str(info["bus"]), "url": str(info["url"]), "pid": pid}
        except (OSError, ValueError, KeyError, TypeError):
            continue
        if not _alive(pid):
            try:
                p.unlink()  # left by a server that was killed
            except OSError:
                pass
            continue
        out.append(entry)
    return out
