"""DeviceNet's duplicate MAC ID check at power-up, against the protocol summary of ODVA (two
requests one second apart, then online; a request or response with its MAC ID while checking, or a
response while online, is a communication fault; online, a request is answered) and the message
layout of the device manuals (identifier 10 MAC 111; R/R bit and port, vendor ID, serial number)."""

from __future__ import annotations

import pytest

from profiles.pipeline.runner import run_scenario
from profiles.pipeline.scenario import parse_scenario
from profiles.polling.dupmac import (
    CHECKING,
    COMMUNICATION_FAULT,
    ONLINE,
    DupMacCheck,
    decode_dup_mac,
    dup_mac_id,
    encode_dup_mac,
)
from profiles.polling.events import CommunicationFault, SlaveLost
from profiles.schema import ScenarioError
from stack import SimBus

S = 1_000_000_000
MS = 1_000_000


def test_the_message_layout_is_the_manuals():
    # "CAN-ID: 1 0 | MAC-ID | 1 1 1"; byte 0: R/R (bit 7) and port; vendor-ID low, high; serial
    # number low .. high
    for mac in (0, 5, 63):
        assert dup_mac_id(mac) == int(f"10{mac:06b}111", 2)
    assert dup_mac_id(5) == 0x42F
    req = encode_dup_mac(response=False, port=0, vendor_id=0x0123, serial_number=0x89ABCDEF)
    assert req == bytes([0x00, 0x23, 0x01, 0xEF, 0xCD, 0xAB, 0x89])
    resp = encode_dup_mac(response=True, port=2, vendor_id=0x0123, serial_number=0x89ABCDEF)
    assert resp[0] == 0x82 and decode_dup_mac(resp) == (True, 2, 0x0123, 0x89ABCDEF)
    assert decode_dup_mac(req[:6]) is None
    with pytest.raises(ValueError, match="MAC ID 64"):
        dup_mac_id(64)


def checks(*starts, mac=7, serials=None):
    """One DupMacCheck per start time (ns) on a 500 kbit/s bus with a plain listener node (it
    acknowledges frames at the CAN level); returns the bus, the checks and a log of what each
    reported."""
    bus = SimBus(500_000, seed=2)
    bus.node("listener")
    log: list[tuple[int, int, str]] = []
    out = []
    for i, t0 in enumerate(starts):
        node = bus.node(f"n{i}")
        c = DupMacCheck(
            node,
            mac,
            vendor_id=1,
            serial_number=(serials or [1000 + i for i in range(len(starts))])[i],
            on_online=lambda t, i=i: log.append((i, t, "online")),
            on_fault=lambda t, why, i=i: log.append((i, t, why)),
        )
        node.call_at(t0, c.start)
        out.append(c)
    return bus, out, log


def test_alone_a_node_goes_online_one_second_after_its_second_request():
    bus, (c,), log = checks(0)
    ends = []
    bus.nodes[1].listen(__import__("stack").TxDone, lambda ev: ends.append((ev.time, ev.frame.data[0])))
    bus.run(until=3 * S)
    assert [d for _, d in ends] == [0x00, 0x00]  # two requests
    assert ends[1][0] > ends[0][0] + S  # the second after the first one's wait
    assert log == [(0, ends[1][0] + S, "online")] and c.state == ONLINE and c.requests_sent == 2


def test_a_node_that_hears_its_mac_id_while_checking_goes_to_communication_fault():
    bus, (a, b), log = checks(0, S // 2)
    bus.run(until=3 * S)
    # b's request at 0.5 s reaches a while a is still checking: a faults; b hears nothing of a
    # any more and is online 1 s after its second request
    assert a.state == COMMUNICATION_FAULT and b.state == ONLINE
    assert log[0][0] == 0 and log[0][2] == "a Duplicate MAC ID request while checking"
    assert log[1][0] == 1 and log[1][2] == "online" and 2.5 * S < log[1][1] < 2.6 * S


def test_an_online_node_answers_a_late_duplicate_which_then_faults():
    bus, (a, b), log = checks(0, 3 * S)
    bus.run(until=6 * S)
    assert a.state == ONLINE and a.responses_sent == 1
    assert b.state == COMMUNICATION_FAULT and b.fault_reason == "a Duplicate MAC ID response while checking"
    assert b.requests_sent == 1  # faulted before its second request


def test_two_duplicates_powered_up_together_collide_and_one_wins():
    """Same MAC ID and same instant: the requests differ in their serial numbers, collide in the
    data field (a bit error, not arbitration), and are repeated until one node, error passive,
    waits out its suspend transmission and hears the other's."""
    bus, (a, b), log = checks(0, 0)
    bus.run(until=3 * S)
    states = sorted([a.state, b.state])
    assert states == [COMMUNICATION_FAULT, ONLINE]
    assert CHECKING not in states


# ---------------------------------------------------------------------------------------------- scenarios


def network(**slave1):
    return {
        "bus": {"bitrate": 500000, "duration": 2.2},
        "nodes": [
            {
                "name": "m",
                "profile": "master",
                "cycle_ms": 5,
                "timeout_ms": 1,
                "dup_mac_check": True,
                "offset_ms": 5,  # the slaves' checks end a little after the master's
                "poll": [{"slave": "s1"}, {"slave": "s2"}],
            },
            dict(
                {"name": "s1", "profile": "slave", "mac_id": 1, "dup_mac_check": True},
                messages=[{"name": "s1_in", "id": 0x3C1, "dlc": 2}],
                **slave1,
            ),
            {
                "name": "s2",
                "profile": "slave",
                "mac_id": 2,
                "dup_mac_check": True,
                "messages": [{"name": "s2_in", "id": 0x3C2, "dlc": 2}],
            },
        ],
    }


def run(raw):
    kept: dict = {}
    res = run_scenario(parse_scenario(raw, "dup.toml"), setup=lambda b: kept.update(b.profiles), record=True)
    return res, kept


def test_io_starts_only_once_every_node_is_online():
    res, p = run(network())
    first_poll = min(r.start for r in res.trace if r.kind == "frame" and r.frame.can_id in (0x40D, 0x415))
    online = p["m"].poller.dup_mac.online_at
    assert online > 2 * S and first_poll == online + 5 * MS  # two requests and two 1-s waits
    ms = res.to_json()["master_slave"]
    for s in ("s1", "s2"):
        assert ms["slaves"][s]["dup_mac_check"]["state"] == "online"
        assert ms["slaves"][s]["polls"] == ms["slaves"][s]["responses"] > 0
    assert ms["masters"]["m"]["dup_mac_check"]["requests_sent"] == 2


def test_a_duplicate_of_a_slaves_mac_id_faults_it_and_the_master_loses_it():
    raw = network()
    raw["bus"]["duration"] = 2.5
    # another device with MAC ID 1, powered up 0.5 s in: its Duplicate MAC ID request
    raw["nodes"].append(
        {
            "name": "intruder",
            "profile": "csma",
            "messages": [
                {
                    "name": "dup_request",
                    "id": dup_mac_id(1),
                    "dlc": 7,
                    "data": encode_dup_mac(response=False, port=0, vendor_id=9, serial_number=9).hex(),
                    "period_ms": 10_000,
                    "offset_ms": 500,
                }
            ],
        }
    )
    res, p = run(raw)
    (fault,) = [e for e in p["s1"].events if isinstance(e, CommunicationFault)]
    assert fault.mac_id == 1 and 500 * MS < fault.time < 501 * MS and p["s1"].state == COMMUNICATION_FAULT
    assert not [
        r for r in res.trace if r.kind == "frame" and r.frame.can_id in (0x3C1, dup_mac_id(1)) and r.start > fault.time
    ]
    lost = [e for e in p["m"].events if isinstance(e, SlaveLost)]
    assert [e.slave for e in lost] == ["s1"]
    assert res.to_json()["master_slave"]["slaves"]["s2"]["timeouts"] == 0


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda r: r["nodes"][0].update(plan="custom"), "dup_mac_check: the duplicate MAC ID check is DeviceNet's"),
        (
            lambda r: r["nodes"][2].update(dup_mac_check=False, vendor_id=5),
            "vendor_id: only the duplicate MAC ID check",
        ),
        (lambda r: r["nodes"][2].update(serial_number=2**32), "serial_number: 4294967296"),
    ],
)
def test_bad_keys_are_one_line(mutate, message):
    raw = network()
    mutate(raw)
    with pytest.raises(ScenarioError) as exc:
        parse_scenario(raw, "dup.toml")
    assert message in str(exc.value) and "\n" not in str(exc.value)
