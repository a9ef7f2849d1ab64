"""The NMT slave's transition table (`profiles.canopen._state`) against CiA 301 7.3.2.2 and
the ``canopen`` library's numbers (a second implementation)."""

import pytest
from canopen.nmt import COMMAND_TO_STATE, NMT_COMMANDS, NMT_STATES

from profiles.canopen._state import SERVICES, NmtCommand, NmtState, allows, next_state, state_name

S, C = NmtState, NmtCommand


def test_state_codes_are_the_heartbeat_bytes_of_cia_301():
    # CiA 301 7.2.8.3.2: 0 boot-up, 4 stopped, 5 operational, 127 pre-operational
    assert (S.INITIALISING, S.STOPPED, S.OPERATIONAL, S.PRE_OPERATIONAL) == (0, 4, 5, 127)
    for s in S:
        assert NMT_STATES[int(s)].replace("-", "_") == s.name


def test_command_specifiers_are_cia_301s_and_the_canopen_librarys():
    assert (C.START, C.STOP, C.ENTER_PRE_OPERATIONAL, C.RESET_NODE, C.RESET_COMMUNICATION) == (1, 2, 0x80, 0x81, 0x82)
    lib = {
        "OPERATIONAL": C.START,
        "STOPPED": C.STOP,
        "PRE-OPERATIONAL": C.ENTER_PRE_OPERATIONAL,
        "RESET": C.RESET_NODE,
        "RESET COMMUNICATION": C.RESET_COMMUNICATION,
    }
    for name, cs in lib.items():
        assert NMT_COMMANDS[name] == cs


@pytest.mark.parametrize(
    "number, state, command, target",
    [
        (3, S.PRE_OPERATIONAL, C.START, S.OPERATIONAL),
        (4, S.OPERATIONAL, C.ENTER_PRE_OPERATIONAL, S.PRE_OPERATIONAL),
        (5, S.PRE_OPERATIONAL, C.STOP, S.STOPPED),
        (6, S.STOPPED, C.START, S.OPERATIONAL),
        (7, S.STOPPED, C.ENTER_PRE_OPERATIONAL, S.PRE_OPERATIONAL),
        (8, S.OPERATIONAL, C.STOP, S.STOPPED),
        (9, S.PRE_OPERATIONAL, C.RESET_NODE, S.INITIALISING),
        (10, S.OPERATIONAL, C.RESET_NODE, S.INITIALISING),
        (11, S.STOPPED, C.RESET_NODE, S.INITIALISING),
        (12, S.PRE_OPERATIONAL, C.RESET_COMMUNICATION, S.INITIALISING),
        (13, S.OPERATIONAL, C.RESET_COMMUNICATION, S.INITIALISING),
        (14, S.STOPPED, C.RESET_COMMUNICATION, S.INITIALISING),
    ],
)
def test_transition_numbered_in_cia_301_state_diagram(number, state, command, target):
    assert next_state(state, command) is target
    # the canopen library's command -> state table agrees where it has one
    assert COMMAND_TO_STATE[int(command)] == int(target)


def test_no_transition_while_initialising_and_for_unknown_specifiers():
    for cs in C:
        assert next_state(S.INITIALISING, cs) is None
    assert next_state(S.OPERATIONAL, 0x03) is None
    assert next_state(S.OPERATIONAL, 0x83) is None


def test_command_for_the_present_state_keeps_it():
    assert next_state(S.OPERATIONAL, C.START) is S.OPERATIONAL
    assert next_state(S.STOPPED, C.STOP) is S.STOPPED


def test_services_per_state_as_cia_301s_table():
    # PDO only operational; SDO, SYNC, TIME, EMCY pre-operational and operational;
    # NMT and error control also stopped; boot-up only initialising
    assert {s for s in S if allows(s, "pdo")} == {S.OPERATIONAL}
    for svc in ("sdo", "sync", "time", "emcy"):
        assert {s for s in S if allows(s, svc)} == {S.PRE_OPERATIONAL, S.OPERATIONAL}
    for svc in ("nmt", "error-control"):
        assert {s for s in S if allows(s, svc)} == {S.PRE_OPERATIONAL, S.OPERATIONAL, S.STOPPED}
    assert {s for s in S if allows(s, "boot-up")} == {S.INITIALISING}
    assert set(SERVICES) == set(S)
    with pytest.raises(ValueError, match="unknown communication object 'lss'"):
        allows(S.OPERATIONAL, "lss")


def test_state_names_mask_the_toggle_bit():
    assert state_name(0x85) == "OPERATIONAL"
    assert state_name(0x7F) == "PRE_OPERATIONAL"
    assert state_name(0x03) == "UNKNOWN(3)"
