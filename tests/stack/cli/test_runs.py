"""Long runs and their outputs on the command line: outputs and optional libraries checked
before a run, the summary table adding up, streaming statistics, Ctrl-C, progress, .trc, and the
options every command documents."""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import json
import os
import re
import signal
from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

import pytest

import stack.cli.demo as demo
from stack.bus.sim import SimBus
from stack.cli import build_parser, main
from stack.io.progress import TimeLimitExceeded, run_sliced, stop_when, time_limit

ROOT = Path(__file__).resolve().parents[3]


def _run(capsys, *argv):
    rc = main(list(argv))
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def _one_line(rc, err):
    assert rc == 2, err
    assert err.startswith("canstack: error: ") and err.count("\n") == 1 and "Traceback" not in err, err


# ---------------------------------------------------------------------------------------------
# the summary table


def test_demo_table_rows_add_up_to_the_header(capsys):
    rc, out, _ = _run(capsys, "demo")
    assert rc == 0
    total = int(re.search(r"(\d+) frames, \d+ error frames", out).group(1))
    rows = re.findall(r"^ +(0x[0-9A-F]+(?: RTR)?) +(\d+) ", out, re.M)
    assert sum(int(n) for _, n in rows) == total == 670
    # the tester's remote request and body's automatic reply are two frames on the wire:
    # one every 50 ms each for 1 s
    assert ("0x700 RTR", "20") in rows and ("0x700", "20") in rows


def test_demo_json_ids_add_up_and_carry_integers(capsys):
    rc, out, _ = _run(capsys, "demo", "--json")
    s = json.loads(out)
    assert sum(v["count"] for v in s["ids"].values()) == s["frames"] == 670
    rtr = s["ids"]["0x700 RTR"]
    assert (rtr["id"], rtr["remote"], rtr["extended"]) == (0x700, True, False)
    assert s["ids"]["0x18FEF100"]["id"] == 0x18FEF100 and s["ids"]["0x18FEF100"]["extended"] is True


# ---------------------------------------------------------------------------------------------
# streaming: no records unless a file is made of them, bounded samples


def _capture_bus(monkeypatch):
    made = {}

    class Recorder(SimBus):
        def __init__(self, *a, **kw):
            made["record"] = kw.get("record")
            made["keep"] = kw.get("keep", True)
            super().__init__(*a, **kw)
            made["bus"] = self

    monkeypatch.setattr(demo, "SimBus", Recorder)
    return made


@pytest.mark.parametrize(
    "extra,record",
    [([], False), (["--faults"], False), (["--trace", "{tmp}/t.blf"], True), (["--vcd", "{tmp}/t.vcd"], True)],
)
def test_demo_makes_trace_records_only_for_a_file_and_keeps_none(monkeypatch, capsys, tmp_path, extra, record):
    made = _capture_bus(monkeypatch)
    rc, out, _ = _run(capsys, "demo", "--duration", "0.05", *[a.format(tmp=tmp_path) for a in extra])
    assert rc == 0 and made["record"] is record
    # the records stream into the file (or the waveform's frames): the bus keeps none of them
    assert made["keep"] is False and len(made["bus"].trace) == 0
    assert "frames" in out
    if record:
        written = next(tmp_path.iterdir())
        assert written.stat().st_size > 0


def test_fault_demo_samples_are_bounded_on_a_long_run(monkeypatch, capsys, tmp_path):
    pytest.importorskip("matplotlib")
    seen = {}
    real = demo.build_fault_demo

    def spy(bus, sample_every=demo.MS // 2):
        seen["every"] = sample_every
        return real(bus, sample_every)

    monkeypatch.setattr(demo, "build_fault_demo", spy)
    monkeypatch.setattr(demo, "run_sliced", lambda bus, until, **kw: True)  # the run itself is not the point
    monkeypatch.setattr(demo, "plot_counters", lambda samples, path: None)
    assert main(["demo", "--faults", "--duration", "1000", "--plot", str(tmp_path / "p.png")]) == 0
    assert seen["every"] == 50_000_000  # 1000 s / 20,000 samples
    assert main(["demo", "--faults", "--duration", "1", "--plot", str(tmp_path / "p.png")]) == 0
    assert seen["every"] == 500_000  # the plot's 0.5 ms on a short run
    assert main(["demo", "--faults", "--duration", "1000"]) == 0
    assert seen["every"] is None  # no plot, no samples


def _digest(bus):
    h = hashlib.sha256()
    for r in bus.trace:
        h.update(repr(r.as_tuple()).encode())
    return h.hexdigest()


def test_a_sliced_run_is_the_same_run():
    whole, sliced = SimBus(500_000, seed=3), SimBus(500_000, seed=3)
    demo.build_demo(whole)
    demo.build_demo(sliced)
    whole.run(until=300_000_000)
    assert run_sliced(sliced, 300_000_000, progress=False)
    assert sliced.now() == whole.now() and _digest(sliced) == _digest(whole)
    assert sliced.summary() == whole.summary()


def test_a_stop_flag_stops_the_run_at_the_end_of_the_slice_it_was_raised_in():
    # a sweep's pool worker passes its stop flag: a stop that comes before the run installed its
    # Ctrl-C handler (SIGINT is ignored then) must still end the run, at a slice's end
    bus = SimBus(500_000, seed=3)
    demo.build_demo(bus)
    raised = []
    bus.call_at(250_000_000, lambda: raised.append(True))
    with stop_when(lambda: bool(raised)):
        assert run_sliced(bus, 20_000_000_000, progress=False) is False
    # slices of 100 ms of bus time for a 20 s run: the one that holds 0.25 s ends at 0.3 s
    assert bus.now() == 300_000_000
    assert run_sliced(bus, 400_000_000, progress=False)  # outside the block the flag counts no more


# ---------------------------------------------------------------------------------------------
# Ctrl-C and progress


def test_ctrl_c_prints_the_summary_so_far_and_keeps_the_trace(monkeypatch, capsys, tmp_path):
    real = demo.build_demo

    def with_ctrl_c(bus):
        real(bus)
        bus.call_at(200_000_000, lambda: os.kill(os.getpid(), signal.SIGINT))

    monkeypatch.setattr(demo, "build_demo", with_ctrl_c)
    trace = tmp_path / "t.csv"
    rc, out, err = _run(capsys, "demo", "--duration", "3600", "--trace", str(trace))
    assert rc == 130
    m = re.search(r"interrupted at ([0-9.]+) s of 3600 s", out)
    assert m and 0.2 <= float(m.group(1)) < 0.5  # at the end of the slice the signal came in
    assert "bus load" in out and "trace:" in out
    n = int(re.search(r"trace: ([\d,]+) records", out).group(1).replace(",", ""))
    assert n == len(trace.read_text().splitlines()) - 1 > 100  # csv: a header line, then the records
    assert err.strip() == f"canstack: interrupted at {m.group(1)} s of 3600 s"


def test_progress_bar_when_asked(capsys):
    pytest.importorskip("tqdm")
    rc, out, err = _run(capsys, "demo", "--duration", "0.2", "--progress")
    assert rc == 0 and "demo:" in err and "s simulated" in err and "bus load" in out
    rc, out, err = _run(capsys, "demo", "--duration", "0.2")  # not a terminal: no bar
    assert rc == 0 and err == ""


# ---------------------------------------------------------------------------------------------
# outputs checked before the run


def test_mf4_without_asammdf_is_refused_before_the_run(monkeypatch, capsys, tmp_path):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "asammdf" else real(name, *a))
    monkeypatch.setattr(demo, "run_sliced", lambda *a, **kw: pytest.fail("the simulation ran"))
    rc, out, err = _run(capsys, "demo", "--trace", str(tmp_path / "out.mf4"))
    _one_line(rc, err)
    assert "asammdf, which is not installed: pip install 'canstack[mf4]'" in err and out == ""
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    assert any(req.startswith("asammdf") for req in extras["mf4"])


def test_plot_without_matplotlib_is_refused_before_the_run(monkeypatch, capsys, tmp_path):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "matplotlib" else real(name, *a))
    monkeypatch.setattr(demo, "run_sliced", lambda *a, **kw: pytest.fail("the simulation ran"))
    rc, _, err = _run(capsys, "demo", "--faults", "--plot", str(tmp_path / "p.png"))
    _one_line(rc, err)
    assert "--plot needs matplotlib" in err and "canstack[plot]" in err


@pytest.mark.parametrize(
    "make,needle",
    [
        (lambda t: str(t), "is a directory, not a file"),
        (lambda t: str(t / "missing" / "x.asc"), "does not exist"),
        (lambda t: str(t / "afile" / "x.asc"), "afile' is a file, not a directory"),
    ],
)
def test_bad_output_paths_name_the_problem(capsys, tmp_path, make, needle):
    (tmp_path / "afile").write_text("x")
    for argv in (["demo", "--trace"], ["demo", "--vcd"], ["demo", "--faults", "--plot"]):
        rc, _, err = _run(capsys, *argv, make(tmp_path))
        _one_line(rc, err)
        assert needle in err and argv[-1] in err


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full (Linux)")
def test_a_full_disk_names_the_file(capsys):
    rc, out, err = _run(capsys, "demo", "--duration", "0.01", "--vcd", "/dev/full")
    _one_line(rc, err)
    assert "--vcd '/dev/full': cannot write: No space left on device" in err
    assert "bus load" in out  # the summary is printed all the same


def test_plot_without_suffix_writes_the_named_file(capsys, tmp_path):
    pytest.importorskip("matplotlib")
    path = tmp_path / "counters"
    assert main(["demo", "--faults", "--duration", "0.05", "--plot", str(path)]) == 0
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and not (tmp_path / "counters.png").exists()


def test_trc_leaves_out_remote_and_error_frames_with_one_line(capsys, tmp_path, caplog):
    path = tmp_path / "t.trc"
    rc, out, err = _run(capsys, "demo", "--duration", "0.2", "--trace", str(path))
    # 0.2 s: 4 remote requests of the tester (every 50 ms from 7 ms), no error frames
    assert rc == 0 and "trace: 130 records written" in out
    assert "(4 remote or error frames left out: .trc cannot hold them)" in out
    assert err == "" and not [r for r in caplog.records if "TRCWriter" in r.getMessage()]


# ---------------------------------------------------------------------------------------------
# what every user sees first


def test_version(capsys):
    rc, out, _ = _run(capsys, "--version")
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    from stack.cli import __version__

    assert rc == 0 and re.fullmatch(r"canstack \S+\n", out)
    assert __version__ == project["version"]  # the fallback when no metadata is installed


@pytest.mark.parametrize("command", ["demo", "frame", "bittiming", "sync", "decode", "render", "restbus"])
def test_every_option_has_help_and_every_command_a_description(command):
    parser = build_parser(None)
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    p = sub.choices[command]
    assert p.description, command
    missing = [a.option_strings or a.dest for a in p._actions if not a.help]
    assert missing == [], f"{command}: options without help: {missing}"


def test_sync_steps_are_bounded_by_the_resolution(capsys):
    rc, _, err = _run(capsys, "sync", "--clock", "16000000", "--bitrate", "500000", "--steps", "1e9")
    _one_line(rc, err)
    # 20000 ppm / 1e9 steps is a scan step of 2e-05 ppm, finer than the 10 ppm resolution:
    # at most 20000 / 10 = 2000 steps
    assert "--steps 1000000000" in err and "at most 2000" in err
    rc, _, err = _run(capsys, "sync", "--clock", "16000000", "--bitrate", "500000", "--resolution", "1e-300")
    _one_line(rc, err)
    assert "--resolution" in err


def test_restbus_duration_is_bounded_on_the_simulated_bus(capsys):
    db = ROOT / "dbc" / "databases" / "powertrain_body.dbc"
    rc, _, err = _run(capsys, "restbus", str(db), "--duration", "1e9")
    _one_line(rc, err)
    assert "at most 3600 s" in err


@pytest.mark.parametrize(
    "argv,message",
    [
        (["frame", "--id", "0x20000000", "--extended"], "out of range for an extended (29-bit) frame"),
        (["frame", "--id", "0x800"], "out of range for a standard (11-bit) frame"),
        (["frame", "--id", "0x1", "--remote", "--data", "01"], "a remote frame carries no data (got 1 byte);"),
    ],
)
def test_wording(capsys, argv, message):
    rc, _, err = _run(capsys, *argv)
    _one_line(rc, err)
    assert message in err


def _spinning_bus():
    """A bus whose timer re-arms itself at the same instant from 5 ms on: its slice never ends."""
    bus = SimBus(500_000)

    def again():
        bus.call_at(bus.now(), again)

    bus.call_at(5_000_000, again)
    return bus


@pytest.mark.wallclock
def test_ctrl_c_stops_a_slice_that_never_ends(monkeypatch):
    """The first Ctrl-C asks for the end of the slice; one that does not come within GRACE_S is
    stopped where it is, and the run returns what it has (issue 26: a 0 ns period ignored
    Ctrl-C and SIGTERM at 100 % CPU)."""
    import threading

    bus = _spinning_bus()
    timer = threading.Timer(0.2, lambda: os.kill(os.getpid(), signal.SIGINT))
    timer.start()
    try:
        assert run_sliced(bus, 10**9, progress=False) is False
    finally:
        timer.cancel()
    assert bus.now() == 5_000_000


@pytest.mark.wallclock
def test_a_run_past_its_time_limit_raises():
    with pytest.raises(TimeLimitExceeded, match=r"time limit of 0.3 s \(wall clock\) at 0.005 s simulated"):
        run_sliced(_spinning_bus(), 10**9, progress=False, time_limit=0.3)
    with time_limit(0.3), pytest.raises(TimeLimitExceeded):  # the sweeps' per-run limit
        run_sliced(_spinning_bus(), 10**9, progress=False)
