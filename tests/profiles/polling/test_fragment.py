"""DeviceNet I/O fragmentation: the fragment byte against a published example (ICP DAS I-7242D
manual, §7.2.11: 10 bytes 01..0A on a poll command go as ``00 01 .. 07`` and ``81 08 09 0A``),
the receiver's rules, and a polled slave with 20 bytes of outputs and 12 of inputs on the
simulated bus, timed against the frame lengths worked out here."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from profiles.pipeline.runner import run_scenario
from profiles.pipeline.scenario import parse_scenario
from profiles.polling.analysis import transaction_bound_ns
from profiles.polling.fragment import FIRST, LAST, MIDDLE, Reassembler, decode_header, encode_header, fragment
from profiles.schema import ScenarioError
from stack import Frame

BIT = 2000  # ns at 500 kbit/s


def test_the_published_example():
    data = bytes(range(1, 11))
    assert fragment(data) == [bytes([0x00, 1, 2, 3, 4, 5, 6, 7]), bytes([0x81, 8, 9, 10])]
    assert decode_header(0x81) == (LAST, 1)
    assert encode_header(MIDDLE, 65) == 0x41  # the count runs modulo 64


def test_counts_wrap_after_63_and_types_are_first_middle_last():
    frames = fragment(bytes(7 * 70))
    kinds = [decode_header(f[0]) for f in frames]
    assert kinds[0] == (FIRST, 0) and kinds[-1] == (LAST, 69 % 64)
    assert all(k == MIDDLE for k, _ in kinds[1:-1]) and [c for _, c in kinds] == [i % 64 for i in range(70)]
    with pytest.raises(ValueError, match="fit one CAN frame"):
        fragment(bytes(8))


@given(st.binary(min_size=9, max_size=255))
def test_reassembly_gives_back_the_message(data):
    r = Reassembler(len(data))
    out = [r.feed(f) for f in fragment(data)]
    assert out[:-1] == [None] * (len(out) - 1) and out[-1] == data and r.messages == 1


def test_the_receivers_rules():
    data = bytes(range(30))  # 5 fragments
    f = fragment(data)
    r = Reassembler(30)
    # a duplicate is ignored, the message still completes
    assert [r.feed(x) for x in [f[0], f[1], f[1], f[2], f[3], f[4]]][-1] == data and r.duplicates == 1
    # a lost middle fragment drops the message; fragments are ignored until the next first one
    assert [r.feed(x) for x in [f[0], f[1], f[3], f[4]]] == [None] * 4 and r.dropped == 1 and r.ignored == 1
    assert [r.feed(x) for x in f][-1] == data
    # a first fragment restarts an unfinished message
    assert [r.feed(x) for x in [f[0], f[1], *f]][-1] == data and r.dropped == 2
    # a middle or last fragment without a first one is ignored; a message of the wrong size dropped
    r2 = Reassembler(31)
    assert r2.feed(f[2]) is None and r2.ignored == 1
    assert [r2.feed(x) for x in f][-1] is None and r2.dropped == 1 and r2.messages == 0


# ---------------------------------------------------------------------------------------------- on the bus

OUT = bytes(range(0x10, 0x24))  # 20 bytes: fragments of 7, 7 and 6 data bytes
IN = bytes(range(0xA0, 0xAC))  # 12 bytes: 7 and 5


def network(**entry):
    return {
        "bus": {"bitrate": 500000, "duration": 0.02, "seed": 1},
        "analysis": {"stuffing": "exact"},
        "nodes": [
            {
                "name": "m",
                "profile": "master",
                "cycle_ms": 5,
                "timeout_ms": 2,
                "poll": [dict({"slave": "s1", "data": OUT.hex()}, **entry)],
            },
            {
                "name": "s1",
                "profile": "slave",
                "mac_id": 1,
                "processing_ms": 0.05,
                "messages": [{"name": "s1_in", "id": 0x3C1, "dlc": 8, "size": 12, "io_data": IN.hex()}],
            },
        ],
    }


def test_a_fragmented_poll_goes_back_to_back_and_the_answer_follows_the_last_fragment():
    kept: dict = {}
    sc = parse_scenario(network(), "frag.toml")
    res = run_scenario(sc, setup=lambda b: kept.update(b.profiles), record=True)
    frames = [r for r in res.trace if r.kind == "frame"]
    req = [r for r in frames if r.frame.can_id == 0x40D][:3]
    resp = [r for r in frames if r.frame.can_id == 0x3C1][:2]
    out_frames = [bytes([0x00]) + OUT[:7], bytes([0x41]) + OUT[7:14], bytes([0x82]) + OUT[14:]]
    in_frames = [bytes([0x00]) + IN[:7], bytes([0x81]) + IN[7:]]
    assert [r.frame.data for r in req] == out_frames and [r.frame.data for r in resp] == in_frames
    # back to back: each fragment 3 bits (intermission) after the previous one
    for a, b in ((req[0], req[1]), (req[1], req[2]), (resp[0], resp[1])):
        assert b.start == a.end + 3 * BIT
    # the slave answers 50 us after the end of the last fragment (its processing delay)
    assert resp[0].start == req[2].end + 50_000
    assert kept["s1"].outputs[Frame(0x40D, b"").key] == OUT
    # the exchange: first request SOF to the last answer's end, exactly the frame lengths
    lengths = [Frame(0x40D, d).bits.length for d in out_frames] + [Frame(0x3C1, d).bits.length for d in in_frames]
    exchange = (sum(lengths[:3]) + 2 * 3) * BIT + 50_000 + (sum(lengths[3:]) + 3) * BIT
    assert resp[1].end - req[0].start == exchange
    ms = res.to_json()["master_slave"]
    s1 = ms["slaves"]["s1"]
    assert s1["polls"] == s1["responses"] == 4 and s1["response_ms"]["max"] * 1e6 == exchange
    tx = sc.tables["master_slave"].masters["m"].transactions[0]
    assert transaction_bound_ns(tx, sc.tables["master_slave"].slaves, 500_000, "exact") == exchange
    # worst-case stuffing bounds it
    assert transaction_bound_ns(tx, sc.tables["master_slave"].slaves, 500_000) >= exchange


def test_the_analysis_bounds_a_fragmented_poll_on_a_shared_bus():
    raw = network()
    raw["bus"]["duration"] = 0.3
    raw["nodes"].append(
        {
            "name": "ecu",
            "profile": "csma",
            "messages": [
                {"name": "fast", "id": 0x100, "dlc": 8, "period_ms": 1},
                {"name": "slow", "id": 0x600, "dlc": 8, "period_ms": 3, "offset_ms": 0.4},
            ],
        }
    )
    res = run_scenario(parse_scenario(raw, "frag.toml"))
    data = res.to_json()
    m = data["master_slave"]["masters"]["m"]
    assert m["bound_method"].startswith("holistic")
    (t,) = m["transactions"]
    assert t["response_ms_max"] <= t["rta_bound_ms"] and m["cycle_ms"]["max"] <= m["cycle_bound_ms"]
    for row in data["messages"]:
        assert row["response_ms"]["max"] <= row["rta_ms"], row["name"]


@pytest.mark.parametrize(
    "mutate, message",
    [
        (
            lambda r: r["nodes"][0]["poll"][0].update(data="00" * 256),
            "data: 256 bytes: canstack takes I/O of at most 255",
        ),
        (lambda r: r["nodes"][0]["poll"][0].update(dlc=8), "dlc: 20 bytes of data go in DeviceNet fragments"),
        (lambda r: r["nodes"][1]["messages"][0].update(size=8), "size: 8"),
        (lambda r: r["nodes"][1]["messages"][0].update(dlc=7), "dlc: 7: the fragments of a 12-byte message"),
        (lambda r: r["nodes"][1]["messages"][0].update(io_data="00"), "io_data: 1 bytes given for size 12"),
        (
            lambda r: (
                r["nodes"][0]["poll"][0].update(style="bit_strobe", slaves=["s1"], slave=None)
                or r["nodes"][0]["poll"][0].pop("slave")
            ),
            "data: 20 bytes: a CAN 2.0 frame carries at most 8",
        ),
    ],
)
def test_bad_fragmentation_keys_are_one_line(mutate, message):
    raw = network()
    mutate(raw)
    with pytest.raises(ScenarioError) as exc:
        parse_scenario(raw, "frag.toml")
    assert message in str(exc.value) and "\n" not in str(exc.value)


def test_a_strobe_response_is_never_fragmented():
    raw = network()
    raw["nodes"][0]["poll"] = [{"style": "bit_strobe", "slaves": ["s1"]}]
    raw["nodes"][1]["messages"][0]["id"] = 0x381
    with pytest.raises(ScenarioError, match="canstack fragments polled I/O only"):
        parse_scenario(raw, "frag.toml")
