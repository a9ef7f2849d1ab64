"""Interaction layer: transmission times measured from the trace against the DBC's attributes."""

from pathlib import Path

import cantools
import pytest

from dbc.ecu import Ecu
from dbc.errors import load_database
from dbc.interaction import SendType, attribute, message_timing, signal_timing
from stack.bus.sim import SimBus

SAMPLE = Path(__file__).resolve().parents[2] / "dbc" / "databases" / "powertrain_body.dbc"
MS = 1_000_000


def queued(bus, can_id):
    """Times the frames with this identifier were queued (the ECU's decision, before blocking)."""
    return [r.queued for r in bus.trace if r.kind == "frame" and r.frame.can_id == can_id]


@pytest.fixture
def db():
    return load_database(SAMPLE)


def one(db, node, **kw):
    bus = SimBus(500_000)
    ecu = Ecu(db, node, bus.node(node), **kw)
    bus.node("listener").subscribe(lambda ev: None)
    return bus, ecu


def test_timing_mapping_matches_dbc_text(db):
    t = message_timing(db, db.get_message_by_name("VehicleSpeed"))
    assert (t.send_type, t.cycle_time, t.delay_time, t.with_delay) == (SendType.CYCLIC_AND_SPONTANEOUS, 100, 20, True)
    t = message_timing(db, db.get_message_by_name("ClusterDiagResponse"))
    assert t.on_request_only
    assert attribute(db, db.get_message_by_name("ClusterDiagResponse"), "GenMsgSendType") == "NoMsgSendType"
    st = signal_timing(db, db.get_message_by_name("DoorStatus").get_signal_by_name("DoorFL"))
    assert (st.send_type, st.with_repetition) == ("OnChange", True)


def test_cyclic_period_and_start_delay(db):
    bus, ecu = one(db, "TCM")
    bus.run(until=200 * MS)
    times = queued(bus, 0x110)
    # GenMsgStartDelayTime 5 ms, GenMsgCycleTime 20 ms
    assert times == [5 * MS + k * 20 * MS for k in range(10)]


def test_cycle_time_alone_means_cyclic():
    text = (
        'VERSION ""\nBS_:\nBU_: A B\nBO_ 1 M: 1 A\n SG_ S : 0|8@1+ (1,0) [0|255] "" B\n'
        'BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;\nBA_DEF_DEF_ "GenMsgCycleTime" 0;\n'
        'BA_ "GenMsgCycleTime" BO_ 1 15;\n'
    )
    db = cantools.database.load_string(text)
    bus, ecu = one(db, "A")
    bus.run(until=100 * MS)
    assert queued(bus, 1) == [k * 15 * MS for k in range(7)]


def test_spontaneous_on_write_and_no_cycle(db):
    bus, ecu = one(db, "BCM")
    bus.run(until=50 * MS)
    assert queued(bus, 0x320) == []
    ecu.set("HeadLight", "Low")  # OnWrite
    bus.run(until=60 * MS)
    ecu.set("HeadLight", "Low")  # same value, still a write
    bus.run(until=100 * MS)
    assert queued(bus, 0x320) == [50 * MS, 60 * MS]


def test_on_change_with_repetitions(db):
    bus, ecu = one(db, "BCM")
    bus.run(until=10 * MS)
    ecu.set("DoorFL", "Open")  # OnChangeWithRepetition, GenMsgNrOfRepetition 2, CycleTimeFast 50
    bus.run(until=400 * MS)
    assert queued(bus, 0x300) == [10 * MS, 60 * MS, 110 * MS]
    ecu.set("DoorFL", "Open")  # unchanged: nothing
    ecu.set("Trunk", "Closed")  # OnChange without repetition, unchanged: nothing
    bus.run(until=600 * MS)
    assert len(queued(bus, 0x300)) == 3
    ecu.set("Trunk", "Open")
    bus.run(until=800 * MS)
    assert queued(bus, 0x300)[3:] == [600 * MS]


def test_cyclic_and_spontaneous_with_delay(db):
    bus, ecu = one(db, "ABS")
    bus.run(until=105 * MS)
    ecu.set("BrakePedal", "Pressed")  # OnChange: send, but >= GenMsgDelayTime (20 ms) after the last
    bus.run(until=110 * MS)
    ecu.set("BrakePedal", "Released")
    ecu.set("VehicleSpeed", 50)  # GenSigSendType Cyclic: no trigger
    bus.run(until=330 * MS)
    # cyclic 0, 100, 200, 300; spontaneous at 120 (100 + delay); the write at 110 falls inside the
    # pending delay and is coalesced into that transmission
    assert queued(bus, 0x210) == [0, 100 * MS, 120 * MS, 200 * MS, 300 * MS]


def test_cyclic_if_active(db):
    bus, ecu = one(db, "BCM")
    bus.run(until=1000 * MS)
    assert queued(bus, 0x310) == []  # inactive: TurnLeft/TurnRight at GenSigInactiveValue 0
    ecu.set("TurnLeft", 1)
    bus.run(until=2200 * MS)
    ecu.set("TurnLeft", 0)
    bus.run(until=4000 * MS)
    # active at 1000: fast cycle 500 ms; after going inactive one last frame with the inactive value
    assert queued(bus, 0x310) == [1000 * MS, 1500 * MS, 2000 * MS, 2500 * MS]
    frames = [r.frame for r in bus.trace if r.frame.can_id == 0x310]
    assert frames[-1].data == b"\x00" and frames[0].data == b"\x01"


def test_stop_cancels_timers(db):
    bus, ecu = one(db, "ECM")
    bus.run(until=25 * MS)
    ecu.stop()
    n = len(queued(bus, 0x100))
    bus.run(until=100 * MS)
    assert len(queued(bus, 0x100)) == n == 3


_SEND_TYPES = ["Cyclic", "CyclicIfActiveAndSpontaneous", "CyclicIfActiveAndSpontaneousWithDelay"]


def _cias_db(send_type: str, fast: int, delay: int = 0):
    """One CyclicIfActiveAndSpontaneous message (id 267) whose only signal L (inactive value 0,
    the default) makes it active; the timing attributes as given."""
    text = (
        'VERSION ""\nNS_ :\nBS_:\nBU_: TX RX\nBO_ 267 M: 1 TX\n SG_ L : 0|8@1+ (1,0) [0|255] "" RX\n'
        'BA_DEF_ BO_ "GenMsgSendType" ENUM ' + ",".join(f'"{t}"' for t in _SEND_TYPES) + ";\n"
        'BA_DEF_ BO_ "GenMsgCycleTimeFast" INT 0 65535;\nBA_DEF_ BO_ "GenMsgDelayTime" INT 0 65535;\n'
        'BA_DEF_DEF_ "GenMsgSendType" "Cyclic";\nBA_DEF_DEF_ "GenMsgCycleTimeFast" 0;\n'
        'BA_DEF_DEF_ "GenMsgDelayTime" 0;\n'
        f'BA_ "GenMsgSendType" BO_ 267 {_SEND_TYPES.index(send_type)};\n'
        f'BA_ "GenMsgCycleTimeFast" BO_ 267 {fast};\nBA_ "GenMsgDelayTime" BO_ 267 {delay};\n'
    )
    db = cantools.database.load_string(text)
    assert db.get_message_by_name("M").send_type == send_type  # as cantools reads the DBC
    return db


def _writes(bus, ecu, writes):
    for t, value in writes:
        bus.run(until=t * MS)
        ecu.set("L", value)


def test_cyclic_if_active_and_spontaneous_one_frame_per_event():
    db = _cias_db("CyclicIfActiveAndSpontaneous", fast=50)
    bus, ecu = one(db, "TX")
    _writes(bus, ecu, [(10, 1), (120, 0)])
    bus.run(until=400 * MS)
    # the write at 10 ms activates it: one spontaneous frame, then the fast cycle (50 ms) from
    # it: 60, 110; the write at 120 ms deactivates it: one spontaneous frame with the inactive
    # value, and the cycle stops
    assert queued(bus, 267) == [10 * MS, 60 * MS, 110 * MS, 120 * MS]
    assert [r.frame.data for r in bus.trace if r.frame.can_id == 267] == [b"\x01"] * 3 + [b"\x00"]


def test_cyclic_if_active_and_spontaneous_with_delay():
    db = _cias_db("CyclicIfActiveAndSpontaneousWithDelay", fast=50, delay=20)
    bus, ecu = one(db, "TX")
    _writes(bus, ecu, [(10, 1), (115, 2), (170, 0)])
    bus.run(until=400 * MS)
    # 10: activated (spontaneous), cycle 60, 110, 160; 115: spontaneous, but at least
    # GenMsgDelayTime 20 ms after the 110 frame: 130; 170: deactivated, spontaneous at
    # 160 + 20 = 180 with the inactive value, and no cycle after it
    assert queued(bus, 267) == [10 * MS, 60 * MS, 110 * MS, 130 * MS, 160 * MS, 180 * MS]
    assert [r.frame.data[0] for r in bus.trace if r.frame.can_id == 267] == [1, 1, 1, 2, 2, 0]
