"""Error records in trace files carry what SocketCAN error frames carry (linux/can/error.h):
written with python-can's writers, read back with its readers, and decoded here with the
kernel header's values (written out below, not imported from the code under test)."""

from __future__ import annotations

import re

import can
import pytest

from stack.bus.faults import FaultInjector
from stack.bus.sim import SimBus
from stack.cli.demo import build_fault_demo
from stack.io.message import record_to_message
from stack.io.tracefile import save_trace
from stack.wire.frame import Frame

# include/uapi/linux/can/error.h
ERR_CLASS = {"CRTL": 0x04, "PROT": 0x08, "ACK": 0x20, "BUSOFF": 0x40, "BUSERROR": 0x80, "CNT": 0x200}
PROT_TYPE = {0x01: "bit", 0x02: "form", 0x04: "stuff", 0x00: "unspec"}
PROT_TX = 0x80
PROT_LOC = {
    0x03: "SOF",
    0x02: "ID28_21",
    0x06: "ID20_18",
    0x04: "SRTR",
    0x05: "IDE",
    0x07: "ID17_13",
    0x0F: "ID12_05",
    0x0E: "ID04_00",
    0x0C: "RTR",
    0x0D: "RES1",
    0x09: "RES0",
    0x0B: "DLC",
    0x0A: "DATA",
    0x08: "CRC_SEQ",
    0x18: "CRC_DEL",
    0x19: "ACK",
    0x1B: "ACK_DEL",
    0x1A: "EOF",
    0x12: "INTERM",
    0x00: "UNSPEC",
}
CRTL = {0x04: "RX_WARNING", 0x08: "TX_WARNING", 0x10: "RX_PASSIVE", 0x20: "TX_PASSIVE", 0x40: "ACTIVE"}
# the trace's field names as the kernel's locations
FIELD_LOC = {
    "SOF": "SOF",
    "DATA": "DATA",
    "CRC": "CRC_SEQ",
    "CRC_DELIM": "CRC_DEL",
    "ACK_DELIM": "ACK_DEL",
    "EOF": "EOF",
    "ACK_SLOT": "ACK",
    "DLC": "DLC",
}
TYPE_OF = {
    "bit": "bit",
    "form": "form",
    "stuff": "stuff",
    "stuff-arbitration": "stuff",
    "crc": "unspec",
    "ack": "unspec",
}


def _faulted_bus() -> SimBus:
    # the fault demo: local noise at ecu2 (warning, passive), then ecu2's transmitter stuck
    # recessive (bit errors at SOF, passive, bus off)
    bus = SimBus(500_000, seed=1)
    build_fault_demo(bus, sample_every=None)
    bus.run(until=600_000_000)
    return bus


@pytest.fixture(scope="module")
def faulted():
    bus = _faulted_bus()
    errors = [r for r in bus.trace if r.kind != "frame"]
    assert len(errors) > 50
    return bus, errors


def _first_node(detail):
    roles = dict(x.split(":") for x in detail["roles"].split(","))
    first = [n for n in detail["seen_by"].split(",") if n]
    return next((n for n in first if roles[n] == "tx"), first[0] if first else None), roles


def _check(rec, can_id: int, data: bytes) -> None:
    d = rec.detail
    node, roles = _first_node(d)
    node = node or rec.sender
    classes = {name for name, bit in ERR_CLASS.items() if can_id & bit}
    assert {"PROT", "BUSERROR", "CNT"} <= classes
    assert ("ACK" in classes) == (d["error"] == "ack")
    assert len(data) == 8
    assert PROT_TYPE[data[2] & 0x7F] == TYPE_OF[d["error"]]
    assert bool(data[2] & PROT_TX) == (roles.get(node) == "tx")
    loc = PROT_LOC[data[3]]
    if d["field"] in FIELD_LOC:
        assert loc == FIELD_LOC[d["field"]], d
    elif d["field"] == "ID":
        assert loc in ("ID28_21", "ID20_18")
    counters = dict(x.split(":") for x in d["counters"].split())
    tec, rec_ = (int(v) for v in counters[node].split("/"))
    assert (data[6], data[7]) == (min(tec, 255), min(rec_, 255))
    states = dict(x.split(":", 1) for x in d.get("states", "").split()) if d.get("states") else {}
    new = states[node].split("->")[1] if node in states else None
    assert ("BUSOFF" in classes) == (new == "bus-off")
    assert ("CRTL" in classes) == (new not in (None, "bus-off"))
    crtl = {name for bit, name in CRTL.items() if data[1] & bit}
    if new == "error-passive":
        assert crtl and crtl <= {"TX_PASSIVE", "RX_PASSIVE"}
        assert ("TX_PASSIVE" in crtl) == (tec >= 128) and ("RX_PASSIVE" in crtl) == (rec_ >= 128)
    elif new == "error-warning":
        assert ("TX_WARNING" in crtl) == (tec >= 96) and ("RX_WARNING" in crtl) == (rec_ >= 96)
    elif new == "error-active":
        assert crtl == {"ACTIVE"}
    else:
        assert not crtl


@pytest.mark.parametrize("suffix", [".blf", ".csv"])
def test_error_frames_round_trip_through_python_can(faulted, tmp_path, suffix):
    bus, errors = faulted
    path = tmp_path / f"faults{suffix}"
    assert save_trace(bus, path) == len(bus.trace)
    back = [m for m in can.LogReader(str(path)) if m.is_error_frame]
    assert len(back) == len(errors)
    for rec, msg in zip(errors, back):
        assert msg.dlc == 8
        _check(rec, msg.arbitration_id, bytes(msg.data))
    # the cases the demo produces are all there: the classes and the types
    seen = {(m.arbitration_id & 0x64, m.data[2] & 0x7F) for m in back}
    assert any(c & 0x40 for c, _ in seen) and any(c & 0x04 for c, _ in seen)  # bus off, state changes
    assert {t for _, t in seen} >= {0x01, 0x02, 0x04, 0x00}


def test_error_frame_hand_worked_ack_error(tmp_path):
    # a lone transmitter: nobody acknowledges. It finds an ACK error in the ACK slot (TEC 0 -> 8):
    # class PROT|BUSERROR|ACK|CNT = 0x2A8, type unspecified + PROT_TX = 0x80, location ACK slot
    # 0x19, TEC 8 / REC 0
    bus = SimBus(500_000)
    a = bus.node("a", one_shot=True)
    a.send(Frame(0x123, b"\x01"))
    bus.run(until=1_000_000)
    rec = next(r for r in bus.trace if r.kind == "error")
    msg = record_to_message(rec)
    assert msg.is_error_frame and msg.arbitration_id == 0x2A8
    assert bytes(msg.data) == bytes([0, 0, 0x80, 0x19, 0, 0, 8, 0])


def test_error_frame_hand_worked_local_crc_error():
    # b alone sees a flipped data bit: a CRC error found by a receiver (no PROT_TX), location the
    # CRC sequence 0x08; b: REC 1 (rule 1) + 8 (rule 2) = 9 (tests/stack/bus/test_fault_confinement)
    bus = SimBus(500_000)
    a = bus.node("a")
    bus.node("b"), bus.node("c")
    FaultInjector(bus).flip(can_id=0x123, field="data", bit=9, nodes=["b"])
    a.send(Frame(0x123, b"\x55\xaa"))
    bus.run(frames=1)
    rec = next(r for r in bus.trace if r.kind == "error")
    assert rec.detail["error"] == "crc" and rec.detail["seen_by"] == "b"
    msg = record_to_message(rec)
    assert msg.arbitration_id == 0x288 and bytes(msg.data) == bytes([0, 0, 0x00, 0x08, 0, 0, 0, 9])


def test_candump_log_carries_the_data_bytes(faulted, tmp_path):
    # python-can's .log writer puts every error frame under CAN_ERR_FLAG|CAN_ERR_BUSERROR
    # (20000080) and its reader keeps only "an error frame"; the 8 bytes are in the file
    bus, errors = faulted
    path = tmp_path / "faults.log"
    save_trace(bus, path)
    lines = [ln for ln in path.read_text().splitlines() if re.search(r" 20000080#", ln)]
    assert len(lines) == len(errors)
    for rec, line in zip(errors, lines):
        _check(rec, record_to_message(rec).arbitration_id, bytes.fromhex(line.split("#")[1]))
    assert sum(m.is_error_frame for m in can.LogReader(str(path))) == len(errors)


def test_asc_keeps_one_error_frame_per_record(faulted, tmp_path):
    # python-can's .asc writer has no fields for an error frame's content: 'ErrorFrame' lines
    bus, errors = faulted
    path = tmp_path / "faults.asc"
    save_trace(bus, path)
    assert path.read_text().count("ErrorFrame") == len(errors)
    assert sum(m.is_error_frame for m in can.LogReader(str(path))) == len(errors)
