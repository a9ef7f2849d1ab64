"""Alive counters and checksums: applied at transmission, verified at reception, failures reported."""

from pathlib import Path

import cantools
import pytest
from crccheck.crc import Crc8Autosar, Crc8SaeJ1850
from hypothesis import given
from hypothesis import strategies as st

from dbc.checks import E2E, AliveCounter, Checksum, crc8_autosar, crc8_sae_j1850, sum8, xor8
from dbc.ecu import Ecu
from dbc.errors import UnknownNameError, load_database
from stack.bus.sim import SimBus
from stack.wire.frame import Frame

SAMPLE = Path(__file__).resolve().parents[2] / "dbc" / "databases" / "powertrain_body.dbc"
MS = 1_000_000


def test_crc8_check_values():
    assert crc8_sae_j1850(b"123456789") == 0x4B
    assert crc8_autosar(b"123456789") == 0xDF


@given(st.binary(max_size=8))
def test_checksums_against_independent_references(data):
    assert crc8_sae_j1850(data) == Crc8SaeJ1850.calc(data)
    assert crc8_autosar(data) == Crc8Autosar.calc(data)
    x = 0
    for b in data:
        x ^= b
    assert xor8(data) == x
    assert sum8(data) == sum(data) % 256


def test_sample_counter_and_crc_on_the_wire():
    db = load_database(SAMPLE)
    bus = SimBus(500_000)
    Ecu(db, "ECM", bus.node("ECM"))
    ipc = Ecu(db, "IPC", bus.node("IPC"))
    bus.run(until=200 * MS)
    frames = [r.frame for r in bus.trace if r.frame.can_id == 0x100]
    assert len(frames) == 20
    counters = [f.data[6] & 0x0F for f in frames]
    assert counters == [k % 16 for k in range(20)]  # 4-bit counter wraps 15 -> 0
    for f in frames:
        assert f.data[7] == Crc8SaeJ1850.calc(f.data[:7])
    assert ipc.failed_checks == 0
    assert ipc.get("EngineCounter") == 19 % 16


def test_xor_checksum_of_gearbox():
    db = load_database(SAMPLE)
    bus = SimBus(500_000)
    Ecu(db, "TCM", bus.node("TCM"))
    bus.node("l").subscribe(lambda ev: None)
    bus.run(until=100 * MS)
    for r in bus.trace:
        d = r.frame.data
        assert d[7] == d[0] ^ d[1] ^ d[2] ^ d[3] ^ d[4] ^ d[5] ^ d[6]


def test_failures_reported_not_ignored():
    db = load_database(SAMPLE)
    bus = SimBus(500_000)
    ipc = Ecu(db, "IPC", bus.node("IPC"))
    fails = []
    ipc.on_check_failed(fails.append)
    rogue = bus.node("rogue")
    msg = db.get_message_by_name("EngineData")

    def good(counter):
        data = bytearray(
            msg.encode(
                {
                    "EngineSpeed": 1000,
                    "EngineTemp": 20,
                    "ThrottlePosition": 0,
                    "EngineTorque": 0,
                    "EngineCounter": counter,
                    "EngineChecksum": 0,
                }
            )
        )
        data[7] = Crc8SaeJ1850.calc(bytes(data[:7]))
        return bytes(data)

    rogue.send(Frame(0x100, good(3)))
    rogue.send(Frame(0x100, good(4)))
    rogue.send(Frame(0x100, good(4)))  # repeated counter
    bad = bytearray(good(5))
    bad[7] ^= 0xFF
    rogue.send(Frame(0x100, bytes(bad)))  # wrong CRC (counter 5 is fine)
    bus.run(duration=5 * MS)
    reasons = [f.reason for f in fails]
    assert reasons == [
        "alive counter EngineCounter = 4, expected 5 (repeated)",
        f"checksum EngineChecksum = 0x{bad[7]:02X}, expected 0x{bad[7] ^ 0xFF:02X}",
    ]
    assert ipc.check_failures == {
        ("EngineData", "counter EngineCounter"): 1,
        ("EngineData", "checksum EngineChecksum (crc8_sae_j1850)"): 1,
    }
    # a failed frame's values are not applied
    assert ipc.get("EngineCounter") == 4


def test_counter_wraps_in_dbc_range_and_custom_checksum():
    text = (
        'VERSION ""\nBS_:\nBU_: A B\nBO_ 5 M: 3 A\n SG_ Cnt : 0|4@1+ (1,0) [2|5] "" B\n'
        ' SG_ Val : 8|8@1+ (1,0) [0|255] "" B\n SG_ Cs : 16|8@1+ (1,0) [0|255] "" B\n'
    )
    db = cantools.database.load_string(text)
    bus = SimBus(500_000)
    a = Ecu(
        db, "A", bus.node("A"), checks=[AliveCounter("M", "Cnt"), Checksum("M", "Cs", lambda b: (sum(b) + 7) & 0xFF)]
    )
    b = Ecu(
        db, "B", bus.node("B"), checks=[AliveCounter("M", "Cnt"), Checksum("M", "Cs", lambda b: (sum(b) + 7) & 0xFF)]
    )
    a.set("Val", 9)
    for _ in range(6):
        a.send("M")
    bus.run(duration=10 * MS)
    frames = [r.frame for r in bus.trace]
    assert [f.data[0] for f in frames] == [2, 3, 4, 5, 2, 3]
    assert all(f.data[2] == (f.data[0] + 9 + 7) & 0xFF for f in frames)
    assert b.failed_checks == 0
    with pytest.raises(UnknownNameError, match="crc8_sae_j1850"):
        Checksum("M", "Cs", "crc8_sae_j1851")


def test_e2e_profile2_through_cantools():
    from cantools.autosar import check_profile2_crc

    text = (
        'VERSION ""\nBS_:\nBU_: A B\nBO_ 9 P: 8 A\n SG_ Crc : 0|8@1+ (1,0) [0|255] "" B\n'
        ' SG_ Ctr : 8|4@1+ (1,0) [0|15] "" B\n SG_ Val : 16|16@1+ (1,0) [0|65535] "" B\n'
    )
    db = cantools.database.load_string(text)
    bus = SimBus(500_000)
    hooks = [AliveCounter("P", "Ctr"), E2E("P", profile=2, data_id=0x42)]
    a = Ecu(db, "A", bus.node("A"), checks=hooks)
    b = Ecu(db, "B", bus.node("B"), checks=[AliveCounter("P", "Ctr"), E2E("P", profile=2, data_id=0x42)])
    for v in (1, 2, 3):
        a.send("P", {"Val": v})
    bus.run(duration=5 * MS)
    frames = [r.frame for r in bus.trace]
    assert all(check_profile2_crc(f.data, 0x42) for f in frames)
    assert b.failed_checks == 0 and b.get("Val") == 3
    bus.node("rogue").send(Frame(9, bytes(8)))
    bus.run(duration=1 * MS)
    assert ("P", "E2E profile 2") in b.check_failures
