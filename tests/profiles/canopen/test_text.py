"""The CANopen section of `canstack experiment`'s text shows every figure its ``--json`` holds."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import tomllib

from stack.cli import main

EXAMPLE = Path(__file__).resolve().parents[3] / "examples" / "canopen.toml"


def _run(capsys, path, *extra):
    rc = main(["experiment", str(path), *extra])
    out = capsys.readouterr().out
    assert rc == 0
    return out


def _blocks(text):
    """{header line: [row cells]} of the tables separated by blank lines."""
    out = {}
    for chunk in text.split("\n\n"):
        lines = chunk.splitlines()
        if lines:
            out[lines[0]] = [line.split() for line in lines[1:] if not line.startswith("analysis: ")]
    return out


def _table(blocks, *words):
    """The rows of the one table whose header holds every word in ``words``."""
    found = [rows for header, rows in blocks.items() if all(w in header for w in words)]
    assert len(found) == 1, (words, list(blocks))
    return found[0]


def _row(rows, *lead):
    """The one row whose first cells are ``lead``."""
    found = [r for r in rows if r[: len(lead)] == [str(x) for x in lead]]
    assert len(found) == 1, (lead, rows)
    return found[0]


def _lat(s):
    if not s["count"]:
        return "-"
    return f"{s['min']:.3f}/{s['mean']:.3f}/{s['p99']:.3f}{'~' if s['p99_error'] else ''}/{s['max']:.3f}"


def _id(v):
    return f"0x{v:03X}"  # CiA 301 COB-IDs are 11-bit: 0x-hex, 3 digits, as every canstack output


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    """The shipped example, io1 also consuming io3's heartbeat (io3 is unplugged at 500 ms: io1
    records a communication error and its consumer table has a row)."""
    text = EXAMPLE.read_text().replace("duration = 1.0", "duration = 0.7")
    text = text.replace(
        "node_id = 1\n[nodes.canopen]\n", "node_id = 1\n[nodes.canopen]\nheartbeat_consumers = {3 = 120}\n"
    )
    raw = tomllib.loads(text)
    assert raw["nodes"][1]["canopen"]["heartbeat_consumers"] == {"3": 120} and raw["bus"]["duration"] == 0.7
    path = tmp_path_factory.mktemp("co") / "co.toml"
    path.write_text(text)
    return path


def test_every_canopen_figure_of_the_json_is_in_the_text(capsys, scenario, tmp_path):
    # one run: the table on stdout, the JSON object (the one --json prints) written by --out
    text = _run(capsys, scenario, "--out", str(tmp_path / "r.json"))
    data = json.loads((tmp_path / "r.json").read_text())["canopen"]
    blocks = _blocks(text)
    devices = [f for f in data.values() if f["profile"] == "canopen"]
    masters = [f for f in data.values() if f["profile"] == "canopen-master"]
    assert len(devices) == 5 and len(masters) == 1
    names = {f["node_id"]: f["node"] for f in devices}
    seen = {n["node_id"]: n for n in masters[0]["nodes"]}
    comm_errors = 0
    for f in devices:
        # a key added to the JSON and not to the text fails here
        assert set(f) == {
            "profile", "node", "node_id", "nmt_state", "boot_ups", "resets", "heartbeat_ms", "heartbeats_sent",
            "sync_received", "sync_timeouts", "sync_length_errors", "emcy_sent", "error_register",
            "errors_active", "tx_refused", "communication_errors", "sdo", "tpdos", "rpdos", "heartbeat_consumer",
        }  # fmt: skip
        n = f["node"]
        m = seen[f["node_id"]]
        assert _row(_table(blocks, "CANopen node", "NMT state"), n) == [
            n, str(f["node_id"]), f["nmt_state"], m["nmt_state"], str(f["boot_ups"]),
            str(f["resets"]["application"]), str(f["resets"]["communication"]), str(f["heartbeat_ms"]),
            str(f["heartbeats_sent"]), str(m["heartbeats_missed"]),
        ]  # fmt: skip
        active = ",".join(f"0x{c:04X}" for c in f["errors_active"]) or "-"
        assert _row(_table(blocks, "CANopen node", "SYNC received"), n) == [
            n, str(f["sync_received"]), str(f["sync_timeouts"]), str(f["sync_length_errors"]), str(f["emcy_sent"]),
            f"0x{f['error_register']:02X}", active, str(f["tx_refused"]), str(len(f["communication_errors"])),
        ]  # fmt: skip
        sdo = f["sdo"]
        assert set(sdo["completed"]) == {
            "expedited download", "expedited upload", "segmented download", "segmented upload", "block download",
            "block upload",
        }  # fmt: skip
        assert _row(_table(blocks, "SDO server", "requests"), n) == [
            n, str(sdo["requests"]), str(sdo["aborts_sent"]), str(sdo["aborts_received"]),
            *(str(sdo["completed"][k]) for k in ("expedited download", "expedited upload", "segmented download",
                                                  "segmented upload", "block download", "block upload")),
        ]  # fmt: skip
        for tp in f["tpdos"]:
            assert _row(_table(blocks, "TPDO", "SYNC->tx"), tp["pdo"], n) == [
                tp["pdo"], n, _id(tp["cob_id"]), "yes" if tp["valid"] else "no", str(tp["transmission_type"]),
                str(tp["queued"]), str(tp["sent"]), str(tp["not_in_window"]), str(tp["refused"]),
                str(tp["sync_to_tx_ms"]["count"]), _lat(tp["sync_to_tx_ms"]), *(tp["mapping"] or ["-"]),
            ]  # fmt: skip
        for rp in f["rpdos"]:
            assert _row(_table(blocks, "RPDO", "applied"), rp["pdo"], n) == [
                rp["pdo"], n, _id(rp["cob_id"]), "yes" if rp["valid"] else "no", str(rp["transmission_type"]),
                str(rp["received"]), str(rp["applied"]), str(rp["length_errors"]), str(rp["timeouts"]),
                *(rp["mapping"] or ["-"]),
            ]  # fmt: skip
        for c in f["heartbeat_consumer"]:
            assert _row(_table(blocks, "heartbeat consumer"), n, c["node_id"]) == [
                n, str(c["node_id"]), c["status"], c["nmt_state"], str(c["received"]), str(c["missed"]),
                str(c["timeouts"]),
            ]  # fmt: skip
        for t, what in f["communication_errors"]:
            assert f"{n}: communication error at {t:.3f} ms: {what}" in text.splitlines()
            comm_errors += 1
    assert comm_errors >= 1  # io1 lost io3's heartbeat: the path above ran

    for m in masters:
        assert set(m) == {"profile", "node", "sync", "nodes", "pdos", "sdo", "events"}
        sdo = m["sdo"]
        assert (
            f"master {m['node']}: SYNC every {m['sync']['period_us']} us, {m['sync']['sent']} sent; "
            f"SDO {sdo['completed']} completed, {sdo['aborted']} aborted, {sdo['timeouts']} timeouts"
        ) in text.splitlines()
        for nd in m["nodes"]:
            assert "guarding" not in nd  # no node guarding in this network: no such columns
            codes = ",".join(f"0x{c:04X}" for c in nd["emcy_codes"]) or "-"
            assert _row(_table(blocks, f"node (master {m['node']})"), names[nd["node_id"]]) == [
                names[nd["node_id"]], str(nd["node_id"]), nd["status"], nd["nmt_state"], nd["last_state"],
                str(nd["boots"]), str(nd["heartbeats_received"]), str(nd["heartbeats_missed"]),
                str(nd["heartbeat_timeouts"]), str(nd["emcy_received"]), codes,
                *("; ".join(nd["config_errors"]) or "-").split(),
            ]  # fmt: skip
        for p in m["pdos"]:
            assert _row(_table(blocks, f"PDO (master {m['node']})"), p["pdo"], names[p["node_id"]]) == [
                p["pdo"], names[p["node_id"]], _id(p["cob_id"]), str(p["transmission_type"]), str(p["received"]),
                str(p["sync_latency_ms"]["count"]), _lat(p["sync_latency_ms"]),
            ]  # fmt: skip
        # the events, counted per node and kind with their first and last time
        rows = _table(blocks, f"event (master {m['node']})")
        kinds = {}
        for e in m["events"]:
            kinds.setdefault((e["node_id"], e["event"]), []).append(e["t_ms"])
        assert len(rows) == len(kinds)
        for (nid, what), ts in kinds.items():
            row = _row(rows, *what.split(), names[nid], nid)
            assert row[-3:] == [str(len(ts)), f"{min(ts):.3f}", f"{max(ts):.3f}"]
        assert (3, "heartbeat lost") in kinds and (1, "boot-up") in kinds


def test_node_guarding_figures_are_in_the_text():
    """A master guarding its nodes (CiA 301 7.2.8.3.2.1, heartbeat 0): per node the requests,
    replies, missed replies and toggle errors the JSON counts, in the master's node table."""
    from profiles.pipeline.metrics import format_table
    from profiles.pipeline.runner import run_scenario
    from profiles.pipeline.scenario import parse_scenario

    raw = {
        "bus": {"bitrate": 1_000_000, "duration": 0.3},
        "nodes": [
            {"name": "plc", "profile": "canopen-master", "canopen": {"nodes": [1, 2], "node_guarding_ms": 20}},
            {"name": "a", "profile": "canopen", "node_id": 1, "canopen": {"heartbeat_ms": 0}},
            {"name": "b", "profile": "canopen", "node_id": 2, "canopen": {"heartbeat_ms": 0}},
        ],
        "faults": [{"kind": "disconnect", "node": "b", "at_ms": 150}],
    }
    data = run_scenario(parse_scenario(raw, "guarded.toml")).to_json()
    blocks = _blocks(format_table(data))
    rows = _table(blocks, "node (master plc)", "guarding requests", "toggle errors")
    names = {1: "a", 2: "b"}
    for n in data["canopen"]["plc"]["nodes"]:
        g = n["guarding"]
        row = _row(rows, names[n["node_id"]], n["node_id"])
        assert row[-4:] == [str(g["requests"]), str(g["replies"]), str(g["missed"]), str(g["toggle_errors"])]
    assert data["canopen"]["plc"]["nodes"][1]["guarding"]["missed"] > 0  # b unplugged: replies missed
