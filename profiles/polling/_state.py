"""The poll-list master's state machine, as tables and nothing else.

Like `profiles.canopen._state` (and h11's ``_state.py``): a pure transition table that
`profiles.polling.master` imports, never the reverse. It holds no node, no timer and no frame.

States: ``idle`` between cycles (and in a cycle before its first request), ``sending`` while a
request waits for the bus, ``waiting`` for the answer(s) once it went out, ``stopped`` after bus
off, ``communication fault`` after its duplicate MAC ID check found another node with its MAC ID. Events, and what each means in each state (an event a state has no entry for is ignored
there — an answer that comes while the request is still queued, a timeout after bus off):

    CYCLE_START  idle                    -> idle      a cycle begins (its slaves due are chosen)
    REQUEST      idle, sending, waiting  -> sending   the next request (or a retry) is queued
    SENT         sending                 -> waiting   the request went out (TxDone): the slaves'
                                                      timeout runs from its SOF
    UNSENT       sending                 -> sending   the bus could not take it by its latest start
    ANSWER       waiting                 -> waiting   an awaited slave answered in time
    TIMEOUT      sending, waiting        -> same      the timeout passed: retry, miss, or go on
    COS          idle, sending, waiting  -> same      a change-of-state message to acknowledge
    CYCLE_END    idle, sending, waiting  -> idle      the last transaction of the cycle ended
    BUS_OFF      idle, sending, waiting  -> stopped   the controller went bus off (rule 10)
    RECOVERED    stopped                 -> idle      error active again (rule 12) and the master
                                                      restarts after bus off
    COMM_FAULT   idle, sending, waiting  -> faulted   a duplicate of its MAC ID (DeviceNet's
                                                      communication fault: for good)

``faulted`` ignores every event: only a power cycle (a new run) leaves it.
"""

from __future__ import annotations

from enum import Enum

__all__ = ["MasterState", "MasterEvent", "TRANSITIONS", "next_state"]


class MasterState(str, Enum):
    """The master's states (their values are what the results print)."""

    IDLE = "idle"
    SENDING = "sending"
    WAITING = "waiting"
    STOPPED = "stopped"
    FAULTED = "communication fault"


class MasterEvent(str, Enum):
    """What happens to a master (see the module docstring)."""

    CYCLE_START = "cycle start"
    REQUEST = "request"
    SENT = "sent"
    UNSENT = "unsent"
    ANSWER = "answer"
    TIMEOUT = "timeout"
    COS = "cos"
    CYCLE_END = "cycle end"
    BUS_OFF = "bus off"
    RECOVERED = "recovered"
    COMM_FAULT = "communication fault"


_S = MasterState
_E = MasterEvent
_RUNNING = (_S.IDLE, _S.SENDING, _S.WAITING)

#: (state, event) -> next state; a pair missing from the table is an event the state ignores.
TRANSITIONS: dict[tuple[MasterState, MasterEvent], MasterState] = {
    (_S.IDLE, _E.CYCLE_START): _S.IDLE,
    (_S.SENDING, _E.SENT): _S.WAITING,
    (_S.SENDING, _E.UNSENT): _S.SENDING,
    (_S.WAITING, _E.ANSWER): _S.WAITING,
    (_S.SENDING, _E.TIMEOUT): _S.SENDING,
    (_S.WAITING, _E.TIMEOUT): _S.WAITING,
    (_S.STOPPED, _E.RECOVERED): _S.IDLE,
}
for _state in _RUNNING:
    TRANSITIONS[(_state, _E.REQUEST)] = _S.SENDING
    TRANSITIONS[(_state, _E.COS)] = _state
    TRANSITIONS[(_state, _E.CYCLE_END)] = _S.IDLE
    TRANSITIONS[(_state, _E.BUS_OFF)] = _S.STOPPED
    TRANSITIONS[(_state, _E.COMM_FAULT)] = _S.FAULTED
del _state


def next_state(state: MasterState, event: MasterEvent) -> MasterState | None:
    """The state ``event`` leads to from ``state``, or None when the master ignores it there."""
    return TRANSITIONS.get((state, event))
