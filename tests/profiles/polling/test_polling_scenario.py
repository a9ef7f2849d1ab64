"""Master/slave scenarios: the DeviceNet identifier plan against the specification's tables, the
custom plan, and every checker refusal as one line naming the file, the node, the entry and the
key."""

from __future__ import annotations

import copy

import pytest

from profiles.pipeline.scenario import parse_scenario
from profiles.polling import plan
from profiles.schema import ScenarioError

# ---------------------------------------------------------------------------------------------- the plan


def test_poll_command_is_group_2_message_5_with_the_slaves_mac_as_destination():
    # "10xxxxxx101  Master's I/O poll command / COS / Cyclic message", xxxxxx = destination MAC ID
    for mac in (0, 1, 9, 63):
        assert plan.poll_command(mac) == int(f"10{mac:06b}101", 2)
    assert plan.poll_command(1) == 0x40D  # the 0x400 | MAC << 3 | 5


def test_poll_response_is_group_1_message_0xF_with_the_slaves_mac_as_source():
    # "01111yyyyyy  Slave's I/O poll response", yyyyyy = source MAC ID
    for mac in (0, 1, 9, 63):
        assert plan.poll_response(mac) == int(f"01111{mac:06b}", 2)
    assert plan.poll_response(1) == 0x3C1


def test_bit_strobe_command_carries_the_masters_mac_and_slaves_answer_with_group_1_message_0xE():
    # "10 Source MAC ID 000  Master's I/O Bit-Strobe Command"; "01110 Source MAC ID  Slave's
    # I/O Bit-Strobe Response": one command identifier per master, one answer per slave
    assert plan.bit_strobe_command(0) == 0x400
    assert plan.bit_strobe_command(5) == int("10000101000", 2) == 0x428
    assert plan.bit_strobe_response(5) == int("01110000101", 2) == 0x385


def test_change_of_state_and_its_acknowledgement():
    # "01101 Source MAC ID  Slave's I/O Change of State or Cyclic Message";
    # "10 Destination MAC ID 010  Master's Change of State or Cyclic Acknowledge Message"
    assert plan.cos_message(4) == int("01101000100", 2) == 0x344
    assert plan.cos_ack(4) == int("10000100010", 2) == 0x422


def test_strobe_data_has_one_bit_per_mac_id_lsb_first():
    assert plan.strobe_data([0, 9, 63]) == bytes([0x01, 0x02, 0, 0, 0, 0, 0, 0x80])
    assert len(plan.strobe_data([])) == 8
    with pytest.raises(ValueError, match="MAC ID 64"):
        plan.strobe_data([64])


def test_arbitration_puts_every_slave_answer_before_every_master_command():
    answers = [f(m) for m in range(64) for f in (plan.poll_response, plan.bit_strobe_response, plan.cos_message)]
    commands = [f(m) for m in range(64) for f in (plan.poll_command, plan.bit_strobe_command, plan.cos_ack)]
    assert max(answers) < min(commands)
    assert sorted(plan.bit_strobe_response(m) for m in (8, 5, 7)) == [0x385, 0x387, 0x388]


def test_describe_names_the_message():
    assert plan.describe(0x40D) == "Group 2 message 5 of MAC ID 1: poll command / COS / cyclic (destination)"
    assert plan.describe(0x385) == "Group 1 message 0xE of MAC ID 5: bit-strobe response"
    assert "outside" in plan.describe(0x700)


# ---------------------------------------------------------------------------------------------- scenarios


def base() -> dict:
    return {
        "bus": {"bitrate": 500000, "duration": 0.05},
        "nodes": [
            {
                "name": "m",
                "profile": "master",
                "cycle_ms": 2,
                "timeout_ms": 1,
                "poll": [
                    {"slave": "s1", "data": "0102"},
                    {"style": "remote", "slave": "s2"},
                    {"style": "bit_strobe", "slaves": ["s3"]},
                    {"style": "cos", "slave": "s4", "epr_ms": 10},
                ],
            },
            {
                "name": "s1",
                "profile": "slave",
                "mac_id": 1,
                "processing_ms": 0.02,
                "messages": [{"name": "s1_in", "id": 0x3C1, "dlc": 4}],
            },
            {"name": "s2", "profile": "slave", "mac_id": 2, "messages": [{"name": "s2_in", "id": 0x3C2, "dlc": 2}]},
            {"name": "s3", "profile": "slave", "mac_id": 3, "messages": [{"name": "s3_in", "id": 0x383, "dlc": 1}]},
            {
                "name": "s4",
                "profile": "slave",
                "mac_id": 4,
                "messages": [{"name": "s4_cos", "id": 0x344, "dlc": 1, "sporadic_ms": 5}],
            },
        ],
    }


def test_the_masters_requests_become_its_messages_with_the_plans_identifiers():
    sc = parse_scenario(base(), "ms.toml")
    m = {x.name: x for x in sc.node("m").messages}
    assert (m["poll_s1"].can_id, m["poll_s1"].dlc, m["poll_s1"].data, m["poll_s1"].remote) == (
        0x40D,
        2,
        b"\x01\x02",
        False,
    )
    assert (m["poll_s2"].can_id, m["poll_s2"].dlc, m["poll_s2"].remote) == (0x3C2, 2, True)  # DLC of the answer
    assert (m["strobe_m"].can_id, m["strobe_m"].data) == (0x400, plan.strobe_data([3]))
    assert (m["ack_s4"].can_id, m["ack_s4"].dlc) == (0x422, 0)
    net = sc.tables["master_slave"]
    assert [t.style for t in net.masters["m"].transactions] == ["polled", "remote", "bit_strobe"]
    assert net.slaves["s1"].watchdog_ns == 4 * 2_000_000  # DeviceNet: 4 x the expected packet rate
    assert net.slaves["s4"].cos[0].name == "s4_cos"


def test_a_custom_plan_takes_the_identifiers_given_extended_too():
    raw = {
        "bus": {"bitrate": 250000, "duration": 0.05},
        "nodes": [
            {
                "name": "m",
                "profile": "master",
                "plan": "custom",
                "cycle_ms": 5,
                "timeout_ms": 2,
                "poll": [
                    {"slave": "a", "id": 0x18DA10F1, "extended": True, "response_id": 0x18DAF110, "dlc": 1},
                    {"style": "bit_strobe", "slaves": ["a", "b"], "id": 0x100, "response_ids": [0x101, 0x102]},
                ],
            },
            {
                "name": "a",
                "profile": "slave",
                "messages": [
                    {"name": "a_in", "id": 0x18DAF110, "extended": True, "dlc": 8},
                    {"name": "a_s", "id": 0x101, "dlc": 1},
                ],
            },
            {"name": "b", "profile": "slave", "messages": [{"name": "b_s", "id": 0x102, "dlc": 1}]},
        ],
    }
    sc = parse_scenario(raw, "custom.toml")
    m = {x.name: x for x in sc.node("m").messages}
    assert (m["poll_a"].can_id, m["poll_a"].extended, m["poll_a"].dlc) == (0x18DA10F1, True, 1)
    assert (m["strobe_m"].can_id, m["strobe_m"].data) == (0x100, bytes(8))  # no MAC IDs: no bits to set


def refused(mutate, source="ms.toml") -> str:
    raw = copy.deepcopy(base())
    mutate(raw)
    with pytest.raises(ScenarioError) as exc:
        parse_scenario(raw, source)
    text = str(exc.value)
    assert "\n" not in text
    return text


def node(raw, name):
    return next(n for n in raw["nodes"] if n["name"] == name)


@pytest.mark.parametrize(
    "mutate,message",
    [
        (
            lambda r: node(r, "m")["poll"][0].update(slave="nobody"),
            "ms.toml: [[nodes]] #1 'm' > [[nodes.poll]] #1: slave: 'nobody' is not a node of this scenario",
        ),
        (
            lambda r: r["nodes"].append({"name": "c", "messages": []}) or node(r, "m")["poll"][0].update(slave="c"),
            "[[nodes.poll]] #1: slave: 'c' is a csma node, not a slave (give it profile = \"slave\")",
        ),
        (
            lambda r: node(r, "m")["poll"][0].update(speed=3),
            "[[nodes.poll]] #1: unknown key 'speed' (allowed: ack, ack_id, data, dlc, epr_ms, extended, id, name, response_id, "
            "response_ids, retries, slave, slaves, style, timeout_ms)",
        ),
        (
            lambda r: node(r, "m")["poll"][0].update(style="broadcast"),
            "[[nodes.poll]] #1: style: 'broadcast' is not one of 'polled', 'remote', 'bit_strobe', 'cos'",
        ),
        (
            lambda r: node(r, "m").pop("timeout_ms"),
            "[[nodes.poll]] #1: key 'timeout_ms' is required (on the entry, or on the master for every entry)",
        ),
        # 8-byte strobe 132 bits, 3 bits of intermission, 1-byte answer 62 bits: 197 bits x 2 us
        (
            lambda r: node(r, "m")["poll"][2].update(timeout_ms=0.2),
            "[[nodes.poll]] #3: timeout_ms: 0.2 is below the worst case of this transaction, 0.3940 ms",
        ),
        (
            lambda r: node(r, "m")["poll"][0].update(id=0x40C),
            "[[nodes.poll]] #1: id: 0x40C is not the DeviceNet poll command of MAC 1 0x40D (leave it out, or set plan = "
            '"custom")',
        ),
        (
            lambda r: node(r, "m")["poll"][2].update(retries=2),
            "[[nodes.poll]] #3: retries: not a key of a bit_strobe entry (a bit-strobe command is a broadcast",
        ),
        (
            lambda r: node(r, "m")["poll"][1].update(data="00"),
            "[[nodes.poll]] #2: data: not a key of a remote entry (a remote frame carries no data)",
        ),
        (
            lambda r: node(r, "m")["poll"][0].update(data="0102", dlc=3),
            "[[nodes.poll]] #1: data: 2 bytes given for dlc 3",
        ),
        (lambda r: node(r, "m")["poll"][0].update(data="zz"), "[[nodes.poll]] #1: data: 'zz' is not hex bytes"),
        (
            lambda r: node(r, "m")["poll"][2].update(slaves=["s3", "s3"]),
            "[[nodes.poll]] #3: slaves: a slave is named twice",
        ),
        (
            lambda r: node(r, "m")["poll"][2].update(dlc=4),
            "[[nodes.poll]] #3: dlc: 4: the DeviceNet bit-strobe command carries 8 bytes",
        ),
        (
            lambda r: node(r, "m").update(plan="custom"),
            "[[nodes.poll]] #1: key 'response_id' is required with plan = \"custom\"",
        ),
        (
            lambda r: node(r, "m")["poll"].append({"style": "bit_strobe", "slaves": ["s1"]}),
            "[[nodes.poll]] #5: a DeviceNet master has one bit-strobe command identifier",
        ),
        (lambda r: node(r, "m").update(cycle_ms=0), "[[nodes]] #1 'm': cycle_ms: 0 must be > 0 (the poll cycle)"),
        (
            lambda r: node(r, "m").update(poll=[]),
            "[[nodes]] #1 'm': poll: a master needs at least one [[nodes.poll]] entry",
        ),
        (
            lambda r: node(r, "m").update(messages=[{"name": "x", "id": 5, "dlc": 0}]),
            "[[nodes]] #1 'm' > [[nodes.messages]] #1 'x': a master sends the requests of its poll list only",
        ),
        (
            lambda r: node(r, "s1").update(mac_id=2),
            "[[nodes]] #3 's2': mac_id: 2 is already the MAC ID of node 's1' (MAC IDs are unique on a DeviceNet network)",
        ),
        (
            lambda r: node(r, "s1").pop("mac_id"),
            "[[nodes.poll]] #1: slave 's1' has no mac_id: the DeviceNet plan derives its identifiers from it",
        ),
        (
            lambda r: node(r, "s1").update(mac_id=64),
            "[[nodes]] #2 's1': mac_id: 64 is outside 0..63 (a DeviceNet MAC ID)",
        ),
        (
            lambda r: node(r, "s1")["messages"][0].update(id=0x3C5),
            "[[nodes.poll]] #1: slave 's1' declares no message with identifier 0x3C1 (poll response of MAC 1)",
        ),
        (
            lambda r: node(r, "s1")["messages"].append({"name": "extra", "id": 0x123, "dlc": 1}),
            "[[nodes]] #2 's1' > [[nodes.messages]] #2 'extra': id: 0x123 is not an I/O identifier of MAC ID 1 in the "
            "DeviceNet plan (poll response 0x3C1, bit-strobe response 0x381, change of state / cyclic 0x341)",
        ),
        (
            lambda r: node(r, "s1")["messages"].append({"name": "sb", "id": 0x381, "dlc": 1}),
            "[[nodes]] #2 's1' > [[nodes.messages]] #2 'sb': no entry of master 'm' asks for 'sb' (0x381)",
        ),
        (
            lambda r: node(r, "s1")["messages"][0].update(period_ms=5),
            "[[nodes.poll]] #1: slave 's1' releases 's1_in' (0x3C1) on its own (period_ms or sporadic_ms)",
        ),
        (
            lambda r: node(r, "s1").update(processing_min_ms=0.5),
            "[[nodes]] #2 's1': processing_min_ms: 0.5 is above processing_ms 0.02",
        ),
        (
            lambda r: r["nodes"].append({"name": "s9", "profile": "slave", "mac_id": 9, "messages": []}),
            "[[nodes]] #6 's9': no master polls this slave",
        ),
        (
            lambda r: r["nodes"].append(dict(node(r, "m"), name="m2", mac_id=10)),
            "[[nodes]] #6 'm2' > [[nodes.poll]] #1: slave: 's1' is already polled by master 'm' (a slave answers one master)",
        ),
        (
            lambda r: node(r, "s4")["messages"][0].pop("sporadic_ms"),
            "[[nodes.poll]] #4: slave 's4' produces no change-of-state / cyclic message 0x344",
        ),
        (
            lambda r: node(r, "m")["poll"][3].update(timeout_ms=1),
            "[[nodes.poll]] #4: timeout_ms: not a key of a cos entry (the master does not poll a cos slave",
        ),
    ],
)
def test_bad_poll_lists_are_one_line_naming_file_node_entry_and_key(mutate, message):
    assert message in refused(mutate)


def test_a_poll_request_may_not_reuse_another_messages_identifier():
    def mutate(r):
        r["nodes"].append({"name": "ecu", "messages": [{"name": "e", "id": 0x40D, "dlc": 1, "period_ms": 10}]})

    assert (
        "[[nodes.poll]] #1: the request 0x40D is already sent as message 'e': two senders of one identifier "
        "collide on the bus"
    ) in refused(mutate)


def test_on_the_command_line_a_bad_entry_is_one_line_with_exit_2(tmp_path, capsys):
    from stack.cli import main

    bad = tmp_path / "bad.toml"
    bad.write_text(
        '[bus]\nbitrate = 500000\nduration = 0.1\n[[nodes]]\nname = "m"\nprofile = "master"\n'
        'cycle_ms = 5\ntimeout_ms = 1\n[[nodes.poll]]\nslave = "x"\n'
    )
    rc = main(["experiment", str(bad)])
    out, err = capsys.readouterr()
    assert rc == 2 and out == ""
    assert err.strip() == (
        f"canstack: error: {bad}: [[nodes]] #1 'm' > [[nodes.poll]] #1: slave: 'x' is not a node of this scenario"
    )
