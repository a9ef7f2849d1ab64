"""Experiments on python-can buses (issue 23, "On a python-can bus"): frames counted, one clock
for releases and ends (also with the CPU loaded), a bus that goes away mid-run, --plot and
--trace from the frames a monitor received."""

import contextlib
import copy
import os
import subprocess
import sys
import threading
import time

import can
import pytest

import stack.cli as cli
from profiles.pipeline.runner import run_on_pycan
from profiles.pipeline.scenario import parse_scenario
from stack.io.serve import BusServer
from stack.wire.frame import Frame

pytestmark = pytest.mark.wallclock

MESSAGES = {
    "a": [{"name": "ma", "id": 0x100, "dlc": 8, "period_ms": 5}],
    "b": [{"name": "mb", "id": 0x200, "dlc": 4, "period_ms": 10}],
}
TOML = """\
[bus]
bitrate = 500000
duration = 0.5

[[nodes]]
name = "a"
messages = [{ name = "ma", id = 0x100, dlc = 8, period_ms = 5 }]

[[nodes]]
name = "b"
messages = [{ name = "mb", id = 0x200, dlc = 4, period_ms = 10 }]

[[nodes]]
name = "rx"
"""


def _scenario(duration=0.5):
    raw = {
        "bus": {"bitrate": 500_000, "duration": duration, "seed": 1},
        "nodes": [{"name": n, "messages": ms} for n, ms in MESSAGES.items()] + [{"name": "rx", "messages": []}],
    }
    return parse_scenario(raw, "test.toml")


def _wire_ms(can_id, dlc):
    """SOF..EOF of the frame at 500 kbit/s: the least a response can be on a bus with wire time."""
    return Frame(can_id, bytes(dlc)).bits.length * 2e-3


@contextlib.contextmanager
def _cpu_load(n=2):
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
            p.wait()


def _stop_when_running(srv, nodes):
    """Close ``srv`` once ``nodes`` clients (the scenario's nodes and the monitor) joined and a
    few periods went by: the bus goes away in the middle of the run."""

    def run():
        if srv.wait_sessions(nodes, timeout=60.0):
            time.sleep(0.3)
        srv.close()

    th = threading.Thread(target=run, daemon=True)
    th.start()
    return th


class _Logger:
    """A python-can bus beside the experiment that counts every frame (with its timestamp)."""

    def __init__(self, bus):
        self.bus = bus
        self.stamps = []
        self._stop = threading.Event()
        self._th = threading.Thread(target=self._run, daemon=True)
        self._th.start()

    def _run(self):
        while not self._stop.is_set():
            m = self.bus.recv(0.05)
            if m is not None and not m.is_error_frame:
                self.stamps.append(m.timestamp)

    def stop(self):
        self._stop.set()
        self._th.join(10)


def test_frames_on_a_virtual_bus_are_counted_as_a_logger_counts_them():
    ch = f"frames-{os.getpid()}"
    with can.Bus(interface="virtual", channel=ch) as bus:
        log = _Logger(bus)
        t_start = time.time()
        res = run_on_pycan(copy.deepcopy(_scenario()), "virtual", ch, duration_s=0.5)
        t_stop = time.time()
        log.stop()
    inside = sum(1 for t in log.stamps if t_start + 0.05 < t < t_stop - 0.2)
    data = res.to_json()
    assert inside > 50  # every 5 and 10 ms for 0.5 s
    # the monitor saw what went out while the run lasted: at least what the logger saw well
    # inside the run, at most everything the logger saw
    assert inside <= data["frames"] <= len(log.stamps)
    assert data["frames"] >= sum(m["sent"] for m in data["messages"])


@pytest.mark.subprocess
def test_no_response_is_negative_on_a_virtual_bus_with_the_cpu_loaded():
    with _cpu_load():
        res = run_on_pycan(copy.deepcopy(_scenario()), "virtual", f"load-{os.getpid()}", duration_s=0.5)
    for m in res.to_json()["messages"]:
        assert m["sent"] > 0 and m["response_ms"]["min"] >= 0, m
        assert all(r >= 0 for r in res.responses_ms(m["name"]))


@pytest.mark.subprocess
@pytest.mark.socket
def test_served_responses_are_at_least_the_wire_time_with_the_cpu_loaded():
    """Over canstack serve the end of each frame is the server's bus time mapped onto this
    process's clock: with the machine loaded a response may grow (lateness), never fall below
    the frame's own time on the wire (a negative response is two clocks compared)."""
    with BusServer(500_000, listen=("127.0.0.1", 0)) as srv, _cpu_load():
        res = run_on_pycan(copy.deepcopy(_scenario()), "canstack", srv.url, duration_s=0.6)
    rows = {m["name"]: m for m in res.to_json()["messages"]}
    for name, (can_id, dlc) in {"ma": (0x100, 8), "mb": (0x200, 4)}.items():
        assert rows[name]["sent"] > 0
        assert min(res.responses_ms(name)) >= _wire_ms(can_id, dlc) - 1e-3, name
    assert res.frames >= rows["ma"]["sent"] + rows["mb"]["sent"]


@pytest.mark.socket
def test_a_served_bus_that_stops_mid_run_interrupts_the_run_at_once():
    srv = BusServer(500_000, listen=("127.0.0.1", 0))
    url = srv.url
    stopper = _stop_when_running(srv, 4)
    try:
        res = run_on_pycan(copy.deepcopy(_scenario(duration=60)), "canstack", url, duration_s=60)
    finally:
        srv.close()
        stopper.join(60)
    data = res.to_json()
    assert data["interrupted"] is True and res.duration_s < 60  # stopped when the bus went, not at its end
    assert url in data["bus_lost"]["bus"] and "closed the connection" in data["bus_lost"]["reason"]
    assert data["bus_lost"]["at_s"] == pytest.approx(res.duration_s, abs=1e-3)
    assert sum(m["sent"] for m in data["messages"]) > 0  # what it had is kept


@pytest.mark.socket
def test_the_command_says_in_one_line_that_the_bus_went_away_and_exits_1(tmp_path, capsys):
    scenario = tmp_path / "s.toml"
    scenario.write_text(TOML)
    out_file = tmp_path / "r.json"
    srv = BusServer(500_000, listen=("127.0.0.1", 0))
    stopper = _stop_when_running(srv, 4)
    try:
        code = cli.main(
            ["experiment", str(scenario), "--interface", "canstack", "--channel", srv.url, "--duration", "60"]
            + ["--out", str(out_file)]
        )
    finally:
        srv.close()
        stopper.join(60)
    out, err = capsys.readouterr()
    assert code == 1, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"canstack experiment: bus canstack {srv.url} lost at "), err
    assert lines[0].endswith("; the results so far are marked interrupted")
    assert '"interrupted": true' in out_file.read_text() and "(interrupted)" in out


def test_plot_and_trace_on_a_virtual_bus(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    scenario = tmp_path / "s.toml"
    scenario.write_text(TOML)
    ch = f"plot-{os.getpid()}"
    code = cli.main(
        ["experiment", str(scenario), "--interface", "virtual", "--channel", ch, "--json"]
        + ["--plot", str(tmp_path / "plots"), "--trace", str(tmp_path / "t.asc")]
    )
    out, err = capsys.readouterr()
    assert code == 0, err
    for name in ("timeline.png", "response_times.png", "bus_load.png"):
        assert (tmp_path / "plots" / name).stat().st_size > 1000
    msgs = [m for m in can.LogReader(str(tmp_path / "t.asc")) if not m.is_error_frame]
    import json

    data = json.loads(out)
    assert len(msgs) == data["frames"] > 0
    assert {m.arbitration_id for m in msgs} <= {0x100, 0x200}
    # bus time from the start of the run: the first frame is not at 0 (python-can's .asc writer
    # would count from it), and the last is inside the run
    stamps = [m.timestamp for m in msgs]
    assert 0 < stamps[0] <= stamps[-1] <= data["duration"] and stamps == sorted(stamps)
    assert f"trace: {len(msgs)} records written to {tmp_path / 't.asc'}" in err


@pytest.mark.parametrize("suffix", [".asc", ".blf", ".log", ".csv"])
def test_every_format_holds_the_bus_time_of_what_the_monitor_received(tmp_path, suffix):
    path = tmp_path / f"t{suffix}"
    res = run_on_pycan(copy.deepcopy(_scenario(0.3)), "virtual", f"tr{suffix}{os.getpid()}", plot=True, trace=str(path))
    got = [(m.timestamp, m.arbitration_id) for m in can.LogReader(str(path)) if not m.is_error_frame]
    want = [(r.end / 1e9, r.frame.can_id) for r in res.trace]  # the timeline records: the same frames
    assert len(got) == len(want) == res.files["trace"]["records"] == res.frames > 0
    # .asc keeps 10 us, .blf 1 us (or 10 us), .log and .csv 1 us: the same times to that
    assert all(abs(a - b) < 1e-5 and i == j for (a, i), (b, j) in zip(got, want))
    assert got[0][0] > 0 and got[-1][0] <= res.duration_s


def test_an_fd_scenario_runs_on_a_virtual_fd_bus_and_a_logger_sees_fd_frames():
    """A scenario with a data bit rate opens its python-can bus with fd=True: python-can's own
    logger on the same channel receives the messages as CAN FD frames with BRS, at their length."""
    raw = {
        "bus": {"bitrate": 500_000, "data_bitrate": 2_000_000, "duration": 0.3},
        "nodes": [
            {
                "name": "a",
                "messages": [{"name": "big", "id": 0x100, "fd": True, "brs": True, "length": 64, "period_ms": 5}],
            },
            {"name": "b", "messages": [{"name": "small", "id": 0x200, "dlc": 4, "period_ms": 10}]},
        ],
    }
    ch = f"fd-{os.getpid()}"
    with can.Bus(interface="virtual", channel=ch, fd=True) as bus:
        res = run_on_pycan(parse_scenario(raw, "fd.toml"), "virtual", ch, duration_s=0.3)
        got = []
        while (m := bus.recv(0)) is not None:
            got.append(m)
    kinds = {(m.arbitration_id, m.is_fd, m.bitrate_switch, len(m.data)) for m in got}
    assert kinds == {(0x100, True, True, 64), (0x200, False, False, 4)}
    rows = {m["name"]: m for m in res.to_json()["messages"]}
    assert rows["big"]["sent"] > 0 and rows["small"]["sent"] > 0
