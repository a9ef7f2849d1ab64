"""Driving the rest bus: --set and stimulus files (checked against cantools' own decoding), every
multiplexer page in turn, and a database that would send nothing (--default-cycle)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import cantools
import pytest

import stack.cli as cli

SAMPLE = str(Path(__file__).resolve().parents[2] / "dbc" / "databases" / "powertrain_body.dbc")
SHARED = Path(os.environ.get("CANSTACK_SHARED") or Path(__file__).resolve().parents[3] / "shared")
MULTIPLEX_2 = SHARED / "corpus" / "dbc" / "cantools" / "multiplex_2.dbc"


def run(capsys, *argv):
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def frames(out: str, name: str) -> list[dict]:
    """The --json rows of message ``name``, with cantools' own decoding of their data."""
    db = cantools.database.load_file(SAMPLE)
    rows = [json.loads(line) for line in out.splitlines()]
    msg = db.get_message_by_name(name)
    picked = [r for r in rows if r["name"] == name]
    for r in picked:
        r["cantools"] = msg.decode(bytes.fromhex(r["data"]), decode_choices=True)
    return picked


def test_set_physical_values_and_choice_names_go_on_the_wire(capsys):
    code, out, err = run(
        capsys,
        "restbus",
        SAMPLE,
        "--duration",
        "0.1",
        "--json",
        "--set",
        "EngineData.EngineSpeed=2000.5",
        "--set",
        "GearboxData.GearSelected=D",
        "--set",
        "EngineData.EngineTorque=-12.3",
    )
    assert code == 0, err
    eng = frames(out, "EngineData")
    assert len(eng) == 10
    assert all(r["cantools"]["EngineSpeed"] == 2000.5 for r in eng)  # from the first frame on
    assert all(r["cantools"]["EngineTorque"] == pytest.approx(-12.3) for r in eng)
    gear = frames(out, "GearboxData")
    assert gear and all(str(r["cantools"]["GearSelected"]) == "D" for r in gear)


@pytest.mark.parametrize("suffix", [".csv", ".toml"])
def test_stimulus_file_changes_signals_at_their_times(capsys, tmp_path, suffix):
    stim = tmp_path / f"stim{suffix}"
    if suffix == ".csv":
        stim.write_text(
            "time,message,signal,value\n0.045,EngineData,EngineSpeed,3000\n0.0,GearboxData,GearSelected,R\n"
            "0.0625,GearboxData,GearSelected,N\n"
        )
    else:
        stim.write_text(
            '[[changes]]\ntime = 0.045\nmessage = "EngineData"\nsignal = "EngineSpeed"\nvalue = 3000\n'
            '[[changes]]\ntime = 0\nmessage = "GearboxData"\nsignal = "GearSelected"\nvalue = "R"\n'
            '[[changes]]\ntime = 0.0625\nmessage = "GearboxData"\nsignal = "GearSelected"\nvalue = "N"\n'
        )
    code, out, err = run(capsys, "restbus", SAMPLE, "--duration", "0.1", "--json", "--stimulus", str(stim))
    assert code == 0, err
    eng = frames(out, "EngineData")  # every 10 ms from 0
    speeds = [(r["t"] < 0.045, r["cantools"]["EngineSpeed"]) for r in eng]
    assert {s for before, s in speeds if before} == {800.0}  # the DBC's start value
    assert {s for before, s in speeds if not before} == {3000.0}
    gear = frames(out, "GearboxData")  # every 20 ms from 5 ms
    assert [str(r["cantools"]["GearSelected"]) for r in gear] == ["R"] * 3 + ["N"] * 2


def test_stimulus_on_a_spontaneous_message_sends_it(capsys, tmp_path):
    stim = tmp_path / "doors.csv"
    stim.write_text("time,message,signal,value\n0.03,DoorStatus,DoorFL,Open\n")
    code, out, err = run(capsys, "restbus", SAMPLE, "--duration", "0.2", "--json", "--stimulus", str(stim))
    assert code == 0, err
    doors = frames(out, "DoorStatus")
    # OnChange with repetition (GenMsgNrOfRepetition 2, GenMsgCycleTimeFast 50 ms): 30, 80, 130 ms
    assert [round(r["t"], 2) for r in doors] == [0.03, 0.08, 0.13]
    assert all(str(r["cantools"]["DoorFL"]) == "Open" for r in doors)


@pytest.mark.parametrize(
    "argv, fragments",
    [
        (["--set", "EngineData.EngineSpeed=20000"], ["EngineData.EngineSpeed", "[0 .. 16000] rpm"]),
        (["--set", "EngineData.EngineTemp=-41"], ["EngineData.EngineTemp", "[-40 .. 215] degC"]),
        (["--set", "GearboxData.GearSelected=X"], ["GearboxData.GearSelected", "P, R, N, D, S"]),
        (["--set", "EngineData.EngineSped=1"], ["'EngineSped'", "EngineSpeed"]),
        (["--set", "EngineDat.EngineSpeed=1"], ["'EngineDat'", "EngineData"]),
        (["--set", "EngineData.EngineSpeed"], ["Message.Signal=VALUE"]),
        (["--set", "EngineData.EngineSpeed=nan"], ["EngineData.EngineSpeed", "finite"]),
        (["--dut", "IPC", "--set", "ClusterStatus.FuelLevel=10"], ["ClusterStatus", "DUT IPC"]),
        (["--default-cycle", "0"], ["--default-cycle", "1 .. 3600000 ms"]),
    ],
)
def test_bad_set_is_one_line_naming_the_signal_exit_2(capsys, argv, fragments):
    code, out, err = run(capsys, "restbus", SAMPLE, "--duration", "0.1", *argv)
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    for f in fragments:
        assert f in err


@pytest.mark.parametrize(
    "name, text, fragments",
    [
        ("h.csv", "t,message,signal,value\n", ["line 1", "time,message,signal,value"]),
        ("cols.csv", "time,message,signal,value\n1,EngineData,EngineSpeed\n", ["line 2", "3 columns"]),
        ("time.csv", "time,message,signal,value\nsoon,EngineData,EngineSpeed,1\n", ["line 2", "'soon'"]),
        ("neg.csv", "time,message,signal,value\n-1,EngineData,EngineSpeed,1\n", ["line 2", ">= 0"]),
        ("range.csv", "time,message,signal,value\n0.5,EngineData,EngineSpeed,-5\n", ["line 2", "[0 .. 16000]"]),
        ("key.toml", '[[changes]]\ntime = 1\nmessage = "EngineData"\nsignal = "EngineSpeed"\n', ["#1", "'value'"]),
        ("extra.toml", "[[change]]\ntime = 1\n", ["'change'", "[[changes]]"]),
        ("bad.toml", "[[changes]\n", ["not valid TOML"]),
    ],
)
def test_bad_stimulus_file_is_one_line_naming_where(capsys, tmp_path, name, text, fragments):
    path = tmp_path / name
    path.write_text(text)
    code, out, err = run(capsys, "restbus", SAMPLE, "--duration", "0.1", "--stimulus", str(path))
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert name in err
    for f in fragments:
        assert f in err


def test_every_multiplexer_page_in_turn_and_decoded_as_cantools_does(capsys):
    code, out, err = run(capsys, "restbus", SAMPLE, "--duration", "1", "--json")
    assert code == 0, err
    gw = frames(out, "GatewayInfo")  # 200 ms cycle: 5 frames, pages 0 and 1 alternating
    assert [str(r["cantools"]["InfoPage"]) for r in gw] == ["Battery", "Environment"] * 2 + ["Battery"]
    for r in gw:  # the monitor decodes each page as cantools does
        assert r["signals"] == {k: str(v) if k == "InfoPage" else v for k, v in r["cantools"].items()}
    assert "BatteryVoltage" in gw[0]["signals"] and "AmbientTemp" in gw[1]["signals"]


@pytest.mark.skipif(not MULTIPLEX_2.is_file(), reason="../shared/corpus is absent")
def test_extended_multiplexing_sends_every_page(capsys):
    """cantools' multiplex_2.dbc nests multiplexers (SG_MUL_VAL_) and names no sender: with a
    default cycle, every multiplexed signal appears in some frame, as cantools decodes them."""
    db = cantools.database.load_file(str(MULTIPLEX_2))
    code, out, err = run(capsys, "restbus", str(MULTIPLEX_2), "--default-cycle", "10", "--duration", "0.5", "--json")
    assert code == 0, err
    rows = [json.loads(line) for line in out.splitlines()]
    for m in db.messages:
        mine = [r for r in rows if r["id"] == m.frame_id and r["extended"] == m.is_extended_frame]
        assert mine and all(r["sender"] == "Vector__XXX" for r in mine)
        seen: set[str] = set()
        for r in mine:
            seen |= set(m.decode(bytes.fromhex(r["data"])))
        assert seen == {s.name for s in m.signals}, m.name


def test_nothing_to_send_says_why_and_offers_default_cycle(capsys, tmp_path):
    dbc = tmp_path / "quiet.dbc"
    dbc.write_text(
        'VERSION ""\nBS_:\nBU_: A B\n'
        'BO_ 100 FromA: 2 A\n SG_ X : 0|16@1+ (0.5,0) [0|100] "V" B\n'
        'BO_ 200 NoSender: 1 Vector__XXX\n SG_ Y : 0|8@1+ (1,0) [0|255] "" B\n'
    )
    code, out, err = run(capsys, "restbus", str(dbc), "--duration", "0.1")
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "quiet.dbc" in err and "1 no sender" in err and "1 no cycle time" in err and "--default-cycle" in err
    code, out, err = run(capsys, "restbus", str(dbc), "--duration", "0.1", "--default-cycle", "20", "--json")
    assert code == 0, err
    rows = [json.loads(line) for line in out.splitlines()]
    assert [r["t"] for r in rows if r["name"] == "FromA"] == pytest.approx([0.0, 0.02, 0.04, 0.06, 0.08], abs=1e-3)
    assert {r["sender"] for r in rows if r["name"] == "NoSender"} == {"Vector__XXX"}
    assert len([r for r in rows if r["name"] == "NoSender"]) == 5
    # a stimulus that writes a spontaneous message is something to send
    code, out, err = run(capsys, "restbus", str(dbc), "--duration", "0.1", "--set", "FromA.X=3")
    assert code == 2 and "--default-cycle" in err  # FromA has no send type: a write sends nothing


def test_dut_unknown_lists_the_nodes(capsys):
    code, out, err = run(capsys, "restbus", SAMPLE, "--dut", "NOPE")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "ECM, TCM, ABS, BCM, IPC, GW" in err


@pytest.mark.wallclock
def test_set_on_a_python_can_bus(capsys, rerun_until):
    """--set drives the same ECUs on python-can's virtual bus (wall clock)."""

    def once():
        code, out, err = run(
            capsys,
            "restbus",
            SAMPLE,
            "--duration",
            "0.2",
            "--interface",
            "virtual",
            "--channel",
            "dbc-test-drive",
            "--json",
            "--set",
            "EngineData.EngineSpeed=1234.5",
            "--set",
            "GearboxData.GearSelected=S",
        )
        assert code == 0, err
        eng, gear = frames(out, "EngineData"), frames(out, "GearboxData")
        assert all(r["cantools"]["EngineSpeed"] == 1234.5 for r in eng)
        assert all(str(r["cantools"]["GearSelected"]) == "S" for r in gear)
        return eng

    rerun_until(once, lambda eng: len(eng) >= 5)
