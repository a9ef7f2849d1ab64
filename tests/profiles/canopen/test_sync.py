"""SYNC on the simulated bus (CiA 301 7.2.5): producer through 0x1005 bit 30 and 0x1006, the
counter of 0x1019 and its overflow, the length rule, the consumer's timeout, and the rules for
changing the objects."""

import pytest

from profiles.canopen.emcy import decode_emcy
from profiles.canopen.sdo import abort
from profiles.canopen.sdo.abort import SdoAbort
from stack import Frame

MS = 1_000_000
US = 1_000


def test_a_device_produces_sync_when_0x1005_bit_30_is_set(bus, device, spy, frames_with):
    d = device(1, heartbeat_ms=0, sync_producer=True, sync_period_us=2000)
    bus.run(until=21 * MS)
    syncs = frames_with(spy, 0x080)
    assert d.store.get(0x1005) == 0x4000_0080
    assert len(syncs) == 10 and all(f.data == b"" for _, f in syncs)  # no counter: DLC 0
    assert {b - a for (a, _), (b, _) in zip(syncs, syncs[1:])} == {2 * MS}


def test_sync_counter_runs_1_to_the_overflow_value(bus, device, spy, frames_with):
    device(1, heartbeat_ms=0, sync_producer=True, sync_period_us=1000, sync_overflow=4)
    bus.run(until=11 * MS)
    assert [f.data[0] for _, f in frames_with(spy, 0x080)] == [1, 2, 3, 4, 1, 2, 3, 4, 1, 2]


def test_the_producers_own_tpdos_follow_its_sync(bus, device, master_node, spy, frames_with):
    d = device(1, heartbeat_ms=0, sync_producer=True, sync_period_us=1000)
    master_node.send(Frame(0x000, b"\x01\x01"))
    bus.run(until=10 * MS)
    syncs = [t for t, _ in frames_with(spy, 0x080)]
    pdos = [t for t, _ in frames_with(spy, 0x181)]
    assert len(pdos) >= 8 and all(any(0 < p - s < 500 * US for s in syncs) for p in pdos)
    assert d.sync.received == len(syncs)


def test_a_sync_of_the_wrong_length_is_ignored_and_reported(bus, device, master_node, spy, frames_with):
    d = device(2, heartbeat_ms=0)
    master_node.send(Frame(0x000, b"\x01\x02"))
    master_node.send(Frame(0x080, b"\x01"))  # a counter while 0x1019 is 0
    bus.run(until=5 * MS)
    assert frames_with(spy, 0x182) == [] and d.sync.received == 0
    ((_, f),) = frames_with(spy, 0x82)
    assert decode_emcy(f.data).code == 0x8240  # unexpected SYNC data length (CANopenNode)
    assert f.data[3] == 1  # the length received


def test_the_consumer_reports_a_missing_sync_after_one_and_a_half_periods(bus, device, master_node, spy, frames_with):
    d = device(2, heartbeat_ms=0, sync_period_us=10_000)
    master_node.send(Frame(0x080))
    bus.run(until=1 * MS)
    t_sync = d.sync.last
    bus.run(until=t_sync + 14_999 * US)
    assert frames_with(spy, 0x82) == []
    bus.run(until=t_sync + 16 * MS)
    assert decode_emcy(frames_with(spy, 0x82)[0][1].data).code == 0x8100
    master_node.send(Frame(0x080))
    bus.run(until=bus.now() + 1 * MS)
    assert decode_emcy(frames_with(spy, 0x82)[-1][1].data).code == 0x0000 and d.sync.timeouts == 1


@pytest.mark.parametrize(
    "index, value, code",
    [
        (0x1019, 1, abort.INVALID_VALUE),  # 1 is reserved
        (0x1019, 241, abort.INVALID_VALUE),
        (0x1005, 0x8000_0080, abort.INVALID_VALUE),  # bit 31 must be 0
        (0x1005, 0x0000_0701, abort.INVALID_VALUE),  # restricted CAN-ID
    ],
)
def test_sync_objects_refuse_reserved_values(bus, device, index, value, code):
    d = device(2, heartbeat_ms=0)
    with pytest.raises(SdoAbort) as exc:
        d.store.sdo_write(index, 0, value.to_bytes(1 if index == 0x1019 else 4, "little"))
    assert exc.value.code == code


def test_the_counter_overflow_can_change_only_while_the_period_is_0(bus, device):
    d = device(2, heartbeat_ms=0, sync_period_us=1000)
    with pytest.raises(SdoAbort) as exc:
        d.store.sdo_write(0x1019, 0, b"\x04")
    assert exc.value.code == abort.DEVICE_STATE  # CANopenNode: ODR_DATA_DEV_STATE
    d.store.sdo_write(0x1006, 0, bytes(4))
    d.store.sdo_write(0x1019, 0, b"\x04")
    assert d.sync.overflow == 4


def test_the_producer_cannot_change_its_can_id_while_producing(bus, device):
    d = device(2, heartbeat_ms=0, sync_producer=True, sync_period_us=1000)
    with pytest.raises(SdoAbort) as exc:
        d.store.sdo_write(0x1005, 0, (0x4000_0090).to_bytes(4, "little"))
    assert exc.value.code == abort.INVALID_VALUE
    d.store.sdo_write(0x1005, 0, (0x0000_0080).to_bytes(4, "little"))  # stop producing first
    d.store.sdo_write(0x1005, 0, (0x4000_0090).to_bytes(4, "little"))
    assert d.sync.cob_id == 0x90 and d.sync.producer
