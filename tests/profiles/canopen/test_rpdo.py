"""Receive PDOs on the simulated bus (CiA 301 7.2.2): they write the dictionary (synchronous
ones at the next SYNC), call the application, and report a wrong length (CANopenNode's EMCY
codes)."""

from profiles.canopen.emcy import decode_emcy
from stack import Frame

MS = 1_000_000


def start(bus, master_node, nid):
    master_node.send(Frame(0x000, bytes([0x01, nid])))
    bus.run(until=bus.now() + 2 * MS)


def test_an_asynchronous_rpdo_writes_its_objects_and_calls_the_application(bus, device, master_node):
    d = device(4, heartbeat_ms=0)  # RPDO1 (0x204, type 255) -> 0x2100 digital outputs
    updates = []
    d.on_rpdo(updates.append)
    start(bus, master_node, 4)
    master_node.send(Frame(0x204, b"\xa5"))
    bus.run(until=bus.now() + 1 * MS)
    assert d.read(0x2100) == 0xA5
    (u,) = updates
    assert (u.n, u.cob_id, u.values) == (1, 0x204, {(0x2100, 0): 0xA5})


def test_a_synchronous_rpdo_takes_effect_at_the_next_sync(bus, device, master_node):
    d = device(4, heartbeat_ms=0)  # RPDO2 (0x304, type 1) -> 0x2101:1, 0x2101:2 (INTEGER16)
    start(bus, master_node, 4)
    master_node.send(Frame(0x304, (1000).to_bytes(2, "little") + (-2).to_bytes(2, "little", signed=True)))
    bus.run(until=bus.now() + 1 * MS)
    assert (d.read(0x2101, 1), d.read(0x2101, 2)) == (0, 0)
    master_node.send(Frame(0x304, (1001).to_bytes(2, "little") + (-3).to_bytes(2, "little", signed=True)))
    bus.run(until=bus.now() + 1 * MS)
    master_node.send(Frame(0x080))
    bus.run(until=bus.now() + 1 * MS)
    assert (d.read(0x2101, 1), d.read(0x2101, 2)) == (1001, -3)  # the last one before the SYNC


def test_an_rpdo_shorter_than_its_mapping_is_not_processed_and_is_an_emcy(bus, device, master_node, spy, frames_with):
    d = device(4, heartbeat_ms=0)  # RPDO3 (0x404) -> 0x2102, UNSIGNED32: 4 bytes
    start(bus, master_node, 4)
    master_node.send(Frame(0x404, b"\x01\x02"))
    bus.run(until=bus.now() + 1 * MS)
    assert d.read(0x2102) == 0
    ((_, f),) = frames_with(spy, 0x84)
    e = decode_emcy(f.data)
    assert e.code == 0x8210 and e.register & 0x10  # PDO not processed due to length error
    master_node.send(Frame(0x404, b"\x01\x02\x03\x04"))  # the right length clears the error
    bus.run(until=bus.now() + 1 * MS)
    assert d.read(0x2102) == 0x04030201
    assert decode_emcy(frames_with(spy, 0x84)[-1][1].data).code == 0x0000


def test_a_longer_rpdo_is_processed_and_reported(bus, device, master_node, spy, frames_with):
    d = device(4, heartbeat_ms=0)
    start(bus, master_node, 4)
    master_node.send(Frame(0x404, b"\x01\x02\x03\x04\x05"))
    bus.run(until=bus.now() + 1 * MS)
    assert d.read(0x2102) == 0x04030201
    assert decode_emcy(frames_with(spy, 0x84)[0][1].data).code == 0x8220  # PDO length exceeded


def test_rpdo_event_timer_reports_a_missing_rpdo(bus, device, master_node, spy, frames_with):
    d = device(4, heartbeat_ms=0, rpdo={1: {"event_timer_ms": 20}})
    start(bus, master_node, 4)
    bus.run(until=bus.now() + 50 * MS)
    assert frames_with(spy, 0x84) == []  # monitoring starts with the first RPDO
    master_node.send(Frame(0x204, b"\x01"))
    bus.run(until=bus.now() + 19 * MS)
    assert frames_with(spy, 0x84) == []
    bus.run(until=bus.now() + 2 * MS)
    assert decode_emcy(frames_with(spy, 0x84)[0][1].data).code == 0x8250 and d.rpdo(1).timeouts == 1


def test_rpdos_outside_operational_are_ignored(bus, device, master_node):
    d = device(4, heartbeat_ms=0)
    master_node.send(Frame(0x204, b"\x11"))
    bus.run(until=bus.now() + 2 * MS)
    assert d.read(0x2100) == 0 and d.rpdo(1).received == 0


def test_a_value_outside_the_objects_limits_is_skipped(bus, device, master_node):
    d = device(4, heartbeat_ms=0, rpdo={1: {"mapping": ["0x2003:0/16"]}})  # temperature -400..1250
    start(bus, master_node, 4)
    master_node.send(Frame(0x204, (2000).to_bytes(2, "little")))
    bus.run(until=bus.now() + 1 * MS)
    assert d.read(0x2003) == 250 and d.rpdo(1).rejected == 1


def test_an_rpdo_that_writes_a_mapped_object_triggers_an_event_driven_tpdo(bus, device, master_node, spy, frames_with):
    device(4, heartbeat_ms=0, rpdo={1: {"mapping": ["0x2001:1/16"]}})  # TPDO2 (255) maps 0x2001:1
    start(bus, master_node, 4)
    n = len(frames_with(spy, 0x284))
    master_node.send(Frame(0x204, (77).to_bytes(2, "little")))
    bus.run(until=bus.now() + 1 * MS)
    frames = frames_with(spy, 0x284)
    assert len(frames) == n + 1 and frames[-1][1].data[:2] == (77).to_bytes(2, "little")
