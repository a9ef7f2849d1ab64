"""Sweeps (`profiles.sweeps.sweep`, `profiles.sweeps.execute`): values and ranges, keys into the scenario, derived
seeds, the canonical order, the same table from one process, a process pool and a Dask
LocalCluster, failed runs in the table, and Ctrl-C keeping what is done."""

from __future__ import annotations

import csv
import hashlib
import os
import sys
from pathlib import Path

import pytest

from profiles.pipeline.runner import run_scenario
from profiles.pipeline.scenario import parse_scenario
from profiles.sweeps.execute import ExecuteError, choose_engine, chunks, dask_available
from profiles.sweeps.sweep import (
    SweepError,
    Vary,
    apply_values,
    parse_vary,
    plan_runs,
    resolve_vary,
    run_seed,
    run_sweep,
    table_columns,
    write_table,
)

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[3]

# two nodes, three periodic messages with release jitter (so the seed matters), 40 ms simulated
SMALL = """
[bus]
bitrate = 500000
duration = 0.04
seed = 7

[[nodes]]
name = "engine"
queue = "priority"
[[nodes.messages]]
name = "EngineData"
id = 0x100
dlc = 8
period_ms = 2
jitter_ms = 0.5
[[nodes.messages]]
name = "EngineTemp"
id = 0x300
dlc = 4
period_ms = 5

[[nodes]]
name = "body"
[[nodes.messages]]
name = "Doors"
id = 0x200
dlc = 2
period_ms = 4
jitter_ms = 1.0

[[faults]]
kind = "bit_errors"
rate = 0.0
"""


def small_raw() -> dict:
    return tomllib.loads(SMALL)


def vary(raw: dict, spec: str) -> Vary:
    return resolve_vary(raw, parse_vary(spec))


# --- values and ranges ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "spec,values",
    [
        ("bus.bitrate=5:50:5", [5, 10, 15, 20, 25, 30, 35, 40, 45, 50]),  # the end falls on a step: included
        ("bus.bitrate=0:10:3", [0, 3, 6, 9]),  # it does not: the last step below it
        ("bus.duration=0.1:0.5:0.1", [0.1, 0.2, 0.3, 0.4, 0.5]),  # decimal steps land exactly
        ("bus.bitrate=10:0:-5", [10, 5, 0]),  # downwards
        ("bus.bitrate=3:5", [3, 4, 5]),  # step 1 when left out
        ("bus.bitrate=1,2:4,9", [1, 2, 3, 4, 9]),  # ranges among single values
    ],
)
def test_ranges_expand_with_the_end_included_when_on_a_step(spec, values):
    v = vary(small_raw(), spec)
    assert list(v.values) == values
    assert all(type(a) is type(b) for a, b in zip(v.values, values))


@pytest.mark.parametrize(
    "spec,message",
    [
        ("bus.bitrate", "expected KEY=V1,V2"),
        ("=1,2", "expected KEY=V1,V2"),
        ("bus..bitrate=1", "is not a dotted key"),
        ("bus.bitrate=", "no values after '='"),
        ("bus.bitrate=1,,2", "an empty value between commas"),
        ("bus.bitrate=1:5:0", "the step of a range must not be 0"),
        ("bus.bitrate=5:1:1", "a step of 1 never goes from 5 to 1"),
        ("bus.bitrate=1:x", "is not a range START:END:STEP"),
        ("bus.bitrate=1:2:3:4", "is not a range START:END:STEP"),
        ("bus.bitrate=0:1e9:1", "gives 1,000,000,001 values"),
    ],
)
def test_a_bad_vary_is_one_line(spec, message):
    with pytest.raises(SweepError) as exc:
        parse_vary(spec)
    assert message in str(exc.value) and "\n" not in str(exc.value)


# --- keys into the scenario ---------------------------------------------------------------------


def test_values_are_typed_as_the_schema_expects():
    raw = small_raw()
    assert vary(raw, "bus.bitrate=250000,0x7A120").values == (250000, 500000)  # TOML integers, hex too
    assert vary(raw, "nodes.engine.messages.EngineData.period_ms=2.5,3").values == (2.5, 3)
    assert vary(raw, "nodes.engine.queue=fifo,mailboxes:2").values == ("fifo", "mailboxes:2")
    assert vary(raw, "nodes.engine.queue=10").values == ("10",)  # a string key keeps text
    assert vary(raw, "nodes.body.listen_only=true,false").values == (True, False)
    assert vary(raw, "bus.bitrate=fast").values == ("fast",)  # the schema will say why not


def test_names_and_indices_resolve_to_paths():
    raw = small_raw()
    assert vary(raw, "nodes.engine.messages.EngineTemp.period_ms=1").path == ("nodes", 0, "messages", 1, "period_ms")
    assert vary(raw, "nodes.1.drift_ppm=50").path == ("nodes", 1, "drift_ppm")  # a list element by index
    assert vary(raw, "faults.0.rate=1e-5").path == ("faults", 0, "rate")
    assert vary(raw, "nodes.body.tx_queue_size=8").path == ("nodes", 1, "tx_queue_size")  # a default key
    assert vary(raw, "analysis.t_error_ms=10").path == ("analysis", "t_error_ms")  # an optional table


@pytest.mark.parametrize(
    "spec,message",
    [
        ("nodes.motor.queue=fifo", "nodes has no element 'motor' (names: engine, body)"),
        ("nodes.engine.messages.Nope.dlc=1", "has no element 'Nope' (names: EngineData, EngineTemp)"),
        ("nodes.engine.quue=fifo", "has no key 'quue'"),
        ("bus.bitrat=1", "bus has no key 'bitrat' (keys: bitrate, data_bitrate, duration, seed)"),
        ("buss.bitrate=1", "the scenario has no 'buss'"),
        ("faults.3.rate=1", "has no element '3'"),
        ("faults.0.bogus=1", "has no key 'bogus'"),
        ("nodes.engine=1", "is a list: name an element"),
        ("bus=1", "is a table; vary a single value"),
        ("nodes.engine.messages=1", "is a list; vary a single value"),
        ("bus.seed=1,2", "use --seed S for the sweep seed and --seeds N"),
    ],
)
def test_a_key_the_scenario_does_not_have_is_refused_before_any_run(spec, message):
    with pytest.raises(SweepError) as exc:
        vary(small_raw(), spec)
    assert message in str(exc.value) and "\n" not in str(exc.value)


def test_apply_values_changes_a_copy():
    raw = small_raw()
    out = apply_values(raw, [(("nodes", 0, "queue"), "fifo"), (("analysis", "t_error_ms"), 10)])
    assert out["nodes"][0]["queue"] == "fifo" and out["analysis"] == {"t_error_ms": 10}
    assert raw["nodes"][0]["queue"] == "priority" and "analysis" not in raw


# --- seeds and order ------------------------------------------------------------------------------


def test_run_seed_is_a_stable_hash_of_the_sweep_seed_parameters_and_replicate():
    params = (("bus.bitrate", 250000), ("nodes.engine.queue", "fifo"))
    # the rule, computed here independently: SHA-256 of repr((seed, sorted params, replicate)), 4 bytes
    text = repr((7, (("bus.bitrate", 250000), ("nodes.engine.queue", "fifo")), 1))
    assert run_seed(7, params, 1) == int.from_bytes(hashlib.sha256(text.encode()).digest()[:4], "big")
    assert run_seed(7, params[::-1], 1) == run_seed(7, params, 1)  # the order of --vary does not matter
    assert len({run_seed(7, params, r) for r in range(50)}) == 50
    assert run_seed(8, params, 1) != run_seed(7, params, 1)


def test_runs_come_in_the_product_order_times_seeds():
    raw = small_raw()
    tasks = plan_runs(raw, "s.toml", [vary(raw, "bus.bitrate=1,2"), vary(raw, "nodes.engine.queue=a,b,c")], seeds=2)
    assert [(t.index, t.params, t.replicate) for t in tasks][:4] == [
        (0, (("bus.bitrate", 1), ("nodes.engine.queue", "a")), 0),
        (1, (("bus.bitrate", 1), ("nodes.engine.queue", "a")), 1),
        (2, (("bus.bitrate", 1), ("nodes.engine.queue", "b")), 0),
        (3, (("bus.bitrate", 1), ("nodes.engine.queue", "b")), 1),
    ]
    assert len(tasks) == 12 and tasks[-1].params == (("bus.bitrate", 2), ("nodes.engine.queue", "c"))
    assert all(t.seed == run_seed(7, t.params, t.replicate) for t in tasks)  # the scenario's bus.seed
    assert plan_runs(raw, "s.toml", [], seeds=3, sweep_seed=1)[2].seed == run_seed(1, (), 2)
    with pytest.raises(SweepError, match="given twice"):
        plan_runs(raw, "s.toml", [vary(raw, "bus.bitrate=1"), vary(raw, "bus.bitrate=2")])


# --- the rows --------------------------------------------------------------------------------------


def test_a_row_is_the_run_of_its_scenario_with_its_seed():
    raw = small_raw()
    res = run_sweep(raw, "s.toml", [vary(raw, "nodes.engine.queue=priority,fifo")], seeds=2)
    assert [r["run"] for r in res.rows] == [0, 1, 2, 3] and not res.failed and res.total == 4
    # independently: the experiment runner on the same scenario with that seed and that queue
    for row in res.rows:
        r2 = dict(raw, bus=dict(raw["bus"], seed=row["seed"]))
        r2["nodes"] = [dict(raw["nodes"][0], queue=row["nodes.engine.queue"]), raw["nodes"][1]]
        direct = run_scenario(parse_scenario(r2, "s.toml"), progress=False).to_json()
        assert row["bus_load"] == direct["bus_load"] and row["frames"] == direct["frames"]
        by_name = {m["name"]: m for m in direct["messages"]}
        assert row["EngineData.max_ms"] == by_name["EngineData"]["response_ms"]["max"]
        assert row["Doors.jitter_ms"] == by_name["Doors"]["jitter_ms"]
        assert row["EngineTemp.misses"] == by_name["EngineTemp"]["deadline_misses"]
        assert row["EngineData.rta_ms"] == by_name["EngineData"]["rta_ms"]
        assert row["deadline_misses"] == sum(m["deadline_misses"] for m in direct["messages"])
        assert row["worst_misses"] == max(m["deadline_misses"] for m in direct["messages"])
    # the FIFO node's messages get the FIFO bound, above the priority queue's
    assert res.rows[0]["EngineData.rta_ms"] < res.rows[2]["EngineData.rta_ms"]
    # replicates differ only by the seed: release jitter draws differ
    assert res.rows[0]["seed"] != res.rows[1]["seed"]
    assert res.rows[0]["Doors.jitter_ms"] != res.rows[1]["Doors.jitter_ms"]


@pytest.mark.socket
@pytest.mark.subprocess
def test_identical_tables_sequential_process_pool_and_dask(monkeypatch):
    # workers the pool or the cluster starts must import this checkout
    monkeypatch.setenv("PYTHONPATH", str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    raw = small_raw()
    varies = [vary(raw, "bus.bitrate=250000,500000"), vary(raw, "nodes.engine.queue=priority,fifo,bogus")]
    seq = run_sweep(raw, "s.toml", varies, seeds=2, workers=1)
    pool = run_sweep(raw, "s.toml", varies, seeds=2, workers=2, engine="processes")
    assert (seq.engine, pool.engine) == ("sequential", "processes")
    assert len(seq.rows) == 12 and len(seq.failed) == 4  # 'bogus' is not a queue policy: those runs fail
    assert pool.rows == seq.rows and pool.columns == seq.columns
    pytest.importorskip("distributed")
    dask = run_sweep(raw, "s.toml", varies, seeds=2, workers=2, engine="dask")
    assert dask.engine == "dask" and dask.rows == seq.rows


@pytest.mark.socket
@pytest.mark.subprocess
def test_a_sweep_on_a_running_scheduler(monkeypatch):
    """--scheduler: the runs go to a cluster this process did not start (here a LocalCluster's
    scheduler, as `dask scheduler` would be), with the same table."""
    distributed = pytest.importorskip("distributed")
    import logging

    monkeypatch.setenv("PYTHONPATH", str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    raw = small_raw()
    varies = [vary(raw, "nodes.body.messages.Doors.period_ms=2,4,8")]
    seq = run_sweep(raw, "s.toml", varies, seeds=2)
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, processes=True, dashboard_address=":0", silence_logs=logging.ERROR
    ) as cluster:
        remote = run_sweep(raw, "s.toml", varies, seeds=2, scheduler=cluster.scheduler_address)
    assert remote.engine == "dask" and remote.rows == seq.rows


def test_a_profile_table_key_is_varied_and_keeps_its_column():
    """A profile's own table (here TDMA's [tdma]) is varied by the keys the file has; a profile
    figure of the same name as the varied key gets a column of its own."""
    from profiles.pipeline.scenario import load_scenario

    raw = load_scenario(ROOT / "examples" / "tdma.toml").raw
    raw = dict(raw, bus=dict(raw["bus"], duration=0.05))
    v = vary(raw, "tdma.basic_cycle_us=5000,10000")
    assert v.path == ("tdma", "basic_cycle_us") and v.values == (5000, 10000)
    res = run_sweep(raw, "tdma.toml", [v])
    assert not res.failed
    assert [r["tdma.basic_cycle_us"] for r in res.rows] == [5000, 10000]
    assert [r["tdma.basic_cycle_us (result)"] for r in res.rows] == [5000, 10000]  # the schedule that ran
    with pytest.raises(SweepError, match="has no key 'bogus'"):
        vary(raw, "tdma.bogus=1")


def test_a_value_that_breaks_a_rule_fails_that_run_only():
    raw = small_raw()
    res = run_sweep(raw, "small.toml", [vary(raw, "bus.bitrate=500000,2000000,fast")])
    ok, too_fast, word = res.rows
    assert ok.get("error") is None and ok["frames"] > 0
    assert too_fast["error"].startswith("small.toml: [bus]: bitrate: 2000000 is outside 1000..")
    assert "1 Mbit/s" in too_fast["error"] and "bus_load" not in too_fast
    assert word["error"] == "small.toml: [bus]: bitrate: 'fast' is a string, expected an integer"
    assert [r["bus.bitrate"] for r in res.rows] == [500000, 2000000, "fast"]


def _hook_module(tmp_path: Path, monkeypatch, body: str) -> None:
    (tmp_path / "sweep_hooks.py").write_text(body)
    monkeypatch.syspath_prepend(str(tmp_path))
    sys.modules.pop("sweep_hooks", None)


def test_a_run_that_raises_is_recorded_with_its_error(tmp_path, monkeypatch):
    _hook_module(
        tmp_path,
        monkeypatch,
        "def hook(node, profile, ctx):\n"
        "    if ctx.scenario.bitrate == 250000:\n        raise RuntimeError('the ECU crashed')\n",
    )
    raw = small_raw()
    raw["nodes"][0]["app"] = "sweep_hooks:hook"
    res = run_sweep(raw, "s.toml", [vary(raw, "bus.bitrate=125000,250000,500000")])
    errors = [r.get("error") for r in res.rows]
    assert errors[0] is None and errors[2] is None
    # the scenario's location, the app and the exception with where it was raised
    assert errors[1].startswith(
        "s.toml: [[nodes]] 'engine': app: sweep_hooks:hook failed: RuntimeError: the ECU crashed"
    )
    assert "sweep_hooks.py:3" in errors[1]
    assert not res.interrupted and len(res.rows) == 3


def test_ctrl_c_keeps_the_runs_done(tmp_path, monkeypatch):
    _hook_module(
        tmp_path,
        monkeypatch,
        "def hook(node, profile, ctx):\n    if ctx.scenario.bitrate == 250000:\n        raise KeyboardInterrupt\n",
    )
    raw = small_raw()
    raw["nodes"][0]["app"] = "sweep_hooks:hook"
    res = run_sweep(raw, "s.toml", [vary(raw, "bus.bitrate=125000,500000,250000,1000000")])
    assert res.interrupted and res.total == 4
    assert [r["bus.bitrate"] for r in res.rows] == [125000, 500000]
    assert all(r.get("error") is None and r["frames"] > 0 for r in res.rows)


# --- engines and tables ----------------------------------------------------------------------------


def test_engine_choice(monkeypatch):
    assert choose_engine(1, None) == "sequential"
    assert choose_engine(2, None, "processes") == "processes"
    assert choose_engine(2, None) == "processes"  # the default (DESIGN.md), dask or not
    if dask_available():
        assert choose_engine(2, None, "dask") == "dask"  # a LocalCluster on request
        assert choose_engine(1, "tcp://127.0.0.1:8786") == "dask"  # a scheduler means Dask
    with pytest.raises(ExecuteError, match="--workers 0: at least 1"):
        choose_engine(0, None)
    with pytest.raises(ExecuteError, match="runs in this process"):
        choose_engine(2, None, "sequential")
    monkeypatch.setattr("profiles.sweeps.execute.dask_available", lambda: False)
    assert choose_engine(2, None) == "processes"  # the standard library's pool without dask
    with pytest.raises(ExecuteError) as exc:
        choose_engine(1, "tcp://127.0.0.1:8786")
    assert (
        str(exc.value) == "--scheduler needs Dask's distributed, which is not installed: pip install 'canstack[dask]'"
    )


def test_chunks_keep_the_order_and_cover_every_task():
    tasks = list(range(1000))
    parts = chunks(tasks, 2)
    assert [t for p in parts for t in p] == tasks
    assert len(parts) == 20 and max(map(len, parts)) <= 50  # 4 a slot would be 8 chunks of 125: 50 at most
    assert len(chunks(list(range(40)), 2)) == 8  # 4 chunks a slot
    assert chunks(list(range(5)), 4) == [[0], [1], [2], [3], [4]]


def test_csv_table_round_trip(tmp_path):
    rows = [
        {"run": 0, "k": "fifo", "replicate": 0, "seed": 5, "bus_load": 0.25, "x.max_ms": None},
        {"run": 1, "k": "fifo", "replicate": 1, "seed": 6, "error": "it broke"},
    ]
    cols = table_columns(rows, ["k"])
    assert cols == ["run", "k", "replicate", "seed", "bus_load", "x.max_ms", "error"]
    write_table(rows, cols, tmp_path / "t.csv")
    with open(tmp_path / "t.csv", newline="") as f:
        got = list(csv.reader(f))
    assert got == [cols, ["0", "fifo", "0", "5", "0.25", "", ""], ["1", "fifo", "1", "6", "", "", "it broke"]]


def test_parquet_table_has_one_type_per_column(tmp_path):
    pq = pytest.importorskip("pyarrow.parquet")
    rows = [
        {"run": 0, "k": 1, "replicate": 0, "seed": 5, "bus_load": 0.25, "m.misses": 0},
        {"run": 1, "k": "x", "replicate": 0, "seed": 6, "error": "bad"},
    ]
    cols = table_columns(rows, ["k"])
    write_table(rows, cols, tmp_path / "t.parquet")
    t = pq.read_table(tmp_path / "t.parquet")
    assert t.column_names == cols
    assert t.column("k").to_pylist() == ["1", "x"]  # mixed kinds become text
    assert t.column("bus_load").to_pylist() == [0.25, None]
    assert t.column("error").to_pylist() == [None, "bad"]
