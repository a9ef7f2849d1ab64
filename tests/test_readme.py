"""The README's examples run as written: every ```python block, and the waveform commands on the
capture the repository ships."""

from __future__ import annotations

import contextlib
import io
import json
import re
import shlex
from pathlib import Path

import pytest

from stack.cli import main

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
BLOCKS = re.findall(r"^```python\n(.*?)^```", README, re.M | re.S)


def test_the_readme_has_python_blocks():
    assert len(BLOCKS) >= 2 and any("FaultInjector" in b for b in BLOCKS)


@pytest.mark.parametrize("index", range(len(BLOCKS)))
def test_python_block_runs(index, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # a block may write a trace into the working directory
    code = compile(BLOCKS[index], f"README.md python block {index + 1}", "exec")
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(code, {"__name__": "__readme__"})


def test_fault_injector_block_reaches_bus_off_and_back(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    block = next(b for b in BLOCKS if "FaultInjector" in b)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(block, "README.md", "exec"), {"__name__": "__readme__"})
    text = out.getvalue()
    # gateway's transmitter is dead from 400 to 410 ms: warning at TEC 96, passive at 128, bus
    # off at 256 (rules 9, 10), back after 128 x 11 recessive bits (rule 12)
    assert "new='bus-off', tec=256" in text and "old='bus-off', new='error-active', tec=0, rec=0" in text


def _command(prefix: str) -> list[str]:
    line = next(ln.strip() for ln in README.splitlines() if ln.strip().startswith(prefix))
    return shlex.split(line)[1:]  # without 'canstack'


def test_decode_example_on_the_shipped_capture(monkeypatch, capsys):
    argv = _command("canstack decode examples/")
    monkeypatch.chdir(ROOT)
    assert main(argv) == 0
    got = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    want = [json.loads(line) for line in (ROOT / "examples" / "frames.jsonl").read_text().splitlines()]
    keys = ("id", "extended", "remote", "dlc", "data")
    assert [{k: g[k] for k in keys} for g in got] == [{k: w[k] for k in keys} for w in want]
    assert all(g["crc_ok"] and g["ack"] for g in got)
    assert got[0]["id"] == 0x0C1 and got[0]["crc"] == 0x5B40  # the specification's example (DESIGN.md)
    assert (ROOT / "examples" / "capture.vcd").stat().st_size < 8192


def test_render_example_makes_the_shipped_capture(tmp_path, monkeypatch, capsys):
    argv = _command("canstack render --bitrate 125000")
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert out.startswith("render: 4 frames, ") and out.rstrip().endswith("written to capture.vcd")
    assert (tmp_path / "capture.vcd").read_bytes() == (ROOT / "examples" / "capture.vcd").read_bytes()
