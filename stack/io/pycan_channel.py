"""The channels of the ``canstack`` python-can interface: a bus private to the process (``"bus0"``)
or one served by ``canstack serve`` (``"tcp://HOST:PORT/NAME"``, ``"unix:///PATH/NAME"``), read by
`parse_channel`; `warn_if_served` warns once per process when a private bus opens while a server
runs on the machine (`PrivateBusWarning`)."""

from __future__ import annotations

import os
import re
import threading
import warnings
from typing import Any

import can

from stack.io.discovery import local_servers
from stack.io.runner import BUS_NAME_RE

__all__ = ["PrivateBusWarning", "parse_channel", "warn_if_served"]


class PrivateBusWarning(UserWarning):
    """A plain channel name opened a bus private to this process while a ``canstack serve`` runs
    on this machine: the served bus may have been meant."""


def _is_socket(path: str) -> bool:
    import stat

    try:
        return stat.S_ISSOCK(os.stat(path).st_mode)
    except OSError:
        return False


def parse_channel(channel: Any) -> tuple[str, str, Any]:
    """A canstack channel read: ('local', name, None) for a bus private to the process, ('tcp', name,
    (host, port)) or ('unix', name, socket path) for a served one; `can.CanInitializationError`
    naming the channel and the forms allowed otherwise."""
    if not isinstance(channel, str) or not channel:
        raise can.CanInitializationError(
            f"canstack channel {channel!r}: give a bus name like 'bus0', 'tcp://127.0.0.1:PORT/bus0' "
            "or 'unix:///path/to/socket/bus0'"
        )
    if "://" not in channel:
        if not BUS_NAME_RE.match(channel):
            raise can.CanInitializationError(
                f"canstack channel {channel!r}: a bus name is 1..64 of A-Z a-z 0-9 _ . - ; "
                "or use tcp://HOST:PORT/NAME or unix:///PATH/NAME"
            )
        return "local", channel, None
    scheme, rest = channel.split("://", 1)
    if scheme == "tcp":
        m = re.match(r"^(\[[^\]]+\]|[^:/]+):(\d{1,5})/([A-Za-z0-9_.\-]{1,64})$", rest)
        if not m:
            raise can.CanInitializationError(f"canstack channel {channel!r}: expected tcp://HOST:PORT/NAME")
        host = m.group(1).strip("[]")
        port = int(m.group(2))
        if not 0 < port < 65536:
            raise can.CanInitializationError(f"canstack channel {channel!r}: port {port} out of range")
        return "tcp", m.group(3), (host, port)
    if scheme == "unix":
        if _is_socket(rest):
            raise can.CanInitializationError(
                f"canstack channel {channel!r}: {rest} is the socket itself; add the bus name: unix://{rest}/NAME"
            )
        path, _, name = rest.rpartition("/")
        if not path.startswith("/") or not BUS_NAME_RE.match(name):
            raise can.CanInitializationError(
                f"canstack channel {channel!r}: expected unix:///ABSOLUTE/SOCKET/PATH/NAME"
            )
        return "unix", name, path
    raise can.CanInitializationError(
        f"canstack channel {channel!r}: unknown form {scheme + '://'!r}; use a bus name, tcp:// or unix://"
    )


_warned_private = False
_warn_lock = threading.Lock()


def warn_if_served(name: str) -> None:
    """Warn once per process when a plain-named (private) bus opens while a `canstack serve`
    runs on this machine: two processes on "bus0" silently see nothing of each other."""
    global _warned_private
    if _warned_private:
        return
    servers = local_servers()
    if not servers:
        return
    with _warn_lock:
        if _warned_private:
            return
        _warned_private = True
    same = [s for s in servers if s["bus"] == name] or servers
    url = same[0]["url"]
    warnings.warn(
        f"canstack channel {name!r} is a bus private to this process (other processes do not see it); "
        f"canstack serve is running on this machine: to share its bus use channel={url!r}",
        PrivateBusWarning,
        stacklevel=4,
    )
