"""Speed figures of the experiments (registered under the ``canstack.bench`` entry point group, so
``python -m stack.bench`` prints them beside the engine's).

- ``runner_vs_engine``: the wall time of `profiles.pipeline.runner.run_scenario` on a scenario, divided by
  the wall time of the bare engine carrying the same traffic (the same nodes on a `SimBus`, each
  message a `Node.send_periodic` with its period and offset, no recorder, no analysis). The
  scenario is examples/powertrain_90.toml's network (17 periodic messages, 5 nodes, 500 kbit/s,
  about 83 % bus load). Target: at most 1.5.
- ``sweep_parallel``: the wall time of a sweep of that network (24 runs of 4 s simulated, each
  with its own seed: about 6 s in one process) in one process, divided by the same sweep with two
  workers — the standard library's process pool, and a Dask LocalCluster when dask is installed
  (with its start-up of 1 to 2 s, and without: the throughput once it runs). The tables must be
  equal. Target on a 2-core machine: at least 1.7.
- ``sweep_overhead``: the wall time per run of a sequential sweep (the raw scenario copied, the
  run's values and seed put in, checked by `parse_scenario`, run, its row built) against a bare
  `run_scenario` of the already-checked scenario with the same seeds: (sweep − bare) / bare.
  Target: at most 0.10.

- ``memory``: the peak resident memory of `canstack experiment` on that network (and on
  examples/master_slave.toml, whose ``[[faults]]`` once kept the whole trace, and with ``--trace``
  streaming to a .blf file) after a run of T and of 4T simulated seconds, each in a fresh
  interpreter, and the growth between them per simulated hour: what an hour costs beyond the
  start. Target: a one-hour run of the powertrain network under 150 MB (the growth near 0).

Sweep figures are the best of ``repeat`` rounds, as `timeit` does: noise only slows a run.
"""

from __future__ import annotations

import copy
import time
from pathlib import Path
from typing import Any

__all__ = ["benchmark", "runner_overhead", "sweep_parallel", "sweep_overhead", "memory"]

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "powertrain_90.toml"


def _bare(scenario: Any) -> float:
    from profiles.base import frame_of
    from stack import SimBus

    bus = SimBus(scenario.bitrate, seed=scenario.seed, record=False)
    for d in scenario.nodes:
        n = bus.node(d.name, queue=d.policy, tx_queue_size=d.tx_queue_size, rx_fifo_size=d.rx_fifo_size)
        for m in d.messages:
            n.send_periodic(frame_of(m), m.period_ns, offset=m.offset_ns)
    t0 = time.perf_counter()
    bus.run(until=scenario.duration_ns - 1)
    return time.perf_counter() - t0


def _runner(scenario: Any) -> float:
    from profiles.pipeline.runner import run_scenario

    t0 = time.perf_counter()
    run_scenario(scenario, record=False, progress=False)
    return time.perf_counter() - t0


def runner_overhead(seconds: float = 4.0, repeat: int = 3) -> dict[str, float]:
    """Best-of-``repeat`` wall times of the runner and of the bare engine on ``seconds`` of
    simulated time of the example network, and their ratio."""
    from profiles.pipeline.scenario import load_scenario

    sc = load_scenario(EXAMPLE)
    sc.duration_ns = round(seconds * 1e9)
    bare = min(_bare(sc) for _ in range(repeat))
    runner = min(_runner(sc) for _ in range(repeat))
    return {"bare_s": bare, "runner_s": runner, "ratio": runner / bare, "simulated_s": seconds}


def _example_raw(seconds: float) -> dict[str, Any]:
    from profiles.pipeline.scenario import load_scenario

    raw = copy.deepcopy(load_scenario(EXAMPLE).raw)
    raw["bus"]["duration"] = seconds
    return raw


_ONE_SWEEP = """
import hashlib, json, sys
from profiles.sweeps.bench import _example_raw, EXAMPLE
from profiles.sweeps.sweep import run_sweep
runs, seconds, kw = json.loads(sys.argv[1])
res = run_sweep(_example_raw(seconds), str(EXAMPLE), [], seeds=runs, progress=False, **kw)
digest = hashlib.sha256(json.dumps(res.rows, sort_keys=True).encode()).hexdigest()
print(json.dumps({"wall_s": res.wall_s, "startup_s": res.startup_s, "rows": digest, "n": len(res.rows)}))
"""


def _one_sweep(runs: int, seconds: float, kw: dict[str, Any]) -> dict[str, Any]:
    """One sweep in a fresh interpreter, as `canstack sweep` starts: every engine begins cold (a
    pool forked from a process that has run the network would inherit its warm caches)."""
    import json
    import os
    import subprocess
    import sys

    root = str(EXAMPLE.parents[1])
    env = dict(os.environ, PYTHONPATH=root + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run(
        [sys.executable, "-c", _ONE_SWEEP, json.dumps([runs, seconds, kw])],
        capture_output=True,
        text=True,
        env=env,
        check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def sweep_parallel(runs: int = 24, seconds: float = 4.0, repeat: int = 3) -> dict[str, Any]:
    """Best-of-``repeat`` wall times of one sweep (``runs`` seeds of the example network, ``seconds``
    simulated each), each in a fresh interpreter: in one process, on a process pool of 2, and on a
    Dask LocalCluster of 2 (when dask is installed); rounds interleaved so that a busy moment of the
    machine hits all three; and the speed-ups. Raises AssertionError if a table differs."""
    from profiles.sweeps.execute import dask_available

    engines: dict[str, dict[str, Any]] = {
        "sequential": {"workers": 1},
        "processes": {"workers": 2, "engine": "processes"},
    }
    if dask_available():
        engines["dask"] = {"workers": 2, "engine": "dask"}
    best: dict[str, dict[str, Any]] = {}
    digest = None
    for _ in range(repeat):
        for name, kw in engines.items():
            r = _one_sweep(runs, seconds, kw)
            digest = digest or r["rows"]
            assert r["rows"] == digest and r["n"] == runs, f"the {name} table differs from the sequential one"
            if name not in best or r["wall_s"] - r["startup_s"] < best[name]["wall_s"] - best[name]["startup_s"]:
                best[name] = r
    seq_s = best["sequential"]["wall_s"]
    out: dict[str, Any] = {
        "runs": runs,
        "simulated_s": seconds,
        "sequential_s": seq_s,
        "processes_s": best["processes"]["wall_s"],
        "processes_speedup": seq_s / best["processes"]["wall_s"],
    }
    if "dask" in best:
        dask_s, startup = best["dask"]["wall_s"], best["dask"]["startup_s"]
        out.update(
            dask_s=dask_s,
            dask_startup_s=startup,
            dask_speedup=seq_s / dask_s,
            dask_speedup_after_startup=seq_s / (dask_s - startup),
        )
    return out


def sweep_overhead(runs: int = 20, seconds: float = 0.25, repeat: int = 3) -> dict[str, float]:
    """Best-of-``repeat`` wall time per run of a sequential sweep against a bare `run_scenario` of
    the same checked scenario with the same seeds (see the module docstring)."""
    from profiles.pipeline.runner import run_scenario
    from profiles.pipeline.scenario import parse_scenario
    from profiles.sweeps.sweep import plan_runs, run_sweep

    raw = _example_raw(seconds)
    seeds = [t.seed for t in plan_runs(raw, str(EXAMPLE), [], seeds=runs)]
    scenario = parse_scenario(raw, str(EXAMPLE))

    def bare() -> float:
        t0 = time.perf_counter()
        for seed in seeds:
            scenario.seed = seed
            run_scenario(scenario, progress=False)
        return time.perf_counter() - t0

    def sweep() -> float:
        t0 = time.perf_counter()
        run_sweep(raw, str(EXAMPLE), [], seeds=runs, progress=False)
        return time.perf_counter() - t0

    b = s = float("inf")
    for _ in range(repeat):  # interleaved, so that a busy moment of the machine hits both
        b = min(b, bare())
        s = min(s, sweep())
    return {
        "runs": runs,
        "simulated_s": seconds,
        "bare_per_run_s": b / runs,
        "sweep_per_run_s": s / runs,
        "overhead": (s - b) / b,
    }


_PEAK = """
import json, resource, sys
from stack.cli import main
main(json.loads(sys.argv[1]))
print(json.dumps(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss), file=sys.stderr)
"""


def _peak_mb(argv: list[str]) -> float:
    """Peak resident memory (MB) of ``canstack ARGV`` run in a fresh interpreter."""
    import json
    import os
    import subprocess
    import sys

    root = str(EXAMPLE.parents[1])
    env = dict(os.environ, PYTHONPATH=root + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run(
        [sys.executable, "-c", _PEAK, json.dumps(argv)], capture_output=True, text=True, env=env, check=True
    )
    kib = json.loads(out.stderr.strip().splitlines()[-1])
    return kib / 1024  # ru_maxrss is in KiB on Linux


def memory(seconds: float = 15.0) -> dict[str, Any]:
    """Peak memory of experiment runs of ``seconds`` and 4 × ``seconds`` simulated, each in a
    fresh interpreter, and the growth per simulated hour between them (see the module
    docstring)."""
    import tempfile

    examples = EXAMPLE.parent
    out: dict[str, Any] = {"simulated_s": [seconds, 4 * seconds]}
    with tempfile.TemporaryDirectory() as tmp:
        cases = {
            "powertrain": [str(EXAMPLE)],
            "master_slave_faults": [str(examples / "master_slave.toml")],
            "powertrain_trace": [str(EXAMPLE), "--trace", str(Path(tmp) / "t.blf")],
        }
        for name, args in cases.items():
            peaks = [_peak_mb(["experiment", *args, "--duration", str(t), "--no-progress"]) for t in out["simulated_s"]]
            growth = (peaks[1] - peaks[0]) / (3 * seconds) * 3600
            out[name] = {"peak_mb": peaks, "mb_per_simulated_hour": growth}
    return out


def benchmark(seconds: float = 3.0) -> dict[str, Any]:
    """Every figure of the experiments, with the lines `python -m stack.bench` prints."""
    r = runner_overhead(seconds=max(0.5, seconds))
    lines = [
        f"experiment runner on {r['simulated_s']:g} s of the 90 % powertrain network: {r['runner_s']:.2f} s vs the bare "
        f"engine {r['bare_s']:.2f} s on the same traffic: {r['ratio']:.2f}x (target <= 1.5)"
    ]
    scale = max(0.25, seconds / 3.0)
    p = sweep_parallel(runs=24, seconds=round(4 * scale, 3))
    text = (
        f"sweep of {p['runs']} runs x {p['simulated_s']:g} s of that network: 1 process {p['sequential_s']:.2f} s; "
        f"--workers 2 on a process pool {p['processes_s']:.2f} s: {p['processes_speedup']:.2f}x"
    )
    if "dask_s" in p:
        text += (
            f"; on a Dask LocalCluster {p['dask_s']:.2f} s ({p['dask_startup_s']:.2f} s of it starting the "
            f"cluster): {p['dask_speedup']:.2f}x, {p['dask_speedup_after_startup']:.2f}x after start-up"
        )
    lines.append(text + " (target >= 1.7)")
    # runs of 0.25 s simulated: long enough that the machinery (the scenario's own check,
    # parse_scenario, most of it) is measured beside a run, not alone
    o = sweep_overhead(runs=max(10, round(20 * min(1.0, scale))), seconds=0.25)
    lines.append(
        f"sweep machinery per run ({o['runs']} runs x {o['simulated_s']:g} s): {o['sweep_per_run_s'] * 1e3:.1f} "
        f"ms vs a bare run_scenario {o['bare_per_run_s'] * 1e3:.1f} ms: {100 * o['overhead']:+.1f} % "
        "(target <= 10 %)"
    )
    m = memory(seconds=round(5 * seconds, 3))
    for name, what in (
        ("powertrain", "the 90 % powertrain network"),
        ("master_slave_faults", "master_slave.toml ([[faults]])"),
        ("powertrain_trace", "the powertrain network with --trace t.blf"),
    ):
        f = m[name]
        lines.append(
            f"memory of canstack experiment, {what}: peak {f['peak_mb'][0]:.0f} MB at {m['simulated_s'][0]:g} s "
            f"simulated, {f['peak_mb'][1]:.0f} MB at {m['simulated_s'][1]:g} s: {f['mb_per_simulated_hour']:+.0f} MB "
            "per simulated hour (target: an hour under 150 MB)"
        )
    return {"runner_vs_engine": r, "sweep_parallel": p, "sweep_overhead": o, "memory": m, "lines": lines}
