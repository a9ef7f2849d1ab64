"""Speed figures of the experiments (registered under the ``canstack.bench`` entry point group, so
``python -m stack.bench`` prints them beside the engine's).

- ``runner_vs_engine``: the wall time of `profiles.runner.run_scenario` on a scenario, divided by
  the wall time of the bare engine carrying the same traffic (the same nodes on a `SimBus`, each
  message a `Node.send_periodic` with its period and offset, no recorder, no analysis). The
  scenario is examples/powertrain_90.toml's network (17 periodic messages, 5 nodes, 500 kbit/s,
  about 83 % bus load). Target: at most 1.5.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

__all__ = ["benchmark", "runner_overhead"]

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "powertrain_90.toml"


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
    from profiles.runner import run_scenario

    t0 = time.perf_counter()
    run_scenario(scenario, record=False, progress=False)
    return time.perf_counter() - t0


def runner_overhead(seconds: float = 4.0, repeat: int = 3) -> dict[str, float]:
    """Best-of-``repeat`` wall times of the runner and of the bare engine on ``seconds`` of
    simulated time of the example network, and their ratio."""
    from profiles.scenario import load_scenario

    sc = load_scenario(EXAMPLE)
    sc.duration_ns = round(seconds * 1e9)
    bare = min(_bare(sc) for _ in range(repeat))
    runner = min(_runner(sc) for _ in range(repeat))
    return {"bare_s": bare, "runner_s": runner, "ratio": runner / bare, "simulated_s": seconds}


def benchmark(seconds: float = 3.0) -> dict[str, Any]:
    """Every figure of the experiments, with the lines `python -m stack.bench` prints."""
    r = runner_overhead(seconds=max(0.5, seconds))
    return {"runner_vs_engine": r, "lines": [
        f"experiment runner on {r['simulated_s']:g} s of the 90 % powertrain network: {r['runner_s']:.2f} s vs the bare "
        f"engine {r['bare_s']:.2f} s on the same traffic: {r['ratio']:.2f}x (target <= 1.5)"]}
