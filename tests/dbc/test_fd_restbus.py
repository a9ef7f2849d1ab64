"""`canstack restbus` on CAN FD databases: the opendbc Ford DBC's cyclic messages on a simulated FD
bus and an FD python-can bus, what goes on the bus decoded by cantools as the independent peer."""

from __future__ import annotations

import json
import math
import os
import re
import threading
from pathlib import Path

import can
import cantools
import pytest

import stack.cli as cli

SHARED = Path(os.environ.get("CANSTACK_SHARED") or Path(__file__).resolve().parents[3] / "shared")
FORD = SHARED / "corpus" / "dbc" / "opendbc" / "ford_lincoln_base_pt.dbc"
FD_ECUS = str(Path(__file__).resolve().parent / "data" / "fd_ecus.dbc")

# ISO 11898-1:2015, table 5: the data lengths a CAN FD DLC codes
ISO_FD_LENGTHS = [0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64]

needs_ford = pytest.mark.skipif(not FORD.is_file(), reason="../shared/corpus not present")


def run(capsys, *argv):
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def plain(value):
    """A cantools value as `canstack restbus --json` writes it: a choice as its name."""
    return str(value) if isinstance(value, cantools.database.namedsignalvalue.NamedSignalValue) else value


def start_delay_ms(m) -> int:
    a = (m.dbc.attributes or {}).get("GenMsgStartDelayTime")
    return int(a.value) if a is not None else 0


@needs_ford
def test_ford_cyclic_messages_are_simulated_on_an_fd_bus(capsys, corpus_databases, read_once):
    code, out, err = run(capsys, "restbus", str(FORD), "--duration", "0.5", "--data-bitrate", "2000000", "--json")
    assert code == 0 and err == ""
    db = corpus_databases[FORD]  # cantools' reading of the file (strict, as cantools loads by default)
    assert all(m.is_fd for m in db.messages)  # the reason this DBC ran nothing before
    rows = [json.loads(line) for line in out.splitlines()]
    counts: dict[str, int] = {}
    for r in rows:
        m = db.get_message_by_frame_id(r["id"] | (0x80000000 if r["extended"] else 0))
        assert r["name"] == m.name
        data = bytes.fromhex(r["data"])
        assert r["fd"] is True and r["brs"] is True  # no CANFD_BRS in this DBC: CANdb++'s default, on
        assert len(data) == min(n for n in ISO_FD_LENGTHS if n >= m.length)
        assert r["signals"] == {k: plain(v) for k, v in m.decode(data[: m.length]).items()}
        counts[m.name] = counts.get(m.name, 0) + 1
    # every message with a sender and a cycle time, at its rate from its start delay; nothing else
    expected = {}
    for m in db.messages:
        if m.cycle_time and m.senders and start_delay_ms(m) < 500:
            expected[m.name] = math.ceil((500 - start_delay_ms(m)) / m.cycle_time)
    assert len(expected) > 140
    assert counts == expected


@needs_ford
def test_ford_without_a_data_bitrate_is_refused_naming_a_message(capsys, corpus_databases, read_once):
    code, out, err = run(capsys, "restbus", str(FORD), "--duration", "1")
    assert code == 2 and out == "" and err.count("\n") == 1
    m = re.search(
        r"message (\w+) is a CAN FD frame and the bus carries classical frames only: give --data-bitrate", err
    )
    assert m and corpus_databases[FORD].get_message_by_name(m.group(1)).is_fd


def test_data_bitrate_below_the_nominal_rate_is_refused(capsys):
    code, out, err = run(capsys, "restbus", FD_ECUS, "--bitrate", "500000", "--data-bitrate", "250000")
    assert code == 2 and err.count("\n") == 1 and "--data-bitrate 250000 below the nominal bit rate 500000" in err


@pytest.mark.wallclock
def test_fd_messages_on_a_python_can_fd_bus_reach_a_python_can_peer(capsys):
    """The rest bus on the canstack interface with --fd; a python-can FD bus on the same channel
    receives the frames, cantools decodes them."""
    db = cantools.database.load_file(FD_ECUS)
    peer = can.Bus(interface="canstack", channel="fdrestbus", fd=True)
    got: list[can.Message] = []
    stop = threading.Event()

    def read() -> None:
        while not stop.is_set():
            msg = peer.recv(0.05)
            if msg is not None:
                got.append(msg)

    reader = threading.Thread(target=read)
    reader.start()
    try:
        code, out, err = run(
            capsys, "restbus", FD_ECUS, "--interface", "canstack", "--channel", "fdrestbus", "--fd", "--duration", "0.3"
        )
    finally:
        stop.set()
        reader.join()
        peer.shutdown()
    assert code == 0, err
    status = [m for m in got if m.arbitration_id == db.get_message_by_name("CameraStatus").frame_id]
    assert status and all(m.is_fd and not m.bitrate_switch and m.dlc == 12 for m in status)  # CANFD_BRS 0
    assert db.get_message_by_name("CameraStatus").decode(status[0].data[:10])["CamTail"] == 85
    raw = [m for m in got if m.is_extended_id]
    assert raw and all(m.is_fd and m.bitrate_switch and len(m.data) == 64 for m in raw)
    assert {m.is_fd for m in got if m.arbitration_id == 0x220} == {False}  # BodyClassic


def test_python_can_bus_without_fd_is_refused_naming_the_message(capsys):
    code, out, err = run(
        capsys, "restbus", FD_ECUS, "--interface", "canstack", "--channel", "nofd", "--duration", "0.1"
    )
    assert code == 2 and err.count("\n") == 1
    assert "message CameraObjects is a CAN FD frame and the bus carries classical frames only: give --fd or" in err


def test_fd_alone_runs_the_simulated_bus_at_2_mbit_data_rate(capsys):
    code, out, err = run(capsys, "restbus", FD_ECUS, "--fd", "--duration", "0.05", "--json")
    assert code == 0, err
    rows = [json.loads(line) for line in out.splitlines()]
    status = [r for r in rows if r["name"] == "CameraStatus"]
    objects = [r for r in rows if r["name"] == "CameraObjects"]
    # CameraStatus: CANFD_BRS "0"; CameraObjects: the definition's default "1"
    assert status and all(r["fd"] is True and r["brs"] is False for r in status)
    assert len(objects) == 5 and all(r["fd"] is True and r["brs"] is True for r in objects)
    # the same bus as --data-bitrate 2000000, frame for frame and ns for ns; another data rate
    # changes the times of the frames with BRS
    assert run(capsys, "restbus", FD_ECUS, "--data-bitrate", "2000000", "--duration", "0.05", "--json")[1] == out
    slower = run(capsys, "restbus", FD_ECUS, "--data-bitrate", "1000000", "--duration", "0.05", "--json")[1]
    assert [json.loads(line)["t"] for line in slower.splitlines()] != [r["t"] for r in rows]
