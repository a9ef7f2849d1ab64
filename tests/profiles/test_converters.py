"""The profiles study's converters: a message set expressed as a TDMA schedule and as a
master/slave network, checked by the scenario checker and run."""

from __future__ import annotations

import pytest

from profiles.message_set import MessageSet, StudyMessage
from profiles.pipeline.runner import run_scenario
from profiles.pipeline.scenario import parse_scenario
from profiles.polling.convert import express_message_set as as_master_slave
from profiles.tdma.convert import express_message_set as as_tdma

MS = 1_000_000


def _set(periods_ms, bitrate=500_000):
    msgs = tuple(
        StudyMessage(f"m{i}", f"n{i % 3}", 0x100 + 0x20 * i, 8, round(p * MS), round(p * MS))
        for i, p in enumerate(periods_ms)
    )
    return MessageSet(bitrate, msgs, 0.2, seed=1)


def test_tdma_windows_repeat_at_least_as_often_as_each_period_and_the_schedule_holds():
    mset = _set([5, 5, 10, 12, 20, 40])
    raw = as_tdma(mset)
    t = raw["tdma"]
    assert t["basic_cycle_us"] == 5000 and t["matrix_cycles"] == 8
    repeat = {w["messages"][0]: w["repeat"] for w in t["windows"]}
    # the largest power of two of 5 ms cycles within each period: 5 -> 1, 10 -> 2, 12 -> 2, 20 -> 4, 40 -> 8
    assert repeat == {"m0": 1, "m1": 1, "m2": 2, "m3": 2, "m4": 4, "m5": 8}
    res = run_scenario(parse_scenario(raw, "tdma-converted"))
    data = res.to_json()
    assert all(w["outside"] == 0 for w in data["tdma"]["windows"])
    assert all(m["deadline_misses"] == 0 and m["sent"] > 0 for m in data["messages"])


def test_tdma_refuses_a_set_whose_windows_do_not_fit_a_basic_cycle():
    with pytest.raises(ValueError, match=r"does not fit a TDMA schedule: its windows need \d+ µs of a 1000 µs"):
        as_tdma(_set([1] * 6))


def test_master_polls_the_fastest_messages_and_the_others_are_cyclic():
    mset = _set([5, 5, 10, 20])
    raw = as_master_slave(mset)
    master = raw["nodes"][0]
    assert master["cycle_ms"] == 5
    polled = [e["response_id"] for e in master["poll"] if e.get("style", "polled") == "polled"]
    assert polled == [0x100, 0x120]
    assert all(e["id"] not in {m.can_id for m in mset.messages} for e in master["poll"] if "id" in e)
    res = run_scenario(parse_scenario(raw, "ms-converted"))
    rows = {m["name"]: m for m in res.to_json()["messages"]}
    assert rows["m0"]["sent"] == rows["m1"]["sent"] == 40  # one answer per 5 ms cycle for 0.2 s
    assert rows["m3"]["sent"] == 10 and all(r["deadline_misses"] == 0 for r in rows.values())


@pytest.mark.parametrize("bitrate", [125_000, 250_000, 800_000, 1_000_000])
def test_tdma_times_are_whole_ntu_at_any_bitrate(bitrate):
    """The schedule's times count NTU (level 1: bit times; 1.25 µs at 800 kbit/s): the converter's
    windows pass the checker's whole-NTU rule and run."""
    raw = as_tdma(_set([7.3, 7.3, 14.9, 29.1], bitrate))
    ntu_us = 1e6 / bitrate
    for w in raw["tdma"]["windows"]:
        for key in ("start_us", "length_us"):
            assert abs(w[key] / ntu_us - round(w[key] / ntu_us)) < 1e-9, (key, w[key])
    data = run_scenario(parse_scenario(raw, "tdma-converted")).to_json()
    assert data["tdma"]["outside"] == 0 and all(m["sent"] > 0 for m in data["messages"])


def _fd_set(data_bitrate=2_000_000):
    msgs = (
        StudyMessage("big", "n0", 0x100, 15, 5 * MS, 5 * MS, fd=True, brs=True),  # 64 bytes
        StudyMessage("mid", "n1", 0x180, 9, 10 * MS, 10 * MS, fd=True),  # 12 bytes, no BRS
        StudyMessage("plain", "n1", 0x200, 8, 10 * MS, 10 * MS),
    )
    return MessageSet(500_000, msgs, 0.05, seed=1, data_bitrate=data_bitrate)


def test_csma_carries_fd_messages_and_the_set_comes_back_from_the_scenario():
    from profiles.sweeps.converters import csma_scenario, message_set_from_scenario

    mset = _fd_set()
    sc = parse_scenario(csma_scenario(mset), "fd-converted")
    assert sc.data_bitrate == 2_000_000
    big, mid, plain = sc.messages
    assert (big.fd, big.brs, big.length, mid.fd, mid.brs, mid.length, plain.fd) == (
        True, True, 64, True, False, 12, False,
    )  # fmt: skip
    back = message_set_from_scenario(sc)
    assert back.data_bitrate == mset.data_bitrate and back.messages == mset.messages
    res = run_scenario(sc)
    assert all(r["sent"] > 0 and r["deadline_misses"] == 0 for r in res.to_json()["messages"])


def test_an_fd_set_without_a_data_bitrate_runs_its_fd_frames_at_the_nominal_rate():
    from profiles.sweeps.converters import csma_scenario

    msgs = (StudyMessage("mid", "n1", 0x180, 9, 10 * MS, 10 * MS, fd=True),)
    sc = parse_scenario(csma_scenario(MessageSet(500_000, msgs, 0.05)), "fd-converted")
    assert sc.data_bitrate == 500_000 and sc.messages[0].fd


@pytest.mark.parametrize("convert", [as_tdma, as_master_slave])
def test_classical_only_profiles_refuse_an_fd_set_naming_the_message(convert):
    with pytest.raises(ValueError, match=r"CAN FD message 'big': .* classical CAN frames only"):
        convert(_fd_set())
