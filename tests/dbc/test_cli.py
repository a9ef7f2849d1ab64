"""`canstack restbus`: output, JSON lines, trace file, and one-line errors with exit status 2."""

import json
from pathlib import Path

import can
import pytest

import stack.cli as cli

SAMPLE = str(Path(__file__).resolve().parents[2] / "dbc" / "databases" / "powertrain_body.dbc")


def run(capsys, *argv):
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_json_lines_one_per_frame(capsys, sample_db):
    code, out, err = run(capsys, "restbus", SAMPLE, "--dut", "IPC", "--duration", "0.1", "--json")
    assert code == 0
    rows = [json.loads(line) for line in out.splitlines()]
    names = {r["name"] for r in rows}
    assert "ClusterStatus" not in names  # the DUT is not simulated
    eng = [r for r in rows if r["name"] == "EngineData"]
    assert len(eng) == 10 and all(r["sender"] == "ECM" and r["id"] == 0x100 for r in eng)
    # times in seconds, 10 ms apart (the first frame wins arbitration at t=0)
    assert eng[1]["t"] - eng[0]["t"] == pytest.approx(0.010, abs=1e-9)
    gear = next(r for r in rows if r["name"] == "GearboxData")
    assert gear["signals"]["GearSelected"] == "P"  # choices as names
    eec1 = next(r for r in rows if r["name"] == "EEC1")
    assert eec1["id"] == 0x0CF00400 and eec1["extended"] is True
    msg = sample_db.get_message_by_name("EngineData")
    assert eng[0]["signals"]["EngineSpeed"] == msg.decode(bytes.fromhex(eng[0]["data"]))["EngineSpeed"]


def test_text_summary_and_trace(capsys, tmp_path):
    trace = tmp_path / "out.asc"
    code, out, err = run(capsys, "restbus", SAMPLE, "--duration", "0.2", "--trace", str(trace))
    assert code == 0
    assert "ClusterStatus" in out and "EngineData" in out
    msgs = [m for m in can.LogReader(str(trace)) if not m.is_error_frame]
    assert sum(1 for m in msgs if m.arbitration_id == 0x100) == 20


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (["--dut", "IPX"], "did you mean 'IPC'"),
        (["--duration", "0"], "--duration"),
        (["--interface", "socketcan", "--channel", "vcan0", "--bus", "sim"], "not both"),
        (["--trace", "x.xyz"], "unknown suffix"),
    ],
)
def test_bad_arguments_one_line_exit_2(capsys, argv, fragment):
    code, out, err = run(capsys, "restbus", SAMPLE, *argv)
    assert code == 2 and fragment in err and len(err.strip().splitlines()) == 1


def test_malformed_and_missing_dbc(capsys, tmp_path):
    bad = tmp_path / "bad.dbc"
    bad.write_text('VERSION ""\n\nBU_: A\n\nBO_ 1 M: 8 A\n SG_ S 0|8@1+ (1,0) [0|1] "" A\n')
    code, out, err = run(capsys, "restbus", str(bad))
    assert code == 2 and "line 6" in err and len(err.strip().splitlines()) == 1
    code, out, err = run(capsys, "restbus", str(tmp_path / "none.dbc"))
    assert code == 2 and "no such file" in err


def test_unknown_interface_is_one_line_exit_2(capsys):
    code, out, err = run(
        capsys, "restbus", SAMPLE, "--interface", "nosuchinterface", "--channel", "x", "--duration", "0.1"
    )
    assert code == 2 and "nosuchinterface" in err and len(err.strip().splitlines()) == 1


@pytest.mark.wallclock
def test_same_restbus_on_a_python_can_bus(capsys, rerun_until):
    """The ECUs run unchanged on python-can's virtual bus through stack.io.driver (wall clock)."""

    def once():
        code, out, err = run(
            capsys,
            "restbus",
            SAMPLE,
            "--dut",
            "IPC",
            "--duration",
            "0.25",
            "--interface",
            "virtual",
            "--channel",
            "dbc-test-restbus",
            "--json",
        )
        assert code == 0, err
        rows = [json.loads(line) for line in out.splitlines()]
        eng = [r for r in rows if r["name"] == "EngineData"]
        counters = [r["signals"]["EngineCounter"] for r in eng]
        assert eng and counters == [(counters[0] + k) % 16 for k in range(len(counters))]  # none lost
        return eng

    # a 10 ms cycle for 0.25 s of wall clock, on a machine that lets the driver's thread keep time
    rerun_until(once, lambda eng: 15 <= len(eng) <= 30)


@pytest.mark.wallclock
def test_bitrate_is_passed_to_the_python_can_bus(capsys):
    """A canstack bus already running at 250 kbit/s refuses nodes joining at another rate, so
    a restbus with --bitrate 125000 must fail and one with 250000 must run."""

    keeper = can.Bus(interface="canstack", channel="dbc-cli-bitrate", bitrate=250_000)
    try:
        code, out, err = run(
            capsys,
            "restbus",
            SAMPLE,
            "--duration",
            "0.1",
            "--interface",
            "canstack",
            "--channel",
            "dbc-cli-bitrate",
            "--bitrate",
            "125000",
        )
        assert code == 2 and "250000" in err and "125000" in err and len(err.strip().splitlines()) == 1
        code, out, err = run(
            capsys,
            "restbus",
            SAMPLE,
            "--duration",
            "0.1",
            "--interface",
            "canstack",
            "--channel",
            "dbc-cli-bitrate",
            "--bitrate",
            "250000",
            "--json",
        )
        assert code == 0 and out
    finally:
        keeper.shutdown()
    code, out, err = run(capsys, "restbus", SAMPLE, "--bitrate", "5", "--duration", "0.1")
    assert code == 2 and "1000..1000000" in err and len(err.strip().splitlines()) == 1


@pytest.mark.wallclock
@pytest.mark.socket
def test_lost_bus_connection_exits_2_with_one_line(capsys):
    """The canstack server goes away once the rest-bus runs (its first frame is on the bus), early
    in a 5 s run: restbus stops and names the error."""
    import threading
    import time

    from stack.io.serve import BusServer

    server = BusServer(500_000, listen=("127.0.0.1", 0))
    closed_at = []

    def close_once_running():
        # the ECUs join one by one (slowly on a loaded machine); closing before the run would
        # test a failed start instead
        deadline = time.monotonic() + 60.0
        while server.runner.call(lambda: server.sim.frames_ok) == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        closed_at.append(time.monotonic())
        server.close()

    closer = threading.Thread(target=close_once_running)
    closer.start()
    try:
        code, out, err = run(
            capsys, "restbus", SAMPLE, "--duration", "5", "--interface", "canstack", "--channel", server.url
        )
        stopped_at = time.monotonic()
    finally:
        closer.join()
        server.close()
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert server.url in err and "failed" in err
    assert stopped_at - closed_at[0] < 4  # it did not run on for the rest of the duration


def test_malformed_dbc_without_line_from_cantools_is_one_line(capsys, tmp_path):
    text = (
        'VERSION ""\nBS_:\nBU_: A\nBO_ 100 M: 8 A\n SG_ S : 0|8@1+ (1,0) [0|255] "" A\n'
        'BA_ "GenMsgCycleTime" BO_ 100 10;\n'
    )
    bad = tmp_path / "undefattr.dbc"
    bad.write_text(text)
    code, out, err = run(capsys, "restbus", str(bad), "--duration", "0.1")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "line 6" in err and 'attribute "GenMsgCycleTime"' in err
