"""The experiment pipeline's analysis and simulation on generated scenarios: they use one
deadline reference (the nominal release, jitter included), so a message that misses in the
simulation is never one the analysis calls schedulable, and no measured figure passes its bound
(``response_ms`` within ``rta_ms``, ``release_response_max_ms`` within ``rta_release_ms``).

The scenarios mix priority, FIFO and mailbox nodes (with and without abort), drifting clocks,
release jitter up to 99 % of the period (the scenario files refuse more) and deadlines below, at and above it; releases are the pipeline's
own (offset 0: every message released together at the start, then uniform jitter)."""

from __future__ import annotations

import random

from profiles.analysis.rta import frame_bits_worst
from profiles.pipeline.runner import run_scenario
from profiles.pipeline.scenario import parse_scenario


def _scenario(rng: random.Random, index: int) -> dict:
    bitrate = rng.choice([250_000, 500_000])
    tau_ms = 1e3 / bitrate
    nodes = []
    ids = iter(rng.sample(range(1, 0x800), 16))
    load = 0.0
    target = rng.uniform(0.3, 0.85)
    for n in range(rng.randint(2, 4)):
        queue = rng.choice(["priority", "fifo", "mailboxes:2", "mailboxes:3", "mailboxes-abort:1"])
        node = {"name": f"n{n}", "queue": queue, "messages": []}
        if rng.random() < 0.4:
            node["drift_ppm"] = rng.choice([-30_000.0, -100.0, 500.0, 30_000.0])
        for k in range(rng.randint(1, 3)):
            dlc = rng.randint(0, 8)
            c_ms = frame_bits_worst(dlc, False) * tau_ms
            period = round(max(4 * c_ms, c_ms / (target / 8) * rng.uniform(0.5, 1.5)), 3)
            load += c_ms / period
            node["messages"].append(
                {
                    "name": f"m{n}_{k}",
                    "id": next(ids),
                    "dlc": dlc,
                    "data": bytes(rng.randrange(256) for _ in range(dlc)).hex(),
                    "period_ms": period,
                    "jitter_ms": round(period * rng.choice([0.0, 0.3, 0.9, 0.99]), 3),
                    "deadline_ms": round(period * rng.choice([0.3, 0.6, 1.0, 1.5]), 3),
                }
            )
        nodes.append(node)
    nodes.append({"name": "rx", "messages": []})
    duration = min(0.25, 30 * max(m["period_ms"] for n in nodes for m in n["messages"]) / 1e3)
    return {
        "bus": {"bitrate": bitrate, "duration": duration, "seed": index},
        "nodes": nodes,
        "analysis": {"stuffing": rng.choice(["worst", "exact"])},
    }


def test_a_simulated_miss_is_never_schedulable_and_no_figure_passes_its_bound():
    rng = random.Random(22)
    misses = bounded = 0
    methods = set()
    for i in range(24):
        res = run_scenario(parse_scenario(_scenario(rng, i), f"generated {i}"), progress=False)
        for row in res.to_json()["messages"]:
            if row["deadline_misses"]:
                misses += 1
                assert row["schedulable"] is not True, (i, row)
            if row["rta_ms"] is None:
                assert row["schedulable"] is not True
                continue
            bounded += 1
            methods.add(row["rta_method"])
            if row["response_ms"] is not None:
                assert row["response_ms"]["max"] <= row["rta_ms"], (i, row)
                assert row["release_response_max_ms"] <= row["rta_release_ms"], (i, row)
    # the check is worth its name only if it saw misses, bounds, and each kind of bound
    assert misses >= 5 and bounded >= 60
    assert {"davis2007", "fifo", "mailbox"} <= methods
