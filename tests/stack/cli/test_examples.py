"""The example scripts a new user copies from keep running, and leave nothing behind."""

import subprocess
import sys
from pathlib import Path

import can
import pytest

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"


@pytest.mark.subprocess
@pytest.mark.parametrize("script", ["quickstart.py", "restbus_example.py", "fd_intolerant.py"])
def test_example_runs(script, tmp_path):
    p = subprocess.run(
        [sys.executable, str(EXAMPLES / script)], cwd=tmp_path, capture_output=True, text=True, timeout=120
    )
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip()
    assert list(tmp_path.iterdir()) == []  # nothing written into the working directory


@pytest.mark.subprocess
def test_quickstart_writes_the_trace_it_is_given(tmp_path):
    out = tmp_path / "run" / "qs.blf"
    out.parent.mkdir()
    work = tmp_path / "work"
    work.mkdir()
    p = subprocess.run(
        [sys.executable, str(EXAMPLES / "quickstart.py"), str(out)],
        cwd=work,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert p.returncode == 0, p.stderr
    n = int(p.stdout.rsplit("trace: ", 1)[1].split()[0])
    assert n == sum(1 for _ in can.LogReader(str(out))) > 100
    assert list(work.iterdir()) == []
