"""CANopen devices and a master from a scenario file (profile = "canopen" / "canopen-master")."""

from __future__ import annotations

import copy
import re
from pathlib import Path

import pytest

from profiles.pipeline.runner import run_scenario
from profiles.pipeline.scenario import load_scenario, parse_scenario
from profiles.schema import ScenarioError

EXAMPLE = Path(__file__).resolve().parents[3] / "examples" / "canopen.toml"

BASE = {
    "bus": {"bitrate": 1_000_000, "duration": 0.3},
    "nodes": [
        {
            "name": "plc",
            "profile": "canopen-master",
            "canopen": {"nodes": [1, 2], "sync_period_us": 1000, "heartbeat_consumer_ms": 75},
        },
        {
            "name": "a",
            "profile": "canopen",
            "node_id": 1,
            "canopen": {"heartbeat_ms": 50, "tpdo": {"1": {"transmission_type": 1}}},
        },
        {"name": "b", "profile": "canopen", "node_id": 2, "canopen": {"heartbeat_ms": 50}},
    ],
}


def test_the_example_network_boots_synchronises_and_reports_the_unplugged_device():
    res = run_scenario(load_scenario(EXAMPLE)).to_json()
    co = res["canopen"]
    master = co["plc"]
    by_id = {n["node_id"]: n for n in master["nodes"]}
    assert by_id[3]["nmt_state"] == "UNKNOWN" and by_id[3]["heartbeat_timeouts"] == 1
    for nid in (1, 2, 4, 5):
        assert by_id[nid]["nmt_state"] == "OPERATIONAL" and by_id[nid]["heartbeats_missed"] == 0
        assert co[f"io{nid}"]["nmt_state"] == "OPERATIONAL"
    # TPDO1 of every device at every SYNC (1 ms for 1 s): the master sees ~990 after boot-up;
    # a synchronous PDO is never received later than the 600 us window plus its own frame
    tpdo1 = {p["node_id"]: p for p in master["pdos"] if p["pdo"] == "TPDO1"}
    assert all(tpdo1[nid]["received"] > 950 for nid in (1, 2, 4, 5))
    for p in master["pdos"]:
        if p["transmission_type"] is not None and 0 < p["transmission_type"] <= 240 and p["received"]:
            assert p["sync_latency_ms"]["max"] <= 0.6 + 0.135  # window + one worst-case 8-byte frame at 1 Mbit/s


@pytest.mark.parametrize(
    "change,expected",
    [
        (lambda r: r["nodes"][2].update(node_id=1), "node_id: 1 is already node 'a''s"),
        (lambda r: r["nodes"][1].update(node_id=128), "node_id: 128 is outside 1..127 (CiA 301 node-ID)"),
        (lambda r: r["nodes"][1].pop("node_id"), "key 'node_id' is required"),
        (lambda r: r["nodes"][1]["canopen"].update(heartbeat_ms=-5), "[[nodes]] #2 'a': canopen: heartbeat_ms -5"),
        (lambda r: r["nodes"][0]["canopen"].update(nodes=[0]), "[[nodes]] #1 'plc': canopen:"),
        (lambda r: r["nodes"][1].update(eds="/nonexistent.eds"), "[[nodes]] #2 'a': canopen:"),
        (
            lambda r: r["nodes"][1].update(messages=[{"name": "x", "id": 1, "dlc": 0}]),
            "a canopen node sends what CiA 301 says",
        ),
    ],
)
def test_bad_canopen_tables_are_refused_before_the_run(change, expected):
    raw = copy.deepcopy(BASE)
    change(raw)
    with pytest.raises(ScenarioError) as err:
        parse_scenario(raw, "co.toml")
    assert expected in str(err.value) and str(err.value).startswith("co.toml: "), str(err.value)


def test_text_table_lists_nodes_and_pdo_latency():
    from profiles.pipeline.metrics import format_table

    text = format_table(run_scenario(parse_scenario(copy.deepcopy(BASE), "co.toml")).to_json())
    assert "CANopen node" in text and re.search(r"^TPDO1 +a +0x181 ", text, re.M)
    # no declared messages: no empty message table, a line that says why
    assert "message " not in text and "no messages declared" in text
