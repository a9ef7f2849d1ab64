"""`canstack sweep`: the commands come from this checkout's pyproject.toml entry points, bad input is
one line with exit status 2 before any run, tables are written, Ctrl-C writes what is done."""

from __future__ import annotations

import csv
import importlib.metadata
import importlib.util
import json
import sys
from pathlib import Path

import pytest

from stack.cli import main

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[3]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())
EXAMPLE = str(ROOT / "examples" / "powertrain_90.toml")


@pytest.fixture(autouse=True)
def commands_of_this_checkout(monkeypatch):
    """The installed distribution's entry points may be an older checkout's: add (or replace) the
    ``canstack.commands`` of this pyproject.toml, as `pip install -e .` would."""
    real = importlib.metadata.entry_points
    ours = [
        importlib.metadata.EntryPoint(name, value, "canstack.commands")
        for name, value in PYPROJECT["project"]["entry-points"]["canstack.commands"].items()
    ]

    def entry_points(**kw):
        eps = list(real(**kw))
        if kw.get("group") == "canstack.commands":
            names = {e.name for e in ours}
            eps = [e for e in eps if e.name not in names] + ours
        return eps

    monkeypatch.setattr(importlib.metadata, "entry_points", entry_points)


def run(capsys, *args: str) -> tuple[int, str, str]:
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def test_pyproject_registers_the_commands_and_the_extras():
    eps = PYPROJECT["project"]["entry-points"]["canstack.commands"]
    assert eps["sweep"] == "profiles.sweeps.cli:register_sweep"
    assert eps["study"] == "profiles.sweeps.cli:register_study"
    extras = PYPROJECT["project"]["optional-dependencies"]
    assert extras["dask"] == ["dask[distributed]>=2024.1"]
    assert any(req.startswith("pyarrow") for req in extras["parquet"])


def test_sweep_writes_the_csv_in_canonical_order(tmp_path, capsys):
    out = tmp_path / "r.csv"
    code, stdout, err = run(
        capsys,
        "sweep",
        EXAMPLE,
        "--vary",
        "nodes.engine.queue=priority,fifo",
        "--vary",
        "nodes.gateway.messages.Diagnostics.deadline_ms=3,10",
        "--duration",
        "0.1",
        "--out",
        str(out),
    )
    assert code == 0, err
    with open(out, newline="") as f:
        rows = list(csv.DictReader(f))
    assert [(r["run"], r["nodes.engine.queue"], r["nodes.gateway.messages.Diagnostics.deadline_ms"]) for r in rows] == [
        ("0", "priority", "3"),
        ("1", "priority", "10"),
        ("2", "fifo", "3"),
        ("3", "fifo", "10"),
    ]
    # the README's figure: with a 3 ms deadline every Diagnostics instance misses; with 10 ms none does
    assert [int(r["Diagnostics.misses"]) for r in rows[:2]] == [10, 0]
    assert {"EngineSpeed.max_ms", "EngineSpeed.misses", "EngineSpeed.rta_ms", "bus_load", "error"} <= set(rows[0])
    assert stdout.splitlines()[0].split()[:3] == [
        "run",
        "nodes.engine.queue",
        "nodes.gateway.messages.Diagnostics.deadline_ms",
    ]
    assert "4 runs; sequential" in err and f"written to {out}" in err


def test_sweep_json_is_one_object(capsys):
    code, stdout, err = run(
        capsys,
        "sweep",
        EXAMPLE,
        "--vary",
        "bus.bitrate=250000,500000",
        "--seeds",
        "2",
        "--duration",
        "0.05",
        "--seed",
        "3",
        "--json",
    )
    assert code == 0, err
    data = json.loads(stdout)
    assert data["runs"] == data["done"] == 4 and data["failed"] == 0 and data["seed"] == 3
    assert data["vary"] == {"bus.bitrate": [250000, 500000]}
    assert [r["replicate"] for r in data["rows"]] == [0, 1, 0, 1]
    assert data["columns"][:4] == ["run", "bus.bitrate", "replicate", "seed"]


def test_sweep_plots(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    code, _, err = run(
        capsys,
        "sweep",
        EXAMPLE,
        "--vary",
        "nodes.engine.messages.EngineSpeed.period_ms=1:2:0.5",
        "--vary",
        "nodes.engine.queue=priority,fifo",
        "--duration",
        "0.05",
        "--plot",
        str(tmp_path / "p"),
        "--metric",
        "worst_misses",
        "--metric",
        "Torque.max_ms",
    )
    assert code == 0, err
    for name in ("worst_misses.png", "Torque.max_ms.png"):
        assert (tmp_path / "p" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_ctrl_c_writes_the_rows_done_and_exits_130(tmp_path, monkeypatch, capsys):
    (tmp_path / "cli_hooks.py").write_text(
        "def hook(node, profile, ctx):\n    if ctx.scenario.bitrate == 250000:\n        raise KeyboardInterrupt\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    text = (
        (ROOT / "examples" / "powertrain_90.toml")
        .read_text()
        .replace('name = "engine"\n', 'name = "engine"\napp = "cli_hooks:hook"\n', 1)
    )
    scenario = tmp_path / "s.toml"
    scenario.write_text(text)
    code, stdout, err = run(
        capsys,
        "sweep",
        str(scenario),
        "--vary",
        "bus.bitrate=125000,500000,250000,1000000",
        "--duration",
        "0.05",
        "--out",
        str(tmp_path / "r.csv"),
    )
    assert code == 130
    with open(tmp_path / "r.csv", newline="") as f:
        assert [r["bus.bitrate"] for r in csv.DictReader(f)] == ["125000", "500000"]
    assert err.startswith("interrupted: 2 of 4 runs done")


@pytest.mark.parametrize(
    "args,message",
    [
        (["--vary", "nodes.engin.queue=fifo"], "--vary nodes.engin.queue: nodes has no element 'engin'"),
        (["--vary", "bus.bitrate=1:10:0"], "the step of a range must not be 0"),
        (["--vary", "bus.bitrate"], "expected KEY=V1,V2"),
        (["--vary", "bus.bitrate=1", "--vary", "bus.bitrate=2"], "given twice"),
        (["--out", "r.txt"], "write .csv or .parquet"),
        (["--out", "/nonexistent/dir/r.csv"], "does not exist"),
        (
            ["--plot", "PLOTDIR", "--vary", "bus.bitrate=1", "--vary", "bus.duration=1", "--vary", "bus.seed=2"],
            "--plot draws one or two varied keys; this sweep varies 3",
        ),
        (
            ["--plot", "PLOTDIR", "--vary", "bus.bitrate=250000", "--metric", "Nope.max_ms"],
            "--metric 'Nope.max_ms': not a column",
        ),
        (["--metric", "bus_load"], "--metric chooses what --plot draws"),
        (["--workers", "0"], "at least 1"),
        (["--seeds", "x"], "is not a whole number"),
        (["--engine", "sequential", "--workers", "2"], "runs in this process"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, args, message):
    args = [a.replace("PLOTDIR", str(tmp_path / "p")) for a in args]
    code, stdout, err = run(capsys, "sweep", EXAMPLE, *args)
    assert code == 2 and stdout == ""
    assert len(err.strip().splitlines()) == 1 and message in err, err


def test_parquet_without_pyarrow_is_refused_before_running(tmp_path, capsys, monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "pyarrow" else real(name, *a))
    code, stdout, err = run(capsys, "sweep", EXAMPLE, "--vary", "bus.bitrate=1", "--out", str(tmp_path / "r.parquet"))
    assert code == 2 and stdout == "" and not (tmp_path / "r.parquet").exists()
    assert err.strip().endswith(
        "Parquet needs pyarrow, which is not installed: pip install 'canstack[parquet]' (or write .csv)"
    )


def test_scheduler_without_dask_names_the_extra(capsys, monkeypatch):
    monkeypatch.setattr("profiles.sweeps.execute.dask_available", lambda: False)
    code, stdout, err = run(
        capsys, "sweep", EXAMPLE, "--vary", "bus.bitrate=250000", "--scheduler", "tcp://127.0.0.1:8786"
    )
    assert code == 2 and stdout == ""
    assert err.strip() == (
        "canstack: error: --scheduler needs Dask's distributed, which is not installed: pip install 'canstack[dask]'"
    )


# --- canstack study --------------------------------------------------------------------------------


def test_study_schedulability_table_json_csv_and_plots(tmp_path, capsys):
    out = tmp_path / "sets.csv"
    code, stdout, err = run(
        capsys,
        "study",
        "schedulability",
        "--sets",
        "4",
        "--messages",
        "5",
        "--per-node",
        "2",
        "--utilisation",
        "0.4,1.0",
        "--out",
        str(out),
        "--json",
    )
    assert code == 0, err
    data = json.loads(stdout)
    assert [p["utilisation"] for p in data["points"]] == [0.4, 1.0] and data["runs"] == data["done"] == 8
    assert data["points"][1]["analysis"] == 0.0  # nothing is guaranteed at 100 %
    assert data["settings"]["release"] == "synchronous (offsets 0)"
    with open(out, newline="") as f:
        rows = list(csv.DictReader(f))
    assert [(r["utilisation"], r["set"]) for r in rows] == [(u, s) for u in ("0.4", "1.0") for s in "0123"]
    assert {"rta_schedulable", "rta_opa_schedulable", "rta_fifo_schedulable", "sim_priority_ok", "sim_fifo_ok"} <= set(
        rows[0]
    )
    if importlib.util.find_spec("matplotlib") is not None:
        code, stdout, err = run(
            capsys,
            "study",
            "schedulability",
            "--sets",
            "2",
            "--messages",
            "4",
            "--utilisation",
            "0.5:1.0:0.25",
            "--plot",
            str(tmp_path / "p"),
        )
        assert code == 0, err
        assert stdout.splitlines()[0].split() == [
            "U",
            "%",
            "sets",
            "RTA",
            "DM",
            "%",
            "RTA",
            "OPA",
            "%",
            "simulated",
            "%",
            "FIFO",
            "RTA",
            "%",
            "FIFO",
            "sim",
            "%",
        ]
        assert len(stdout.splitlines()) == 1 + 3 + 5  # header, 3 points, 5 breakdown lines
        for name in ("schedulability.png", "fifo_vs_priority.png"):
            assert (tmp_path / "p" / name).read_bytes()[:4] == b"\x89PNG"


def test_study_profiles_on_a_scenario(tmp_path, capsys):
    code, stdout, err = run(
        capsys,
        "study",
        "profiles",
        "--scenario",
        EXAMPLE,
        "--duration",
        "0.2",
        "--json",
        "--out",
        str(tmp_path / "p.csv"),
    )
    assert code == 0, err
    data = json.loads(stdout)
    assert len(data["messages"]) == 17 and data["duration"] == 0.2
    csma = next(r for r in data["rows"] if r["profile"] == "csma")
    assert csma["Diagnostics.misses"] == 20 and 0.8 < csma["bus_load"] < 0.85  # as the experiment says
    with open(tmp_path / "p.csv", newline="") as f:
        assert [r["profile"] for r in csv.DictReader(f)] == [r["profile"] for r in data["rows"]]
    code, stdout, err = run(capsys, "study", "profiles", "--messages", "4", "--utilisation", "0.3")
    assert code == 0, err
    head = stdout.splitlines()[1].split()
    assert head[:4] == ["message", "ID", "period", "ms"] and "bus load %" in stdout


@pytest.mark.parametrize(
    "args,message",
    [
        (["schedulability", "--utilisation", "0:1:0"], "the step of a range must not be 0"),
        (["schedulability", "--utilisation", "2"], "a utilisation is from 0.001 to 1.5"),
        (["schedulability", "--utilisation", "half"], "is not a utilisation"),
        (["schedulability", "--period-range", "5"], "give MIN,MAX in ms"),
        (["schedulability", "--sets", "0"], "at least 1"),
        (["schedulability", "--generator", "magic"], "invalid choice"),
        (["schedulability", "--out", "x.json"], "write .csv or .parquet"),
        (["profiles", "--scenario", "nowhere.toml"], "nowhere.toml: no such scenario file"),
        (["profiles", "--utilisation", "3"], "'3': a utilisation is from 0.001 to 1.5"),
        (["nosuch"], "invalid choice"),
    ],
)
def test_study_bad_input_is_one_line_and_exit_2(capsys, args, message):
    code, stdout, err = run(capsys, "study", *args)
    assert code == 2 and stdout == ""
    assert len(err.strip().splitlines()) == 1 and message in err, err


def test_the_x_scale_of_a_sweep_plot():
    """Log when asked, or (by default) when the values span two decades (100x) or more; never
    with a value at or below 0, which a log axis cannot place; names on a category axis."""
    from profiles.sweeps.plots import x_scale

    assert x_scale([1, 2, 5]) == "linear" and x_scale([1, 2, 5], log_x=True) == "log"
    assert x_scale([1, 10, 100]) == "log" and x_scale([1, 10, 99]) == "linear"  # 100x is two decades
    assert x_scale([1, 10, 100], log_x=False) == "linear"
    assert x_scale([0, 10, 1000]) == "linear" and x_scale([0, 10, 1000], log_x=True) == "linear"
    assert x_scale(["priority", "fifo"], log_x=True) == "category"


@pytest.mark.parametrize(
    "values,flag,scale",
    [
        ("1:2:0.5", [], "linear"),
        ("1:2:0.5", ["--log-x"], "log"),
        ("1,10,100", [], "log"),  # two decades: log without being asked
        ("1,10,100", ["--no-log-x"], "linear"),
    ],
)
def test_sweep_log_x_reaches_the_written_figure(tmp_path, capsys, monkeypatch, values, flag, scale):
    """The axis of the figure as it is saved (matplotlib cannot read a PNG back, so the figure is
    looked at on its way to the file), and the PNG is written."""
    pytest.importorskip("matplotlib")
    from matplotlib.figure import Figure

    seen = []
    save = Figure.savefig

    def looking(fig, *a, **k):
        seen.append(fig.axes[0].get_xscale())
        return save(fig, *a, **k)

    monkeypatch.setattr(Figure, "savefig", looking)
    code, _, err = run(
        capsys,
        "sweep",
        EXAMPLE,
        "--vary",
        f"nodes.engine.messages.EngineSpeed.period_ms={values}",
        "--duration",
        "0.02",
        "--plot",
        str(tmp_path / "p"),
        "--metric",
        "bus_load",
        *flag,
    )
    assert code == 0, err
    assert seen == [scale]
    assert (tmp_path / "p" / "bus_load.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_study_profiles_of_an_fd_scenario_keeps_its_data_bit_rate_and_fd_messages(capsys):
    """`study profiles --scenario` on a CAN FD scenario with --duration: the set keeps the file's
    data bit rate and each message its fd/brs (the JSON says so); CSMA runs it, and the
    profiles that send classical frames only are listed as skipped with the reason."""
    path = ROOT / "examples" / "fd_packed.toml"
    raw = tomllib.loads(path.read_text())
    # ISO 11898-1:2015's DLC of each FD length above 8 bytes
    fd_dlc = {12: 9, 16: 10, 20: 11, 24: 12, 32: 13, 48: 14, 64: 15}
    declared = {
        m["name"]: (m.get("fd", False), m.get("brs", False), fd_dlc[m["length"]])
        for n in raw["nodes"]
        for m in n.get("messages", [])
    }
    code, stdout, err = run(capsys, "study", "profiles", "--scenario", str(path), "--duration", "0.2", "--json")
    assert code == 0, err
    data = json.loads(stdout)
    assert data["data_bitrate"] == raw["bus"]["data_bitrate"] and data["duration"] == 0.2
    assert {m["name"]: (m["fd"], m["brs"], m["dlc"]) for m in data["messages"]} == declared
    assert [r["profile"] for r in data["rows"]] == ["csma"]
    assert "classical CAN frames only" in data["skipped"]["master/slave"]
