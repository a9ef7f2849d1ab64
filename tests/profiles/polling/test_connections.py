"""DeviceNet I/O connections: expected packet rate (EPR), the change-of-state heartbeat and
production inhibit time, the watchdogs of 4 × EPR at both ends, and acknowledged COS messages
sent again when their acknowledgement does not come (Acknowledge Handler: 16 ms, retry limit 1).

The expectations are DeviceNet's numbers applied by hand to what the trace shows: a consumer's
watchdog expires exactly 4 × EPR after the last packet it consumed (the end of that frame on the
bus); a COS producer never goes longer than its EPR without producing, nor produces sooner than
its inhibit time after the last production; an unacknowledged message goes out again 16 ms after
the end of its frame."""

from __future__ import annotations

from pathlib import Path

import pytest

from profiles.pipeline.runner import run_scenario
from profiles.pipeline.scenario import parse_scenario
from profiles.polling.connection import CosProducer, Watchdog
from profiles.polling.events import COS, POLL, MasterBack, MasterLost, RetryLimitReached, SlaveBack, SlaveLost
from profiles.schema import ScenarioError
from stack import Frame, SimBus, TxDone

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"
MS = 1_000_000
EPR = 25 * MS  # door4's EPR in examples/master_slave_mixed.toml


def run_example(faults=None, duration=None):
    import tomllib

    raw = tomllib.loads((EXAMPLES / "master_slave_mixed.toml").read_text())
    if faults:
        raw["faults"] = faults
    if duration:
        raw["bus"]["duration"] = duration
    kept: dict = {}
    res = run_scenario(
        parse_scenario(raw, "master_slave_mixed.toml"), setup=lambda b: kept.update(b.profiles), record=True
    )
    return res, kept


def frames(res, can_id):
    return [r for r in res.trace if r.kind == "frame" and r.frame.can_id == can_id]


# ---------------------------------------------------------------------------------------------- healthy bus


def test_a_healthy_bus_reports_no_loss_and_the_cos_slave_beats_at_its_epr():
    res, p = run_example()
    for name in ("valve1", "valve2", "prox3", "door4"):
        assert not [e for e in p[name].events if isinstance(e, MasterLost)], name
    assert not [e for e in p["scanner"].events if isinstance(e, (SlaveLost, SlaveBack))]
    door = p["door4"]
    assert door.figures()["heartbeats"] > 0 and door.figures()["retransmissions"] == 0
    cos = frames(res, 0x344)
    acks = frames(res, 0x422)
    assert len(cos) == len(acks) == door.figures()["acks_received"]
    gaps = [b.start - a.start for a, b in zip(cos, cos[1:])]
    # never sooner than the production inhibit time (sporadic_ms = 10), never later than the EPR
    # plus the longest the frame may wait for the bus (its response-time bound)
    bound = next(r for r in res.to_json()["messages"] if r["name"] == "door4_cos")["rta_ms"] * MS
    assert min(gaps) >= 10 * MS - bound
    assert max(gaps) <= EPR + bound


# ---------------------------------------------------------------------------------------------- lost ends


def test_an_unplugged_cos_slave_is_timed_out_by_the_master_after_4_eprs_and_taken_back():
    res, p = run_example([{"kind": "disconnect", "node": "door4", "at_ms": 500, "reconnect_ms": 800}], duration=1.0)
    lost = [e for e in p["scanner"].events if isinstance(e, SlaveLost)]
    back = [e for e in p["scanner"].events if isinstance(e, SlaveBack)]
    last = max(r.end for r in frames(res, 0x344) if r.end < 500 * MS)
    assert [(e.slave, e.connection, e.time) for e in lost] == [("door4", COS, last + 4 * EPR)]
    first = min(r.end for r in frames(res, 0x344) if r.start > 800 * MS)
    assert [(e.slave, e.connection, e.time) for e in back] == [("door4", COS, first)]
    link = res.to_json()["master_slave"]["slaves"]["door4"]
    assert link["cos_lost_ms"] == [[lost[0].time / MS, first / MS]] and link["cos_lost"] is False
    # the polled slaves never noticed
    for name in ("valve1", "valve2", "prox3"):
        assert not [e for e in p[name].events if isinstance(e, MasterLost)], name
    # door4 heard no acknowledgement either: its own watchdog over the acks, 4 x EPR after the last
    last_ack = max(r.end for r in frames(res, 0x422) if r.end < 500 * MS)
    gone = [e for e in p["door4"].events if isinstance(e, MasterLost)]
    assert [(e.connection, e.time, e.watchdog) for e in gone] == [(COS, last_ack + 4 * EPR, 4 * EPR)]


def test_an_unplugged_master_is_detected_by_every_slave_and_unacknowledged_cos_is_sent_again():
    res, p = run_example([{"kind": "disconnect", "node": "scanner", "at_ms": 500, "reconnect_ms": 700}], duration=1.0)
    # polled slaves: 4 x the master's EPR (the 5 ms cycle) after the last request they received
    for name, request in (("valve1", 0x40D), ("valve2", 0x415), ("prox3", 0x400)):
        last = max(r.end for r in frames(res, request) if r.end < 500 * MS)
        gone = [e for e in p[name].events if isinstance(e, MasterLost)]
        assert [(e.connection, e.time) for e in gone] == [(POLL, last + 20 * MS)], name
        assert [e.connection for e in p[name].events if isinstance(e, MasterBack)] == [POLL]
    # the COS slave: 4 x its EPR after the last acknowledgement
    door = p["door4"]
    last_ack = max(r.end for r in frames(res, 0x422) if r.end < 500 * MS)
    gone = [e for e in door.events if isinstance(e, MasterLost)]
    assert [(e.connection, e.time) for e in gone] == [(COS, last_ack + 4 * EPR)]


def test_an_unacknowledged_cos_message_goes_out_again_16_ms_after_its_end_once():
    """A COS slave whose data rarely change (heartbeat every 50 ms) and a master off the bus from
    200 to 400 ms: every production in between goes out twice — the retransmission queued 16 ms
    (the Acknowledge Timer) after the end of the first — and then the retry limit is reported."""
    raw = raw_cos(epr_ms=50)
    raw["bus"]["duration"] = 0.5
    raw["nodes"][1]["messages"][0]["mean_ms"] = 10_000
    raw["nodes"].append({"name": "tap", "profile": "csma"})  # acknowledges frames at the CAN level
    raw["faults"] = [{"kind": "disconnect", "node": "m", "at_ms": 200, "reconnect_ms": 400}]
    kept: dict = {}
    res = run_scenario(parse_scenario(raw, "ms.toml"), setup=lambda b: kept.update(b.profiles), record=True)
    cos = [r for r in frames(res, 0x344) if 200 * MS <= r.start < 400 * MS]
    first, again = cos[0::2], cos[1::2]
    assert len(first) == len(again) >= 3
    for a, b in zip(first, again):
        assert a.end + 16 * MS <= b.start <= a.end + 16 * MS + 1 * MS  # the bus is idle: at once
    door = kept["d"]
    limits = [e for e in door.events if isinstance(e, RetryLimitReached)]
    assert door.figures()["retransmissions"] == len(again) == len(limits)
    assert [e.time for e in limits] == [b.end + 16 * MS for b in again]
    assert all(e.retries == 1 for e in limits)


# ---------------------------------------------------------------------------------------------- scenario keys


def raw_cos(**entry):
    return {
        "bus": {"bitrate": 500000, "duration": 0.05},
        "nodes": [
            {"name": "m", "profile": "master", "cycle_ms": 5, "poll": [dict({"style": "cos", "slave": "d"}, **entry)]},
            {
                "name": "d",
                "profile": "slave",
                "mac_id": 4,
                "messages": [{"name": "d_cos", "id": 0x344, "dlc": 1, "sporadic_ms": 10}],
            },
        ],
    }


@pytest.mark.parametrize(
    "entry, message",
    [
        ({}, "[[nodes.poll]] #1: key 'epr_ms' is required for the change-of-state message 'd_cos'"),
        ({"epr_ms": 5}, "[[nodes.poll]] #1: epr_ms: 5 is below the production inhibit time of 'd_cos'"),
        ({"epr_ms": 0}, "[[nodes.poll]] #1: epr_ms: 0"),
    ],
)
def test_a_cos_connection_needs_an_epr_no_shorter_than_its_inhibit_time(entry, message):
    with pytest.raises(ScenarioError) as exc:
        parse_scenario(raw_cos(**entry), "ms.toml")
    assert message in str(exc.value) and "\n" not in str(exc.value)


def test_a_cyclic_connections_epr_is_its_period():
    raw = raw_cos(epr_ms=20)
    raw["nodes"][1]["messages"][0] = {"name": "d_cyc", "id": 0x344, "dlc": 1, "period_ms": 10}
    with pytest.raises(ScenarioError, match="epr_ms: 20 is not the period of the cyclic message 'd_cyc'"):
        parse_scenario(raw, "ms.toml")
    raw["nodes"][0]["poll"][0].pop("epr_ms")
    sc = parse_scenario(raw, "ms.toml")
    link = sc.tables["master_slave"].masters["m"].cos[0]
    assert link.epr_ns == {"d_cyc": 10 * MS} and link.watchdog_ns == 40 * MS


def test_acknowledge_handler_keys_are_checked():
    raw = raw_cos(epr_ms=20)
    raw["nodes"][1]["retry_limit"] = 256
    with pytest.raises(ScenarioError, match="retry_limit: 256"):
        parse_scenario(raw, "ms.toml")


# ---------------------------------------------------------------------------------------------- the parts


def producer_on_a_bus(epr=EPR, **kw):
    """A CosProducer for a 1-byte COS message (inhibit 10 ms, EPR 25 ms) on a node of a bus whose
    other node acknowledges nothing at the application level (a plain listener)."""
    from profiles.declarations import MessageDecl

    bus = SimBus(500_000, seed=1)
    node = bus.node("d")
    bus.node("listener")
    m = MessageDecl(
        name="d_cos",
        node="d",
        can_id=0x344,
        extended=False,
        dlc=1,
        data=b"\x01",
        remote=False,
        period_ns=None,
        sporadic_ns=10 * MS,
        mean_ns=None,
        offset_ns=0,
        jitter_ns=0,
        deadline_ns=None,
    )
    sent: list[int] = []
    ends: list[int] = []

    def send(msg):
        sent.append(node.now())
        return node.send(Frame(msg.can_id, msg.data))

    def done(ev):
        ends.append(ev.time)
        p.sent(ev.request, ev.time)

    p = CosProducer(node, m, epr, send, **kw)
    node.listen(TxDone, done)
    return bus, node, p, sent, ends


def test_heartbeat_every_epr_and_changes_no_sooner_than_the_inhibit_time():
    bus, node, p, sent, _ = producer_on_a_bus()
    p.start()
    node.call_at(52 * MS, p.change)  # 2 ms after the last production: waits for the inhibit time
    node.call_at(55 * MS, p.change)  # coalesced into the same production
    bus.run(until=100 * MS)
    # nothing changed until 52 ms: one heartbeat per EPR; then the change at the end of the
    # inhibit time, and the heartbeat restarts from there
    assert sent == [25 * MS, 50 * MS, 60 * MS, 85 * MS]
    assert (p.productions, p.heartbeats) == (4, 3)


def test_an_unacknowledged_message_is_sent_again_after_the_acknowledge_timer_up_to_the_retry_limit():
    limits = []
    bus, node, p, sent, ends = producer_on_a_bus(
        100 * MS, acked=True, retry_limit=2, on_retry_limit=lambda t, n: limits.append((t, n))
    )
    p.start()
    node.call_at(1 * MS, p.change)
    bus.run(until=99 * MS)  # before the heartbeat
    # two retries, each 16 ms after the end of the previous attempt's frame, then the limit
    assert sent == [1 * MS, ends[0] + 16 * MS, ends[1] + 16 * MS]
    assert limits == [(ends[2] + 16 * MS, 2)] and p.retransmissions == 2 and p.retry_limits == 1
    # an acknowledgement stops the retries
    bus2, node2, q, sent2, _ = producer_on_a_bus(acked=True)
    q.start()
    node2.call_at(30 * MS, q.acked)
    bus2.run(until=49 * MS)
    assert sent2 == [25 * MS] and q.retransmissions == 0


def test_watchdog_fires_timeout_after_the_last_kick_and_reports_the_return():
    bus = SimBus(500_000)
    node = bus.node("n")
    fired = []
    w = Watchdog(node, 10 * MS, fired.append)
    w.start(0)
    node.call_at(4 * MS, lambda: w.kick(4 * MS))
    node.call_at(9 * MS, lambda: w.kick(9 * MS))
    bus.run(until=30 * MS)
    assert fired == [19 * MS] and w.expired
    back = []
    node.call_at(31 * MS, lambda: back.append(w.kick(31 * MS)))
    node.call_at(33 * MS, lambda: back.append(w.kick(33 * MS)))
    bus.run(until=50 * MS)
    assert back == [True, False] and fired == [19 * MS, 43 * MS]
