"""`canstack experiment`: the table, --json, --plot, and bad input as one line with exit 2."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
EXAMPLES = ROOT / "examples"


def canstack(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    import os

    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, "-m", "stack.cli", *args], capture_output=True, text=True, env=env, cwd=cwd)


def test_experiment_prints_the_table_worst_offenders_first(capsys):
    rc, out, err = _main(capsys, "experiment", str(EXAMPLES / "powertrain_90.toml"))
    assert rc == 0, err
    lines = out.splitlines()
    assert "bus load 8" in lines[0]
    first_row = next(line for line in lines if line and not line.startswith(("message", "examples", "/")))
    assert first_row.startswith("Diagnostics")  # the only message with deadline misses comes first
    assert "analysis: not schedulable: Diagnostics" in out


def test_experiment_json_is_one_object(tmp_path, capsys):
    rc, out, err = _main(
        capsys, "experiment", str(EXAMPLES / "body_network.toml"), "--json", "--out", str(tmp_path / "r.json")
    )
    assert rc == 0, err
    data = json.loads(out)
    assert data["frames"] > 0 and len(data["messages"]) == 7
    assert json.loads((tmp_path / "r.json").read_text()) == data


def test_experiment_plots(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    # 20 ms: every message of the network is sent, and the timeline has fewer frames to draw
    rc, _, err = _main(
        capsys,
        "experiment",
        str(EXAMPLES / "powertrain_90.toml"),
        "--plot",
        str(tmp_path / "plots"),
        "--duration",
        "0.02",
    )
    assert rc == 0, err
    for name in ("timeline.png", "response_times.png", "bus_load.png"):
        assert (tmp_path / "plots" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize(
    "args,message",
    [
        (["experiment", "nowhere.toml"], "canstack: error: nowhere.toml: no such scenario file"),
        (
            ["experiment", "EXAMPLES/body_network.toml", "--interface", "virtual"],
            "canstack: error: --interface and --channel go together",
        ),
        (["experiment", "EXAMPLES/body_network.toml", "--duration", "-1"], "a duration is > 0"),
        (
            ["experiment", "EXAMPLES/body_network.toml", "--plot", "EXAMPLES/body_network.toml"],
            "is a file; give a directory for the plots",
        ),
        (["experiment", "BAD"], "BAD.toml: [[nodes]] #1 'a' > [[nodes.messages]] #1 'm': dlc: 12 is outside 0..8"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, args, message):
    bad = tmp_path / "BAD.toml"
    bad.write_text(
        '[bus]\nbitrate = 500000\nduration = 1.0\n[[nodes]]\nname = "a"\n'
        '[[nodes.messages]]\nname = "m"\nid = 1\ndlc = 12\nperiod_ms = 10\n'
    )
    args = [str(bad) if a == "BAD" else a.replace("EXAMPLES", str(EXAMPLES)) for a in args]
    rc, out, err = _main(capsys, *args)
    assert rc == 2
    assert out == "" and len(err.strip().splitlines()) == 1
    assert message.replace("BAD.toml", str(bad)) in err.replace(str(EXAMPLES) + "/", ""), err


@pytest.mark.subprocess
def test_bad_input_from_a_shell_is_one_line_and_exit_2(tmp_path):
    """The contract above as a shell sees it: the process's status and all of its output, whatever
    else a fresh interpreter might print on stderr (a warning, a log line)."""
    bad = tmp_path / "BAD.toml"
    bad.write_text(
        '[bus]\nbitrate = 500000\nduration = 1.0\n[[nodes]]\nname = "a"\n'
        '[[nodes.messages]]\nname = "m"\nid = 1\ndlc = 12\nperiod_ms = 10\n'
    )
    out = canstack("experiment", str(bad))
    assert out.returncode == 2 and out.stdout == ""
    assert out.stderr.strip().splitlines() == [out.stderr.strip()] and "dlc: 12 is outside 0..8" in out.stderr


def _main(capsys, *argv):
    from stack.cli import main

    rc = main(list(argv))
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def test_overrides_give_the_run_an_edited_file_gives(tmp_path, capsys):
    """--seed, --bitrate, --duration and --set change the scenario as a copy edited by hand does."""
    text = (EXAMPLES / "body_network.toml").read_text()
    edited = tmp_path / "edited.toml"
    edited.write_text(
        text.replace("bitrate = 125000", "bitrate = 250000")
        .replace("seed = 1\n", "seed = 11\n")
        .replace('name = "climate"\n', 'name = "climate"\nqueue = "fifo"\n')
    )
    assert edited.read_text().count("250000") == 1 and "seed = 11" in edited.read_text()
    assert 'name = "climate"\nqueue = "fifo"' in edited.read_text()
    rc, by_hand, err = _main(capsys, "experiment", str(edited), "--json", "--duration", "0.5")
    assert rc == 0, err
    rc, overridden, err = _main(
        capsys,
        "experiment",
        str(EXAMPLES / "body_network.toml"),
        "--json",
        "--seed",
        "11",
        "--bitrate",
        "250000",
        "--set",
        "bus.duration=0.5",
        "--set",
        "nodes.climate.queue=fifo",
    )
    assert rc == 0, err
    a, b = json.loads(by_hand), json.loads(overridden)
    a.pop("scenario"), b.pop("scenario")
    assert a == b and b["seed"] == 11 and b["bitrate"] == 250000 and b["duration"] == 0.5


@pytest.mark.parametrize(
    "args,message",
    [
        (
            ["--set", "nodes.nobody.queue=fifo"],
            "--set nodes.nobody.queue: nodes has no element 'nobody' (names: bcm, cluster",
        ),
        (["--set", "bus.bitrate"], "--set 'bus.bitrate': expected KEY=VALUE"),
        (["--set", "bus.bitrate=2000000"], "[bus]: bitrate: 2000000 is outside 1000..1000000"),
        (["--seed", "3", "--set", "bus.seed=4"], "--seed and --set bus.seed=... both given"),
        (["--data-bitrate", "100000"], "[bus]: data_bitrate: 100000 is below the bitrate 125000"),
        (
            ["--data-bitrate", "2000000", "--set", "bus.data_bitrate=4000000"],
            "--data-bitrate and --set bus.data_bitrate=... both given",
        ),
        (["--out", "r.txt"], "write .json (the result) or .csv (one row per message)"),
        (["--samples", "s.json"], "--samples 's.json': write .csv or .parquet"),
        (["--trace", "t.xyz"], "unknown suffix '.xyz'"),
    ],
)
def test_bad_overrides_and_outputs_are_one_line(tmp_path, capsys, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    rc, out, err = _main(capsys, "experiment", str(EXAMPLES / "body_network.toml"), *args)
    assert rc == 2 and out == "" and err.count("\n") == 1, err
    assert message in err


def test_out_csv_writes_the_message_rows(tmp_path, capsys):
    import csv

    rc, out, err = _main(
        capsys, "experiment", str(EXAMPLES / "body_network.toml"), "--json", "--out", str(tmp_path / "r.csv")
    )
    assert rc == 0, err
    data = json.loads(out)
    with open(tmp_path / "r.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["name"] for r in rows] == [m["name"] for m in data["messages"]]
    for r, m in zip(rows, data["messages"]):
        assert int(r["sent"]) == m["sent"] and float(r["response_max_ms"]) == m["response_ms"]["max"]


def test_the_text_shows_every_figure_of_the_messages(capsys):
    """Each message row carries what its JSON object has: period, deadline, every count, the
    response figures, the time from release, both bounds, schedulable, jitter; identifiers as
    0x0C1; a name longer than its column is cut with a mark."""
    rc, out, _ = _main(capsys, "experiment", str(EXAMPLES / "powertrain_90.toml"), "--json")
    data = json.loads(out)
    rc, text, _ = _main(capsys, "experiment", str(EXAMPLES / "powertrain_90.toml"))
    header = next(line for line in text.splitlines() if line.startswith("message "))
    for column in ("period", "deadline", "released", "sent", "received", "failed", "dropped", "miss", "p99",
                   "from release", "RTA", "R", "sched", "max/RTA", "jitter"):  # fmt: skip
        assert f" {column} " in f" {header} ", column
    for m in data["messages"]:
        row = next(line for line in text.splitlines() if line.startswith(m["name"] + " "))
        cells = row.split()
        assert f"0x{m['id']:03X}" in cells and f"{m['period_ms']:.3f}" in cells and f"{m['deadline_ms']:.3f}" in cells
        assert str(m["released"]) in cells and f"{m['release_response_max_ms']:.3f}" in cells


def test_the_text_shows_every_controller_counter_of_the_json(capsys):
    """The JSON's ``nodes`` (each controller's counters) are a table in the text too: one row per
    node, each counter under its column; the frames the nodes sent add up to the bus's count in
    the first line."""
    path = str(EXAMPLES / "body_network.toml")
    rc, out, _ = _main(capsys, "experiment", path, "--json")
    nodes = json.loads(out)["nodes"]
    rc, text, _ = _main(capsys, "experiment", path)
    lines = text.splitlines()
    header = next(line for line in lines if line.startswith("node ") and " TEC " in line)
    columns = {"tx": "tx_frames", "rx": "rx_frames", "rx overruns": "rx_overruns", "arb lost": "arbitration_lost",
               "retransmissions": "retransmissions", "tx failed": "tx_failed", "TEC": "txerr", "REC": "rxerr"}  # fmt: skip
    for name, counters in nodes.items():
        row = next(line for line in lines if line.startswith(name + " ") and "0x" not in line)
        for column, key in columns.items():
            end = header.index(f" {column} " if column != "REC" else " REC") + 1 + len(column)
            # right-aligned: the cell under a header ends where the header ends
            assert row[:end].split()[-1] == str(counters[key]), (name, column)
        assert len(row.split()) == 1 + len(counters), name
    frames = int(re.search(r", (\d+) frames,", lines[0]).group(1))
    assert sum(c["tx_frames"] for c in nodes.values()) == frames


def test_tdma_and_master_slave_sections_in_the_text(capsys):
    rc, text, _ = _main(capsys, "experiment", str(EXAMPLES / "tdma.toml"))
    assert "2 master switches" in text and "1 late" in text
    assert "master switch at 75.508 ms: gateway -> engine, 254 us after the end of the cycle" in text
    assert re.search(r"^window +kind .* intrusions$", text, re.M)
    rc, text, _ = _main(capsys, "experiment", str(EXAMPLES / "master_slave.toml"))
    # valve2 is unplugged from 300 to 700 ms: lost, and it loses its master, over those intervals
    row = next(line for line in text.splitlines() if line.startswith("valve2 "))
    assert "312.3-710.7" in row and "315.5-710.4" in row


@pytest.mark.subprocess
def test_output_piped_into_head_costs_no_file(tmp_path):
    """The table is printed after every file is written: a reader that stops after one line
    (head -1 closes the pipe) takes nothing from the files."""
    import os

    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    for argv, files in (
        (["demo", "--trace", "p.blf", "--vcd", "p.vcd"], ("p.blf", "p.vcd")),
        (
            ["experiment", str(EXAMPLES / "tdma.toml"), "--trace", "t.asc", "--samples", "s.csv", "--out", "r.json"],
            ("t.asc", "s.csv", "r.json"),
        ),
    ):
        proc = subprocess.Popen(
            [sys.executable, "-m", "stack.cli", *argv],
            cwd=tmp_path,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        try:
            proc.stdout.readline()
            proc.stdout.close()  # as head -1 does
            proc.wait(timeout=120)
        finally:
            proc.kill()
            proc.wait()
        for f in files:
            assert (tmp_path / f).stat().st_size > 0, f
    assert can_frames(tmp_path / "p.blf") > 600


def can_frames(path):
    import can

    return sum(1 for _ in can.LogReader(str(path)))


def test_plot_into_new_nested_folders(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    rc, _, err = _main(
        capsys, "experiment", str(EXAMPLES / "canopen.toml"), "--duration", "0.01", "--plot", str(tmp_path / "a" / "b")
    )
    assert rc == 0, err
    assert {p.name for p in (tmp_path / "a" / "b").iterdir()} >= {
        "timeline.png",
        "response_times.png",
        "response_cdf.png",
        "bus_load.png",
    }


def test_the_examples_are_listed_copied_and_run_from_anywhere(tmp_path, capsys, monkeypatch):
    rc, out, _ = _main(capsys, "examples")
    listed = {line.split()[0] for line in out.splitlines() if line.strip() and not line.startswith("canstack")}
    assert {p.name for p in EXAMPLES.glob("*.toml")} <= listed
    # every file the examples folder holds ships and is listed (a script's data too)
    assert {p.name for p in EXAMPLES.iterdir() if p.is_file() and p.name != "__init__.py"} <= listed
    rc, out, err = _main(capsys, "examples", "--to", str(tmp_path / "mine"), "tdma", "powertrain_90.toml")
    assert rc == 0, err
    assert (tmp_path / "mine" / "tdma.toml").read_bytes() == (EXAMPLES / "tdma.toml").read_bytes()
    rc, out, err = _main(capsys, "examples", "--to", str(tmp_path / "mine"), "tdma")
    assert rc == 2 and "tdma.toml is there already (--force replaces it)" in err
    monkeypatch.chdir(tmp_path)  # no examples/ here: the shipped one runs
    rc, out, err = _main(capsys, "experiment", "examples/tdma.toml", "--json")
    assert rc == 0 and json.loads(out)["frames"] == 242 and "the shipped example" in err
