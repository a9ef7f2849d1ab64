"""The [tdma] table: every refusal of the scenario checker names the file, the table, the key and
the rule; the reference message layout; the analytic bounds of exclusive windows (hand-worked at
500 kbit/s, one bit = 2 µs = one NTU)."""

from __future__ import annotations

import copy

import pytest
from hypothesis import given
from hypothesis import strategies as st

from profiles.pipeline.scenario import parse_scenario
from profiles.schema import ScenarioError
from profiles.tdma.monitor import message_bounds
from profiles.tdma.schedule import (
    MARK_MODULUS,
    ReferenceInfo,
    Window,
    decode_reference,
    encode_reference,
    frame_ns_worst,
)

BASE = {
    "bus": {"bitrate": 500000, "duration": 0.1},
    "nodes": [
        {"name": "gw", "profile": "tdma", "messages": [{"name": "A", "id": 0x100, "dlc": 8}]},
        {
            "name": "eng",
            "profile": "tdma",
            "messages": [{"name": "B", "id": 0x110, "dlc": 8}, {"name": "E", "id": 0x111, "dlc": 1}],
        },
        {"name": "abs", "profile": "tdma", "messages": [{"name": "C", "id": 0x120, "dlc": 4}]},
        {"name": "body", "profile": "csma", "messages": [{"name": "L", "id": 0x400, "dlc": 8, "period_ms": 10}]},
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
            {"start_us": 1500, "length_us": 2000, "kind": "arbitrating", "messages": ["E"]},
            {"start_us": 4000, "length_us": 500, "kind": "free"},
        ],
    },
}


def scenario(mutate=None):
    raw = copy.deepcopy(BASE)
    if mutate is not None:
        mutate(raw)
    return parse_scenario(raw, "net.toml")


def window(raw, i):
    return raw["tdma"]["windows"][i - 1]


def test_the_base_schedule_is_accepted_and_stored():
    sc = scenario()
    s = sc.tables["tdma"]
    assert s.basic_cycle_ns == 5_000_000 and s.matrix_cycles == 4 and s.level == 1
    assert s.tx_enable_ns == 32_000  # default: 16 NTU of 2 µs
    assert s.reference_ids == (0x010, 0x011)
    assert s.gated == ("body",)
    # a message with one window gets its period from the matrix: repeat x basic cycle
    msgs = {m.name: m for m in sc.messages}
    assert msgs["A"].period_ns == 5_000_000 and msgs["B"].period_ns == 10_000_000
    assert msgs["L"].period_ns == 10_000_000  # CSMA messages keep theirs


def refuse(mutate, *parts):
    with pytest.raises(ScenarioError) as e:
        scenario(mutate)
    text = str(e.value)
    assert text.startswith("net.toml: "), text
    assert "\n" not in text
    for p in parts:
        assert p in text, text
    return text


# -- the refusals the issue lists ------------------------------------------------------------


def test_overlapping_windows_are_refused():
    def m(raw):
        window(raw, 2)["start_us"] = 800  # 800..1200 overlaps window 1 (500..900) in every cycle

    refuse(
        m, "[tdma] > [[tdma.windows]] #2: start_us:", "overlaps window #1 (exclusive, 500..900 µs)", "in basic cycle 0"
    )


def test_windows_at_the_same_time_in_different_matrix_rows_do_not_overlap():
    s = scenario().tables["tdma"]  # windows 2 and 3 share 1000..1400 µs: B in even, C in odd cycles
    assert [w.active(c) for c in range(4) for w in s.windows[1:3]] == [True, False, False, True] * 2


def test_a_message_that_does_not_fit_its_window_is_refused():
    # 8 bytes: 135 bits worst case with intermission = 270 µs, + Tx_Enable 32 µs = 302 µs
    def m(raw):
        window(raw, 1)["length_us"] = 300

    refuse(
        m,
        "[[tdma.windows]] #1: length_us:",
        "message 'A' does not fit",
        "270 µs (135 bits",
        "Tx_Enable window of 32 µs",
        "needs 302 µs, the window is 300 µs",
    )


def test_the_error_budget_counts_in_the_fit():
    def m(raw):
        raw["tdma"]["error_budget_bits"] = 50  # + 100 µs: 402 µs > 400 µs

    refuse(m, "[[tdma.windows]] #1: length_us:", "plus the error budget 100 µs", "needs 402 µs")


def test_a_window_past_the_cycle_end_is_refused():
    def m(raw):
        window(raw, 5)["length_us"] = 1200  # 4000 + 1200 > 5000

    refuse(m, "[[tdma.windows]] #5: length_us:", "ends at 5200 µs, past the end of the basic cycle (5000 µs")


def test_a_repeat_that_is_not_a_power_of_two_is_refused():
    def m(raw):
        window(raw, 2)["repeat"] = 3

    refuse(m, "[[tdma.windows]] #2: repeat: 3 is not a power of two")


def test_an_exclusive_window_from_two_nodes_is_refused():
    def m(raw):
        window(raw, 1)["messages"] = ["A", "C"]

    refuse(
        m,
        "[[tdma.windows]] #1: messages: 'C' (node 'abs') and 'A' (node 'gw'): an exclusive window belongs to one node",
    )


# -- the other rules -------------------------------------------------------------------------


@pytest.mark.parametrize(
    "mutate, parts",
    [
        (
            lambda r: window(r, 1).update(messages=["A", "E"]) or r["tdma"]["windows"].pop(3),
            ["#1: messages:", "belongs to one node"],
        ),
        (
            lambda r: window(r, 2).update(messages=["B", "E"]) or r["tdma"]["windows"].pop(3),
            ["#2: messages: an exclusive window carries exactly one message (got 2)"],
        ),
        (lambda r: window(r, 2).update(repeat=8), ["#2: repeat: 8 is more than matrix_cycles 4"]),
        (lambda r: window(r, 3).update(base_cycle=2), ["#3: base_cycle: 2 must be below repeat 2"]),
        (
            lambda r: r["tdma"].update(matrix_cycles=3),
            ["[tdma]: matrix_cycles: 3 is not one of 1, 2, 4, 8, 16, 32, 64"],
        ),
        (
            lambda r: r["tdma"].update(reference_id=0x013),
            ["[tdma]: reference_id: 0x13 has its three least significant bits set", "give 0x10"],
        ),
        (
            lambda r: r["tdma"].update(reference_id=0x100),
            ["[tdma]: reference_id: 0x100..0x101", "includes message 'A' (0x100)"],
        ),
        (
            lambda r: r["tdma"].update(time_masters=["gw", "body"]),
            ["[tdma]: time_masters: 'body' is not a node with profile = 'tdma'"],
        ),
        (lambda r: r["tdma"].update(time_masters=[]), ["[tdma]: time_masters: 0 names given", "1 to 8"]),
        (lambda r: r["tdma"].update(time_masters=["gw", "gw"]), ["[tdma]: time_masters: 'gw' is named twice"]),
        (lambda r: r["tdma"].update(level=3), ["[tdma]: level: 3 is not 1 or 2"]),
        (
            lambda r: r["tdma"].update(basic_cycle_us=200000),
            ["[tdma]: basic_cycle_us: 200000 µs is 100000 NTU", "at most 65535 NTU"],
        ),
        (
            lambda r: r["tdma"].update(watch_trigger_us=5100),
            [
                "[tdma]: watch_trigger_us: 5100 µs must be after the backup masters' reference message",
                "Initial_Ref_Offset 127 NTU",
            ],
        ),
        (lambda r: r["tdma"].update(initial_ref_offset=200), ["[tdma]: initial_ref_offset: 200 is outside 0..127"]),
        (
            lambda r: window(r, 1).update(start_us=100),
            ["#1: start_us: 100 µs overlaps the reference message", "first 130 µs"],
        ),
        (lambda r: window(r, 5).update(messages=["A"]), ["#5: messages: a free window is reserved"]),
        (
            lambda r: window(r, 4).update(messages=["E", "L"]),
            ["#4: messages: 'L' is a message of node 'body' (profile 'csma')"],
        ),
        (lambda r: window(r, 4).update(messages=["Nope"]), ["#4: messages: 'Nope' is not a message of a node"]),
        (lambda r: window(r, 4).update(kind="shared"), ["#4: kind: 'shared' is not one of 'exclusive'"]),
        (lambda r: window(r, 4).update(colour="red"), ["#4: unknown key 'colour'"]),
        (lambda r: r["tdma"]["windows"].pop(3), ["[[nodes]] 'eng' > [[nodes.messages]] 'E': in no [[tdma.windows]]"]),
        (
            lambda r: r["nodes"][0]["messages"][0].update(period_ms=5),
            ["[[nodes]] 'gw' > [[nodes.messages]] 'A': period_ms: a TDMA message is released by its time window"],
        ),
        (
            lambda r: r["nodes"][0]["messages"][0].update(offset_ms=1),
            ["'A': offset_ms: a TDMA message is released at its window's start"],
        ),
        (lambda r: r.pop("tdma"), ["[[nodes]] 'gw': profile: 'tdma' needs a [tdma] table"]),
        (
            lambda r: [n.update(profile="csma", messages=[]) for n in r["nodes"][:3]],
            ["[tdma]: no node has profile = 'tdma'"],
        ),
        (
            lambda r: window(r, 4).update(length_us=250),
            [
                "[[nodes]] 'body' > [[nodes.messages]] 'L': no arbitrating window fits it (270 µs worst case",
                "widest is 250 µs",
                "tdma_gated = false",
            ],
        ),
    ],
)
def test_every_other_rule_names_file_table_key(mutate, parts):
    refuse(mutate, *parts)


def test_an_ungated_csma_node_needs_no_arbitrating_window():
    def m(raw):
        raw["tdma"]["windows"].pop(3)
        raw["tdma"]["windows"].pop(3)
        raw["nodes"][1]["messages"].pop()
        raw["nodes"][3]["tdma_gated"] = False

    assert scenario(m).tables["tdma"].gated == ()


def test_a_scenario_without_tdma_is_not_touched():
    raw = {
        "bus": {"bitrate": 500000, "duration": 0.1},
        "nodes": [{"name": "a", "messages": [{"name": "X", "id": 1, "dlc": 1, "period_ms": 1}]}],
    }
    assert "tdma" not in parse_scenario(raw).tables


# -- reference message -----------------------------------------------------------------------


def test_reference_layout_by_hand():
    assert encode_reference(5, level=1) == b"\x05"
    # Master_Ref_Mark 0x123456 (1/128 NTU): NTU_Res 0x56 -> byte 1 = 0x56 << 1 | Disc_Bit,
    # whole NTU 0x2468 -> bytes 2..3 low, high
    assert encode_reference(63, level=2, mark=0x123456, disc=True) == bytes([63, 0xAD, 0x68, 0x24])
    assert decode_reference(bytes([0x80 | 7]), 1) == ReferenceInfo(7, True, None, False)
    assert decode_reference(b"", 1) is None and decode_reference(b"\x01\x00\x00", 2) is None  # DLC too short
    with pytest.raises(ValueError):
        encode_reference(64, level=1)


@given(st.integers(0, 63), st.integers(0, MARK_MODULUS - 1), st.booleans())
def test_reference_round_trip(cycle, mark, disc):
    assert decode_reference(encode_reference(cycle, level=2, mark=mark, disc=disc), 2) == (cycle, False, mark, disc)


def test_reference_identifier_carries_the_master_priority():
    s = scenario().tables["tdma"]
    f = s.reference_frame(1, 2)
    assert (f.can_id, f.data) == (0x011, b"\x02")
    assert s.priority_of(0x011, False) == 1 and s.priority_of(0x018, False) is None
    assert s.priority_of(0x011, True) is None


def test_worst_case_lengths():
    assert frame_ns_worst(8, False, False, 2000) == 270_000  # 135 bits (Davis et al. eq. 1)
    assert frame_ns_worst(8, False, False, 2000, intermission=False) == 264_000
    assert frame_ns_worst(1, False, False, 2000) == 130_000  # the level-1 reference message: 65 bits


def test_window_matrix_rows():
    w = Window(1, 0, 1, "exclusive", ("A",), base_cycle=1, repeat=4)
    assert [c for c in range(16) if w.active(c)] == [1, 5, 9, 13]


def test_analytic_bounds_of_exclusive_windows():
    s = scenario().tables["tdma"]
    # response: Tx_Enable 32 µs + 132 bits (264 µs); latency: + the longest distance between windows
    assert message_bounds(s, "A") == (296_000, 5_296_000, None)
    assert message_bounds(s, "B") == (296_000, 10_296_000, None)
    assert message_bounds(s, "C") == (216_000, 10_216_000, None)  # 4 bytes: 95 bits, 92 without intermission
    rta, latency, note = message_bounds(s, "E")
    assert rta is None and latency is None and "arbitrating" in note


# -- the standard's ranges, the window kinds, level 2's NTU ---------------------------------------


@pytest.mark.parametrize(
    "mutate, parts",
    [
        (
            lambda r: r["tdma"].update(tx_enable_us=34),
            ["[tdma]: tx_enable_us: 34 µs is 17 NTU: the Tx_Enable window is 1..16 NTU (2..32 µs of 2 µs NTU"],
        ),
        (
            lambda r: r["tdma"].update(tx_enable_us=3),
            ["[tdma]: tx_enable_us: 3 µs is 1.5 NTU: a time of the schedule is a whole number of NTU (2 µs each)"],
        ),
        (lambda r: r["tdma"].update(tx_enable_us=0), ["[tdma]: tx_enable_us: 0"]),
        (lambda r: window(r, 1).update(start_us=501), ["#1: start_us: 501 µs is 250.5 NTU: a time of the schedule"]),
        (lambda r: window(r, 2).update(length_us=401), ["#2: length_us: 401 µs is 200.5 NTU"]),
        (lambda r: r["tdma"].update(basic_cycle_us=5001), ["[tdma]: basic_cycle_us: 5001 µs is 2500.5 NTU"]),
        (
            lambda r: window(r, 1).update(arbitration="single"),
            ["#1: arbitration: 'single': only an arbitrating window is single or merged (this one is exclusive)"],
        ),
        (lambda r: window(r, 4).update(arbitration="both"), ["#4: arbitration: 'both' is not one of 'single'"]),
        (
            lambda r: r["tdma"].update(gap_mode=True),
            ["[tdma]: gap_mode: gap mode (Next_is_Gap", "is not modelled"],
        ),
        (lambda r: r["tdma"].update(tur=8.0), ["[tdma]: tur: level 1's NTU is the nominal bit time"]),
        (lambda r: r["tdma"].update(level=2), ["[tdma]: key 'tur' is required at level 2"]),
        (
            lambda r: r["tdma"].update(level=2, tur=8.0),
            ["[tdma]: key 'can_clock_mhz' is required at level 2"],
        ),
        (
            lambda r: r["tdma"].update(level=2, tur=3.9, can_clock_mhz=8),
            ["[tdma]: tur: 3.9 is not 4.0002..131071 (a time unit ratio NC/DC"],
        ),
        (
            lambda r: r["tdma"].update(level=2, tur=24.0, can_clock_mhz=8),  # 3 µs NTU: 5000 µs is no whole NTU
            ["[tdma]: basic_cycle_us: 5000 µs is 1666.67 NTU: a time of the schedule is a whole number of NTU (3 µs"],
        ),
    ],
)
def test_values_outside_the_standards_ranges_are_refused(mutate, parts):
    refuse(mutate, *parts)


def test_tx_enable_at_the_ends_of_its_range():
    assert scenario(lambda r: r["tdma"].update(tx_enable_us=2)).tables["tdma"].tx_enable_ns == 2_000
    assert scenario(lambda r: r["tdma"].update(tx_enable_us=32)).tables["tdma"].tx_enable_ns == 32_000


def test_arbitrating_windows_are_merged_unless_said_single():
    s = scenario().tables["tdma"]
    w = s.windows[3]
    assert w.arbitration == "merged" and not w.triggered
    assert s.latest_start_ns(w, 40_000) == w.end_ns - 40_000  # starts throughout
    s = scenario(lambda r: window(r, 4).update(arbitration="single")).tables["tdma"]
    w = s.windows[3]
    assert w.single and w.triggered and s.latest_start_ns(w, 40_000) == w.start_ns + s.tx_enable_ns
    assert s.windows[0].arbitration == "" and "single arbitrating" in s.windows[3].label()


def test_a_single_arbitrating_window_fits_its_messages_after_tx_enable():
    # E: 1 byte, 65 bits worst case with intermission = 130 µs; + Tx_Enable 32 µs = 162 µs
    refuse(
        lambda r: window(r, 4).update(arbitration="single", length_us=160),
        "#4: length_us: message 'E' does not fit",
        "after a Tx_Enable window of 32 µs needs 162 µs",
    )


def test_level_2_counts_in_the_ntu_its_time_unit_ratio_gives():
    """tur 8 of an 8 MHz clock: an NTU of 1 µs (half the bit time at 500 kbit/s)."""
    s = scenario(lambda r: r["tdma"].update(level=2, tur=8.0, can_clock_mhz=8.0)).tables["tdma"]
    assert s.ntu_length == 1000.0 and s.ntu(127) == 127_000
    assert s.tx_enable_ns == 16_000  # the default 16 NTU
    assert s.bit_ns == 2000.0 and s.budget_ns == 0
