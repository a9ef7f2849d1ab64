"""The ECU's signal API, range checks, names, multiplexing and extended identifiers."""

from pathlib import Path

import cantools
import pytest

from dbc.ecu import CheckFailed, Ecu, SignalChanged, initial_values
from dbc.errors import ChoiceError, DbcError, DbcLoadError, SignalRangeError, UnknownNameError, load_database
from stack.bus.sim import SimBus
from stack.wire.frame import Frame

SAMPLE = Path(__file__).resolve().parents[2] / "dbc" / "databases" / "powertrain_body.dbc"
MS = 1_000_000


@pytest.fixture
def net():
    db = load_database(SAMPLE)
    bus = SimBus(500_000)
    ecus = {n: Ecu(db, n, bus.node(n)) for n in ("ECM", "TCM", "ABS", "BCM", "IPC", "GW")}
    return db, bus, ecus


def test_initial_values_come_from_gensigstartvalue(net):
    db, bus, ecus = net
    bus.run(until=50 * MS)
    ipc = ecus["IPC"]
    # GenSigStartValue raw 3200 * 0.25 rpm, raw 130 - 40 degC (from the DBC text)
    assert ipc.get("EngineSpeed") == 800.0
    assert ipc.get("EngineTemp") == 90
    assert ipc.get("GearSelected") == "P"
    assert ipc.get("GatewayInfo.BatteryVoltage") == pytest.approx(12.6)


def test_set_physical_and_choice_reaches_receiver_as_cantools_decodes(net):
    db, bus, ecus = net
    ecus["ECM"].set("EngineSpeed", 2500.25)
    ecus["TCM"].set("GearSelected", "D")
    bus.run(until=50 * MS)
    ipc = ecus["IPC"]
    assert ipc.get("EngineSpeed") == 2500.25
    assert ipc.get("GearSelected") == "D"
    # the bytes on the wire are cantools' encoding of the same values
    msg = db.get_message_by_name("GearboxData")
    last = [r.frame for r in bus.trace if r.frame.can_id == msg.frame_id][-1]
    assert msg.decode(last.data)["GearSelected"] == "D"
    assert last.data[0] & 0x0F == 3  # VAL_ 272 GearSelected 3 "D"


def test_unknown_names_suggest_closest(net):
    db, bus, ecus = net
    with pytest.raises(UnknownNameError) as e:
        ecus["BCM"].set("DoorFX", 1)
    assert "DoorFL" in e.value.suggestions and "did you mean" in str(e.value)
    with pytest.raises(UnknownNameError, match="'ECM'"):
        Ecu(db, "ECN", bus.node("x"))
    with pytest.raises(UnknownNameError, match="EngineData"):
        ecus["ECM"].send("EngineDta")
    with pytest.raises(DbcError, match="sent by BCM"):
        ecus["ECM"].set("DoorFL", 1)


def test_range_strict_and_clamp(net):
    db, bus, ecus = net
    ecm = ecus["ECM"]
    with pytest.raises(SignalRangeError, match=r"\[0 .. 16000\] rpm"):
        ecm.set("EngineSpeed", 16000.25)
    with pytest.raises(SignalRangeError):
        ecm.set("EngineTorque", -1000.1)
    ecm.set("EngineSpeed", 99999, clamp=True)
    assert ecm.get("EngineSpeed") == 16000
    clamping = Ecu(db, "ABS", bus.node("abs2"), clamp=True, start=False)
    clamping.set("VehicleSpeed", -5)
    assert clamping.get("VehicleSpeed") == 0
    with pytest.raises(ChoiceError) as e:
        ecus["TCM"].set("GearSelected", "Drive")
    assert "P, R, N, D, S" in str(e.value)
    with pytest.raises(DbcError, match="no value table"):
        ecm.set("EngineSpeed", "fast")


def test_raw_range_applies_without_dbc_range():
    text = 'VERSION ""\nBS_:\nBU_: A B\nBO_ 1 M: 1 A\n SG_ S : 0|4@1+ (2,10) [0|0] "" B\n'
    db = cantools.database.load_string(text)
    bus = SimBus(500_000)
    ecu = Ecu(db, "A", bus.node("A"))
    ecu.set("S", 40)  # raw 15: the top of 4 bits
    with pytest.raises(SignalRangeError, match="4-bit raw range"):
        ecu.set("S", 42)


def test_subscriptions(net):
    db, bus, ecus = net
    seen, changes = [], []
    ecus["IPC"].on_message("DoorStatus", seen.append)
    ecus["IPC"].on_signal("DoorFL", changes.append)
    ecus["BCM"].set("DoorFL", "Open")
    bus.run(until=10 * MS)
    assert seen and seen[0].signals["DoorFL"] == "Open"
    assert [(c.old, c.new) for c in changes] == [(None, "Open")]
    assert isinstance(changes[0], SignalChanged)


def test_multiplexed_message_round_trip(net):
    db, bus, ecus = net
    gw, ipc = ecus["GW"], ecus["IPC"]
    gw.update("GatewayInfo", {"InfoPage": "Environment", "AmbientTemp": 21.5, "VehicleTime": 1234})
    bus.run(until=450 * MS)
    assert ipc.values("GatewayInfo") == {"InfoPage": "Environment", "AmbientTemp": 21.5, "VehicleTime": 1234}
    msg = db.get_message_by_name("GatewayInfo")
    frame = gw.encode_frame("GatewayInfo")
    assert frame.data == msg.encode({"InfoPage": 1, "AmbientTemp": 21.5, "VehicleTime": 1234})


def test_extended_j1939_identifier(net):
    db, bus, ecus = net
    bus.run(until=60 * MS)
    eec1 = [r.frame for r in bus.trace if r.sender == "ECM" and r.frame.extended]
    assert eec1 and eec1[0].can_id == 0x0CF00400  # BO_ 2364539904 = 0x80000000 | 0x0CF00400
    # a different J1939 source address still decodes (matched by PGN)
    ecus["GW"].node.subscribe(lambda ev: None)
    other = bus.node("other_sa")
    data = db.get_message_by_name("EEC1").encode({"EngineSpeedJ1939": 1500, "DriverDemandTorque": 10})
    other.send(Frame(0x0CF00417, data, extended=True))
    bus.run(duration=1 * MS)
    assert ecus["GW"].get("EngineSpeedJ1939") == 1500


def test_on_request_message_only_when_asked(net):
    db, bus, ecus = net
    bus.run(until=300 * MS)
    assert not [r for r in bus.trace if r.frame.can_id == 0x7A0]
    bus.run(until=305 * MS)  # between cycles: the request is not queued behind them
    ecus["IPC"].send("ClusterDiagResponse", {"DiagData": 42})
    bus.run(duration=1 * MS)
    sent = [r for r in bus.trace if r.frame.can_id == 0x7A0]
    assert len(sent) == 1 and sent[0].frame.data == (42).to_bytes(8, "little")


def test_decode_error_is_reported(net):
    db, bus, ecus = net
    fails: list[CheckFailed] = []
    ecus["IPC"].on_check_failed(fails.append)
    bus.run(until=5 * MS)  # between two EngineData cycles: no collision with the ECM's frame
    bus.node("rogue").send(Frame(0x100, b"\x01"))  # EngineData id with 1 byte instead of 8
    bus.run(duration=1 * MS)
    assert fails and fails[0].check == "decode" and fails[0].message == "EngineData"
    assert ecus["IPC"].check_failures[("EngineData", "decode")] == 1


def test_malformed_dbc_names_line(tmp_path):
    p = tmp_path / "bad.dbc"
    p.write_text(
        'VERSION ""\n\nBU_: A B\n\nBO_ 100 Msg: 8 A\n SG_ Ok : 0|8@1+ (1,0) [0|255] "" B\n'
        ' SG_ Bad 8|8@1+ (1,0) [0|255] "" B\n'
    )
    with pytest.raises(DbcLoadError) as e:
        load_database(p)
    assert e.value.line == 7 and "Invalid syntax" in e.value.reason
    p.write_text('VERSION ""\n\nBU_: A B\n\nBO_ 100 Msg: 1 A\n SG_ Big : 0|16@1+ (1,0) [0|255] "" B\n')
    with pytest.raises(DbcLoadError) as e:
        load_database(p)
    assert e.value.line == 5 and "does not fit" in e.value.reason
    with pytest.raises(DbcLoadError, match="no such file"):
        load_database(tmp_path / "missing.dbc")


def test_initial_values_select_defined_mux_branch():
    db = cantools.database.load_file(str(SAMPLE))
    v = initial_values(db, db.get_message_by_name("GatewayInfo"))
    assert v["InfoPage"] == 0
    text = (
        'VERSION ""\nBS_:\nBU_: A B\nBO_ 1 M: 2 A\n SG_ Mux M : 0|8@1+ (1,0) [0|255] "" B\n'
        ' SG_ X m3 : 8|8@1+ (1,0) [0|255] "" B\n SG_ Y m5 : 8|8@1+ (1,0) [0|255] "" B\n'
    )
    db2 = cantools.database.load_string(text)
    m = db2.messages[0]
    v2 = initial_values(db2, m)
    assert v2["Mux"] == 3
    assert m.decode(m.encode(v2, strict=False)) == {"Mux": 3, "X": 0}


def _page_frames(bus, msg, page):
    """GatewayInfo frames on the wire whose multiplexer (byte 0, InfoPage) selects ``page``."""
    return [r.frame for r in bus.trace if r.frame.can_id == msg.frame_id and r.frame.data[0] == page]


def test_multiplexed_reception_keeps_every_page(net):
    db, bus, ecus = net
    gw, ipc = ecus["GW"], ecus["IPC"]
    msg = db.get_message_by_name("GatewayInfo")  # cycle 200 ms: frames at 0, 200, 400 ms
    changes = []
    ipc.on_signal("BatteryVoltage", changes.append)
    bus.run(until=250 * MS)
    gw.update("GatewayInfo", {"InfoPage": "Environment", "AmbientTemp": 21.5, "VehicleTime": 99})
    bus.run(until=450 * MS)
    page0, page1 = _page_frames(bus, msg, 0), _page_frames(bus, msg, 1)
    # pages in turn: 0 ms page 0, 200 ms page 1; the update selects page 1, which then stays (400 ms)
    assert len(page0) == 1 and len(page1) == 2
    last0, last1 = msg.decode(page0[-1].data), msg.decode(page1[-1].data)
    assert "BatteryVoltage" not in last1  # the page-1 frame does not carry it ...
    # ... yet the receiver still knows the value the last page-0 frame carried
    assert ipc.get("BatteryVoltage") == last0["BatteryVoltage"]
    assert ipc.get("AmbientTemp") == last1["AmbientTemp"] == 21.5
    assert ipc.values("GatewayInfo") == {**last0, **last1}
    # no change event for BatteryVoltage when a frame of the other page comes in
    assert [(c.old, c.new) for c in changes] == [(None, last0["BatteryVoltage"])]


def test_multiplexed_value_of_another_page_goes_out_when_its_page_comes_round(net):
    db, bus, ecus = net
    gw = ecus["GW"]
    msg = db.get_message_by_name("GatewayInfo")  # 200 ms cycle; pages InfoPage 0 and 1
    gw.set("AmbientTemp", 20)  # a page-1 signal: kept, and sent with page 1 (the second frame)
    assert gw.get("AmbientTemp") == 20
    bus.run(until=250 * MS)
    sent = [msg.decode(r.frame.data) for r in bus.trace if r.frame.can_id == msg.frame_id]
    assert [s["InfoPage"] for s in sent] == ["Battery", "Environment"]
    assert sent[1]["AmbientTemp"] == 20
    gw.set("InfoPage", "Battery")  # the application selects a page: it stays
    bus.run(until=850 * MS)
    sent = [msg.decode(r.frame.data) for r in bus.trace if r.frame.can_id == msg.frame_id]
    assert [s["InfoPage"] for s in sent[2:]] == ["Battery"] * 3
    gw.rotate_pages("GatewayInfo")
    bus.run(until=1250 * MS)
    sent = [msg.decode(r.frame.data) for r in bus.trace if r.frame.can_id == msg.frame_id]
    assert {str(s["InfoPage"]) for s in sent[5:]} == {"Battery", "Environment"}


def test_encode_frame_changes_nothing(net):
    db, bus, ecus = net
    ecm, ipc = ecus["ECM"], ecus["IPC"]
    msg = db.get_message_by_name("EngineData")  # cycle 10 ms, counter 0..15 (EngineCounter)
    fails: list[CheckFailed] = []
    ipc.on_check_failed(fails.append)
    bus.run(until=25 * MS)
    wire = [r.frame for r in bus.trace if r.frame.can_id == msg.frame_id]
    last_counter = msg.decode(wire[-1].data)["EngineCounter"]
    peek = ecm.encode_frame("EngineData")
    assert msg.decode(peek.data)["EngineCounter"] == (last_counter + 1) % 16  # the next one
    assert ecm.encode_frame("EngineData") == peek  # asking again gives the same frame
    other = ecm.encode_frame("EngineData", {"EngineSpeed": 1000})
    assert msg.decode(other.data)["EngineSpeed"] == 1000
    assert msg.decode(other.data)["EngineCounter"] == (last_counter + 1) % 16
    assert ecm.get("EngineSpeed") == msg.decode(wire[-1].data)["EngineSpeed"]  # values untouched
    bus.run(until=60 * MS)
    after = [r.frame for r in bus.trace if r.frame.can_id == msg.frame_id][len(wire) :]
    assert after[0].data == peek.data  # the next transmission is the frame encode_frame showed
    counters = [msg.decode(f.data)["EngineCounter"] for f in after]
    assert counters == [(last_counter + 1 + k) % 16 for k in range(len(counters))]
    assert fails == [] and ipc.failed_checks == 0


_HEAD = 'VERSION ""\nNS_ :\nBS_:\nBU_: A B\nBO_ 100 M: 8 A\n SG_ S : 0|8@1+ (1,0) [0|255] "" B\n'


def _line_of(text: str, start: str) -> int:
    return next(i for i, line in enumerate(text.splitlines(), 1) if line.startswith(start))


def test_malformed_dbc_undefined_attribute_names_line_and_reason(tmp_path):
    text = _HEAD + 'CM_ BO_ 100 "a comment";\nBA_ "GenMsgCycleTime" BO_ 100 10;\n'
    p = tmp_path / "undefattr.dbc"
    p.write_text(text)
    with pytest.raises(cantools.database.errors.Error):
        cantools.database.load_file(str(p))  # cantools rejects it, naming no line
    with pytest.raises(DbcLoadError) as e:
        load_database(p)
    assert e.value.line == _line_of(text, 'BA_ "GenMsgCycleTime"')
    assert "GenMsgCycleTime" in e.value.reason and "BA_DEF_" in e.value.reason
    assert "\n" not in str(e.value)


def test_malformed_dbc_dangling_val_names_line_and_reason(tmp_path):
    text = _HEAD + 'VAL_ 100 S 1 "one" 0 "zero" ;\nVAL_ 100 T 1 "on" 0 "off" ;\n'
    p = tmp_path / "dangling.dbc"
    p.write_text(text)
    with pytest.raises(DbcLoadError) as e:
        load_database(p)
    assert e.value.line == _line_of(text, "VAL_ 100 T")
    assert "has no signal T" in e.value.reason and "\n" not in str(e.value)
    p.write_text(_HEAD + 'VAL_ 101 S 1 "one" ;\n')  # no message 101 at all
    with pytest.raises(DbcLoadError) as e:
        load_database(p)
    assert e.value.line == 7 and "no message has identifier 101" in e.value.reason
