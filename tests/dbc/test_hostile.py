"""Hostile databases and early-closing output (issue 26, rest bus): every bad DBC is one line
naming the file, message and signal, exit status 2 — never a traceback, a hang or exit 0 — and
the files asked for are written even when standard output goes away."""

from __future__ import annotations

import random
import re
import subprocess
import sys
from pathlib import Path

import can
import pytest

import stack.cli as cli

SAMPLE = Path(__file__).resolve().parents[2] / "dbc" / "databases" / "powertrain_body.dbc"
TEXT = SAMPLE.read_text()


def run(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def mutate(old: str, new: str) -> str:
    assert old in TEXT, old
    return TEXT.replace(old, new, 1)


# (name, database text, what the one line must say)
BAD = [
    ("scale0", mutate("(0.25,0) [0|16000]", "(0,0) [0|16000]"), ["EngineData", "EngineSpeed", "scale 0"]),
    ("negstart", mutate("SG_ EngineSpeed : 0|16@1+", "SG_ EngineSpeed : -1|16@1+"), ["EngineSpeed", "start bit -1"]),
    (
        "startvalue",
        mutate('BA_ "GenSigStartValue" SG_ 256 EngineTemp 130;', 'BA_ "GenSigStartValue" SG_ 256 EngineTemp 999;'),
        ["EngineData", "EngineTemp", "999", "[0 .. 255]"],
    ),
    ("nomessages", TEXT[: TEXT.index("BO_ 256")], ["no messages"]),
    ("truncated", TEXT[: TEXT.index(" SG_ ThrottlePosition") + 20], ["EngineData", "truncated"]),
    ("truncated2", TEXT[: TEXT.index("BO_ 272") + 12], ["BO_ 272", "truncated"]),
    (
        "negcycle",
        mutate('BA_ "GenMsgCycleTime" BO_ 256 10;', 'BA_ "GenMsgCycleTime" BO_ 256 -10;'),
        ["EngineData", "GenMsgCycleTime", "-10"],
    ),
    (
        "duplicateid",
        mutate("BO_ 1024 ClusterStatus", "BO_ 1952 ClusterStatus"),
        ["ClusterDiagResponse", "0x7A0", "ClusterStatus"],
    ),
    (
        "checksum",
        mutate('"crc8_sae_j1850"', '"crc99"'),
        ["EngineData", "EngineChecksum", "crc99"],
    ),
]


@pytest.mark.parametrize("name, text, fragments", BAD, ids=[b[0] for b in BAD])
def test_bad_database_is_one_line_naming_file_message_signal(capsys, tmp_path, name, text, fragments):
    path = tmp_path / f"{name}.dbc"
    path.write_text(text)
    code, out, err = run(capsys, "restbus", path, "--duration", "0.05")
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert f"{name}.dbc" in err
    for f in fragments:
        assert f in err, err


def _mutations(count: int, seed: int) -> list[str]:
    """``count`` mutations of the sample database: a number replaced by a hostile one, a line
    dropped or doubled, the file cut short, or two characters swapped."""
    rng = random.Random(seed)
    lines = TEXT.splitlines(keepends=True)
    hostile = ["-1", "0", "-0.0", "1e400", "99999999999999999999", "4294967296", "0.000001", "x", ""]
    out = []
    numbers = list(re.finditer(r"-?\d+(\.\d+)?", TEXT))
    for _ in range(count):
        kind = rng.randrange(5)
        if kind == 0:
            m = rng.choice(numbers)
            out.append(TEXT[: m.start()] + rng.choice(hostile) + TEXT[m.end() :])
        elif kind == 1:
            i = rng.randrange(len(lines))
            out.append("".join(lines[:i] + lines[i + 1 :]))
        elif kind == 2:
            i = rng.randrange(len(lines))
            out.append("".join(lines[: i + 1] + lines[i:]))
        elif kind == 3:
            out.append(TEXT[: rng.randrange(len(TEXT))])
        else:
            i = rng.randrange(len(TEXT) - 1)
            out.append(TEXT[:i] + TEXT[i + 1] + TEXT[i] + TEXT[i + 2 :])
    return out


def test_generated_mutations_never_traceback(capsys, tmp_path):
    """Every second of 120 mutations of the shipped database (the other half runs with ``-m
    campaign``), each run for 20 simulated ms: exit 0 with frames on the bus, or exit 2 with one
    line naming the file; an exception escaping `main` fails the test."""
    _run_batch(capsys, tmp_path, list(enumerate(_mutations(120, seed=26)))[::2])


@pytest.mark.campaign
def test_the_other_half_of_the_mutations(capsys, tmp_path):
    _run_batch(capsys, tmp_path, list(enumerate(_mutations(120, seed=26)))[1::2])


def _run_batch(capsys, tmp_path, mutations: list[tuple[int, str]]) -> None:
    outcomes = {0: 0, 2: 0}
    for i, text in mutations:
        path = tmp_path / f"m{i:03}.dbc"
        path.write_text(text)
        code, out, err = run(capsys, "restbus", path, "--duration", "0.02")
        assert code in (0, 2), (i, code, err)
        outcomes[code] += 1
        if code == 2:
            assert len(err.strip().splitlines()) == 1 and f"m{i:03}.dbc" in err, (i, err)
        else:
            assert "frames on the bus" in out and " 0 frames" not in out, (i, out)
    assert outcomes[0] and outcomes[2]  # each half holds both kinds


@pytest.mark.subprocess
def test_trace_is_written_when_stdout_closes_early(tmp_path):
    """``restbus --json --trace x.asc | head -1``: the reader goes after one line; the run
    finishes and writes the whole trace."""
    trace = tmp_path / "x.asc"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "stack.cli",
            "restbus",
            str(SAMPLE),
            "--json",
            "--trace",
            str(trace),
            "--duration",
            "0.5",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline()
        proc.stdout.close()  # as head does after its line
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert first.startswith(b"{")
    assert proc.returncode == 0, err
    assert b"Traceback" not in err
    msgs = [m for m in can.LogReader(str(trace)) if not m.is_error_frame]
    assert sum(1 for m in msgs if m.arbitration_id == 0x100) == 50  # EngineData, 10 ms for 0.5 s


@pytest.mark.subprocess
def test_duplicate_id_is_one_line_on_stderr_of_the_command(tmp_path):
    """cantools logs a warning as it overwrites the identifier; the command prints only its error."""
    path = tmp_path / "dup.dbc"
    path.write_text({b[0]: b[1] for b in BAD}["duplicateid"])
    out = subprocess.run(
        [sys.executable, "-m", "stack.cli", "restbus", str(path), "--duration", "0.05"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1, out.stderr
    assert "0x7A0" in out.stderr  # BO_ 1952: 11-bit, upper-case hex as every output
