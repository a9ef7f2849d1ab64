"""EMCY producer (CiA 301 7.2.7; objects 0x1001, 0x1003, 0x1014, 0x1015) decoded by the
``canopen`` library's EMCY consumer, and TIME (7.2.6) against the library's TIME producer."""

import pytest
from canopen.sdo import SdoAbortedError
from canopen.timestamp import TIME_OF_DAY_STRUCT, TimeProducer

from profiles.canopen.emcy import decode_emcy, describe, register_bits
from profiles.canopen.timestamp import decode_time_of_day, encode_time_of_day
from stack import Frame

MS = 1_000_000
REMOTE_OPTIONS = {"heartbeat_ms": 0}  # the `remote` fixture's device: no heartbeat frames


def test_emcy_message_layout_decoded_by_the_library(remote, lib, spy, frames_with):
    dev, node = remote
    dev.report_error(0x4210, b"\x01\x02\x03")  # temperature: device
    lib.run(1 * MS)
    ((_, f),) = frames_with(spy, 0x85)  # COB-ID 0x80 + node-ID
    assert f.data == bytes([0x10, 0x42, 0x09, 1, 2, 3, 0, 0])  # code LE, register, 5 bytes
    (e,) = node.emcy.active
    assert (e.code, e.register, e.data) == (0x4210, 0x09, b"\x01\x02\x03\x00\x00")
    assert e.get_desc() == "Temperature" and describe(0x4210) == "temperature"


def test_error_register_history_and_reset(remote, lib):
    dev, node = remote
    dev.report_error(0x2310, b"")  # current
    dev.report_error(0x3120, b"")  # voltage
    dev.report_error(0x2310, b"")  # active already: no second EMCY
    lib.run(2 * MS)
    assert len(node.emcy.log) == 2
    assert node.sdo[0x1001].raw == 0x01 | 0x02 | 0x04
    assert node.sdo[0x1003][0].raw == 2
    assert node.sdo[0x1003][1].raw == 0x3120 and node.sdo[0x1003][2].raw == 0x2310  # newest first
    dev.clear_error(0x2310)
    dev.clear_error(0x3120)
    lib.run(2 * MS)
    assert node.emcy.log[-1].code == 0x0000 and node.emcy.active == []
    assert node.sdo[0x1001].raw == 0
    node.sdo[0x1003][0].raw = 0  # writing 0 clears the history
    assert node.sdo[0x1003][0].raw == 0
    with pytest.raises(SdoAbortedError) as exc:
        node.sdo[0x1003][1].raw
    assert exc.value.code == 0x0800_0024


def test_register_bits_per_cia_301():
    assert register_bits(0x1000) == 0x01
    assert register_bits(0x2100) == 0x03
    assert register_bits(0x3300) == 0x05
    assert register_bits(0x4200) == 0x09
    assert register_bits(0x8130) == 0x11 and register_bits(0x8210) == 0x11
    assert register_bits(0xFF01) == 0x81


def test_inhibit_time_spaces_emcy_messages(bus, device, spy, frames_with, master_node):
    dev = device(5, heartbeat_ms=0, emcy_inhibit_100us=20)  # 2 ms
    starts = []
    bus.node("sof-spy").subscribe(lambda ev: starts.append(ev.sof) if ev.frame.can_id == 0x85 else None)
    bus.run(until=2 * MS)
    for code in (0x1000, 0x2000, 0x3000):
        dev.report_error(code)
    bus.run(until=20 * MS)
    assert [decode_emcy(f.data).code for _, f in frames_with(spy, 0x85)] == [0x1000, 0x2000, 0x3000]
    assert all(b - a >= 2 * MS for a, b in zip(starts, starts[1:]))


def test_emcy_waits_while_stopped(bus, device, spy, frames_with, master_node):
    dev = device(5, heartbeat_ms=0)
    master_node.send(Frame(0x000, b"\x02\x05"))
    bus.run(until=2 * MS)
    dev.report_error(0x1000)
    bus.run(until=5 * MS)
    assert frames_with(spy, 0x85) == []  # no EMCY in stopped (CiA 301 NMT table)
    master_node.send(Frame(0x000, b"\x80\x05"))
    bus.run(until=8 * MS)
    assert decode_emcy(frames_with(spy, 0x85)[0][1].data).code == 0x1000


def test_emcy_disabled_through_bit_31_of_0x1014(remote, lib, spy, frames_with):
    dev, node = remote
    node.sdo[0x1014].raw = 0x8000_0085
    dev.report_error(0x1000)
    lib.run(2 * MS)
    assert frames_with(spy, 0x85) == []


def test_time_of_day_matches_the_canopen_library():
    unix = 1_700_000_000.250
    sent = []

    class Net:
        def send_message(self, can_id, data):
            sent.append((can_id, data))

    TimeProducer(Net()).transmit(unix)
    cob, data = sent[0]
    assert cob == 0x100 and data == encode_time_of_day(int(unix * 1000))
    ms, days = TIME_OF_DAY_STRUCT.unpack(data)
    assert decode_time_of_day(data) == int(unix * 1000)
    assert days == (int(unix) - 441_763_200) // 86_400  # days since 1984-01-01


def test_time_producer_and_consumer(bus, device, spy, frames_with, master_node):
    producer = device(1, heartbeat_ms=0, time_producer_ms=10, time_epoch_s=1_700_000_000)
    consumer = device(2, heartbeat_ms=0)  # the default EDS consumes TIME (0x1012 bit 31)
    got = []
    consumer.on_time(got.append)
    bus.run(until=35 * MS)
    frames = frames_with(spy, 0x100)
    assert len(frames) == 4 and producer.store.get(0x1012) == 0xC000_0100
    assert got == [decode_time_of_day(f.data) for _, f in frames]
    assert got[1] - got[0] == 10  # ms of node time between two
