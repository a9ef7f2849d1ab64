"""DBC ECUs send and receive CAN FD messages: FD frames as cantools marks the messages, bit rate
switching from the DBC's CANFD_BRS attribute, payloads padded to the DLC's size, counters and
checksums as on classical frames; an FD message on a bus without FD is refused by name."""

from __future__ import annotations

from functools import reduce
from pathlib import Path

import cantools
import pytest

from dbc import Ecu, load_database
from dbc.errors import FdNotCarriedError
from dbc.transmit import DEFAULT_BRS, fd_format
from stack import Frame, SimBus

FD_ECUS = Path(__file__).resolve().parent / "data" / "fd_ecus.dbc"

# ISO 11898-1:2015, table 5: the data lengths a CAN FD DLC codes
ISO_FD_LENGTHS = [0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64]


def peer() -> cantools.database.can.Database:
    """The database as cantools alone reads it: the independent decoder."""
    return cantools.database.load_file(str(FD_ECUS))


def fd_bus() -> SimBus:
    return SimBus(500_000, data_bitrate=2_000_000, seed=3)


def received_by(bus: SimBus, name: str) -> list[Frame]:
    got: list[Frame] = []
    bus.node(name).subscribe(lambda ev: got.append(ev.frame))
    return got


def test_fd_messages_go_out_as_fd_frames_with_the_dbc_brs():
    bus = fd_bus()
    seen = received_by(bus, "sniffer")
    Ecu(load_database(FD_ECUS), "Camera", bus.node("Camera"))
    bus.run(until=101_000_000)
    db = peer()
    by_id = {(m.frame_id, bool(m.is_extended_frame)): m for m in db.messages}
    names = {}
    for f in seen:
        m = by_id[(f.can_id, f.extended)]
        names.setdefault(m.name, []).append(f)
        assert f.fd is True and m.is_fd
        # CANFD_BRS: "0" on CameraStatus, the definition's default "1" elsewhere
        assert f.brs is (m.dbc.attributes.get("CANFD_BRS") is None)
        # the smallest CAN FD length holding the DBC's length (ISO's DLC table)
        assert len(f.data) == min(n for n in ISO_FD_LENGTHS if n >= m.length)
        assert f.dlc == ISO_FD_LENGTHS.index(len(f.data))
    assert {k: len(v) for k, v in names.items()} == {"CameraObjects": 11, "CameraStatus": 3, "CameraRaw": 2}
    status = names["CameraStatus"][0]
    assert len(status.data) == 12 and status.data[10:] == b"\x00\x00"  # 10 bytes padded to DLC 9
    assert db.get_message_by_name("CameraStatus").decode(status.data[:10])["CamTail"] == 85
    raw = names["CameraRaw"][0]
    assert raw.extended and raw.dlc == 15 and raw.data[63] == 204
    assert db.get_message_by_name("CameraRaw").decode(raw.data)["RawLast"] == 204


def test_counter_and_checksum_on_an_fd_frame_as_on_a_classical_one():
    bus = fd_bus()
    seen = received_by(bus, "sniffer")
    Ecu(load_database(FD_ECUS), "Camera", bus.node("Camera"))
    bus.run(until=45_000_000)
    msg = peer().get_message_by_name("CameraObjects")
    objects = [f for f in seen if f.can_id == msg.frame_id]
    assert len(objects) == 5
    for i, f in enumerate(objects):
        values = msg.decode(f.data, decode_choices=False)
        assert values["ObjCounter"] == i % 16
        assert values["ObjLast"] == 170
        # the XOR of every payload byte but the checksum's own (byte 19), written in the test
        assert f.data[19] == reduce(lambda a, b: a ^ b, f.data[:19], 0)


def test_receiving_ecu_decodes_fd_frames_and_checks_them():
    bus = fd_bus()
    db = load_database(FD_ECUS)
    camera = Ecu(db, "Camera", bus.node("Camera"))
    fusion = Ecu(db, "Fusion", bus.node("Fusion"))
    got = []
    fusion.on_message("CameraStatus", got.append)
    bus.run(until=60_000_000)
    assert fusion.get("CamTail") == 85 and fusion.get("ObjLast") == 170 and fusion.get("RawLast") == 204
    assert fusion.failed_checks == 0 and fusion.get("ObjCounter") == 5
    assert (
        got
        and got[0].frame.fd
        and got[0].signals == peer().get_message_by_name("CameraStatus").decode(got[0].frame.data[:10])
    )
    # a corrupted checksum is caught on an FD frame too (the counter right: only the checksum fails)
    camera.stop()
    bus.run(until=bus.now() + 1_000_000)  # what was queued went out
    counter = (fusion.get("ObjCounter") + 1) % 16
    msg = peer().get_message_by_name("CameraObjects")
    data = bytearray(msg.encode({"ObjCounter": counter, "ObjCount": 1, "ObjRange": 2, "ObjLast": 3, "ObjChecksum": 0}))
    data[19] = reduce(lambda a, b: a ^ b, data[:19], 0) ^ 0xFF
    bus.node("Intruder").send(Frame(msg.frame_id, bytes(data), fd=True, brs=True))
    bus.run(until=bus.now() + 1_000_000)
    assert list(fusion.check_failures) == [("CameraObjects", "checksum ObjChecksum (xor)")]


def test_encode_and_decode_frame_of_an_fd_message_match_cantools():
    db = load_database(FD_ECUS)
    fusion = Ecu(db, "Fusion", fd_bus().node("Fusion"))
    msg = peer().get_message_by_name("CameraStatus")
    frame = fusion.encode_frame("CameraStatus", {"CamState": 7, "CamTail": 9})
    assert frame.fd and not frame.brs and frame.data == msg.encode({"CamState": 7, "CamTail": 9}) + bytes(2)
    assert fusion.decode_frame(frame) == ("CameraStatus", msg.decode(frame.data[:10]))


def test_brs_follows_the_attribute_and_its_default():
    db = load_database(FD_ECUS)
    assert [fd_format(db, m) for m in db.messages] == [(True, True), (True, False), (True, True), (False, False)]
    # a DBC without the CANFD_BRS definition: the stated default (CANdb++'s "1")
    bare = load_database(Path(__file__).resolve().parent / "data" / "fd_only.dbc")
    assert "CANFD_BRS" not in bare.dbc.attribute_definitions
    assert {fd_format(bare, m) for m in bare.messages} == {(True, DEFAULT_BRS)} and DEFAULT_BRS is True


def test_fd_message_on_a_bus_without_fd_is_an_error_naming_it():
    bus = SimBus(500_000)
    with pytest.raises(FdNotCarriedError, match=r"message CameraObjects is a CAN FD frame \(20 bytes\)") as exc:
        Ecu(load_database(FD_ECUS), "Camera", bus.node("Camera"))
    assert exc.value.message == "CameraObjects" and "'classic'" in str(exc.value)
    # a node that only receives FD messages is made: nothing it sends is FD
    body = Ecu(load_database(FD_ECUS), "Body", bus.node("Body"))
    assert body.tx_messages == ["BodyClassic"]
