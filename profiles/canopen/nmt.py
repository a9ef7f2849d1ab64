"""NMT: network management (CiA 301 7.2.8.2.1 module control, 7.3.2 the NMT slave).

`NmtSlave` drives the transition table of `profiles.canopen._state` from NMT messages (COB-ID
0x000, two bytes: command specifier, node-ID or 0 for all); `nmt_command` builds those messages
for a master. The slave never sends anything itself: the device sends the boot-up message and
the heartbeat (`profiles.canopen.heartbeat`) and re-initialises what a reset asks for.
"""

from __future__ import annotations

from collections.abc import Callable

from profiles.canopen import cob
from profiles.canopen._state import RESETS, NmtCommand, NmtState, ResetKind, next_state
from stack import Frame

__all__ = ["NmtSlave", "nmt_command", "NmtState", "NmtCommand", "ResetKind"]


def nmt_command(command: int, node_id: int = 0) -> Frame:
    """The NMT module control message (CiA 301 7.2.8.3.1): COB-ID 0x000, data [command
    specifier, node-ID]; node-ID 0 addresses every node."""
    cs = NmtCommand(command)
    if isinstance(node_id, bool) or not isinstance(node_id, int) or not 0 <= node_id <= 127:
        raise ValueError(f"node_id {node_id!r}: an NMT command addresses node 1..127, or 0 for all nodes")
    return Frame(cob.NMT, bytes([cs, node_id]))


class NmtSlave:
    """The NMT state of one device (CiA 301 7.3.2.2) and the commands addressed to it.

    ``on_state(old, new)`` is called after every change of state; ``on_reset(kind)`` when a
    reset node / reset communication command arrives (the device re-initialises, sends its
    boot-up message and calls `booted`). Counters: ``commands`` (addressed to this node and
    acted on), ``ignored`` (wrong length, unknown specifier, or while initialising).
    """

    def __init__(
        self, node_id: int, on_state: Callable[[NmtState, NmtState], None], on_reset: Callable[[ResetKind], None]
    ) -> None:
        self.node_id = cob.check_node_id(node_id)
        self.state = NmtState.INITIALISING
        self.on_state = on_state
        self.on_reset = on_reset
        self.commands = 0
        self.ignored = 0
        self.history: list[tuple[str, str]] = []  # (command or event, state after)

    def on_command(self, data: bytes) -> None:
        """An NMT message (CiA 301 7.2.8.3.1): acted on when it is two bytes long and addresses
        this node or all nodes (CANopenNode ignores other lengths too)."""
        if len(data) != 2 or data[1] not in (0, self.node_id):
            if len(data) != 2:
                self.ignored += 1
            return
        cs = data[0]
        nxt = next_state(self.state, cs)
        if nxt is None:
            self.ignored += 1
            return
        self.commands += 1
        kind = RESETS.get(NmtCommand(cs))
        if kind is not None:
            self.history.append((NmtCommand(cs).name, NmtState.INITIALISING.name))
            self._set(NmtState.INITIALISING)
            self.on_reset(kind)
            return
        self.history.append((NmtCommand(cs).name, nxt.name))
        if nxt is not self.state:
            self._set(nxt)

    def booted(self, operational: bool = False) -> None:
        """Initialisation finished, boot-up message sent: transition (2) to pre-operational
        (or straight to operational for a self-starting device, CiA 302's 'auto start')."""
        self._set(NmtState.OPERATIONAL if operational else NmtState.PRE_OPERATIONAL)

    def error_behaviour(self, new: NmtState, event: str) -> None:
        """The device's own change of state after an error (CiA 301 0x1029), logged as ``event``."""
        self.history.append((event, new.name))
        self._set(new)

    def power_off(self) -> None:
        """The device stops: back to initialising, without telling anyone."""
        self.state = NmtState.INITIALISING

    def _set(self, new: NmtState) -> None:
        old = self.state
        self.state = new
        if new is not old:
            self.on_state(old, new)
