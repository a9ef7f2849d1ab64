"""The experiment runner: metrics of a run against the response-time analysis, determinism, the
release sources, faults, and the same scenario on python-can buses."""

from __future__ import annotations

import copy
import json
import math
import random
from pathlib import Path

import pytest

from profiles.analysis.rta import frame_bits_worst
from profiles.pipeline.runner import run_on_pycan, run_scenario
from profiles.pipeline.scenario import load_scenario, parse_scenario

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"


def _scenario(messages_by_node, *, bitrate=500_000, duration=0.2, seed=1, analysis=None, faults=None, **node_kw):
    """A scenario of these nodes and messages, plus a silent node "rx" that acknowledges (a
    transmitter alone on a bus gets ACK errors)."""
    node_kw.pop("record", None)
    nodes = dict(messages_by_node)
    nodes.setdefault("rx", [])
    raw = {
        "bus": {"bitrate": bitrate, "duration": duration, "seed": seed},
        "nodes": [dict({"name": n, "messages": ms}, **node_kw.get(n, {})) for n, ms in nodes.items()],
    }
    if analysis:
        raw["analysis"] = analysis
    if faults:
        raw["faults"] = faults
    return parse_scenario(raw, "test.toml")


def _rows(result):
    return {m["name"]: m for m in result.to_json()["messages"]}


def test_synchronous_release_meets_the_exact_analysis_for_the_lowest_priority_message():
    """With every message released at t = 0 (the critical instant) and the analysis given each
    frame's exact length, the lowest-priority message's first response is the analysis' R to the
    nanosecond, less the 3-bit intermission the analysis counts in C and the simulation does not
    (it measures to the end of EOF)."""
    periods = [1, 2, 2, 4, 5, 5, 10]
    msgs = {
        f"n{i}": [{"name": f"m{i}", "id": 0x100 + 0x10 * i, "dlc": 8, "period_ms": p, "data": "55" * 8}]
        for i, p in enumerate(periods)
    }
    res = run_scenario(_scenario(msgs, analysis={"stuffing": "exact"}))
    rows = _rows(res)
    low = rows["m6"]
    bit_ms = 1e3 / 500_000
    assert low["response_ms"]["max"] == pytest.approx(low["rta_ms"] - 3 * bit_ms, abs=1e-9)
    assert all(r["response_ms"]["max"] <= r["rta_ms"] for r in rows.values())


def test_simulated_worst_cases_never_exceed_the_analysis_on_random_networks():
    """Random periodic sets (random offsets, release jitter, payloads, 2..5 nodes with priority
    queues) below full load: every measured response stays within the bound of the analysis
    with worst-case stuffing."""
    for seed in range(12):
        rng = random.Random(seed)
        ids = rng.sample(range(0x080, 0x700), 10)
        nodes: dict[str, list] = {}
        for i, can_id in enumerate(ids):
            period = rng.choice([2, 2.5, 4, 5, 10, 20])
            dlc = rng.randint(0, 8)
            nodes.setdefault(f"n{i % rng.randint(2, 5)}", []).append(
                {
                    "name": f"m{i}",
                    "id": can_id,
                    "dlc": dlc,
                    "period_ms": period,
                    "offset_ms": rng.choice([0, 0, rng.uniform(0, period)]),
                    "jitter_ms": rng.choice([0, rng.uniform(0, period / 3)]),
                    "data": bytes(rng.randrange(256) for _ in range(dlc)).hex(),
                }
            )
        res = run_scenario(_scenario(nodes, bitrate=rng.choice([125_000, 250_000, 500_000]), duration=0.3, seed=seed))
        for r in res.to_json()["messages"]:
            if r["rta_ms"] is None or r["response_ms"] is None:
                continue
            assert r["response_ms"]["max"] <= r["rta_ms"] + 1e-9, (seed, r["name"])
            assert r["deadline_misses"] == 0 or r["schedulable"] is False, (seed, r["name"])


def test_the_analysis_predicts_the_deadline_miss_the_simulation_shows():
    res = run_scenario(load_scenario(EXAMPLES / "powertrain_90.toml"))
    rows = _rows(res)
    diag = rows["Diagnostics"]
    assert diag["schedulable"] is False and diag["deadline_misses"] > 0
    assert diag["response_ms"]["max"] > diag["deadline_ms"]
    for r in rows.values():
        assert r["response_ms"]["max"] <= r["rta_ms"]
        if r["schedulable"]:
            assert r["deadline_misses"] == 0
    assert 0.8 < res.bus_load < 0.9


def test_fifo_queues_show_priority_inversion_within_the_fifo_bound():
    prio = _rows(run_scenario(load_scenario(EXAMPLES / "powertrain_90.toml")))
    fifo_res = run_scenario(load_scenario(EXAMPLES / "powertrain_90_fifo.toml"))
    fifo = _rows(fifo_res)
    # the engine's 2 ms messages wait behind its own 20 ms ones: several times the priority run's
    for name in ("EngineSpeed", "Torque", "ThrottlePosition"):
        assert fifo[name]["response_ms"]["max"] > 3 * prio[name]["response_ms"]["max"]
        assert fifo[name]["deadline_misses"] > 0 and prio[name]["deadline_misses"] == 0
        assert fifo[name]["rta_method"] == "fifo" and fifo[name]["schedulable"] is False
    for r in fifo.values():  # the FIFO analysis bounds every message, and no miss goes unpredicted
        assert r["response_ms"]["max"] <= r["rta_ms"] and r["release_response_max_ms"] <= r["rta_release_ms"]
        assert r["deadline_misses"] == 0 or r["schedulable"] is False
    assert any("FIFO" in n for n in fifo_res.analysis["notes"])


def test_same_scenario_and_seed_give_the_same_result():
    sc = load_scenario(EXAMPLES / "body_network.toml")
    a = run_scenario(copy.deepcopy(sc)).to_json()
    b = run_scenario(copy.deepcopy(sc)).to_json()
    assert a == b
    sc2 = copy.deepcopy(sc)
    sc2.seed = 2
    c = run_scenario(sc2).to_json()
    assert c["messages"] != a["messages"]  # jitter and sporadic arrivals are drawn from the seed


def test_sporadic_messages_keep_their_minimum_inter_arrival_and_mean():
    sc = _scenario({"a": [{"name": "s", "id": 0x100, "dlc": 1, "sporadic_ms": 5, "mean_ms": 20}]}, duration=20.0)
    res = run_scenario(sc)
    starts = list(res.tracks["s"].starts)
    gaps = [(b - a) / 1e6 for a, b in zip(starts, starts[1:])]
    assert min(gaps) >= 5.0
    assert 18.0 < sum(gaps) / len(gaps) < 22.0  # 1000 arrivals: the mean within ~3 standard errors


def test_release_jitter_stays_within_its_bound_and_the_nominal_times_do_not_drift():
    sc = _scenario({"a": [{"name": "j", "id": 0x100, "dlc": 0, "period_ms": 10, "jitter_ms": 2}]}, duration=2.0)
    res = run_scenario(sc)
    tr = res.tracks["j"]
    # alone on the bus: SOF = release; release k lies in [10 k, 10 k + 2] ms
    for k, sof in enumerate(tr.starts):
        assert 10_000_000 * k <= sof <= 10_000_000 * k + 2_000_000
    assert res.to_json()["messages"][0]["jitter_ms"] <= 4.0  # start-to-start distance varies by 2 J at most


def test_a_drifting_node_releases_on_its_own_clock():
    """+1000 ppm: in 1 s of bus time the node's clock counts 1.001 s, so a 10 ms message is
    released 101 times (local 0..1000 ms) instead of 100."""
    msgs = {
        "fast": [{"name": "f", "id": 0x100, "dlc": 1, "period_ms": 10}],
        "exact": [{"name": "e", "id": 0x200, "dlc": 1, "period_ms": 10}],
    }
    res = run_scenario(_scenario(msgs, duration=1.0, fast={"drift_ppm": 1000}))
    rows = _rows(res)
    assert (rows["f"]["released"], rows["e"]["released"]) == (101, 100)


def test_instances_that_cannot_keep_up_are_deadline_misses():
    """A message whose period (0.5 ms) is shorter than its own frame (8 zero bytes at 125 kbit/s:
    about 1 ms) piles up in its queue: every instance ends after its deadline or is still
    waiting past it at the end, and the analysis finds the load above 1."""
    res = run_scenario(
        _scenario({"hog": [{"name": "hog", "id": 0x001, "dlc": 8, "period_ms": 0.5}]}, bitrate=125_000, duration=0.2)
    )
    row = _rows(res)["hog"]
    assert row["released"] == 400 and row["sent"] < row["released"] / 1.9
    assert row["deadline_misses"] >= row["released"] - 1
    assert row["schedulable"] is False and row["rta_ms"] is None
    assert res.bus_load > 0.99


def test_faults_are_injected_and_receptions_counted_from_what_receivers_accepted():
    msgs = {
        "a": [{"name": "ma", "id": 0x100, "dlc": 8, "period_ms": 1}],
        "b": [{"name": "mb", "id": 0x200, "dlc": 8, "period_ms": 1}],
    }
    sc = _scenario(msgs, duration=0.5, faults=[{"kind": "bit_errors", "rate": 2e-3}])
    res = run_scenario(sc)
    # receptions are counted as the bus runs: faults keep no trace (memory stays flat)
    assert res.error_frames > 0 and res.trace == []
    for r in res.to_json()["messages"]:
        assert r["received"] >= r["sent"] * 0.99  # retransmitted: every instance arrives in the end
        assert r["released"] >= r["received"] and r["released"] >= r["sent"]  # instances, not attempts


def test_application_hooks_run_before_the_start(tmp_path, monkeypatch):
    mod = tmp_path / "app_for_test.py"
    mod.write_text(
        "def setup(node, profile, context):\n"
        "    profile.set_data('m', bytes([0xAB]))\n"
        "    context.recorder.tracks['m'].decl.options['touched'] = True\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    sc = _scenario(
        {"a": [{"name": "m", "id": 0x100, "dlc": 1, "period_ms": 10}]},
        duration=0.05,
        a={"app": "app_for_test:setup"},
        record=None,
    )
    res = run_scenario(sc, record=True)
    assert res.trace[0].frame.data == b"\xab" and res.tracks["m"].decl.options["touched"]


@pytest.mark.wallclock
def test_the_same_scenario_runs_on_python_cans_virtual_bus(rerun_until):
    sc = _scenario(
        {
            "a": [{"name": "ma", "id": 0x100, "dlc": 8, "period_ms": 10}],
            "b": [{"name": "mb", "id": 0x200, "dlc": 4, "period_ms": 20}],
        },
        bitrate=500_000,
    )

    def run():
        res = run_on_pycan(copy.deepcopy(sc), "virtual", f"runner-test-{random.random()}", duration_s=0.5)
        rows = _rows(res)
        assert res.driver.startswith("virtual")
        for r in rows.values():
            # on the wall clock a frame counts as sent when the monitor's receive thread saw it: the
            # ones released in the last moments before the stop may still be on their way, none may
            # be lost
            assert r["failed"] == r["dropped"] == 0 and 0 < r["sent"] <= r["released"]
            assert 0 <= r["response_ms"]["min"] <= r["response_ms"]["max"]
        return rows

    def timely(rows):  # threads that lagged by no more than 50 ms (a shared machine lags by tens)
        return all(
            r["released"] - 1 - math.ceil(50 / r["period_ms"]) <= r["sent"] and r["response_ms"]["max"] < 50
            for r in rows.values()
        )

    rerun_until(run, timely)


@pytest.mark.wallclock
@pytest.mark.socket
def test_the_same_scenario_runs_through_canstack_serve(rerun_until):
    from stack.io.serve import BusServer

    sc = _scenario(
        {
            "a": [{"name": "ma", "id": 0x100, "dlc": 8, "period_ms": 10}],
            "b": [{"name": "mb", "id": 0x200, "dlc": 4, "period_ms": 20}],
        },
        bitrate=500_000,
    )

    def run():
        with BusServer(500_000, name="runner", listen=("127.0.0.1", 0)) as server:
            res = run_on_pycan(copy.deepcopy(sc), "canstack", server.url, duration_s=0.6)
        rows = _rows(res)
        # through the served bus the monitor's timestamps are the wire's end of EOF: a frame alone
        # on the bus takes its exact length (8 bytes at 500 kbit/s: at least 111 bits = 222 us)
        ma = rows["ma"]  # (what may still be on its way at the stop: as on the virtual bus above)
        assert ma["failed"] == ma["dropped"] == 0 and 0 < ma["sent"] <= ma["released"]
        assert ma["response_ms"]["min"] >= 0.222 - 1e-6
        assert 0 < res.bus_load < 0.2
        return ma

    rerun_until(run, lambda ma: ma["released"] - 1 - math.ceil(50 / ma["period_ms"]) <= ma["sent"])


def test_faults_are_refused_on_a_python_can_bus():
    from profiles.schema import ScenarioError

    sc = _scenario(
        {"a": [{"name": "m", "id": 1, "dlc": 0, "period_ms": 1}]}, faults=[{"kind": "never_ack", "node": "a"}]
    )
    with pytest.raises(ScenarioError, match="need the simulated bus"):
        run_on_pycan(sc, "virtual", "x")


def test_worst_case_frame_time_used_by_the_analysis_is_the_specifications():
    """The bound the runner prints for a message alone on the bus is its worst-case frame time C
    (eq. 1 with the intermission), blocking 0: 135 bits at 500 kbit/s for 8 bytes."""
    res = run_scenario(_scenario({"a": [{"name": "m", "id": 0x100, "dlc": 8, "period_ms": 10}]}, duration=0.05))
    row = res.to_json()["messages"][0]
    assert frame_bits_worst(8, False) == 135
    assert row["rta_ms"] == pytest.approx(135 * 2e-3)


def test_result_json_has_the_documented_keys():
    res = run_scenario(load_scenario(EXAMPLES / "body_network.toml"))
    data = json.loads(json.dumps(res.to_json()))
    assert {"bus_load", "duration", "frames", "error_frames", "messages"} <= set(data)
    row = data["messages"][0]
    assert {
        "name",
        "node",
        "id",
        "extended",
        "dlc",
        "period_ms",
        "deadline_ms",
        "released",
        "sent",
        "received",
        "response_ms",
        "jitter_ms",
        "deadline_misses",
        "rta_ms",
        "schedulable",
    } <= set(row)
    assert set(row["response_ms"]) == {"min", "mean", "p99", "max", "p99_error"}
