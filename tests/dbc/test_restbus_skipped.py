"""`canstack restbus` refuses a CAN FD message on a bus without FD by name, runs it on an FD bus
(--data-bitrate), says which messages are no CAN frame (classical and longer than 8 bytes,
containers), prints its lines on stdout as `demo` does, and stops cleanly on Ctrl-C."""

from __future__ import annotations

import json
import os
import re
import signal
from pathlib import Path
from typing import ClassVar

import pytest

import dbc.cli as restbus_cli
import stack.cli as cli

DATA = Path(__file__).resolve().parent / "data"
FD_ONLY = str(DATA / "fd_only.dbc")  # RadarObjects (12 bytes, FD, 10 ms), RadarStatus (8 bytes, FD, 100 ms)
MIXED = str(DATA / "mixed.dbc")  # RadarObjects (FD), RadarStatus (classical, 100 ms), BodyLong (12 bytes, classical)
SAMPLE = str(Path(__file__).resolve().parents[2] / "dbc" / "databases" / "powertrain_body.dbc")


def run(capsys, *argv):
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_fd_message_on_a_bus_without_fd_is_refused_by_name(capsys):
    code, out, err = run(capsys, "restbus", FD_ONLY, "--duration", "1")
    assert code == 2 and out == "" and err.count("\n") == 1
    assert err == (
        f"canstack: error: {FD_ONLY}: message RadarObjects is a CAN FD frame and the bus carries classical "
        "frames only: give --data-bitrate D (e.g. 2000000) for a CAN FD bus\n"
    )


def test_database_of_fd_messages_runs_on_an_fd_bus(capsys):
    code, out, err = run(capsys, "restbus", FD_ONLY, "--duration", "1", "--data-bitrate", "2000000")
    assert code == 0 and err == ""
    assert re.search(r"Radar +RadarObjects +100 +10\.00", out) and re.search(r"Radar +RadarStatus +10 +100\.00", out)
    assert "simulated: Radar, Fusion; 110 frames on the bus in 1 s\n" in out


@pytest.mark.parametrize("json_mode", [False, True])
def test_classical_messages_longer_than_8_bytes_are_still_skipped(capsys, json_mode):
    code, out, err = run(
        capsys, "restbus", MIXED, "--duration", "1", "--data-bitrate", "2000000", *(["--json"] if json_mode else [])
    )
    assert code == 0
    assert err == (
        f"canstack: warning: {MIXED}: 1 of 3 messages skipped: 1 longer than 8 bytes "
        "(a classical frame carries at most 8 bytes, a CAN FD frame 64)\n"
    )
    if json_mode:
        rows = [json.loads(line) for line in out.splitlines()]
        assert {r["name"] for r in rows} == {"RadarStatus", "RadarObjects"} and len(rows) == 110
        objects = [r for r in rows if r["name"] == "RadarObjects"]
        # FD frames carry fd and brs (no CANFD_BRS in the DBC: on), classical ones no fd key
        assert all(r["fd"] is True and r["brs"] is True and len(r["data"]) == 24 for r in objects)
        assert all("fd" not in r for r in rows if r["name"] == "RadarStatus")
    else:
        assert re.search(r"Radar +RadarStatus +10 +100\.00", out)
        assert (
            "simulated: Radar, Fusion, Body; 110 frames on the bus in 1 s; 1 of 3 messages skipped: 1 longer than 8 bytes\n"
        ) in out


def test_text_lines_on_stdout_json_info_on_stderr(capsys, tmp_path):
    trace = tmp_path / "t.asc"
    code, out, err = run(capsys, "restbus", SAMPLE, "--duration", "0.2", "--trace", str(trace))
    assert code == 0 and err == ""
    assert re.search(r"^trace: \d+ records written to .*t\.asc$", out, re.M)
    assert re.search(r"^simulated: .*frames on the bus in 0\.2 s$", out, re.M)
    code, out, err = run(capsys, "restbus", SAMPLE, "--duration", "0.2", "--trace", str(trace), "--json")
    assert code == 0 and all(line.startswith("{") for line in out.splitlines())
    assert re.fullmatch(r"trace: \d+ records written to .*t\.asc\n", err)


def test_unwritable_trace_is_refused_before_the_run(capsys, tmp_path):
    (tmp_path / "afile").write_text("")
    code, out, err = run(capsys, "restbus", SAMPLE, "--trace", str(tmp_path / "afile" / "t.asc"))
    assert code == 2 and out == "" and "afile' is a file, not a directory" in err and err.count("\n") == 1
    code, out, err = run(capsys, "restbus", SAMPLE, "--trace", str(tmp_path / "no" / "t.asc"))
    assert code == 2 and "does not exist" in err


def test_binary_database_is_not_echoed(capsys, tmp_path):
    binary = tmp_path / "firmware.dbc"
    binary.write_bytes(b"\x7fELF\x02\x01\x01\x00" + bytes(range(256)))
    code, out, err = run(capsys, "restbus", str(binary))
    assert code == 2 and err.count("\n") == 1 and err.isprintable() is False  # only the newline
    assert "binary content (a NUL byte at offset 7)" in err and "\x7f" not in err and "\x01" not in err


def test_ctrl_c_keeps_the_summary_so_far(capsys, monkeypatch, tmp_path):
    real = restbus_cli.run_sliced

    def interrupted(bus, until, **kw):
        bus.call_at(300_000_000, lambda: os.kill(os.getpid(), signal.SIGINT))
        return real(bus, until, **kw)

    monkeypatch.setattr(restbus_cli, "run_sliced", interrupted)
    trace = tmp_path / "t.csv"
    code, out, err = run(capsys, "restbus", SAMPLE, "--duration", "3600", "--trace", str(trace))
    assert code == 130
    m = re.search(r"interrupted at ([0-9.]+) s of 3600 s", out)
    assert m and 0.3 <= float(m.group(1)) < 1.0
    assert "EngineData" in out and trace.stat().st_size > 0
    assert err.startswith("canstack: interrupted at")


def test_python_can_run_stops_cleanly_on_ctrl_c(monkeypatch):
    class Driver:
        errors: ClassVar[list] = []
        stopped = False

        def start(self):
            pass

        def stop(self):
            self.stopped = True

    def ctrl_c(_):
        raise KeyboardInterrupt

    monkeypatch.setattr(restbus_cli.time, "sleep", ctrl_c)
    drv = Driver()
    ran, complete = restbus_cli._run_driver(drv, 1e9)
    assert complete is False and drv.stopped and ran < 1
