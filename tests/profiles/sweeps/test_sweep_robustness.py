"""Sweeps and studies under trouble (issue 26): a pool worker that dies, SIGTERM, a run that
never ends, options that overflow; and their exit status when a run failed (issue 23)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from profiles.sweeps.execute import WORKER_LOSSES
from profiles.sweeps.plots import wants_log
from profiles.sweeps.schedulability import SchedulabilityStudy, breakdown_text
from profiles.sweeps.sweep import parse_vary, resolve_vary, run_sweep
from stack.cli import main

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[3]
EXAMPLE = str(ROOT / "examples" / "powertrain_90.toml")

SMALL = """
[bus]
bitrate = 500000
duration = 0.02
seed = 7

[[nodes]]
name = "engine"
app = "sweep_killer:hook"
[[nodes.messages]]
name = "EngineData"
id = 0x100
dlc = 8
period_ms = 2
jitter_ms = 0.5

[[nodes]]
name = "body"
[[nodes.messages]]
name = "Doors"
id = 0x200
dlc = 2
period_ms = 4
"""


def _run(capsys, *argv):
    rc = main(list(argv))
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


@pytest.mark.subprocess
def test_a_worker_that_dies_costs_only_its_own_run(tmp_path, monkeypatch):
    """The run at 250 kbit/s kills its worker process every time (as the OOM killer or a kill
    -9 would): the pool breaks, the other runs are rerun and complete, and that run alone is a
    failed row. Without it, 50 of 62 rows were BrokenProcessPool errors."""
    (tmp_path / "sweep_killer.py").write_text(
        "import os, signal\n"
        "def hook(node, profile, ctx):\n"
        "    if ctx.scenario.bitrate == 250000 and os.environ.get('SWEEP_KILLER_PARENT') != str(os.getpid()):\n"
        "        os.kill(os.getpid(), signal.SIGKILL)\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("SWEEP_KILLER_PARENT", str(os.getpid()))
    sys.modules.pop("sweep_killer", None)
    raw = tomllib.loads(SMALL)
    v = resolve_vary(raw, parse_vary("bus.bitrate=125000,250000,500000,1000000"))
    res = run_sweep(raw, "k.toml", [v], seeds=2, workers=2, engine="processes")
    assert len(res.rows) == 8 and not res.interrupted
    failed = [r for r in res.rows if r.get("error")]
    assert [r["bus.bitrate"] for r in failed] == [250000, 250000]
    assert all(f"died {WORKER_LOSSES} times" in r["error"] for r in failed)
    # the others are the rows one process gives (the killer spares this process)
    alone = run_sweep(raw, "k.toml", [v], seeds=2)
    assert [r for r in res.rows if not r.get("error")] == [r for r in alone.rows if r["bus.bitrate"] != 250000]


def test_sweep_and_study_exit_1_when_a_run_failed_with_its_row_written(tmp_path, capsys):
    out = tmp_path / "r.csv"
    rc, _, err = _run(
        capsys, "sweep", EXAMPLE, "--vary", "bus.bitrate=500000,2000000", "--duration", "0.05", "--out", str(out)
    )
    assert rc == 1, err
    lines = out.read_text().splitlines()
    assert len(lines) == 3 and "bitrate: 2000000 is outside" in lines[2]
    assert "1 failed (see the error column)" in err


@pytest.mark.wallclock
def test_a_run_past_its_time_limit_is_a_failed_row(tmp_path, capsys):
    """An hour of bus time cannot be simulated in 1 s of wall clock: that run is stopped and its
    row says so; the short one is done."""
    out = tmp_path / "r.csv"
    rc, _, err = _run(
        capsys, "sweep", EXAMPLE, "--vary", "bus.duration=0.01,3600", "--time-limit", "1", "--out", str(out)
    )
    assert rc == 1, err
    rows = out.read_text().splitlines()
    assert "stopped after the time limit of 1 s (wall clock)" in rows[2] and "time limit" not in rows[1]


@pytest.mark.subprocess
@pytest.mark.wallclock
def test_sigterm_on_a_pool_sweep_writes_the_rows_and_ends_the_workers(tmp_path, wait_until):
    """SIGTERM is handled as Ctrl-C: the workers are asked to stop their runs, the rows done are
    written, the exit status is 143, and no worker is left behind."""
    started = tmp_path / "started"
    (tmp_path / "mark_start.py").write_text(
        "import os\n"
        "def hook(node, profile, ctx):\n"
        f"    open({str(started)!r} + f'{{os.getpid()}}_{{ctx.scenario.duration_ns}}', 'w').close()\n"
    )
    scenario = tmp_path / "long.toml"
    scenario.write_text(
        (ROOT / "examples" / "powertrain_90.toml")
        .read_text()
        .replace('name = "engine"\n', 'name = "engine"\napp = "mark_start:hook"\n', 1)
    )
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), str(tmp_path), os.environ.get("PYTHONPATH", "")]))
    out = tmp_path / "r.csv"
    proc = subprocess.Popen(
        [sys.executable, "-m", "stack.cli", "sweep", str(scenario), "--vary", "bus.duration=0.01,600,600,600",
         "--workers", "2", "--out", str(out), "--no-progress"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        # both workers are in a 600 s run once two of those have started
        wait_until(
            lambda: len(list(tmp_path.glob("started*_600000000000"))) >= 2, timeout=120, what="the long runs to start"
        )
        workers = {int(p.name[len("started") :].split("_")[0]) for p in tmp_path.glob("started*")}
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
        proc.wait()
    assert proc.returncode == 143, err
    assert "interrupted:" in err and out.exists()
    rows = out.read_text().splitlines()
    assert len(rows) >= 2 and rows[1].split(",")[1] == "0.01"  # the short run is written

    def gone(pid: int) -> bool:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        return False

    wait_until(lambda: all(gone(p) for p in workers), timeout=30, what="the workers to end")


@pytest.mark.parametrize(
    "argv,message",
    [
        (["sweep", EXAMPLE, "--vary", "bus.duration=0:1e1000000:1"], "gives more than 100,000 values"),
        (["sweep", EXAMPLE, "--vary", "bus.duration=0:1:1e-999999"], "gives more than 100,000 values"),
        (["sweep", EXAMPLE, "--vary", "bus.seed=1", "--vary", "bus.bitrate=1000:1000000:1"], "--vary bus.seed"),
        (
            ["sweep", EXAMPLE, "--vary", "bus.bitrate=1000:100000:1", "--vary", "bus.duration=1:100:1"],
            "the sweep would make 9,900,100 runs (99001 × 100): at most 1,000,000",
        ),
        (["study", "profiles", "--bitrate", "0"], "--bitrate: 0: a CAN 2.0 bus runs at 1000..1000000 bit/s"),
        (["study", "profiles", "--utilisation", "1e-300"], "a utilisation is from 0.001 to 1.5"),
        (["study", "profiles", "--messages", "5000"], "is at most 2,048"),
        (["study", "schedulability", "--bitrate", "-1"], "a CAN 2.0 bus runs at 1000..1000000 bit/s"),
        (["study", "schedulability", "--bitrate", "1"], "a CAN 2.0 bus runs at 1000..1000000 bit/s"),
        (["study", "schedulability", "--period-range", "1e300,inf"], "(finite numbers)"),
        (["study", "schedulability", "--messages", "3000"], "is at most 2,048"),
        (["study", "schedulability", "--sets", "1000000000"], "sets per point is at most 100,000"),
    ],
)
def test_options_that_overflow_are_refused_before_the_first_run(capsys, argv, message):
    rc, out, err = _run(capsys, *argv)
    assert rc == 2 and out == "" and err.count("\n") == 1, err
    assert message in err


def test_seeds_on_a_scenario_that_draws_nothing_says_so(capsys):
    rc, _, err = _run(
        capsys, "sweep", EXAMPLE, "--vary", "bus.bitrate=250000,500000", "--seeds", "3", "--duration", "0.05"
    )
    assert rc == 0
    assert "every one of the 3 seeds of each combination gave the same row: nothing in this scenario is drawn" in err


def test_varied_values_over_two_decades_go_on_a_log_axis():
    assert wants_log([0.1, 1, 10]) and wants_log([125000, 1000000 * 100])
    assert not wants_log([125000, 250000, 500000, 1000000]) and not wants_log([0, 1, 1000]) and not wants_log(["a"])


@pytest.mark.parametrize(
    "fractions,expected",
    [
        ([1.0, 0.9, 0.4], "breakdown 28.0 %"),  # 0.2 + 0.1 × (0.9 − 0.5) / (0.9 − 0.4)
        ([0.3, 0.1, 0.0], "below 50 % from the first point (10 %)"),
        ([1.0, 1.0, 0.9], "never below 50 % up to 30 %"),
    ],
)
def test_the_breakdown_says_why_a_curve_has_none(fractions, expected):
    from profiles.sweeps.schedulability import breakdown

    pts = [{"utilisation": u, "analysis": f} for u, f in zip((0.1, 0.2, 0.3), fractions)]
    study = SchedulabilityStudy(
        [], pts, {"analysis": breakdown([(p["utilisation"], p["analysis"]) for p in pts])}, 0, False, "sequential", 0.0
    )
    assert breakdown_text(study, "analysis") == expected
