"""`canstack experiment`: the table, --json, --plot, and bad input as one line with exit 2."""

from __future__ import annotations

import json
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


@pytest.mark.subprocess
def test_experiment_prints_the_table_worst_offenders_first():
    out = canstack("experiment", str(EXAMPLES / "powertrain_90.toml"))
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert "bus load 8" in lines[0]
    first_row = next(line for line in lines if line and not line.startswith(("message", "examples", "/")))
    assert first_row.startswith("Diagnostics")  # the only message with deadline misses comes first
    assert "analysis: not schedulable: Diagnostics" in out.stdout


@pytest.mark.subprocess
def test_experiment_json_is_one_object(tmp_path):
    out = canstack("experiment", str(EXAMPLES / "body_network.toml"), "--json", "--out", str(tmp_path / "r.json"))
    assert out.returncode == 0, out.stderr
    data = json.loads(out.stdout)
    assert data["frames"] > 0 and len(data["messages"]) == 7
    assert json.loads((tmp_path / "r.json").read_text()) == data


@pytest.mark.subprocess
def test_experiment_plots(tmp_path):
    pytest.importorskip("matplotlib")
    out = canstack(
        "experiment", str(EXAMPLES / "powertrain_90.toml"), "--plot", str(tmp_path / "plots"), "--duration", "0.1"
    )
    assert out.returncode == 0, out.stderr
    for name in ("timeline.png", "response_times.png", "bus_load.png"):
        assert (tmp_path / "plots" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.subprocess
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
def test_bad_input_is_one_line_and_exit_2(tmp_path, args, message):
    bad = tmp_path / "BAD.toml"
    bad.write_text(
        '[bus]\nbitrate = 500000\nduration = 1.0\n[[nodes]]\nname = "a"\n'
        '[[nodes.messages]]\nname = "m"\nid = 1\ndlc = 12\nperiod_ms = 10\n'
    )
    args = [str(bad) if a == "BAD" else a.replace("EXAMPLES", str(EXAMPLES)) for a in args]
    out = canstack(*args)
    assert out.returncode == 2
    assert out.stdout == "" and len(out.stderr.strip().splitlines()) == 1
    assert message.replace("BAD.toml", str(bad)) in out.stderr.replace(str(EXAMPLES) + "/", ""), out.stderr
