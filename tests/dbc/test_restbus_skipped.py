"""`canstack restbus` says which database messages a CAN 2.0 bus cannot carry (CAN FD, longer
than 8 bytes, containers), refuses a database with nothing left to simulate, prints its lines
on stdout as `demo` does, and stops cleanly on Ctrl-C."""

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

SHARED = Path(os.environ.get("CANSTACK_SHARED") or Path(__file__).resolve().parents[3] / "shared")
DATA = Path(__file__).resolve().parent / "data"
FD_ONLY = str(DATA / "fd_only.dbc")  # RadarObjects (12 bytes, FD), RadarStatus (8 bytes, FD)
MIXED = str(DATA / "mixed.dbc")  # RadarObjects (FD), RadarStatus (classical, 100 ms), BodyLong (12 bytes, classical)
SAMPLE = str(Path(__file__).resolve().parents[2] / "dbc" / "databases" / "powertrain_body.dbc")
FORD = SHARED / "corpus" / "dbc" / "opendbc" / "ford_lincoln_base_pt.dbc"


def run(capsys, *argv):
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_database_of_fd_messages_only_is_refused_with_the_reason(capsys):
    code, out, err = run(capsys, "restbus", FD_ONLY, "--duration", "1")
    assert code == 2 and out == "" and err.count("\n") == 1
    assert err == (
        f"canstack: error: {FD_ONLY}: nothing to simulate: 2 of 2 messages skipped: 2 CAN FD "
        "(a CAN 2.0 bus carries classical frames of at most 8 bytes)\n"
    )


@pytest.mark.parametrize("json_mode", [False, True])
def test_skipped_messages_are_counted_by_reason(capsys, json_mode):
    code, out, err = run(capsys, "restbus", MIXED, "--duration", "1", *(["--json"] if json_mode else []))
    assert code == 0
    assert err == (
        f"canstack: warning: {MIXED}: 2 of 3 messages skipped: 1 CAN FD, 1 longer than 8 bytes "
        "(a CAN 2.0 bus carries classical frames of at most 8 bytes)\n"
    )
    if json_mode:
        rows = [json.loads(line) for line in out.splitlines()]
        assert {r["name"] for r in rows} == {"RadarStatus"} and len(rows) == 10  # 100 ms for 1 s
    else:
        assert re.search(r"Radar +RadarStatus +10 +100\.00", out)
        # the text summary says it too
        assert (
            "simulated: Radar, Fusion, Body; 10 frames on the bus in 1 s; "
            "2 of 3 messages skipped: 1 CAN FD, 1 longer than 8 bytes\n"
        ) in out


@pytest.mark.skipif(not FORD.is_file(), reason="../shared/corpus not present")
def test_opendbc_ford_every_message_is_fd(capsys):
    code, out, err = run(capsys, "restbus", str(FORD), "--duration", "1")
    assert code == 2 and err.count("\n") == 1
    assert "nothing to simulate: 331 of 331 messages skipped: 331 CAN FD" in err


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
