"""Scenario files: what they may say, and one error per broken rule naming the file, the table, the
key and the rule."""

from __future__ import annotations

import copy

import pytest

from profiles.pipeline.scenario import load_scenario, parse_scenario
from profiles.schema import ScenarioError

BASE = {
    "bus": {"bitrate": 500000, "duration": 1.0, "seed": 3},
    "nodes": [
        {
            "name": "engine",
            "queue": "priority",
            "messages": [
                {"name": "EngineData", "id": 0x100, "dlc": 8, "period_ms": 10},
                {"name": "EngineTemp", "id": 0x300, "dlc": 4, "period_ms": 100, "offset_ms": 2.5},
            ],
        },
        {
            "name": "body",
            "queue": "mailboxes-abort:2",
            "drift_ppm": 150,
            "messages": [
                {
                    "name": "Doors",
                    "id": 0x18FEF100,
                    "extended": True,
                    "dlc": 2,
                    "sporadic_ms": 20,
                    "mean_ms": 50,
                    "jitter_ms": 1,
                    "deadline_ms": 5,
                    "data": "0102",
                }
            ],
        },
    ],
}


def _with(path: str, value, base=BASE):
    raw = copy.deepcopy(base)
    cur = raw
    parts = path.split(".")
    for p in parts[:-1]:
        cur = cur[int(p)] if p.isdigit() else cur[p]
    last = parts[-1]
    if value is _DELETE:
        del cur[int(last) if last.isdigit() else last]
    else:
        cur[int(last) if last.isdigit() else last] = value
    return raw


_DELETE = object()


def test_a_good_scenario_reads_into_typed_declarations():
    sc = parse_scenario(BASE, "good.toml")
    assert (sc.bitrate, sc.duration_ns, sc.seed) == (500_000, 1_000_000_000, 3)
    engine, body = sc.nodes
    assert engine.profile == "csma" and engine.policy == "priority" and engine.priority_queue
    assert body.policy == "mailbox" and body.mailboxes == 2 and body.abort and body.drift_ppm == 150
    data, temp = engine.messages
    assert (data.period_ns, data.deadline_ns, data.offset_ns) == (10_000_000, 10_000_000, 0)
    assert temp.offset_ns == 2_500_000 and temp.id_text == "0x300"
    doors = body.messages[0]
    assert doors.extended and doors.sporadic_ns == 20_000_000 and doors.mean_ns == 50_000_000
    assert doors.interval_ns == 20_000_000 and doors.deadline_ns == 5_000_000 and doors.data == b"\x01\x02"
    assert doors.id_text == "0x18FEF100"


@pytest.mark.parametrize(
    "path,value,expected",
    [
        ("bus.bitrate", 2_000_000, "good.toml: [bus]: bitrate: 2000000 is outside 1000..1000000 (a CAN 2.0 bus runs"),
        ("bus.bitrate", "500k", "good.toml: [bus]: bitrate: '500k' is a string, expected an integer"),
        ("bus.bitrate", True, "good.toml: [bus]: bitrate: True is a boolean, expected an integer"),
        ("bus.duration", 0, "good.toml: [bus]: duration: 0 must be at least 1e-06"),
        (
            "bus.colour",
            "red",
            "good.toml: [bus]: unknown key 'colour' (allowed: bitrate, data_bitrate, duration, seed)",
        ),
        ("bus", _DELETE, "good.toml: top level: key 'bus' is required"),
        ("nodes.0.queue", "lifo", "good.toml: [[nodes]] #1 'engine': queue: 'lifo' is not one of 'priority', 'fifo'"),
        ("nodes.0.queue", "mailboxes:0", "'mailboxes:N', 'mailboxes-abort:N' (N from 1 to 9999 transmit mailboxes)"),
        ("nodes.0.profile", "token-ring", "[[nodes]] #1 'engine': profile: 'token-ring' is not one of "),
        ("nodes.1.name", "engine", "[[nodes]] #2 'engine': name: 'engine' is already the name of node #1"),
        ("nodes.0.name", "my engine", "name: 'my engine': a node name is non-empty, without spaces"),
        ("nodes.1.drift_ppm", 2e6, "drift_ppm: 2000000.0 is outside -100000..100000"),
        (
            "nodes.0.messages.0.dlc",
            9,
            "good.toml: [[nodes]] #1 'engine' > [[nodes.messages]] #1 'EngineData': dlc: 9 is outside 0..8",
        ),
        (
            "nodes.0.messages.0.id",
            0x800,
            "[[nodes.messages]] #1 'EngineData': id: 0x800 is not a standard (11-bit) identifier 0..0x7FF",
        ),
        ("nodes.0.messages.0.period_ms", 0, "[[nodes.messages]] #1 'EngineData': period_ms: 0 must be > 0 (a period)"),
        ("nodes.0.messages.0.period_ms", _DELETE, "key 'period_ms' or 'sporadic_ms' is required"),
        ("nodes.0.messages.0.sporadic_ms", 5, "give period_ms (periodic) or sporadic_ms (sporadic), not both"),
        ("nodes.0.messages.0.jitter_ms", 10, "jitter_ms: 10 must be below the period 10 ms"),
        ("nodes.0.messages.0.data", "0102", "data: 2 bytes given for dlc 8"),
        ("nodes.0.messages.0.data", "zz", "data: 'zz' is not hex bytes"),
        ("nodes.0.messages.0.prio", 1, "unknown key 'prio'"),
        (
            "nodes.0.messages.1.id",
            0x100,
            "[[nodes.messages]] 'EngineTemp': id: 0x100 is already used by message "
            "'EngineData': two senders of one identifier collide",
        ),
        ("nodes.0.messages.1.name", "EngineData", "name: 'EngineData' is already a message of node 'engine'"),
        ("nodes.1.messages.0.mean_ms", 10, "mean_ms: 10 is below the minimum inter-arrival sporadic_ms 20"),
    ],
)
def test_each_broken_rule_is_named(path, value, expected):
    with pytest.raises(ScenarioError) as err:
        parse_scenario(_with(path, value), "good.toml")
    assert expected in str(err.value), str(err.value)
    assert str(err.value).startswith("good.toml: ")


@pytest.mark.parametrize(
    "fault,expected",
    [
        ({"kind": "lightning"}, "[[faults]] #1: kind: 'lightning' is not one of 'bit_errors', 'flip'"),
        ({"kind": "bit_errors", "rate": 0.9}, "[[faults]] #1: rate: 0.9 is outside 0..0.5 (a bit-error rate)"),
        ({"kind": "bit_errors"}, "[[faults]] #1: key 'rate' is required"),
        ({"kind": "disconnect", "node": "gateway", "at_ms": 5}, "node: 'gateway' is not a node of this scenario"),
        (
            {"kind": "disconnect", "node": "body", "at_ms": 5, "reconnect_ms": 5},
            "reconnect_ms: 5 must be after at_ms 5",
        ),
        ({"kind": "stuck", "node": "body", "level": "high"}, "level: 'high' is not one of 'dominant', 'recessive'"),
        ({"kind": "bit_errors", "rate": 1e-4, "nodes": ["ghost"]}, "nodes: 'ghost' is not a node of this scenario"),
        (
            {"kind": "babbling_idiot", "node": "body", "data": "00" * 9},
            "data: 9 bytes: a CAN 2.0 frame carries at most 8",
        ),
    ],
)
def test_fault_tables_are_checked(fault, expected):
    raw = copy.deepcopy(BASE)
    raw["faults"] = [fault]
    with pytest.raises(ScenarioError, match=None) as err:
        parse_scenario(raw, "f.toml")
    assert expected in str(err.value), str(err.value)


def test_files_that_are_not_scenarios_are_refused_naming_the_file(tmp_path):
    with pytest.raises(ScenarioError, match="no such scenario file"):
        load_scenario(tmp_path / "missing.toml")
    with pytest.raises(ScenarioError, match="is a directory"):
        load_scenario(tmp_path)
    bad = tmp_path / "bad.toml"
    bad.write_text("[bus\nbitrate = 1")
    with pytest.raises(ScenarioError, match=r"bad.toml: not valid TOML"):
        load_scenario(bad)
    binary = tmp_path / "bin.toml"
    binary.write_bytes(b"\xff\xfe\x00\x01")
    with pytest.raises(ScenarioError, match=r"bin.toml: not a text file"):
        load_scenario(binary)


def test_the_examples_are_valid_scenarios():
    from pathlib import Path

    examples = Path(__file__).resolve().parents[3] / "examples"
    files = sorted(examples.glob("*.toml"))
    assert files
    for f in files:
        sc = load_scenario(f)
        assert sc.nodes and sc.duration_ns > 0


def test_each_fault_kind_reaches_the_injector_method_of_its_name(monkeypatch):
    """The table dispatches: each kind's checked values reach `FaultInjector`'s method of the same
    name, with times in ns (a spy stands in for each method)."""
    from profiles.pipeline.faults import FAULT_KINDS, inject_faults
    from stack import FaultInjector, SimBus

    minimal = {
        "bit_errors": {"rate": 1e-4},
        "flip": {"id": 0x100},
        "stuck": {"node": "body", "level": "dominant", "start_ms": 1.5, "end_ms": 2},
        "disconnect": {"node": "body", "at_ms": 3, "reconnect_ms": 4.25},
        "babbling_idiot": {"node": "body", "id": 0x10, "data": "aa55"},
        "never_ack": {"node": "engine"},
    }
    assert set(minimal) == set(FAULT_KINDS)
    calls = []
    for name in FAULT_KINDS:
        monkeypatch.setattr(FaultInjector, name, lambda self, *a, _n=name, **kw: calls.append((_n, a, kw)))
    raw = copy.deepcopy(BASE)
    raw["faults"] = [{"kind": k, **v} for k, v in minimal.items()]
    sc = parse_scenario(raw, "f.toml")
    inject_faults(SimBus(500_000), sc.faults)
    by_kind = {c[0]: c for c in calls}
    assert [c[0] for c in calls] == list(FAULT_KINDS)
    assert by_kind["bit_errors"][1:] == ((1e-4,), {"nodes": None})
    assert by_kind["stuck"][1:] == (("body", "dominant"), {"start": 1_500_000, "end": 2_000_000})
    assert by_kind["disconnect"][1:] == (("body",), {"at": 3_000_000, "reconnect_at": 4_250_000})
    assert by_kind["babbling_idiot"][1:] == (
        ("body",),
        {"can_id": 0x10, "data": b"\xaa\x55", "start": 0, "end": None},
    )
    assert by_kind["flip"][2]["can_id"] == 0x100 and by_kind["never_ack"][1] == ("engine",)
