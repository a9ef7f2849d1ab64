"""The node API additions on the simulated bus, exact to the ns: one-shot per node and per request,
the latest start time, start-of-frame times, the bit time and local clocks."""

from __future__ import annotations

import pytest

from stack.bus.sim import SimBus
from stack.controller.clock import LocalClock
from stack.controller.events import ArbitrationLost, Received, TxDone, TxFailed
from stack.wire.frame import Frame

BIT = 2_000  # ns at 500 kbit/s


def _pair(**cfg):
    bus = SimBus(500_000)
    return bus, bus.node("a", **cfg), bus.node("b")


def test_one_shot_set_after_attach_takes_effect():
    """The bug: the flag was cached when the node was attached, so a frame that lost
    arbitration was sent again. Now it fails, and is never on the bus."""
    bus, a, b = _pair()
    a.one_shot = True
    failed: list[TxFailed] = []
    a.listen(TxFailed, failed.append)
    b.send(Frame(0x100))
    loser = a.send(Frame(0x200))
    bus.run(duration=2_000_000)
    assert loser.state == "failed" and failed[0].reason == "arbitration lost (one-shot)"
    assert [r.frame.can_id for r in bus.trace] == [0x100]


def test_one_shot_per_request_leaves_the_others_retrying():
    bus, a, b = _pair()
    b.send(Frame(0x100))
    once = a.send(Frame(0x200), one_shot=True)
    bus.run(duration=2_000_000)
    assert once.state == "failed" and once.reason == "arbitration lost (one-shot)"
    b.send(Frame(0x100))
    again = a.send(Frame(0x200))  # not one-shot: loses, then goes out after
    bus.run(duration=2_000_000)
    assert again.state == "sent" and again.losses == 1
    assert [r.frame.can_id for r in bus.trace] == [0x100, 0x100, 0x200]


def test_one_shot_request_destroyed_by_an_error_is_not_retried():
    bus = SimBus(500_000)
    a = bus.node("a")
    b = bus.node("b")
    from stack.bus.faults import FaultInjector

    FaultInjector(bus).flip(can_id=0x123, occurrence=1, field="data", bit=3)
    req = a.send(Frame(0x123, b"\x01\x02"), one_shot=True)
    bus.run(duration=2_000_000)
    assert req.state == "failed" and req.reason.endswith("error (one-shot)")
    assert b.rx_frames == 0 and a.tx_frames == 0 and a.retransmissions == 0


def test_latest_start_time_is_inclusive_and_withdraws_after_it():
    """A frame queued behind another can start only at the end of that frame plus 3 bits of
    intermission: with not_after exactly there it goes out, one ns earlier it is withdrawn."""
    for margin, expected in ((0, "sent"), (-1, "failed")):
        bus, a, b = _pair()
        first = Frame(0x100, bytes(8))
        b.send(first)
        start = (first.bits.length + 3) * BIT  # the second arbitration
        late = a.send(Frame(0x200), not_after=start + margin)
        failed: list[TxFailed] = []
        a.listen(TxFailed, failed.append)
        bus.run(duration=2_000_000)
        assert late.state == expected, margin
        if expected == "sent":
            assert late.sof == start
        else:
            assert failed[0].reason == f"not started by its latest start time {start - 1} ns"
            assert failed[0].time == start  # withdrawn 1 ns after its latest start
            assert [r.frame.can_id for r in bus.trace] == [0x100]


def test_latest_start_time_in_the_past_withdraws_at_once():
    bus, a, b = _pair()
    bus.run(until=1_000_000)
    req = a.send(Frame(0x100), not_after=500_000)
    bus.run(duration=1_000)
    assert req.state == "failed" and bus.trace == []


def test_start_of_frame_times_match_the_trace():
    bus, a, b = _pair()
    done: list[TxDone] = []
    got: list[Received] = []
    a.listen(TxDone, done.append)
    b.subscribe(got.append)
    frames = [Frame(0x100 + i, bytes(i)) for i in range(3)]
    for f in frames:
        a.send(f)
    bus.run(duration=5_000_000)
    starts = [r.start for r in bus.trace]
    ends = [r.end for r in bus.trace]
    assert [ev.sof for ev in got] == starts == [ev.sof for ev in done]
    assert [ev.time for ev in got] == ends
    # back to back: each SOF is 3 intermission bits after the previous end of EOF
    assert all(s == e + 3 * BIT for s, e in zip(starts[1:], ends))
    assert a.bit_ns == BIT and a.capabilities >= {"sof", "latest-start", "one-shot"}


def test_start_of_frame_of_a_frame_after_an_error_is_its_own_attempt():
    from stack.bus.faults import FaultInjector

    bus, a, b = _pair()
    done: list[TxDone] = []
    a.listen(TxDone, done.append)
    FaultInjector(bus).flip(can_id=0x123, occurrence=1, field="data", bit=0)
    a.send(Frame(0x123, b"\x55"))
    bus.run(duration=3_000_000)
    err, ok = bus.trace
    assert err.kind == "error" and ok.kind == "frame"
    assert done[0].sof == ok.start > err.end


def test_local_clock_conversions():
    c = LocalClock(offset_ns=1_000, drift_ppm=250.0)
    assert c.local(0) == 1_000
    assert c.local(1_000_000_000) == 1_000 + 1_000_000_000 + 250_000
    for t_local in (1_000, 1_001, 999_999_999, 1_000_251_000, 7_654_321_987):
        t_bus = c.bus(t_local)
        assert c.local(t_bus) >= t_local and (t_bus == 0 or c.local(t_bus - 1) < t_local)
    slow = LocalClock(drift_ppm=-100.0)
    assert slow.local(10_000_000_000) == 10_000_000_000 - 1_000_000
    with pytest.raises(ValueError, match="drift 200000"):
        LocalClock(drift_ppm=200_000)
    with pytest.raises(ValueError, match="offset"):
        LocalClock(offset_ns=1.5)  # type: ignore[arg-type]


def test_drifting_node_reports_local_times_and_its_timers_fire_at_local_times():
    bus = SimBus(500_000)
    a = bus.node("a", clock=LocalClock(offset_ns=0, drift_ppm=1_000.0))  # 0.1 % fast
    b = bus.node("b")
    got: list[Received] = []
    a.subscribe(got.append)
    fired: list[int] = []
    a.call_at(10_010_000, lambda: fired.append(bus.now()))  # local 10.01 ms = bus 10 ms
    b.call_at(20_000_000, lambda: b.send(Frame(0x100)))
    bus.run(duration=30_000_000)
    assert fired == [10_000_000]
    rec = bus.trace[0]
    assert got[0].time == rec.end + rec.end // 1000 and got[0].sof == rec.start + rec.start // 1000
    assert a.now() == 30_030_000


def test_arbitration_lost_event_names_the_winner():
    bus, a, b = _pair()
    lost: list[ArbitrationLost] = []
    a.listen(ArbitrationLost, lost.append)
    b.send(Frame(0x100))
    a.send(Frame(0x200))
    bus.run(duration=2_000_000)
    assert [(e.frame.can_id, e.winner.can_id, e.time) for e in lost] == [(0x200, 0x100, 0)]


def test_failures_say_why_in_one_word():
    from stack.bus.faults import FaultInjector

    bus, a, b = _pair()
    kinds: list[tuple[str, str]] = []
    a.listen(TxFailed, lambda ev: kinds.append((ev.kind, ev.reason)))
    FaultInjector(bus).flip(can_id=0x300, occurrence=1, field="crc", bit=2, nodes=["b"])
    b.send(Frame(0x100))
    a.send(Frame(0x200), one_shot=True)  # loses to 0x100
    # b alone sees a CRC error; its error flag after the ACK delimiter is dominant where the
    # transmitter sends its recessive EOF: for the transmitter, a bit error
    a.send(Frame(0x300, b"\x01"), one_shot=True)
    late = a.send(Frame(0x400), not_after=0)
    gone = a.send(Frame(0x500))
    a.abort(gone)
    bus.run(duration=3_000_000)
    assert late.state == "failed"
    assert sorted(k for k, _ in kinds) == ["aborted", "arbitration", "bit", "expired"]
    assert dict(kinds)["arbitration"] == "arbitration lost (one-shot)"


def test_listen_only_switched_at_run_time_stops_acknowledging():
    """The only other node going listen-only leaves the transmitter without acknowledgement:
    ACK errors (rule 3) from the next frame on."""
    bus, a, b = _pair()
    a.send(Frame(0x100))
    bus.run(duration=1_000_000)
    assert a.tx_frames == 1 and a.tec == 0
    b.listen_only = True
    a.send(Frame(0x101))
    bus.run(duration=2_000_000)
    assert a.tx_frames == 1 and a.tec > 0 and bus.trace[-1].detail["error"] == "ack"
    b.listen_only = False
    bus.run(duration=2_000_000)
    assert a.tx_frames == 2


def test_filters_that_are_not_a_list_are_refused_naming_the_value():
    from stack.controller.filters import validate_filters

    for bad in (5, True, 1.5, "0x100"):
        with pytest.raises(ValueError, match=r"must be a list of .* or None"):
            validate_filters(bad)  # type: ignore[arg-type]


def test_unlisten_stops_the_callbacks_and_the_bus_goes_back_to_its_fast_path():
    bus, a, b = _pair()
    done: list[TxDone] = []
    lost: list[ArbitrationLost] = []
    a.listen(TxDone, done.append)
    a.listen(ArbitrationLost, lost.append)
    a.send(Frame(0x200))
    b.send(Frame(0x100))
    bus.run(duration=2_000_000)
    assert len(done) == 1 and len(lost) == 1 and a in bus._arb_watch
    assert a.unlisten(TxDone, done.append) and a.unlisten(ArbitrationLost, lost.append)
    assert not a.unlisten(TxDone, done.append)
    assert a not in bus._arb_watch  # nobody to tell about lost rounds any more
    a.send(Frame(0x200))
    b.send(Frame(0x100))
    bus.run(duration=2_000_000)
    assert len(done) == 1 and len(lost) == 1
