"""The TDMA (TTCAN-like) profile on the simulated bus, against hand-worked times.

The network of most tests: 500 kbit/s (one bit = one NTU = 2 µs), a 5 ms basic cycle in a matrix
of 4, time masters gw (priority 0, reference 0x010) and eng (priority 1, 0x011), Initial_Ref_Offset
127 NTU = 254 µs, Tx_Enable 16 NTU = 32 µs.

At power-up every node is Synchronising with cycle time zero and both potential masters request a
reference message at the end of that first cycle plus their Initial_Ref_Offset: 5 ms + 254 µs.
They start together and arbitration picks gw (the lower identifier): reference k (k = 0, 1, …)
starts at 5.254 ms + k × 5 ms and carries Cycle_Count k mod 4. Nodes are in schedule after the
second reference message (ISO 11898-4 8.2), so messages go out from cycle 1 on: A at +500 µs in
every cycle, B at +1000 µs in even cycles, C at +1000 µs in odd cycles.
"""

from __future__ import annotations

import copy
from pathlib import Path

import pytest

from profiles.pipeline.runner import run_scenario
from profiles.pipeline.scenario import load_scenario, parse_scenario

ROOT = Path(__file__).resolve().parents[3]
BIT = 2000
FIRST_REF = 5_000_000 + 127 * BIT  # 5.254 ms
CYCLE = 5_000_000

NET = {
    "bus": {"bitrate": 500000, "duration": 0.1, "seed": 1},
    "nodes": [
        {"name": "gw", "profile": "tdma", "messages": [{"name": "A", "id": 0x100, "dlc": 8}]},
        {"name": "eng", "profile": "tdma", "messages": [{"name": "B", "id": 0x110, "dlc": 8}]},
        {"name": "abs", "profile": "tdma", "messages": [{"name": "C", "id": 0x120, "dlc": 4}]},
    ],
    "tdma": {
        "reference_id": 0x010,
        "time_masters": ["gw", "eng"],
        "basic_cycle_us": 5000,
        "matrix_cycles": 4,
        "windows": [
            {"start_us": 500, "length_us": 400, "kind": "exclusive", "messages": ["A"]},
            {"start_us": 1000, "length_us": 400, "kind": "exclusive", "messages": ["B"], "repeat": 2},
            {"start_us": 1000, "length_us": 400, "kind": "exclusive", "messages": ["C"], "repeat": 2, "base_cycle": 1},
        ],
    },
}


LEVEL_2 = {"tur": 16.0, "can_clock_mhz": 8.0}  # an NTU of 16 periods of an 8 MHz clock: 2 µs, one bit


def net(mutate=None):
    raw = copy.deepcopy(NET)
    if mutate is not None:
        mutate(raw)
    return raw


def run(raw, **kw):
    res = run_scenario(parse_scenario(raw, "net.toml"), record=True, **kw)
    return res, res.to_json()


def sofs(res, can_id, kind="frame"):
    return [r.start for r in res.trace if r.kind == kind and r.frame.can_id == can_id]


def row(data, name):
    return next(m for m in data["messages"] if m["name"] == name)


def tdma_row(data, name):
    return next(m for m in data["tdma"]["messages"] if m["name"] == name)


def test_fault_free_schedule_is_exact_to_the_nanosecond():
    res, data = run(net())
    t = data["tdma"]
    refs = [r for r in res.trace if r.frame.can_id in (0x010, 0x011)]
    n = len(refs)
    assert n == 19  # 5.254 ms + k x 5 ms < 100 ms
    assert [r.start for r in refs] == [FIRST_REF + k * CYCLE for k in range(n)]
    assert [r.frame.can_id for r in refs] == [0x010] * n
    assert [r.frame.data for r in refs] == [bytes([k % 4]) for k in range(n)]  # Cycle_Count
    assert sofs(res, 0x100) == [FIRST_REF + k * CYCLE + 500_000 for k in range(1, n)]
    assert sofs(res, 0x110) == [FIRST_REF + k * CYCLE + 1_000_000 for k in range(1, n) if k % 2 == 0]
    assert sofs(res, 0x120) == [FIRST_REF + k * CYCLE + 1_000_000 for k in range(1, n) if k % 2 == 1]
    assert t["outside"] == 0 and t["reference_messages"] == n and t["cycles_without_reference"] == 0
    assert t["master_switches"] == 0 and t["late_references"] == 0
    for m in t["messages"]:
        assert m["jitter_us"] * 1000 <= BIT and m["outside"] == 0 and m["late_starts"] == 0
    assert [(w["frames"], w["outside"], w["late_starts"]) for w in t["windows"]] == [(18, 0, 0), (9, 0, 0), (9, 0, 0)]
    assert t["nodes"]["gw"]["master_mode"] == "current_master"
    assert t["nodes"]["eng"]["master_mode"] == "backup_master"
    assert t["nodes"]["abs"] == {
        "sync_mode": "in_schedule",
        "master_mode": "time_slave",
        "watch_triggers": 0,
        "restarts": 0,
    }


def test_spine_rows_are_filled_for_tdma_messages():
    _, data = run(net())
    a = row(data, "A")
    # released at the window's start; 8 zero bytes after identifier 0x100: 108 bits and 15 stuff bits,
    # 123 bits SOF to EOF = 246 µs
    assert (a["released"], a["sent"], a["deadline_misses"]) == (18, 18, 0)
    assert a["response_ms"]["max"] == pytest.approx(0.246) and a["response_ms"]["min"] == a["response_ms"]["max"]
    assert a["period_ms"] == 5.0 and a["jitter_ms"] == 0.0  # start to start
    # the analytic bound (Tx_Enable + worst-case frame) is in the tdma section
    assert tdma_row(data, "A")["rta_ms"] == pytest.approx(0.296)
    assert a["response_ms"]["max"] <= tdma_row(data, "A")["rta_ms"]
    assert tdma_row(data, "B")["latency_bound_ms"] == pytest.approx(10.296)


def test_failover_within_the_watch_timeout_and_the_primary_returns_at_a_cycle_boundary():
    """examples/tdma.toml: the gateway (priority 0) is off the bus from 75 ms to 125 ms."""
    res = run_scenario(load_scenario(ROOT / "examples" / "tdma.toml"), record=True)
    t = res.to_json()["tdma"]
    # the reference due at 75.254 ms does not come: the engine sends its own after its
    # Initial_Ref_Offset, 127 NTU = 254 µs, and keeps the matrix (Cycle_Count goes on)
    # back at 125 ms, the gateway hears references at 125.508 and 130.508 ms (synchronised at the
    # second, ISO 11898-4 8.3), meets the engine at offset 0 at 135.508 ms and wins arbitration
    # the time after the previous reference is the 5000 µs basic cycle plus the time after its end
    assert t["switches"] == [
        {
            "at_ms": 75.508,
            "from": "gateway",
            "to": "engine",
            "after_reference_us": 5254.0,
            "after_cycle_end_us": 254.0,
            "cut_cycle_short": False,
        },
        {
            "at_ms": 135.508,
            "from": "engine",
            "to": "gateway",
            "after_reference_us": 5000.0,
            "after_cycle_end_us": 0.0,
            "cut_cycle_short": False,
        },
    ]
    assert t["master_switches"] == 2 and t["late_references"] == 1 and t["cycles_without_reference"] == 0
    refs = [r for r in res.trace if r.kind == "frame" and r.frame.can_id in (0x010, 0x011)]
    counts = [r.frame.data[0] & 0x3F for r in refs]
    assert counts == [k % 4 for k in range(len(refs))]
    gaps = {b.start - a.start for a, b in zip(refs, refs[1:])}
    assert gaps == {CYCLE, CYCLE + 127 * BIT}
    # the returning master never sent a reference before it was synchronised
    assert [r.start for r in refs if r.frame.can_id == 0x010 and 75_000_000 < r.start < 135_508_000] == []
    assert t["outside"] == 0
    assert t["nodes"]["gateway"]["watch_triggers"] == 1  # it lost the schedule once, off the bus
    assert t["nodes"]["gateway"]["master_mode"] == "current_master"
    assert t["nodes"]["engine"]["master_mode"] == "backup_master"


def test_every_master_gone_the_network_restarts_after_the_init_watch_trigger():
    """Both potential masters are off the bus from 40 to 70 ms. The last reference started at
    35.254 ms; every node reaches its Watch_Trigger 5.768 ms later — the basic cycle, the backups'
    254 µs, the reference's 130 µs and room for its repetition after an error frame, 2 x (65 + 31)
    bits = 384 µs — at 41.022 ms and restarts. The masters failed, so back on the bus they only
    listen (ISO 11898-4 8.3) — and nobody talks: after a whole Init_Watch_Trigger of silence
    (65535 NTU = 131.07 ms, at 172.092 ms) they may start the network again, like at power-up:
    their references meet at 172.092 + 5.254 = 177.346 ms, gw wins, and the matrix starts over at
    Cycle_Count 0."""

    def m(raw):
        raw["bus"]["duration"] = 0.2
        raw["faults"] = [
            {"kind": "disconnect", "node": "gw", "at_ms": 40, "reconnect_ms": 70},
            {"kind": "disconnect", "node": "eng", "at_ms": 40, "reconnect_ms": 70},
        ]

    res, data = run(net(m))
    t = data["tdma"]
    refs = [r for r in res.trace if r.kind == "frame" and r.frame.can_id in (0x010, 0x011)]
    after = [(r.start, r.frame.can_id, r.frame.data) for r in refs if r.start > 36_000_000]
    assert after[:2] == [(177_346_000, 0x010, b"\x00"), (182_346_000, 0x010, b"\x01")]
    # basic cycles that passed with no reference at all (due 40.254 ms on, each past the watch slack)
    assert t["cycles_without_reference"] == (177_346_000 - 35_254_000 - 768_000) // CYCLE == 28
    for name in ("gw", "eng", "abs"):
        assert t["nodes"][name]["watch_triggers"] == 1
    assert t["master_switches"] == 0 and t["outside"] == 0
    assert t["nodes"]["gw"]["master_mode"] == "current_master"


def test_a_master_stuck_recessive_goes_bus_off_while_the_backup_keeps_the_schedule():
    """gw's transmitter is stuck recessive from 40 to 120 ms: its reference at 40.254 ms fails
    (bit errors, error passive), the engine's arrives 254 µs after the cycle end. In later cycles
    both request at offset 0; the simulated bus gives gw's attempt the bus first (the lower
    identifier), it fails, and the engine's request — still active, no reference has completed —
    goes out right after it. gw reaches bus off, recovers, listens until it is synchronised
    (ISO 11898-4 8.3), fails again …; when the fault ends it takes the schedule back."""

    def m(raw):
        raw["bus"]["duration"] = 0.15
        raw["faults"] = [{"kind": "stuck", "node": "gw", "level": "recessive", "start_ms": 40, "end_ms": 120}]

    res, data = run(net(m))
    t = data["tdma"]
    first = t["switches"][0]
    assert (first["at_ms"], first["from"], first["to"], first["after_cycle_end_us"]) == (40.508, "gw", "eng", 254.0)
    assert first["cut_cycle_short"] is False
    for sw in t["switches"]:  # never a negative time after a cycle's end
        assert sw["after_cycle_end_us"] >= 0 and sw["after_reference_us"] >= 0
    assert t["switches"][-1]["to"] == "gw" and t["switches"][-1]["at_ms"] > 120
    assert t["cycles_without_reference"] == 0 and t["outside"] == 0
    assert t["nodes"]["gw"]["bus_off"] >= 1 and t["nodes"]["gw"]["master_mode"] == "current_master"
    assert t["nodes"]["eng"]["watch_triggers"] == t["nodes"]["abs"]["watch_triggers"] == 0
    refs = [r for r in res.trace if r.frame.can_id in (0x010, 0x011)]
    followed = 0
    for a, b in zip(refs, refs[1:]):
        # from the second cycle on, both request at the cycle end: the engine's waits for gw's
        # failed attempt and starts after the intermission
        if a.kind == "error" and a.start > 41_000_000 and b.start - a.end < CYCLE // 2:
            assert (b.kind, b.frame.can_id, b.start) == ("frame", 0x011, a.end + 3 * BIT)
            followed += 1
    assert followed >= 5
    ok = [r for r in refs if r.kind == "frame"]
    assert all(r.frame.can_id == 0x011 for r in ok if 40_500_000 < r.start < 120_000_000)
    assert max(b.start - a.start for a, b in zip(ok, ok[1:])) < CYCLE + 127 * BIT + 100 * BIT


def test_tx_enable_misses_are_counted_and_never_sent_late():
    """An ungated CSMA frame (0x050, 8 bytes) starts 100 µs before A's window in every cycle and
    holds the bus past A's Tx_Enable window (32 µs): A is withdrawn every time, never sent late."""

    def m(raw):
        raw["nodes"].append(
            {
                "name": "body",
                "profile": "csma",
                "tdma_gated": False,
                "messages": [
                    {"name": "Blocker", "id": 0x050, "dlc": 8, "period_ms": 5, "offset_ms": (FIRST_REF + 400_000) / 1e6}
                ],
            }
        )

    res, data = run(net(m))
    a = tdma_row(data, "A")
    assert a["late_starts"] == 18 and a["frames"] == 0
    assert sofs(res, 0x100) == []
    assert row(data, "A")["deadline_misses"] == 18 and row(data, "A")["failed"] == 18
    w1 = data["tdma"]["windows"][0]
    assert (w1["late_starts"], w1["intrusions"]) == (18, 19)


def test_one_shot_in_exclusive_windows_a_flipped_bit_is_not_retried():
    def m(raw):
        raw["faults"] = [{"kind": "flip", "id": 0x100, "occurrence": 3, "field": "data", "bit": 0}]

    res, data = run(net(m))
    errors = [r for r in res.trace if r.kind != "frame" and r.frame.can_id == 0x100]
    assert [r.start for r in errors] == [FIRST_REF + 3 * CYCLE + 500_000]
    # no retransmission in that window: A's next frame is in its next window
    assert sofs(res, 0x100) == [FIRST_REF + k * CYCLE + 500_000 for k in range(1, 19) if k != 3]
    a = tdma_row(data, "A")
    assert (a["failed"], a["frames"], a["outside"]) == (1, 17, 0)
    assert data["tdma"]["windows"][0]["failed"] == 1
    assert row(data, "A")["failed"] == 1


@pytest.mark.parametrize("level", [1, 2])
def test_a_disturbed_reference_is_repeated_at_once_with_an_updated_master_ref_mark(level):
    def m(raw):
        raw["tdma"]["level"] = level
        if level == 2:
            raw["tdma"].update(LEVEL_2)
        raw["faults"] = [{"kind": "flip", "id": 0x010, "occurrence": 5, "field": "data", "bit": 0}]

    res, data = run(net(m))
    err = next(r for r in res.trace if r.kind != "frame" and r.frame.can_id == 0x010)
    assert err.start == FIRST_REF + 4 * CYCLE
    retry = next(r for r in res.trace if r.kind == "frame" and r.start > err.start)
    assert retry.frame.can_id == 0x010 and retry.start == err.end + 3 * BIT  # after the intermission
    assert retry.frame.data[0] == 4 % 4  # the same Cycle_Count (reference 4 of a matrix of 4)
    t = data["tdma"]
    assert t["nodes"]["gw"]["reference_retransmissions"] == 1 and t["outside"] == 0
    if level == 2:
        # the mark went out updated: the receivers' time unit ratio stays exact
        mark = (retry.frame.data[2] | retry.frame.data[3] << 8) << 7 | retry.frame.data[1] >> 1
        assert mark * BIT / 128 == pytest.approx(retry.start, abs=BIT / 128)
        assert {n["tur"] for n in t["nodes"].values()} == {1.0}
    # the cycle restarts at the repeated reference: A follows it 500 µs later
    assert retry.start + 500_000 in sofs(res, 0x100)


DRIFT = 2000.0  # ppm, both ways


def drifting(level):
    """A 60 ms basic cycle (30000 NTU) with a perfect time master and two senders whose clocks are
    2000 ppm fast and slow, windows of 320 µs at 50 ms and 55 ms."""
    return {
        "bus": {"bitrate": 500000, "duration": 0.5, "seed": 1},
        "nodes": [
            {"name": "master", "profile": "tdma"},
            {
                "name": "fast",
                "profile": "tdma",
                "drift_ppm": DRIFT,
                "messages": [{"name": "Fast", "id": 0x100, "dlc": 8}],
            },
            {
                "name": "slow",
                "profile": "tdma",
                "drift_ppm": -DRIFT,
                "messages": [{"name": "Slow", "id": 0x101, "dlc": 8}],
            },
        ],
        "tdma": {
            "reference_id": 0x10,
            "time_masters": ["master"],
            "basic_cycle_us": 60000,
            "level": level,
            **(LEVEL_2 if level == 2 else {}),
            "windows": [
                {"start_us": 50000, "length_us": 320, "kind": "exclusive", "messages": ["Fast"]},
                {"start_us": 55000, "length_us": 320, "kind": "exclusive", "messages": ["Slow"]},
            ],
        },
    }


def test_level_1_drifts_out_of_its_windows_where_level_2_holds():
    _, d1 = run(drifting(1))
    _, d2 = run(drifting(2))
    fast1, slow1 = tdma_row(d1, "Fast"), tdma_row(d1, "Slow")
    # level 1 counts the cycle on the local clock: 50 ms of a clock 2000 ppm fast pass in
    # 50 ms / 1.002 of bus time, 99.8 µs early; 55 ms of one 2000 ppm slow take 55 ms / 0.998,
    # 110.22 µs late
    assert fast1["start_offset_us"]["min"] == pytest.approx(-50_000 * DRIFT * 1e-6 / (1 + DRIFT * 1e-6), abs=BIT / 1000)
    assert slow1["start_offset_us"]["max"] == pytest.approx(55_000 * DRIFT * 1e-6 / (1 - DRIFT * 1e-6), abs=BIT / 1000)
    assert fast1["outside"] == fast1["frames"] > 0 and slow1["outside"] == slow1["frames"] > 0
    assert d1["tdma"]["outside"] == 2 * fast1["frames"]
    # level 2 measures the cycle in the master's time units (TUR from two reference messages)
    t2 = d2["tdma"]
    assert t2["outside"] == 0
    for name in ("Fast", "Slow"):
        r = tdma_row(d2, name)
        assert r["frames"] == fast1["frames"] and r["late_starts"] == 0
        assert abs(r["start_offset_us"]["min"]) * 1000 <= BIT and abs(r["start_offset_us"]["max"]) * 1000 <= BIT
    assert t2["nodes"]["fast"]["tur"] == pytest.approx(1 / (1 + DRIFT * 1e-6), abs=1e-7)
    assert t2["nodes"]["slow"]["tur"] == pytest.approx(1 / (1 - DRIFT * 1e-6), abs=1e-7)


MIXED_WINDOW = {"start_us": 1500, "length_us": 3000, "kind": "arbitrating"}


def mixed(gated):
    def m(raw):
        raw["bus"]["duration"] = 0.3
        raw["tdma"]["windows"].append(dict(MIXED_WINDOW))
        raw["nodes"].append(
            {
                "name": "body",
                "profile": "csma",
                "tdma_gated": gated,
                "messages": [
                    {"name": "Lights", "id": 0x050, "dlc": 8, "period_ms": 3, "jitter_ms": 1},
                    {"name": "Doors", "id": 0x400, "dlc": 8, "period_ms": 7},
                ],
            }
        )

    return net(m)


def test_a_gated_csma_node_sends_only_in_arbitrating_windows():
    res, data = run(mixed(True))
    t = data["tdma"]
    assert t["outside"] == 0 and t["gated"]["body"]["outside"] == 0 and t["gated"]["body"]["frames"] > 100
    refs = [r.start for r in res.trace if r.frame.can_id == 0x010]
    for r in res.trace:
        if r.frame.can_id in (0x050, 0x400):
            ref = max(x for x in refs if x <= r.start)
            assert ref + 1_500_000 <= r.start and r.end <= ref + 4_500_000
    for w in t["windows"][:3]:
        assert (w["late_starts"], w["intrusions"], w["lost_arbitration"]) == (0, 0, 0)
        assert all(m["jitter_us"] == 0 for m in t["messages"])
    assert t["nodes"]["body"]["gated"] is True and t["nodes"]["body"]["gate_wait_ms"]["max"] > 0


def test_an_ungated_csma_node_breaks_the_schedule():
    _, data = run(mixed(False))
    t = data["tdma"]
    assert t["outside"] > 0 and t["unscheduled"]["outside"] > 0
    excl = t["windows"][:3]
    assert sum(w["intrusions"] for w in excl) > 0
    assert sum(w["late_starts"] + w["lost_arbitration"] for w in excl) > 0
    # the TDMA frames that do go out still start within Tx_Enable: never late
    for m in t["messages"]:
        assert m["outside"] == 0 and m["start_offset_us"]["max"] <= 32


def test_deterministic():
    _, a = run(mixed(True))
    _, b = run(mixed(True))
    assert a == b


def test_example_schedule_plot(tmp_path):
    pytest.importorskip("matplotlib")
    from profiles.pipeline.cli import _profile_plots

    sc = load_scenario(ROOT / "examples" / "tdma.toml")
    res = run_scenario(sc, record=True)
    plots = _profile_plots(sc)
    assert list(plots) == ["tdma_schedule"]
    out = plots["tdma_schedule"](res, tmp_path / "s.png")
    assert out.stat().st_size > 10_000


def arbitration(kind):
    """A (gw, 0x100) and C (abs, 0x120) share an arbitrating window at 500 µs in even basic cycles;
    C alone has one at the same time in odd cycles."""

    def m(raw):
        raw["tdma"]["windows"] = [
            {"start_us": 500, "length_us": 800, "kind": "arbitrating", "arbitration": kind, "messages": ["A", "C"]},
            {"start_us": 1500, "length_us": 400, "kind": "exclusive", "messages": ["B"]},
        ]
        raw["tdma"]["windows"][0].update(repeat=2, base_cycle=0)
        raw["tdma"]["windows"].append(
            {
                "start_us": 500,
                "length_us": 800,
                "kind": "arbitrating",
                "arbitration": kind,
                "messages": ["C"],
                "repeat": 2,
                "base_cycle": 1,
            }
        )

    return net(m)


def test_a_single_arbitrating_window_starts_only_in_tx_enable_and_does_not_retry():
    res, data = run(arbitration("single"))
    refs = sofs(res, 0x010)
    a, c = sofs(res, 0x100), sofs(res, 0x120)
    even = [r for k, r in enumerate(refs) if k % 2 == 0 and k >= 2]
    odd = [r for k, r in enumerate(refs) if k % 2 == 1 and k >= 1]
    assert len(a) >= 8 and len(c) >= 8
    # A wins every even cycle at the window's start; C lost arbitration there and is not repeated
    # in that window: it goes at its next trigger, the odd cycle's window, at the start
    assert set(a) == {r + 500_000 for r in even if r + 500_000 < res.scenario.duration_ns}
    assert set(c) == {r + 500_000 for r in odd if r + 500_000 < res.scenario.duration_ns}
    row = tdma_row(data, "C")
    assert row["lost_arbitration"] == len(a) and row["outside"] == 0
    assert data["tdma"]["windows"][0]["lost_arbitration"] == len(a)


def test_a_merged_arbitrating_window_lets_the_loser_start_later_in_it():
    res, data = run(arbitration("merged"))
    a = [r for r in res.trace if r.kind == "frame" and r.frame.can_id == 0x100]
    c = sofs(res, 0x120)
    assert len(a) >= 8
    # in even cycles C retries after A, 3 bits (the intermission) after A's end
    for fa in a:
        assert fa.end + 3 * BIT in c
    assert tdma_row(data, "C")["lost_arbitration"] == 0  # a retry that succeeds is no loss here
    assert data["tdma"]["outside"] == 0


def test_level_2_times_its_reference_in_the_configured_ntu():
    """tur 8 of an 8 MHz clock: an NTU of 1 µs. The first reference comes at the end of the first
    basic cycle plus Initial_Ref_Offset 127 NTU = 127 µs (not the 254 µs of 127 bit times), and its
    Master_Ref_Mark counts 1 µs NTUs with 1/128 NTU fractions."""

    def m(raw):
        raw["tdma"].update(level=2, tur=8.0, can_clock_mhz=8.0)

    res, data = run(net(m))
    refs = [r for r in res.trace if r.kind == "frame" and r.frame.can_id == 0x010]
    assert refs[0].start == 5_000_000 + 127_000
    for r in refs[:5]:
        d = r.frame.data
        mark = (d[2] | d[3] << 8) << 7 | d[1] >> 1
        assert mark / 128 * 1000 == pytest.approx(r.start, abs=1000 / 128)  # NTU of 1 µs
    assert data["tdma"]["tx_enable_us"] == 16  # the default 16 NTU of 1 µs
    # the schedule holds: A at each window start
    assert {r.start + 500_000 for r in refs[1:-1]} <= set(sofs(res, 0x100))


# ---------------------------------------------------------------------------------------------
# A master switch that cuts the old master's cycle short
# A master switch that cuts the old master's basic cycle short (issue 26): the returning primary
# whose oscillator is slow starts its reference message earlier, one NTU a cycle (ISO 11898-4
# 9.5.1, Ref_Trigger_Offset down to -127), until it wins — inside the cycle the backup started.
# The monitor reports the switch with ``cut_cycle_short`` and no time after the cycle's end
# (never a negative one).
#
# Worked by hand from the schedule of `NET` (500 kbit/s, NTU = one bit = 2 µs, 5 ms
# basic cycle, Initial_Ref_Offset 127 NTU) with gw's clock 1000 ppm slow:
#
# - at power-up both masters request at the end of the first cycle plus 127 NTU, each on its own
#   clock: eng (exact) at 5.254 ms, gw at 5.254 ms local = 5.259 ms on the bus: eng's reference
#   goes first and eng is the current master, its references every 5 ms from 5.254 ms;
# - gw is in schedule after the second reference (10.254 ms), a backup that sees a current master
#   of lower priority: its offset becomes 0, then -1, -2, -3 NTU at the references of 15.254,
#   20.254 and 25.254 ms;
# - a gw cycle of 5000 µs local lasts 5000 / 0.999 = 5005.005 µs on the bus: at offset 0, -1, -2 gw
#   requests 5005.0, 5003.0, 5001.0 µs after eng's reference and loses to eng's request at 5000 µs
#   (its request is withdrawn when eng's reference completes); at -3 NTU it requests
#   (5000 - 6) / 0.999 = 4998.999 µs after the reference of 25.254 ms and sends alone;
# - that is 4998.999 µs after the last reference: shorter than a cycle of the new master (5005.005
#   µs on the bus), so the switch cut the cycle short and comes 0 µs after its end.

SLOW_GW_PPM = -1000.0


def _gw_local(t_bus: int) -> int:
    """gw's local time at bus time ``t_bus``: local = bus x (1 + ppm 1e-6), to the ns."""
    return t_bus + round(t_bus * SLOW_GW_PPM * 1e-6)


def _gw_bus(t_local: int) -> int:
    """The first bus ns at which gw's local clock reads ``t_local``."""
    t = round(t_local / (1 + SLOW_GW_PPM * 1e-6)) - 2
    while _gw_local(t) < t_local:
        t += 1
    return t


def test_a_slow_primary_takes_over_by_cutting_the_backups_cycle_short():
    def slow_gw(raw):
        raw["bus"]["duration"] = 0.05
        raw["nodes"][0]["drift_ppm"] = SLOW_GW_PPM

    res, data = run(net(slow_gw))
    t = data["tdma"]
    ntu, cycle, first = 2_000, 5_000_000, 5_254_000
    eng_refs = [first + k * cycle for k in range(5)]  # eng's references until gw wins
    ref = eng_refs[-1]
    takeover = _gw_bus(_gw_local(ref) + cycle - 3 * ntu)
    assert takeover == 30_252_999  # 4998.999 µs after eng's reference of 25.254 ms
    assert t["switches"] == [
        {
            "at_ms": takeover / 1e6,
            "from": "eng",
            "to": "gw",
            "after_reference_us": (takeover - ref) / 1000,
            "after_cycle_end_us": 0.0,
            "cut_cycle_short": True,
        }
    ]
    assert (takeover - ref) < _gw_bus(_gw_local(ref) + cycle) - ref  # shorter than gw's own cycle
    refs = [(r.start, r.frame.can_id) for r in res.trace if r.kind == "frame" and r.frame.can_id in (0x010, 0x011)]
    assert refs[:6] == [(s, 0x011) for s in eng_refs] + [(takeover, 0x010)]
    assert t["master_switches"] == 1 and t["nodes"]["gw"]["master_mode"] == "current_master"
