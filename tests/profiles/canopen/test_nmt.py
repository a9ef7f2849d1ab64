"""NMT slave behaviour on the simulated bus (CiA 301 7.3.2): boot-up, commands, state gating
of PDO and SDO, resets — checked on the wire with CiA 301's COB-IDs and codes."""

import canopen
import pytest
from canopen.sdo import SdoCommunicationError

from profiles.canopen._state import NmtState
from profiles.canopen.dictionary import DEFAULT_EDS
from stack import Frame

MS = 1_000_000


def nmt(master_node, bus, cs, node_id=0, run_ms=5):
    master_node.send(Frame(0x000, bytes([cs, node_id])))
    bus.run(until=bus.now() + run_ms * MS)


def test_boot_up_message_then_pre_operational(bus, device, spy, frames_with):
    d = device(9, heartbeat_ms=0)
    bus.run(until=5 * MS)
    boot = frames_with(spy, 0x709)
    assert [f.data for _, f in boot] == [b"\x00"]  # CiA 301 7.2.8.3.2: 0x700 + node-ID, one byte 0
    assert d.state is NmtState.PRE_OPERATIONAL
    assert [s for _, s in d.state_log] == ["PRE_OPERATIONAL"]


def test_boot_delay_and_self_starting_device(bus, device, spy, frames_with):
    d = device(9, heartbeat_ms=0, boot_delay_ms=3, start_operational=True)
    bus.run(until=2 * MS)
    assert frames_with(spy, 0x709) == [] and d.state is NmtState.INITIALISING
    bus.run(until=5 * MS)
    assert frames_with(spy, 0x709)[0][0] >= 3 * MS and d.state is NmtState.OPERATIONAL


def test_commands_follow_the_transition_table_and_the_heartbeat_reports_each_state(
    bus, device, master_node, spy, frames_with
):
    d = device(4, heartbeat_ms=100)
    bus.run(until=2 * MS)
    for cs, state, code in (
        (0x01, NmtState.OPERATIONAL, 5),
        (0x02, NmtState.STOPPED, 4),
        (0x80, NmtState.PRE_OPERATIONAL, 127),
        (0x02, NmtState.STOPPED, 4),
        (0x01, NmtState.OPERATIONAL, 5),
        (0x80, NmtState.PRE_OPERATIONAL, 127),
    ):
        n = len(spy)
        nmt(master_node, bus, cs, 4)
        assert d.state is state
        # as CANopenNode does, the device reports a new state at once
        assert [f.data for _, f in frames_with(spy[n:], 0x704)] == [bytes([code])]


def test_commands_for_another_node_or_malformed_are_ignored(bus, device, master_node):
    d = device(4, heartbeat_ms=0)
    bus.run(until=2 * MS)
    nmt(master_node, bus, 0x01, 5)
    assert d.state is NmtState.PRE_OPERATIONAL
    master_node.send(Frame(0x000, b"\x01"))  # one byte: not an NMT message (CANopenNode: DLC 2)
    master_node.send(Frame(0x000, b"\x01\x04\x00"))
    master_node.send(Frame(0x000, b"\x07\x04"))  # no such command specifier
    bus.run(until=bus.now() + 5 * MS)
    assert d.state is NmtState.PRE_OPERATIONAL and d.nmt.ignored == 3
    nmt(master_node, bus, 0x01, 0)  # node-ID 0: all nodes
    assert d.state is NmtState.OPERATIONAL


def test_pdos_only_in_operational(bus, device, master_node, spy, frames_with):
    d = device(6, heartbeat_ms=0)
    for _ in range(5):  # SYNC in pre-operational: TPDO1 (type 1) silent
        master_node.send(Frame(0x80))
        bus.run(until=bus.now() + 1 * MS)
    assert frames_with(spy, 0x186) == []
    nmt(master_node, bus, 0x01, 6)
    for _ in range(5):
        master_node.send(Frame(0x80))
        bus.run(until=bus.now() + 1 * MS)
    assert len(frames_with(spy, 0x186)) == 5
    nmt(master_node, bus, 0x02, 6)  # stopped: silent again, RPDOs ignored too
    n = len(spy)
    master_node.send(Frame(0x206, b"\x5a"))
    for _ in range(5):
        master_node.send(Frame(0x80))
        bus.run(until=bus.now() + 1 * MS)
    assert frames_with(spy[n:], 0x186) == [] and d.read(0x2100) == 0


def test_sdo_in_pre_operational_and_operational_but_not_stopped(bus, device, lib, master_node):
    d = device(7, heartbeat_ms=0)
    node = canopen.RemoteNode(7, str(DEFAULT_EDS))
    node.sdo.RESPONSE_TIMEOUT = 0.01  # the stopped device never answers: do not wait long
    lib.add_node(node)
    lib.run(2 * MS)
    assert node.sdo[0x1017].raw == 0
    nmt(master_node, bus, 0x01, 7)
    assert node.sdo[0x1017].raw == 0
    nmt(master_node, bus, 0x02, 7)
    with pytest.raises(SdoCommunicationError):
        node.sdo[0x1017].raw  # CiA 301: no SDO in stopped — no answer at all, as in CANopenNode
    assert d.sdo.requests == 2
    nmt(master_node, bus, 0x80, 7)
    assert node.sdo[0x1017].raw == 0


def test_reset_communication_restores_the_communication_area_only(bus, device, master_node, spy, frames_with):
    d = device(3, heartbeat_ms=0)
    bus.run(until=2 * MS)
    d.write(0x1017, 0, 500)
    d.write(0x2000, 0, 0x42)
    nmt(master_node, bus, 0x01, 3)
    n = len(spy)
    nmt(master_node, bus, 0x82, 3)
    assert next(f.data for _, f in frames_with(spy[n:], 0x703)) == b"\x00"  # boot-up again
    assert d.state is NmtState.PRE_OPERATIONAL
    assert d.read(0x1017) == 0 and d.read(0x2000) == 0x42  # 0x1000..0x1FFF reset, application kept
    assert d.resets == {"application": 0, "communication": 1}


def test_reset_node_restores_every_object(bus, device, master_node):
    d = device(3, heartbeat_ms=0)
    bus.run(until=2 * MS)
    d.write(0x2000, 0, 0x42)
    d.write(0x1017, 0, 500)
    nmt(master_node, bus, 0x81, 3)
    assert d.read(0x2000) == 0 and d.read(0x1017) == 0
    assert d.resets == {"application": 1, "communication": 0} and d.boot_ups == 2


def test_options_survive_a_reset_as_a_dcf_would(bus, device, master_node):
    d = device(3, heartbeat_ms=200, values={"0x2003": 300})
    bus.run(until=2 * MS)
    d.write(0x1017, 0, 10)
    nmt(master_node, bus, 0x81, 3)
    assert d.read(0x1017) == 200 and d.read(0x2003) == 300


def test_stop_takes_the_device_off_the_bus_silently(bus, device, spy):
    d = device(3, heartbeat_ms=10)
    bus.run(until=55 * MS)  # between two heartbeats (a frame already on the wire would finish)
    d.stop()
    n = len(spy)
    bus.run(until=200 * MS)
    assert spy[n:] == [] and d.state is NmtState.INITIALISING
