"""The NMT slave state machine of CiA 301 (clause 7.3.2.2), as tables and nothing else.

Like h11's ``_state.py``: a pure transition table other modules import, never the reverse. It
holds no node, no timer and no frame; `profiles.canopen.nmt` drives it.

States and their codes are the ones the heartbeat and boot-up messages carry (CiA 301 table
"state of the NMT slave"): 0 initialisation (the boot-up message), 4 stopped, 5 operational,
127 pre-operational. Node-guarding replies carry the same codes in bits 6..0 with the toggle bit
in bit 7.

NMT command specifiers (byte 0 of the NMT message, COB-ID 0x000; byte 1 is the node-ID, 0 for
all nodes): 0x01 start remote node, 0x02 stop remote node, 0x80 enter pre-operational, 0x81 reset
node, 0x82 reset communication.

Transitions (the numbers of CiA 301's state diagram):

    (1)  power on                      -> INITIALISING   (automatic)
    (2)  initialisation finished        -> PRE_OPERATIONAL (automatic, after the boot-up message)
    (3)  start remote node              PRE_OPERATIONAL -> OPERATIONAL
    (4)  enter pre-operational          OPERATIONAL     -> PRE_OPERATIONAL
    (5)  stop remote node               PRE_OPERATIONAL -> STOPPED
    (6)  start remote node              STOPPED         -> OPERATIONAL
    (7)  enter pre-operational          STOPPED         -> PRE_OPERATIONAL
    (8)  stop remote node               OPERATIONAL     -> STOPPED
    (9)(10)(11)   reset node            any             -> INITIALISING (reset application)
    (12)(13)(14)  reset communication   any             -> INITIALISING (reset communication)

A command that names the state the node is in already (start while operational) changes
nothing. While initialising the node does not listen to NMT at all.

Which communication objects work in which state (CiA 301 table "NMT states and communication
objects"): PDO only in operational; SDO, SYNC, TIME and EMCY in pre-operational and operational;
the boot-up message only when leaving initialisation; NMT itself and error control (heartbeat,
node guarding) in pre-operational, operational and stopped.
"""

from __future__ import annotations

from enum import Enum, IntEnum

__all__ = ["NmtState", "NmtCommand", "ResetKind", "TRANSITIONS", "SERVICES", "next_state", "allows", "state_name"]


class NmtState(IntEnum):
    """NMT slave states with the codes of the heartbeat/boot-up byte (CiA 301 7.2.8.3.2)."""

    INITIALISING = 0
    STOPPED = 4
    OPERATIONAL = 5
    PRE_OPERATIONAL = 127


class NmtCommand(IntEnum):
    """NMT command specifiers (CiA 301 7.2.8.3.1), byte 0 of the NMT message on COB-ID 0x000."""

    START = 0x01
    STOP = 0x02
    ENTER_PRE_OPERATIONAL = 0x80
    RESET_NODE = 0x81
    RESET_COMMUNICATION = 0x82


class ResetKind(str, Enum):
    """What a reset re-initialises (CiA 301 7.3.2.2.1): the application resets every object
    (manufacturer 0x2000-0x5FFF and profile 0x6000-0x9FFF areas too), the communication reset
    only the communication profile area 0x1000-0x1FFF."""

    APPLICATION = "application"
    COMMUNICATION = "communication"


_S = NmtState
_C = NmtCommand

#: (state, command) -> next state, for the states that listen to NMT. Reset commands lead to
#: INITIALISING; `RESETS` says which reset.
TRANSITIONS: dict[tuple[NmtState, NmtCommand], NmtState] = {}
for _state in (_S.PRE_OPERATIONAL, _S.OPERATIONAL, _S.STOPPED):
    TRANSITIONS[(_state, _C.START)] = _S.OPERATIONAL  # (3), (6)
    TRANSITIONS[(_state, _C.STOP)] = _S.STOPPED  # (5), (8)
    TRANSITIONS[(_state, _C.ENTER_PRE_OPERATIONAL)] = _S.PRE_OPERATIONAL  # (4), (7)
    TRANSITIONS[(_state, _C.RESET_NODE)] = _S.INITIALISING  # (9)..(11)
    TRANSITIONS[(_state, _C.RESET_COMMUNICATION)] = _S.INITIALISING  # (12)..(14)
del _state

#: the reset a command asks for
RESETS: dict[NmtCommand, ResetKind] = {
    _C.RESET_NODE: ResetKind.APPLICATION,
    _C.RESET_COMMUNICATION: ResetKind.COMMUNICATION,
}

#: communication objects active in each state (CiA 301 table "NMT states and communication objects")
SERVICES: dict[NmtState, frozenset[str]] = {
    _S.INITIALISING: frozenset({"boot-up"}),
    _S.PRE_OPERATIONAL: frozenset({"sdo", "sync", "time", "emcy", "nmt", "error-control"}),
    _S.OPERATIONAL: frozenset({"pdo", "sdo", "sync", "time", "emcy", "nmt", "error-control"}),
    _S.STOPPED: frozenset({"nmt", "error-control"}),
}


def next_state(state: NmtState, command: int) -> NmtState | None:
    """The state ``command`` leads to from ``state`` (CiA 301 7.3.2.2), or None when the node
    ignores it: an unknown command specifier, or any command while initialising."""
    try:
        cmd = NmtCommand(command)
    except ValueError:
        return None
    return TRANSITIONS.get((state, cmd))


def allows(state: NmtState, service: str) -> bool:
    """Whether ``service`` ('pdo', 'sdo', 'sync', 'time', 'emcy', 'nmt', 'error-control',
    'boot-up') works in ``state`` (CiA 301 table of NMT states and communication objects)."""
    if service not in SERVICES[NmtState.OPERATIONAL] | {"boot-up"}:
        raise ValueError(f"unknown communication object {service!r}")
    return service in SERVICES[state]


def state_name(code: int) -> str:
    """The state's name for a heartbeat byte (toggle bit masked off), 'UNKNOWN(n)' otherwise."""
    try:
        return NmtState(code & 0x7F).name
    except ValueError:
        return f"UNKNOWN({code & 0x7F})"
