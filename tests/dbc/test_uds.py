"""UDS (ISO 14229-1) over ISO-TP (ISO 15765-2) on a DBC ECU, with udsoncan as the client on the
simulated bus: every service, the DIDs mapped to signals (checked against cantools' decoding of
the frames on the bus), and flow control (block size, STmin) visible in the bus timing."""

from __future__ import annotations

from pathlib import Path

import pytest

udsoncan = pytest.importorskip("udsoncan")
from udsoncan.client import Client  # noqa: E402
from udsoncan.exceptions import NegativeResponseException  # noqa: E402

from dbc import Ecu, load_database  # noqa: E402
from dbc.diag import DID_ACTIVE_SESSION, DID_VIN, UdsServer, attach_uds  # noqa: E402
from dbc.diag.client import SimConnection  # noqa: E402
from stack import SimBus  # noqa: E402

SAMPLE = Path(__file__).resolve().parents[2] / "dbc" / "databases" / "powertrain_body.dbc"
VIN = "WVWZZZ1JZXW000001"
MS = 1_000_000


@pytest.fixture
def ecu_and_client():
    db = load_database(SAMPLE)
    bus = SimBus(500_000, seed=1, record=True)
    ecm = Ecu(db, "ECM", bus.node("ECM"))
    resets: list[int] = []
    srv = attach_uds(ecm, 0x7E0, 0x7E8, vin=VIN, on_reset=resets.append)
    conn = SimConnection(bus, bus.node("tester"), 0x7E0, 0x7E8, stmin_ms=5, block_size=2)
    cfg = dict(udsoncan.configs.default_client_config)
    cfg["data_identifiers"] = {
        DID_VIN: udsoncan.AsciiCodec(17),
        DID_ACTIVE_SESSION: "B",
        0x1000: ">H",  # EngineData.EngineSpeed: 16 bits unsigned
        0x1003: ">h",  # EngineData.EngineTorque: 16 bits signed
        0x1001: "B",
        0x0FFF: "B",  # not served
    }
    with Client(conn, config=cfg) as client:
        yield db, bus, ecm, srv, client, resets


def frames_of(bus, can_id):
    return [r for r in bus.trace if r.kind == "frame" and r.frame.can_id == can_id]


def test_vin_and_active_session(ecu_and_client):
    db, bus, ecm, srv, client, resets = ecu_and_client
    assert client.read_data_by_identifier(DID_VIN).service_data.values[DID_VIN] == VIN
    assert client.read_data_by_identifier(DID_ACTIVE_SESSION).service_data.values[DID_ACTIVE_SESSION] == (1,)
    resp = client.change_session(3)
    # P2 50 ms, P2* 5000 ms as udsoncan parses the DiagnosticSessionControl response
    assert resp.service_data.p2_server_max == pytest.approx(0.05)
    assert resp.service_data.p2_star_server_max == pytest.approx(5.0)
    assert client.read_data_by_identifier(DID_ACTIVE_SESSION).service_data.values[DID_ACTIVE_SESSION] == (3,)


def test_signal_dids_read_and_write_through_the_dbc(ecu_and_client):
    db, bus, ecm, srv, client, resets = ecu_and_client
    ecm.set("EngineTorque", -12.5)
    # raw values, as cantools encodes them: EngineSpeed 800 rpm / 0.25, torque -12.5 Nm / 0.1
    got = client.read_data_by_identifier([0x1000, 0x1003]).service_data.values
    assert got[0x1000] == (3200,) and got[0x1003] == (-125,)
    with pytest.raises(NegativeResponseException) as exc:
        client.write_data_by_identifier(0x1000, 8000)  # writing needs a non-default session
    assert exc.value.response.code == 0x7F
    client.change_session(3)
    client.write_data_by_identifier(0x1000, 8000)  # raw 8000 = 2000 rpm
    assert ecm.get("EngineSpeed") == 2000.0
    t = bus.now()
    bus.run(until=t + 30 * MS)
    msg = db.get_message_by_name("EngineData")
    after = [msg.decode(r.frame.data)["EngineSpeed"] for r in frames_of(bus, 0x100) if r.start > t]
    assert after and set(after) == {2000.0}  # on the wire, as cantools decodes it
    with pytest.raises(NegativeResponseException) as exc:
        client.write_data_by_identifier(0x1000, 65000)  # 16250 rpm: above the DBC's 16000
    assert exc.value.response.code == 0x31  # requestOutOfRange
    with pytest.raises(NegativeResponseException) as exc:
        client.read_data_by_identifier(0x0FFF)
    assert exc.value.response.code == 0x31
    assert sorted(srv.dids) == [*range(0x1000, 0x1008), DID_ACTIVE_SESSION, DID_VIN]  # 8 signals of ECM


def test_dtcs_set_by_the_application_read_and_cleared(ecu_and_client):
    db, bus, ecm, srv, client, resets = ecu_and_client
    assert client.get_number_of_dtc_by_status_mask(0xFF).service_data.dtc_count == 0
    srv.set_dtc(0x123456)
    srv.set_dtc(0x0A0B0C, status=0x01)
    assert client.get_number_of_dtc_by_status_mask(0xFF).service_data.dtc_count == 2
    dtcs = client.get_dtc_by_status_mask(0x08).service_data.dtcs  # confirmedDTC only
    assert [(d.id, d.status.confirmed) for d in dtcs] == [(0x123456, True)]
    client.clear_dtc(0x123456)
    assert [d.id for d in client.get_dtc_by_status_mask(0xFF).service_data.dtcs] == [0x0A0B0C]
    client.clear_dtc(0xFFFFFF)
    assert client.get_number_of_dtc_by_status_mask(0xFF).service_data.dtc_count == 0


def test_tester_present_ecu_reset_and_s3(ecu_and_client):
    db, bus, ecm, srv, client, resets = ecu_and_client
    client.change_session(3)
    client.tester_present()
    client.ecu_reset(1)  # hard reset: answered, then the application is told
    assert resets == [1] and srv.session == 1
    client.change_session(3)
    bus.run(until=bus.now() + 4 * 1000 * MS)
    client.tester_present()  # keeps the session (S3 = 5 s)
    bus.run(until=bus.now() + 4 * 1000 * MS)
    assert srv.session == 3
    bus.run(until=bus.now() + 2 * 1000 * MS)
    assert srv.session == 1  # 6 s without a request


def test_negative_responses_from_the_standard():
    bus = SimBus(500_000)
    srv = UdsServer(bus.node("ecu"), 0x700, 0x708)
    assert srv.respond(b"\x85\x01") == b"\x7f\x85\x11"  # serviceNotSupported
    assert srv.respond(b"\x10\x09") == b"\x7f\x10\x12"  # subFunctionNotSupported
    assert srv.respond(b"\x10") == b"\x7f\x10\x13"  # incorrectMessageLengthOrInvalidFormat
    assert srv.respond(b"\x3e\x80") is None  # suppressPosRspMsgIndicationBit
    assert srv.respond(b"\x22\xf1") == b"\x7f\x22\x13"


def test_flow_control_block_size_and_stmin_on_the_bus(ecu_and_client):
    """The tester asks for STmin 5 ms and blocks of 2; reading every DID gives a long response:
    consecutive frames leave at least 5 ms apart (end of one to start of the next) and a flow
    control frame from the tester comes after every second one."""
    db, bus, ecm, srv, client, resets = ecu_and_client
    start = bus.now()
    values = client.read_data_by_identifier([DID_VIN, 0x1000, 0x1003])  # 7 bytes: a single frame
    assert values.service_data.values[DID_VIN] == VIN
    seq = [r for r in bus.trace if r.kind == "frame" and r.frame.can_id in (0x7E0, 0x7E8) and r.start >= start]
    kinds = [(r.frame.can_id, r.frame.data[0] >> 4) for r in seq]
    # request (single frame), first frame, FC, then CF CF FC CF ...
    assert kinds[:3] == [(0x7E0, 0), (0x7E8, 1), (0x7E0, 3)]
    rest = kinds[3:]
    cfs = [i for i, k in enumerate(rest) if k == (0x7E8, 2)]
    assert len(cfs) >= 4
    for i in range(len(rest)):
        if rest[i] == (0x7E0, 3):  # every FC follows exactly two CFs since the last one
            assert rest[i - 2 : i] == [(0x7E8, 2), (0x7E8, 2)]
    assert seq[2].frame.data[1:3] == bytes((2, 5))  # FC: BS 2, STmin 5 ms
    cf_records = [r for r in seq[3:] if r.frame.can_id == 0x7E8]
    for a, b in zip(cf_records, cf_records[1:]):
        assert b.start - a.end >= 5 * MS


def test_server_flow_control_for_a_long_request():
    """The server asks testers for STmin 3 ms and blocks of 1: a long request (eight DIDs) comes
    in with a flow control frame after each consecutive frame, 3 ms apart."""
    db = load_database(SAMPLE)
    bus = SimBus(500_000, seed=2, record=True)
    ecm = Ecu(db, "ECM", bus.node("ECM"))
    attach_uds(ecm, 0x7E0, 0x7E8, stmin_ms=3, block_size=1)
    conn = SimConnection(bus, bus.node("tester"), 0x7E0, 0x7E8)
    cfg = dict(udsoncan.configs.default_client_config)
    ids = list(range(0x1000, 0x1008))
    cfg["data_identifiers"] = {d: ">H" if d in (0x1000, 0x1003) else "B" for d in ids}
    with Client(conn, config=cfg) as client:
        got = client.read_data_by_identifier(ids).service_data.values
    assert got[0x1000] == (3200,)
    req = [r for r in bus.trace if r.kind == "frame" and r.frame.can_id in (0x7E0, 0x7E8)]
    kinds = [(r.frame.can_id, r.frame.data[0] >> 4) for r in req]
    assert kinds[:5] == [(0x7E0, 1), (0x7E8, 3), (0x7E0, 2), (0x7E8, 3), (0x7E0, 2)]
    assert req[1].frame.data[1:3] == bytes((1, 3))
    tester_cfs = [r for r in req if r.frame.can_id == 0x7E0 and r.frame.data[0] >> 4 == 2]
    fcs = [r for r in req if r.frame.can_id == 0x7E8 and r.frame.data[0] >> 4 == 3]
    for fc, cf in zip(fcs, tester_cfs):
        assert cf.start - fc.end >= 3 * MS  # can-isotp waits STmin after each flow control


def test_any_stack_node_can_serve_application_dids():
    """Not only a DBC ECU: a bare node with an application's DID."""
    from dbc.diag import DataIdentifier

    bus = SimBus(250_000)
    counter = {"n": 0}

    def read() -> bytes:
        counter["n"] += 1
        return counter["n"].to_bytes(2, "big")

    UdsServer(bus.node("app"), 0x600, 0x680, dids=[DataIdentifier(0xA000, "calls", read)])
    conn = SimConnection(bus, bus.node("tester"), 0x600, 0x680)
    cfg = dict(udsoncan.configs.default_client_config)
    cfg["data_identifiers"] = {0xA000: ">H"}
    with Client(conn, config=cfg) as client:
        assert client.read_data_by_identifier(0xA000).service_data.values[0xA000] == (1,)
        assert client.read_data_by_identifier(0xA000).service_data.values[0xA000] == (2,)


@pytest.mark.parametrize(
    "spec, fragment",
    [
        ("ECX:0x7E0:0x7E8", "did you mean 'ECM'"),
        ("ECM:0x7E0", "NODE:REQ_ID:RESP_ID"),
        ("ECM:0x800:0x7E8", "11-bit"),
        ("ECM:0x100:0x7E8", "EngineData"),
        ("ECM:0x7E0:0x7E0", "must differ"),
    ],
)
def test_restbus_uds_bad_spec_one_line_exit_2(capsys, spec, fragment):
    import stack.cli as cli

    code = cli.main(["restbus", str(SAMPLE), "--duration", "0.1", "--uds", spec])
    out, err = capsys.readouterr()
    assert code == 2 and fragment in err and len(err.strip().splitlines()) == 1, err


def test_restbus_uds_prints_its_dids(capsys):
    import stack.cli as cli

    code = cli.main(["restbus", str(SAMPLE), "--duration", "0.1", "--uds", "TCM:0x7E1:0x7E9"])
    out, err = capsys.readouterr()
    assert code == 0, err
    lines = out.splitlines()
    assert lines[0] == "UDS: TCM answers requests on 0x7E1, responds on 0x7E9; DIDs:"
    db = load_database(SAMPLE)
    signals = [f"{m.name}.{s.name}" for m in db.messages if "TCM" in m.senders for s in m.signals]
    assert [line.split()[1] for line in lines[1 : 1 + len(signals)]] == signals
    assert lines[1 + len(signals) : 3 + len(signals)] == ["  0xF186  ActiveDiagnosticSession", "  0xF190  VIN"]
