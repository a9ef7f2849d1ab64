"""Error control on the simulated bus: heartbeat producer (0x1017) and consumer (0x1016) with
the heartbeat event, node guarding with the toggle bit and life guarding (CiA 301 7.2.8.3.2)."""

import canopen
import pytest

from profiles.canopen.dictionary import DEFAULT_EDS
from profiles.canopen.emcy import decode_emcy
from profiles.canopen.sdo.abort import SdoAbort
from stack import Frame

MS = 1_000_000


def test_producer_sends_every_period_on_its_grid(bus, device, spy, frames_with):
    device(2, heartbeat_ms=20)
    bus.run(until=205 * MS)
    hb = frames_with(spy, 0x702)
    assert hb[0][1].data == b"\x00"  # boot-up first
    beats = [t for t, f in hb[1:]]
    assert [f.data for _, f in hb[1:]] == [b"\x7f"] * 10  # pre-operational, 127
    gaps = {b - a for a, b in zip(beats, beats[1:])}
    assert gaps == {20 * MS}  # exactly the producer time: no drift from callback latency


def test_writing_0x1017_changes_the_period_and_0_stops_it(bus, device, lib, spy, frames_with):
    device(2, heartbeat_ms=20)
    node = canopen.RemoteNode(2, str(DEFAULT_EDS))
    lib.add_node(node)
    lib.run(50 * MS)
    node.sdo[0x1017].raw = 5
    n = len(spy)
    lib.run(50 * MS)
    beats = [t for t, _ in frames_with(spy[n:], 0x702)]
    assert {b - a for a, b in zip(beats, beats[1:])} == {5 * MS}
    node.sdo[0x1017].raw = 0
    n = len(spy)
    lib.run(50 * MS)
    assert frames_with(spy[n:], 0x702) == []


def test_the_canopen_library_follows_the_heartbeat(bus, device, lib, master_node):
    device(2, heartbeat_ms=10)
    node = canopen.RemoteNode(2, str(DEFAULT_EDS))
    lib.add_node(node)
    lib.run(30 * MS)
    assert node.nmt.state == "PRE-OPERATIONAL"
    node.nmt.state = "OPERATIONAL"  # the library sends NMT start
    lib.run(30 * MS)
    assert node.nmt.state == "OPERATIONAL"
    node.nmt.state = "STOPPED"
    lib.run(30 * MS)
    assert node.nmt.state == "STOPPED"


def test_consumer_reports_a_lost_heartbeat_with_emcy_0x8130_and_clears_it(bus, device, lib, spy, frames_with):
    watcher = device(1, heartbeat_ms=0, heartbeat_consumers={3: 25})
    watched = device(3, heartbeat_ms=10)
    node = canopen.RemoteNode(1, str(DEFAULT_EDS))
    lib.add_node(node)  # the library's EMCY consumer decodes what the watcher sends
    lib.run(100 * MS)
    assert watcher.consumer.nodes[3].status == "active" and node.emcy.log == []
    watched.stop()
    t_stop = bus.now()
    lib.run(100 * MS)
    emcy = frames_with(spy, 0x81)
    assert len(emcy) == 1 and emcy[0][0] - t_stop <= 25 * MS + 1 * MS
    assert node.emcy.active[0].code == 0x8130 and node.emcy.active[0].register & 0x11 == 0x11
    assert node.emcy.active[0].data[0] == 3  # which node (CANopenNode puts it in the info)
    assert watcher.read(0x1001) == 0x11  # generic + communication
    assert watcher.read(0x1003, 0) == 1 and watcher.read(0x1003, 1) & 0xFFFF == 0x8130
    m = watcher.consumer.nodes[3]
    assert m.timeouts == 1 and m.missed == (bus.now() - m.last) // (25 * MS)  # each consumer time of silence
    watched.start()  # boot-up, then heartbeats again: the error goes, error reset EMCY
    lib.run(100 * MS)
    assert node.emcy.active == [] and node.emcy.log[-1].code == 0x0000
    assert watcher.read(0x1001) == 0


def test_consumer_entries_are_checked(bus, device):
    d = device(1, heartbeat_ms=0, heartbeat_consumers={3: 25})
    with pytest.raises(SdoAbort) as exc:
        d.store.sdo_write(0x1016, 2, ((3 << 16) | 50).to_bytes(4, "little"))
    assert exc.value.code == 0x0604_0043  # node 3 monitored twice: parameter incompatibility
    with pytest.raises(SdoAbort) as exc:
        d.store.sdo_write(0x1016, 2, ((1 << 24) | (4 << 16) | 50).to_bytes(4, "little"))
    assert exc.value.code == 0x0609_0030


def test_node_guarding_replies_with_toggle_bit_and_state(bus, device, master_node, spy, frames_with):
    device(8, heartbeat_ms=0)
    replies = []
    for _ in range(4):
        master_node.send(Frame(0x708, remote=True, dlc=1))
        bus.run(until=bus.now() + 2 * MS)
    master_node.send(Frame(0x000, b"\x01\x08"))
    for _ in range(2):
        master_node.send(Frame(0x708, remote=True, dlc=1))
        bus.run(until=bus.now() + 2 * MS)
    replies = [f.data[0] for _, f in frames_with(spy, 0x708)][1:]  # after the boot-up message
    # bit 7 toggles from 0, bits 6..0 the state: 127 pre-operational, then 5 operational
    assert replies == [0x7F, 0xFF, 0x7F, 0xFF, 0x05, 0x85]


def test_node_guarding_is_not_answered_while_the_heartbeat_runs(bus, device, master_node, spy, frames_with):
    device(8, heartbeat_ms=1000)
    master_node.send(Frame(0x708, remote=True, dlc=1))
    bus.run(until=5 * MS)
    assert [f.data for _, f in frames_with(spy, 0x708)] == [b"\x00"]  # the boot-up only


def test_life_guarding_event_after_guard_time_times_life_time_factor(bus, device, master_node, spy, frames_with):
    d = device(8, heartbeat_ms=0, guard_time_ms=10, life_time_factor=3)
    master_node.send(Frame(0x708, remote=True, dlc=1))
    bus.run(until=5 * MS)
    t_request = frames_with(spy, 0x708, remote=True)[0][0]
    bus.run(until=t_request + 29 * MS)
    assert frames_with(spy, 0x88) == []
    bus.run(until=t_request + 31 * MS)
    ((t, f),) = frames_with(spy, 0x88)
    assert decode_emcy(f.data).code == 0x8130 and d.guarding.life_guarding_events == 1
    master_node.send(Frame(0x708, remote=True, dlc=1))  # guarding again: error reset
    bus.run(until=bus.now() + 3 * MS)
    assert decode_emcy(frames_with(spy, 0x88)[-1][1].data).code == 0x0000


def test_master_guards_nodes_and_sees_a_missing_reply(bus, device):
    from profiles.canopen import CanopenMaster

    d = device(8, heartbeat_ms=0)
    m = CanopenMaster(bus.node("m"), nodes=[8], node_guarding_ms=20, reset_nodes=False, read_pdo_config=False)
    m.start()
    bus.run(until=5 * MS)
    d.stop()
    d.start()  # a boot-up the master sees
    bus.run(until=200 * MS)
    g = m.guarding.nodes[8]
    assert g.replies >= 9 and g.toggle_errors == 0 and g.missed == 0 and m.node_state(8) == "OPERATIONAL"
    d.stop()
    bus.run(until=300 * MS)
    assert g.missed >= 4 and ("guarding: no reply" in [w for _, n, w in m.events])
