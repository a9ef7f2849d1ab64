"""The master/slave profile on the simulated bus: the poll cycle against hand-worked frame times,
the worst case never exceeded (alone on the bus, and on a bus shared with CSMA/CR traffic under
the response-time analysis), timeouts, retries, lost slaves and their return, overruns, bus off
and the slaves' watchdogs, change of state, python-can, the plot."""

from __future__ import annotations

import copy
import json
import random
from pathlib import Path

import pytest

from profiles.pipeline.runner import run_on_pycan, run_scenario
from profiles.pipeline.scenario import load_scenario, parse_scenario
from profiles.polling import plan
from profiles.polling.events import CycleOverrun, MasterBack, MasterLost, MasterStopped, SlaveBack, SlaveLost
from stack import Frame

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"
BIT = 2000  # ns at 500 kbit/s


def network(duration: float = 0.02, **over) -> dict:
    """One master polling: s1 (polled, 2 bytes out, 4 in, 20 us processing), s2 (remote frame
    answered by its mailbox, 2 bytes), s3 and s4 (bit-strobe, 1 byte each, 10 us)."""
    raw = {
        "bus": {"bitrate": 500000, "duration": duration, "seed": 1},
        "nodes": [
            {
                "name": "m",
                "profile": "master",
                "cycle_ms": 2,
                "timeout_ms": 1,
                "poll": [
                    {"slave": "s1", "data": "0102"},
                    {"style": "remote", "slave": "s2"},
                    {"style": "bit_strobe", "slaves": ["s3", "s4"]},
                ],
            },
            {
                "name": "s1",
                "profile": "slave",
                "mac_id": 1,
                "processing_ms": 0.02,
                "messages": [{"name": "s1_in", "id": 0x3C1, "dlc": 4, "data": "00a01234"}],
            },
            {
                "name": "s2",
                "profile": "slave",
                "mac_id": 2,
                "messages": [{"name": "s2_in", "id": 0x3C2, "dlc": 2, "data": "0190"}],
            },
            {
                "name": "s3",
                "profile": "slave",
                "mac_id": 3,
                "processing_ms": 0.01,
                "messages": [{"name": "s3_in", "id": 0x383, "dlc": 1, "data": "01"}],
            },
            {
                "name": "s4",
                "profile": "slave",
                "mac_id": 4,
                "processing_ms": 0.01,
                "messages": [{"name": "s4_in", "id": 0x384, "dlc": 1, "data": "00"}],
            },
        ],
    }
    raw.update(over)
    return raw


def run(raw, **kw):
    res = run_scenario(parse_scenario(raw, "ms.toml"), **kw)
    return res, res.to_json()["master_slave"]


# ---------------------------------------------------------------------------------------------- the cycle


def test_worst_case_cycle_from_frame_lengths_worked_by_hand():
    """Eq. 1 of Davis et al. less its 3-bit intermission (g = 34): poll command, 2 bytes: 50 + 13
    + 12 = 75 -> 72 bits; poll response, 4 bytes: 66 + 13 + 16 = 95 -> 92; with 20 us (10 bits) of
    processing: 72 + 10 + 92 = 174 bits. Remote frame: 34 + 13 + 8 = 55 -> 52 bits, answered by the
    mailbox after the 3-bit intermission, 2 bytes: 72 -> 52 + 3 + 72 = 127 bits. Bit-strobe, 8
    bytes: 98 + 13 + 24 = 135 -> 132 bits; two 1-byte answers (65 -> 62 bits) both ready 5 bits
    after it: 5 + 2 x 65 - 3 = 132 -> 264 bits. Cycle: 174 + 127 + 264 + 2 x 3 = 571 bits."""
    res, ms = run(network())
    m = ms["masters"]["m"]
    assert [t["bound_ms"] for t in m["transactions"]] == [174 * BIT / 1e6, 127 * BIT / 1e6, 264 * BIT / 1e6]
    assert m["cycle_bound_ms"] == 571 * BIT / 1e6 == 1.142
    assert m["bound_method"].startswith("frame lengths")
    assert m["cycles"] == 10 and m["overruns"] == 0
    assert m["cycle_ms"]["max"] <= m["cycle_bound_ms"]
    for t in m["transactions"]:
        assert t["response_ms_max"] <= t["bound_ms"]


def test_the_simulated_cycle_is_the_exact_frame_lengths_to_the_nanosecond():
    """With the payloads fixed and the processing delays too, every cycle takes the frames'
    exact stuffed lengths, the processing delays and the intermissions — what the bound with
    ``stuffing = "exact"`` says."""
    raw = network(analysis={"stuffing": "exact"})
    res, ms = run(raw)
    length = {  # SOF to the end of EOF, the real stuffed bit streams
        "cmd": Frame(plan.poll_command(1), bytes.fromhex("0102")).bits.length,
        "r1": Frame(0x3C1, bytes.fromhex("00a01234")).bits.length,
        "rtr": Frame(0x3C2, remote=True, dlc=2).bits.length,
        "r2": Frame(0x3C2, bytes.fromhex("0190")).bits.length,
        "strobe": Frame(plan.bit_strobe_command(0), plan.strobe_data([3, 4])).bits.length,
        "r3": Frame(0x383, b"\x01").bits.length,
        "r4": Frame(0x384, b"\x00").bits.length,
    }
    t1 = length["cmd"] + 10 + length["r1"]
    t2 = length["rtr"] + 3 + length["r2"]
    t3 = length["strobe"] + 5 + length["r3"] + 3 + length["r4"]  # 0x383 wins, 0x384 follows
    m = ms["masters"]["m"]
    expected = (t1 + 3 + t2 + 3 + t3) * BIT / 1e6
    assert m["cycle_ms"]["min"] == m["cycle_ms"]["max"] == pytest.approx(expected, abs=1e-9)
    assert m["cycle_bound_ms"] == pytest.approx(expected, abs=1e-9)
    assert ms["slaves"]["s1"]["response_ms"]["max"] == pytest.approx(t1 * BIT / 1e6, abs=1e-9)
    assert ms["slaves"]["s2"]["response_ms"]["max"] == pytest.approx(t2 * BIT / 1e6, abs=1e-9)
    assert ms["slaves"]["s4"]["response_ms"]["max"] == pytest.approx(t3 * BIT / 1e6, abs=1e-9)
    # a cycle starts every 2 ms: the first requests' SOFs
    starts = list(res.tracks["poll_s1"].starts)
    assert [b - a for a, b in zip(starts, starts[1:])] == [2_000_000] * 9


def test_bit_strobe_answers_come_in_identifier_order():
    res, _ = run(network(), record=True)
    order = [r.frame.can_id for r in res.trace if r.frame.can_id in (0x383, 0x384)]
    assert order == [0x383, 0x384] * 10


def random_network(rng: random.Random, *, shared: bool = False) -> dict:
    bitrate = rng.choice([125_000, 250_000, 500_000, 1_000_000])
    n = rng.randint(1, 6)
    nodes, poll, strobed = [], [], []
    for i in range(1, n + 1):
        style = rng.choice(["polled", "polled", "remote", "bit_strobe"])
        hi = rng.choice([0.0, 0.002, 0.02, 0.1])
        dlc = rng.randint(0, 8)
        rid = plan.bit_strobe_response(i) if style == "bit_strobe" else plan.poll_response(i)
        nodes.append(
            {
                "name": f"s{i}",
                "profile": "slave",
                "mac_id": i,
                "processing_ms": hi,
                "processing_min_ms": rng.choice([0.0, hi / 2, hi]),
                "messages": [
                    {
                        "name": f"s{i}_in",
                        "id": rid,
                        "dlc": dlc,
                        "data": bytes(rng.randrange(256) for _ in range(dlc)).hex(),
                    }
                ],
            }
        )
        if style == "bit_strobe":
            strobed.append(f"s{i}")
        else:
            entry = {"slave": f"s{i}", "style": style}
            if style == "polled":
                out = rng.randint(0, 8)
                entry["data"] = bytes(rng.randrange(256) for _ in range(out)).hex()
            poll.append(entry)
    if strobed:
        poll.insert(rng.randrange(len(poll) + 1), {"style": "bit_strobe", "slaves": strobed})
    if shared and rng.random() < 0.5:  # a slave that reports changes of state, acknowledged or not
        nodes.append(
            {
                "name": "cos",
                "profile": "slave",
                "mac_id": 40,
                "messages": [
                    {"name": "cos_out", "id": plan.cos_message(40), "dlc": 2, "sporadic_ms": rng.choice([5, 10])}
                ],
            }
        )
        poll.append({"style": "cos", "slave": "cos", "ack": rng.random() < 0.5, "epr_ms": rng.choice([10, 25])})
    cycle = 20.0 if bitrate < 500_000 else 10.0
    nodes.insert(0, {"name": "m", "profile": "master", "cycle_ms": cycle, "timeout_ms": cycle, "poll": poll})
    if shared:
        for k in range(rng.randint(1, 3)):
            msgs = []
            for j in range(rng.randint(1, 3)):
                dlc = rng.randint(0, 8)
                msgs.append(
                    {
                        "name": f"e{k}{j}",
                        "id": rng.choice([rng.randrange(0x001, 0x300), rng.randrange(0x600, 0x7F0)]),
                        "dlc": dlc,
                        "period_ms": rng.choice([5, 10, 20]) * 1_000_000 / bitrate,
                        "offset_ms": rng.uniform(0, 3),
                        "jitter_ms": rng.choice([0, 0.5]),
                    }
                )
            nodes.append({"name": f"ecu{k}", "messages": msgs})
        ids = set()
        for nd in nodes:  # drop random identifiers that collide
            nd["messages"] = [m for m in nd.get("messages", []) if not (m["id"] in ids or ids.add(m["id"]))]
    return {
        "bus": {"bitrate": bitrate, "duration": 0.25 if bitrate >= 500_000 else 0.5, "seed": rng.randrange(99)},
        "nodes": nodes,
    }


def test_the_simulated_cycle_never_exceeds_the_worst_case_alone_on_the_bus():
    for seed in range(15):
        raw = random_network(random.Random(seed))
        try:
            _, ms = run(raw)
        except ValueError as exc:  # a random timeout below a slow transaction: not this test's point
            assert "timeout_ms" in str(exc)
            continue
        m = ms["masters"]["m"]
        assert m["bound_method"].startswith("frame lengths"), seed
        assert m["cycle_ms"]["max"] <= m["cycle_bound_ms"] + 1e-9, seed
        for t in m["transactions"]:
            assert t["response_ms_max"] <= t["bound_ms"] + 1e-9, (seed, t["name"])
        for s in ms["slaves"].values():
            assert s["timeouts"] == 0 and s["responses"] == s["polls"] > 0, seed


def test_on_a_shared_bus_the_analysis_bounds_every_transaction_and_the_other_messages():
    """CSMA/CR nodes of higher and lower priority, sometimes a slave's change-of-state messages:
    the cycle and each transaction stay within the holistic bound, and the spine's response-time
    analysis, given the profile's traffic model, still bounds every CSMA message."""
    checked = 0
    for seed in range(12):
        raw = random_network(random.Random(100 + seed), shared=True)
        try:
            res, ms = run(raw)
        except ValueError as exc:
            assert "timeout_ms" in str(exc)
            continue
        m = ms["masters"]["m"]
        if m["cycle_bound_ms"] is None:  # an overloaded random bus: no bound to check
            continue
        checked += 1
        assert m["cycle_ms"]["max"] <= m["cycle_bound_ms"] + 1e-9, seed
        for t in m["transactions"]:
            assert t["response_ms_max"] <= t["rta_bound_ms"] + 1e-9, (seed, t["name"])
            assert t["end_ms_max"] <= t["end_bound_ms"] + 1e-9, (seed, t["name"])
        for row in res.to_json()["messages"]:
            if row["rta_ms"] is not None and row["response_ms"] is not None:
                assert row["response_ms"]["max"] <= row["rta_ms"] + 1e-9, (seed, row["name"])
        assert res.analysis["applies"] is True
    assert checked >= 8


def test_the_mixed_example_is_bounded_by_the_analysis_not_by_frame_lengths():
    res = run_scenario(load_scenario(EXAMPLES / "master_slave_mixed.toml"))
    data = res.to_json()
    m = data["master_slave"]["masters"]["scanner"]
    assert m["bound_method"].startswith("holistic response-time analysis")
    assert m["chain_bound_ms"] < m["cycle_ms"]["max"] <= m["cycle_bound_ms"] == m["rta_cycle_bound_ms"]
    door = data["master_slave"]["slaves"]["door4"]
    cos = {r["name"]: r for r in data["messages"]}
    assert door["cos"] == door["acks"] == door["acks_received"] == cos["door4_cos"]["sent"] == cos["ack_door4"]["sent"]
    for row in data["messages"]:
        assert row["response_ms"]["max"] <= row["rta_ms"]
    worst = max(m["transactions"], key=lambda t: t["response_ms_max"])
    readme = (EXAMPLES.parent / "docs" / "pages" / "experiments" / "polling.md").read_text(encoding="utf-8")
    assert (
        f"the frame-length bound ({m['chain_bound_ms']:.3f} ms) no longer applies and `master_slave` says so; the\n"
        f"measured cycle reaches {m['cycle_ms']['max']:.3f} ms against the analysis' {m['cycle_bound_ms']:.3f} ms, "
        f"the slowest transaction {worst['response_ms_max']:.3f} ms\n"
        f"against {worst['rta_bound_ms']:.3f} ms"
    ) in readme


def test_an_overrun_is_reported_and_the_next_cycle_starts_at_once():
    raw = network()
    raw["nodes"][0]["cycle_ms"] = 0.5  # the work takes about 1 ms
    res, profiles = run_built(raw)
    m = res.to_json()["master_slave"]["masters"]["m"]
    assert m["overruns"] == m["cycles"] - 1 or m["overruns"] == m["cycles"]
    # no silent drift: the next cycle's first request is queued when the last answer ends
    starts = list(res.tracks["poll_s1"].starts)
    gaps = {b - a for a, b in zip(starts, starts[1:])}
    assert min(gaps) == round(m["cycle_ms"]["min"] * 1e6) + 3 * BIT
    events = [e for e in profiles["m"].events if isinstance(e, CycleOverrun)]
    assert len(events) == m["overruns"] and all(e.length > 500_000 for e in events)


def run_built(raw_or_scenario, **kw):
    """Run and keep the profiles (for their events)."""
    sc = raw_or_scenario if not isinstance(raw_or_scenario, dict) else parse_scenario(raw_or_scenario, "ms.toml")
    kept: dict = {}
    res = run_scenario(sc, setup=lambda built: kept.update(built.profiles), **kw)
    return res, kept


# ---------------------------------------------------------------------------------------------- faults


def test_an_unplugged_slave_is_timed_out_lost_polled_slower_and_taken_back():
    """examples/master_slave.toml: valve2 is off the bus from 300 to 700 ms. Cycles start every
    5 ms; valve2 is the second transaction; its timeout is 1 ms with one retry."""
    res, profiles = run_built(load_scenario(EXAMPLES / "master_slave.toml"))
    data = res.to_json()
    ms = data["master_slave"]
    scanner = profiles["scanner"]
    v2 = ms["slaves"]["valve2"]
    # every missed poll is the request and one retry, each timed out
    assert v2["timeouts"] == 2 * v2["missed"]
    lost = [e for e in scanner.events if isinstance(e, SlaveLost)]
    back = [e for e in scanner.events if isinstance(e, SlaveBack)]
    assert [(e.slave, e.missed) for e in lost] == [("valve2", 3)] and [e.slave for e in back] == ["valve2"]
    # the polls of 300, 305 and 310 ms missed: lost during the third, after two timeouts of 1 ms
    assert 310e6 + 2e6 < lost[0].time < 310e6 + 2e6 + 0.5e6
    # then polled every 10th cycle (50 ms): the first poll after the reconnection at 700 ms answers
    assert 700e6 < back[0].time < 700e6 + 50e6
    assert v2["missed"] == 3 + 7  # 360, 410, ..., 660 ms
    assert v2["lost"] is False and v2["lost_ms"] == [[lost[0].time / 1e6, back[0].time / 1e6]]
    # the others keep their cycle
    m = ms["masters"]["scanner"]
    assert m["cycles"] == 200 and m["overruns"] == 0
    for name, s in ms["slaves"].items():
        if name != "valve2":
            assert s["polls"] == s["responses"] == 200 and s["timeouts"] == 0, name
    assert m["clean_cycle_ms"]["max"] <= m["cycle_bound_ms"]
    # ten cycles wait for valve2's two timeouts: three before it is lost, then one every 50 ms
    assert scanner.clean_ns.n == 190 and scanner.cycle_ns.exact  # a short run keeps every cycle
    assert sorted(scanner.cycle_ns.values)[190] > m["cycle_bound_ms"] * 1e6 + 2 * 1e6 - 1e6
    # valve2's own watchdog: 20 ms (4 cycles) after the last request it received, and back at the next
    slave = profiles["valve2"]
    gone = [e for e in slave.events if isinstance(e, MasterLost)]
    again = [e for e in slave.events if isinstance(e, MasterBack)]
    assert len(gone) == 1 and gone[0].watchdog == 20_000_000
    assert 295e6 < gone[0].time - 20e6 < 300e6  # the request of the cycle at 295 ms
    assert len(again) == 1 and again[0].time < back[0].time


def bus_off_network(**stuck):
    raw = network(duration=0.2)
    raw["nodes"][0]["restart_after_bus_off"] = stuck.pop("restart", False)
    for s in raw["nodes"][1:]:
        s["watchdog_ms"] = 10
    raw["faults"] = [dict({"kind": "stuck", "node": "m", "level": "recessive", "start_ms": 50.5}, **stuck)]
    return raw


def test_a_master_that_goes_bus_off_stops_and_the_slaves_watchdogs_fire():
    res, profiles = run_built(bus_off_network(), record=True)
    master = profiles["m"]
    stops = [e for e in master.events if isinstance(e, MasterStopped)]
    assert len(stops) == 1 and stops[0].reason == "bus off" and master.state == "stopped"
    # nothing of the master reaches the bus after the fault, and nothing at all after bus off
    assert not [r for r in res.trace if r.kind == "frame" and r.start > 50.5e6]
    for name in ("s1", "s2", "s3", "s4"):
        slave = profiles[name]
        (gone,) = [e for e in slave.events if isinstance(e, MasterLost)]
        # the watchdog fires 10 ms after the last request the slave received (the cycle at 50 ms)
        last = max(r.end for r in res.trace if r.kind == "frame" and r.frame.key in slave.config.requests)
        assert gone.time == last + 10_000_000
        assert slave.state == "master lost"


def test_a_master_restarts_after_its_controller_recovers_and_the_slaves_see_it_back():
    res, profiles = run_built(bus_off_network(end_ms=120, restart=True))
    master = profiles["m"]
    assert master.state != "stopped"
    for name in ("s1", "s3"):
        slave = profiles[name]
        assert [type(e) for e in slave.events] == [MasterLost, MasterBack]
        assert 120e6 < slave.events[1].time < 125e6
    ms = res.to_json()["master_slave"]
    assert ms["masters"]["m"]["events"]["MasterStopped"] >= 1
    assert ms["slaves"]["s1"]["timeouts"] == 0  # a master that cannot send does not time its slaves out


def test_change_of_state_without_acknowledgement():
    raw = network()
    raw["nodes"].append(
        {
            "name": "door",
            "profile": "slave",
            "mac_id": 9,
            "messages": [{"name": "door_cos", "id": 0x349, "dlc": 1, "period_ms": 1}],
        }
    )
    raw["nodes"][0]["poll"].append({"style": "cos", "slave": "door", "ack": False})
    res, ms = run(raw)
    assert "ack_door" not in {r["name"] for r in res.to_json()["messages"]}
    door = ms["slaves"]["door"]
    assert door["cos"] == 20 and door["acks"] == 0 and door["acks_received"] == 0
    # an unacknowledged cyclic connection is the slave's only one: it consumes nothing, so it has
    # no watchdog and reports no loss of master (DeviceNet's watchdog times what a node consumes)
    assert door["master_lost"] == 0 and door["watchdog_ms"] == {}


def test_the_same_scenario_and_seed_give_the_same_results():
    sc = load_scenario(EXAMPLES / "master_slave.toml")
    a = run_scenario(copy.deepcopy(sc)).to_json()
    b = run_scenario(copy.deepcopy(sc)).to_json()
    assert a == b


# ---------------------------------------------------------------------------------------------- elsewhere


@pytest.mark.wallclock
def test_the_wall_clock_example_runs_on_python_cans_virtual_bus(rerun_until):
    """examples/master_slave_wallclock.toml: a cycle of 20 ms with 10 ms timeouts leaves Python's
    thread wake-ups room (the simulated example's 1 ms timeouts do not: see the README)."""

    def run():
        sc = load_scenario(EXAMPLES / "master_slave_wallclock.toml")
        res = run_on_pycan(sc, "virtual", f"polling-test-{random.random()}", duration_s=0.4)
        assert res.driver.startswith("virtual")
        ms = res.to_json()["master_slave"]
        for s in ms["slaves"].values():  # an answer never comes before its request
            assert s["response_ms"] is None or s["response_ms"]["min"] > 0
        return ms

    def timely(ms):  # a run whose timers fired in time: every poll answered, no slave lost
        return ms["masters"]["scanner"]["cycles"] >= 10 and all(
            s["polls"] >= 10 and s["responses"] >= s["polls"] - 1 and not s["lost"] for s in ms["slaves"].values()
        )

    rerun_until(run, timely)


def test_plot_of_the_poll_cycle(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    from stack.cli import main

    rc = main(
        ["experiment", str(EXAMPLES / "master_slave.toml"), "--plot", str(tmp_path), "--duration", "0.32", "--json"]
    )
    out, err = capsys.readouterr()
    assert rc == 0, err
    assert (tmp_path / "poll_cycle.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the cycles of the plot window ([plot] window_ms = [290, 320]): valve2 unplugged at 300 ms
    # makes them longer (two timeouts of 1 ms), not late
    cycles = json.loads(out)["master_slave"]["masters"]["scanner"]["window_cycles_ms"]
    assert [round(a) for a, _, _ in cycles] == [290, 295, 300, 305, 310, 315]
    lengths = [b - a for a, b, _ in cycles]
    bound = json.loads(out)["master_slave"]["masters"]["scanner"]["cycle_bound_ms"]
    assert all(x <= bound for x in lengths[:2] + lengths[5:])  # 315: valve2 lost, not polled
    assert all(x > 2 + 1.5 for x in lengths[2:5])
    assert not any(overrun for _, _, overrun in cycles)


def test_the_readmes_comparison_table_is_what_the_two_examples_measure():
    """The polling docs page, "Master/slave against CSMA/CR, the same I/O": every figure of the table, from a run
    of both scenario files."""
    readme = (EXAMPLES.parent / "docs" / "pages" / "experiments" / "polling.md").read_text(encoding="utf-8")
    ms = run_scenario(load_scenario(EXAMPLES / "master_slave_vs_csma_polled.toml")).to_json()
    cs = run_scenario(load_scenario(EXAMPLES / "master_slave_vs_csma_csma.toml")).to_json()
    tx = {t["slaves"][0]: t for t in ms["master_slave"]["masters"]["plc"]["transactions"]}
    rows = {r["name"]: r for r in cs["messages"]}
    for i in range(1, 9):
        t, s = tx[f"io{i}"], ms["master_slave"]["slaves"][f"io{i}"]
        out, inp = rows[f"out{i}"], rows[f"in{i}"]
        want = (
            f"| io{i} | {t['request_end_ms_max']:.3f} ({t['request_end_bound_ms']:.3f}) | "
            f"{t['response_ms_max']:.3f} ({t['bound_ms']:.3f}) | {s['jitter_ms']:.3f} | "
            f"{out['response_ms']['max']:.3f} ({out['rta_ms']:.3f}) | "
            f"{inp['response_ms']['max']:.3f} ({inp['rta_ms']:.3f}) | {inp['jitter_ms']:.3f} |"
        )
        assert want in readme
    m = ms["master_slave"]["masters"]["plc"]
    last = max(r["response_ms"]["max"] for r in cs["messages"])
    bound = max(r["rta_ms"] for r in cs["messages"])
    assert (
        f"| **all 16 frames of a period** | **{m['cycle_ms']['max']:.3f} ({m['cycle_bound_ms']:.3f})** | | | "
        f"**{last:.3f} ({bound:.3f})** | | |"
    ) in readme
    assert ms["frames"] == cs["frames"] == 6400
    assert f"**{100 * ms['bus_load']:.1f} %, 6400**" in readme and round(ms["bus_load"], 4) == round(cs["bus_load"], 4)
