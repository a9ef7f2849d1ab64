"""Error detection, signalling and the 12 fault-confinement rules of CAN 2.0, one test per rule.

Expected counter values are worked out by hand from the specification's rules for each
scenario (the comments give the arithmetic), not read back from the implementation.
"""

import pytest

from stack.bus.faults import FaultInjector
from stack.bus.sim import SimBus
from stack.controller.events import ErrorStateChanged, TxFailed
from stack.controller.node import ErrorState
from stack.wire.coding import Field
from stack.wire.frame import Frame

F = Frame(0x123, b"\x55\xaa")


def three(seed=0, **kw):
    bus = SimBus(500_000, seed=seed)
    a, b, c = bus.node("a", **kw), bus.node("b"), bus.node("c")
    return bus, a, b, c, FaultInjector(bus)


def first_error(bus):
    return next(r for r in bus.trace if r.kind != "frame" or (r.detail and "error" in r.detail))


def test_rule_1_receivers_detecting_an_error_add_1():
    # a global flip in the data field: the transmitter sees a bit error first, the receivers a
    # stuff error in its error flag (they are not first, so rule 2 does not apply to them)
    bus, a, b, c, fi = three()
    fi.flip(can_id=0x123, field="data", bit=3)
    a.send(F)
    bus.run(frames=1)
    rec = first_error(bus)
    assert rec.detail["error"] == "bit" and rec.detail["seen_by"] == "a"
    assert "b:rule 1" in rec.detail["rules"] and "rule 2" not in rec.detail["rules"]
    assert rec.detail["counters"] == "a:8/0 b:0/1 c:0/1"


def test_rule_2_receiver_first_to_detect_sees_dominant_after_its_flag():
    # a local flip seen by b only: b finds a CRC error, flags after the ACK delimiter; a and c
    # see b's flag as a form/bit error and flag too, so b reads dominant right after its flag
    bus, a, b, c, fi = three()
    fi.flip(can_id=0x123, field="data", bit=9, nodes=["b"])
    a.send(F)
    bus.run(frames=1)
    rec = first_error(bus)
    assert rec.detail["error"] == "crc" and rec.detail["seen_by"] == "b"
    assert rec.detail["counters"] == "a:8/0 b:0/9 c:0/1"  # b: 1 (rule 1) + 8 (rule 2)


def test_rule_3_transmitter_sending_error_flag_adds_8():
    bus, a, b, c, fi = three()
    fi.flip(can_id=0x123, field="crc", bit=2)
    a.send(F)
    bus.run(duration=1_000_000)
    assert first_error(bus).detail["counters"].startswith("a:8/0")
    assert a.tec == 7  # then the retransmission succeeds: rule 7


def test_rule_3_exception_1_lone_transmitter_stops_at_128_error_passive():
    bus = SimBus(500_000)
    a = bus.node("a")
    states = []
    a.listen(ErrorStateChanged, states.append)
    a.send(F)
    bus.run(duration=40_000_000)
    # 16 ACK errors x 8 = 128 -> error passive; then passive ACK errors leave TEC unchanged
    assert a.tec == 128 and a.state is ErrorState.PASSIVE
    assert [s.new for s in states] == ["error-warning", "error-passive"]
    assert states[0].tec == 96 and states[1].tec == 128
    last = bus.trace[-1]
    assert "rule 3 exception 1" in last.detail["rules"]


def test_rule_3_exception_2_stuff_error_in_arbitration_leaves_tec():
    # ID 0x000: SOF + 4 dominant identifier bits, then a recessive stuff bit at position 5;
    # the transmitter alone reads it dominant: a stuff error during arbitration (exception 2)
    f0 = Frame(0x000, b"\x01")
    assert f0.bits.stuff_positions[0] == 5 and f0.bits.bits[5] == "1"
    bus, a, b, c, fi = three()
    fi.flip(can_id=0x000, field="raw", bit=5, nodes=["a"])
    a.send(f0)
    bus.run(frames=1)
    rec = first_error(bus)
    assert rec.detail["error"] == "stuff-arbitration"
    assert "a:rule 3 exception 2" in rec.detail["rules"]
    assert rec.detail["counters"].startswith("a:0/0")


def test_rule_4_transmitter_bit_error_in_its_active_error_flag():
    bus, a, b, c, fi = three()
    p = F.bits.position(Field.DATA, 3)
    fi.flip(can_id=0x123, field="data", bit=3)  # a: bit error at p, flag from p+1
    fi.flip(can_id=0x123, field="raw", bit=p + 3, nodes=["a"])  # a reads recessive in its flag
    a.send(F)
    bus.run(frames=1)
    rec = first_error(bus)
    assert "a:rule 3,rule 4" in rec.detail["rules"]
    assert rec.detail["counters"].startswith("a:16/0")


def test_rule_5_receiver_bit_error_in_its_active_error_flag():
    bus, a, b, c, fi = three()
    fi.flip(can_id=0x123, field="data", bit=9, nodes=["b"])  # b: CRC error at the ACK delimiter
    ack_delim = F.bits.position(Field.ACK_DELIM)
    fi.flip(can_id=0x123, field="raw", bit=ack_delim + 2, nodes=["b"])  # inside b's flag
    a.send(F)
    bus.run(frames=1)
    rec = first_error(bus)
    assert "b:rule 1,rule 5" in rec.detail["rules"]
    # b restarts its flag after the bit error, so it ends last and reads recessive after it
    # (no rule 2 for b); c's flag ends first and c reads b's flag: rule 2 for c
    assert rec.detail["counters"] == "a:8/0 b:0/9 c:0/9"
    assert "c:rule 1,rule 2" in rec.detail["rules"]


def test_rule_6_dominant_bits_after_the_flag():
    # b stuck dominant for 100 bits on an idle bus: a and c see a SOF, a stuff error at the 6th
    # dominant bit (rule 1), send their flag (bits 7..12), then count dominant bits: the 14th
    # after the flag and every 8th after it add 8 (rule 6)
    bus = SimBus(500_000)
    a, b, c = bus.node("a"), bus.node("b"), bus.node("c")
    fi = FaultInjector(bus)
    fi.stuck("b", "dominant", start=1_000_000, end=1_000_000 + 100 * 2000)
    bus.run(until=5_000_000)
    # stuff error at bit 5 (SOF + 5 dominant): rule 1 (+1); flag at bits 6..11; bit 12 is
    # dominant: rule 2 (+8); dominant bits 12..99 are 88 after the flag: the 8th after it (the
    # 14th counted from the flag's first bit), 16th, ..., 88th add 8 each (rule 6)
    rule6 = 88 // 8
    assert rule6 == 11
    assert a.rec == c.rec == 1 + 8 + 8 * rule6 == 97
    # the stuck node's own controller reads the same dominant bus
    assert b.rec == 97


def test_rule_7_success_decrements_tec():
    bus, a, b, c, fi = three()
    fi.flip(can_id=0x123, field="crc", bit=0)
    for _ in range(3):
        a.send(F)
    bus.run(duration=2_000_000)
    assert a.tec == 8 - 3  # one error (+8), three frames sent (-1 each)


def test_rule_8_reception_decrements_rec_and_caps_above_127():
    bus, a, b, c, fi = three()
    b.set_counters(0, 5, 0)
    c.set_counters(0, 140, 0)
    for _ in range(2):
        a.send(F)
    bus.run()
    assert b.rec == 3 and c.rec == 126  # c: 140 -> 127 (rule 8) -> 126
    assert c.state is ErrorState.WARNING


def test_rule_9_and_11_passive_at_128_and_back_to_active():
    bus = SimBus(500_000)
    a = bus.node("a")
    a.send(F)
    bus.run(duration=40_000_000)
    assert a.state is ErrorState.PASSIVE
    bus.node("b")  # someone to acknowledge: the pending frame goes through
    bus.run(duration=1_000_000)
    assert a.tec == 127 and a.state is ErrorState.WARNING  # rule 11: active again (warning >= 96)


def test_rule_10_stuck_recessive_transmitter_goes_passive_then_bus_off():
    # a's transmitter is disconnected: its SOF never reaches the wire, it reads recessive: a bit
    # error (rule 3: TEC 8), then one in every bit of its active error flag (rule 4: +8 each).
    # At 96 it is error warning, at 128 error passive (rule 9): from then on its flag is a
    # passive one, which completes (6 recessive bits), so the first attempt ends at TEC 128
    # after 1 + 15 bit errors. Each later attempt is one SOF bit error, +8 (rule 3): 16 more
    # attempts reach 256, bus off (rule 10) — 17 attempts in all.
    bus = SimBus(500_000)
    a, b = bus.node("a"), bus.node("b", auto_recovery=False)
    a.auto_recovery = False
    fi = FaultInjector(bus)
    fi.stuck("a", "recessive")
    changes = []
    a.listen(ErrorStateChanged, changes.append)
    a.send(F)
    bus.run(duration=2_000_000)
    assert [(c.old, c.new, c.tec) for c in changes] == [
        ("error-active", "error-warning", 96),
        ("error-warning", "error-passive", 128),
        ("error-passive", "bus-off", 256),
    ]
    bit = 2000  # ns at 500 kbit/s
    # TEC 96 after the SOF error (bit 0) and 11 flag-bit errors (bits 1..11): at the end of bit 11
    assert changes[0].time == 12 * bit and changes[1].time == 16 * bit
    assert a.state is ErrorState.BUS_OFF and a.tec == 256 and bus.error_frames == 17
    assert b.rec == 0 and bus.frames_ok == 0


def test_state_changes_inside_a_long_episode_happen_at_their_bit_times():
    # c is stuck dominant from 300 us for 100 ms: every node sees SOF then dominant bits — a
    # stuff error at the 6th (bit 5 of the episode, rule 1: REC 1), its active flag (6 bits),
    # then the first dominant bit after its flag (rule 2: +8 = 9) and rule 6 at the 8th one
    # after the flag and each 8 more (+8 each). REC reaches 96 at 9 + 11 * 8 = 97: the 11th
    # rule-6 increment, 8 * 10 bits after the first at the 8th dominant bit after the flag.
    bus = SimBus(500_000)
    a, b, c = bus.node("a"), bus.node("b"), bus.node("c")
    fi = FaultInjector(bus)
    fi.stuck("c", "dominant", start=300_000, end=100_300_000)
    changes = []
    b.listen(ErrorStateChanged, changes.append)
    bus.run(until=50_000_000)
    # bits from the episode's SOF: stuff error at bit 5, flag bits 6..11, dominant run from 12;
    # the 8th dominant bit after the flag is bit 19, the 11th increment bit 19 + 80 = 99
    assert changes and changes[0].new == "error-warning" and changes[0].rec == 97
    assert changes[0].time == 300_000 + 100 * 2000
    assert changes[1].new == "error-passive" and changes[1].time == 300_000 + (99 + 32 + 1) * 2000
    assert b.state is ErrorState.PASSIVE  # long before the episode ends at 100.3 ms
    bus.run(until=200_000_000)
    # the episode is 50,000 bits; the dominant run after the flag lasts bits 12..49,999 (49,988
    # bits): rule 6 at runs 8, 16, ..., 49,984 = 6,248 increments. REC = 1 + 8 + 6,248 * 8
    assert b.rec == 1 + 8 + 6248 * 8 and b.state is ErrorState.PASSIVE


def test_rule_12_recovery_after_128_times_11_recessive_bits():
    bus = SimBus(500_000)
    a, b = bus.node("a"), bus.node("b")
    a.set_counters(256, 0, 0)
    t_off = bus.now()
    changes = []
    a.listen(ErrorStateChanged, changes.append)
    bus.run(until=10_000_000)
    assert a.state is ErrorState.ACTIVE and a.tec == a.rec == 0
    assert changes[0].new == "error-active" and changes[0].time == t_off + 128 * 11 * 2000


def test_rule_12_manual_recovery_waits_for_the_host():
    bus = SimBus(500_000)
    a, b = bus.node("a", auto_recovery=False), bus.node("b")
    a.set_counters(256, 0, 0)
    bus.run(until=10_000_000)
    assert a.state is ErrorState.BUS_OFF
    a.recover()
    bus.run(until=20_000_000)
    assert a.state is ErrorState.ACTIVE


def test_recovery_counts_frame_ends_under_traffic():
    # under load every frame end gives one run of 11 recessive bits (ACK delimiter, EOF,
    # intermission): bus off lasts about 128 frames
    bus = SimBus(500_000)
    a, b, c = bus.node("a"), bus.node("b"), bus.node("c")
    b.listen(__import__("stack.controller.events", fromlist=["TxDone"]).TxDone, lambda ev: b.send(ev.frame))
    b.send(Frame(0x100, bytes(8)))
    a.set_counters(256, 0, 0)
    bus.run(frames=100)
    assert a.state is ErrorState.BUS_OFF
    bus.run(frames=40)
    assert a.state is ErrorState.ACTIVE


def test_double_reception_when_last_eof_bit_is_dominant():
    bus, a, b, c, fi = three()
    fi.flip(can_id=0x123, field="eof", bit=6)  # global: receivers overload, transmitter errs
    a.send(F)
    bus.run()
    got_b = [f for _, f in iter(b.recv, None)]
    assert got_b == [F, F] and a.tx_frames == 1 and a.retransmissions == 1


def test_inconsistent_omission_at_last_but_one_eof_bit():
    bus, a, b, c, fi = three(one_shot=True)  # the transmitter gives up instead of resending
    fi.flip(can_id=0x123, field="eof", bit=5, nodes=["b"])
    a.send(F)
    bus.run()
    assert [f for _, f in iter(c.recv, None)] == [F]  # c accepted at the last-but-one bit
    assert b.recv() is None  # b saw a form error and dropped it
    assert a.tx_failed == 1


def test_passive_receiver_error_does_not_destroy_the_frame():
    bus, a, b, c, fi = three()
    b.set_counters(0, 130, 0)  # error passive
    fi.flip(can_id=0x123, field="data", bit=9, nodes=["b"])
    a.send(F)
    bus.run()
    assert bus.frames_ok == 1 and a.tec == 0 and c.recv()[1] == F and b.recv() is None


def test_error_passive_transmitter_suspends_8_bits():
    bus = SimBus(500_000)
    a, b, c = bus.node("a"), bus.node("b"), bus.node("c")
    a.set_counters(130, 0, 0)
    a.send(Frame(0x100, b"\x01"))
    a.send(Frame(0x100, b"\x02"))
    b.send(Frame(0x200, b"\x03"))
    bus.run()
    # a sends first; its second frame would win again but a must wait 3 + 8 bits, so b goes
    assert [r.sender for r in bus.trace] == ["a", "b", "a"]
    r0, r1 = bus.trace[0], bus.trace[1]
    assert r1.start - r0.end == 3 * 2000  # b starts at the end of intermission


def test_one_shot_reports_failure_on_error():
    bus, a, b, c, fi = three(one_shot=True)
    fi.flip(can_id=0x123, field="data", bit=0)
    failed = []
    a.listen(TxFailed, failed.append)
    a.send(F)
    bus.run()
    assert failed and "bit error" in failed[0].reason and bus.frames_ok == 0


def test_never_acking_node_and_disconnect():
    bus = SimBus(500_000)
    a, b = bus.node("a"), bus.node("b")
    fi = FaultInjector(bus)
    fi.never_ack("b")
    a.send(F)
    bus.run(duration=1_000_000)
    assert bus.frames_ok == 0 and a.tec > 0
    bus2 = SimBus(500_000)
    x, y, z = bus2.node("x"), bus2.node("y"), bus2.node("z")
    FaultInjector(bus2).disconnect("z", at=0, reconnect_at=5_000_000)
    x.send_periodic(F, 1_000_000, count=10)
    bus2.run()
    assert y.rx_frames == 10 and z.rx_frames == 5


def test_babbling_idiot_starves_lower_priorities():
    bus = SimBus(500_000)
    a, b, c = bus.node("a"), bus.node("b"), bus.node("c")
    FaultInjector(bus).babbling_idiot("c", can_id=0x001, start=1_000_000, end=5_000_000)
    b.send_periodic(Frame(0x300, b"\x01"), 500_000)
    bus.run(until=6_000_000)
    during = [r for r in bus.trace if 1_200_000 < r.start < 4_900_000]
    assert during and all(r.sender == "c" for r in during)


@pytest.mark.parametrize(
    "kw,msg",
    [
        ({"field": "bogus"}, "unknown field 'bogus'"),
        ({"field": "data", "bit": 64}, "bit 64 outside field data"),
        ({"field": "crc", "bit": -1}, "bit -1 outside field crc"),
        ({"nodes": ["nobody"]}, "unknown node 'nobody'"),
    ],
)
def test_bad_fault_specifications(kw, msg):
    bus = SimBus()
    bus.node("a")
    with pytest.raises(ValueError, match=msg):
        FaultInjector(bus).flip(**kw)


@pytest.mark.parametrize("rate", [-0.1, 1.5, float("nan")])
def test_bad_bit_error_rate(rate):
    bus = SimBus()
    with pytest.raises(ValueError, match="outside \\[0, 1\\]"):
        FaultInjector(bus).bit_errors(rate)


@pytest.mark.parametrize("count", [1, 2])
def test_overload_frames_delay_the_next_frame(count):
    # a receiver that needs a delay (c) starts an overload flag at the first intermission bit;
    # a and b read that dominant bit in their intermission and send overload flags from the next
    # bit: 7 dominant bits, then the 8-bit delimiter; no counter changes (an overload is no error)
    bus = SimBus(500_000)
    a, b, c = bus.node("a"), bus.node("b"), bus.node("c")
    FaultInjector(bus).overload("c", frames=count)
    a.send(F)
    a.send(F)
    bus.run()
    r0, r1 = bus.trace
    assert (r0.end - r0.start) // 2000 == F.bits.length + count * (7 + 8)
    assert (r1.start - r0.end) // 2000 == 3
    assert all(n.tec == 0 and n.rec == 0 for n in (a, b, c)) and r1.kind == "frame"


def test_overload_count_is_at_most_two():
    bus = SimBus()
    bus.node("a")
    with pytest.raises(ValueError, match="0, 1 or 2"):
        FaultInjector(bus).overload("a", frames=3)


# --- behaviours found in review -------------------------------------------------------------


def test_receiver_reading_its_dominant_ack_as_recessive_has_a_bit_error():
    bus, a, b, c, fi = three()
    fi.flip(can_id=0x123, field="ack", bit=0, nodes=["b"])
    a.send(F)
    bus.run(frames=1)
    rec = first_error(bus)
    assert rec.detail["error"] == "bit" and rec.detail["field"] == "ACK_SLOT" and rec.detail["seen_by"] == "b"


def test_arbitration_lost_through_a_flip_is_not_a_retransmission():
    # a sends 0x123; b sees nothing odd; a alone reads a recessive ID bit as dominant: it has
    # lost arbitration (to nobody), becomes a receiver, and retries as after any lost round
    bus, a, b, c, fi = three()
    ones = [i for i in range(11) if F.bits.bits[F.bits.position("ID", i)] == "1"]
    fi.flip(can_id=0x123, field="ID", bit=ones[0], nodes=["a"])
    a.send(F)
    bus.run()
    assert a.arbitration_lost == 1 and a.retransmissions == 0 and a.tx_frames == 1


def test_suspended_passive_node_does_not_lose_arbitration():
    bus = SimBus(500_000)
    a, b = bus.node("a", one_shot=True), bus.node("b")
    bus.node("c")
    a.set_counters(130, 0, 0)
    a.send(Frame(0x300, b"\x01"))
    a.send(Frame(0x301, b"\x02"))  # a is suspended when b's frame goes: not a loss
    b.send_periodic(Frame(0x400, b"\x03"), 10_000_000, offset=0, count=1)
    bus.run(until=5_000_000)
    assert a.tx_frames == 2 and a.tx_failed == 0 and a.arbitration_lost == 0


def test_identical_frames_from_two_senders_are_not_received_by_either():
    bus = SimBus(500_000)
    a, b, c = bus.node("a"), bus.node("b"), bus.node("c")
    b.set_counters(0, 5, 0)
    a.send(F)
    b.send(F)
    bus.run()
    assert a.tx_frames == b.tx_frames == 1 and b.rx_frames == 0 and b.rec == 5
    assert c.rx_frames == 1 and c.rec == 0


def test_faulty_bus_keeps_remote_replies_and_self_reception():
    bus = SimBus(500_000)
    a = bus.node("a", receive_own_messages=True)
    b, deaf = bus.node("b"), bus.node("deaf")
    FaultInjector(bus).never_ack("deaf")  # every attempt is replayed bit by bit now
    b.set_remote_reply(Frame(0x700, b"\x5a"))
    a.send(Frame(0x700, remote=True, dlc=1))
    bus.run()
    assert [r.frame for r in bus.trace] == [Frame(0x700, remote=True, dlc=1), Frame(0x700, b"\x5a")]
    assert [f for _, f in iter(a.recv, None)] == [Frame(0x700, remote=True, dlc=1), Frame(0x700, b"\x5a")]


def test_each_stuck_fault_ends_on_its_own():
    bus = SimBus(500_000)
    a, b, c = bus.node("a"), bus.node("b"), bus.node("c")
    fi = FaultInjector(bus)
    fi.stuck("b", "dominant", start=1_000_000, end=1_000_000 + 40 * 2000)
    fi.stuck("a", "recessive", start=0)  # for good: a can never transmit
    bus.run(until=3_000_000)
    # the dominant fault ended after 40 bits, although a's fault never ends
    assert c.rec == 1 + 8 + 8 * ((40 - 12) // 8)


def test_run_guards_against_endless_retransmission():
    bus = SimBus()
    a, deaf = bus.node("a"), bus.node("deaf")
    FaultInjector(bus).never_ack("deaf")
    a.send(F)
    with pytest.raises(ValueError, match="never end"):
        bus.run(frames=1)
    bus2 = SimBus()
    x = bus2.node("x")
    x.send(F)
    bus2.disconnect(x)
    bus2.run()  # nothing on the bus can happen: returns
    assert bus2.trace == []


def test_run_guard_counts_a_stuck_recessive_node_as_unable_to_ack():
    bus = SimBus()
    a, b = bus.node("a"), bus.node("b")
    FaultInjector(bus).stuck("b", "recessive")
    a.send(F)
    with pytest.raises(ValueError, match="never end"):
        bus.run()


def test_transmitter_disconnected_mid_frame_loses_its_frame():
    # a leaves the bus at bit 25 of its frame: from there the wire is recessive, so b finds a
    # stuff error at the sixth recessive bit in a row (worked out from the frame's bits), and
    # nobody receives the frame; a sends it again after it reconnects
    f = Frame(0x100, b"\x01" * 8)
    bus = SimBus(500_000)
    a, b = bus.node("a"), bus.node("b")
    FaultInjector(bus).disconnect("a", at=25 * 2000, reconnect_at=5_000_000)
    a.send(f)
    bus.run(until=2_000_000)
    wire = f.bits.bits[:25] + "1" * 20
    expect = next(i for i in range(5, len(wire)) if wire[i - 5 : i + 1] == "111111")
    err = bus.trace[0]
    assert err.kind == "error" and err.detail["error"] == "stuff" and err.detail["seen_by"] == "b"
    assert err.detail["bit"] == expect and b.recv() is None and a.tx_frames == 0
    bus.run(until=10_000_000)
    assert b.recv() == (bus.trace[-1].end, f) and bus.trace[-1].start == 5_000_000


def test_stuck_dominant_starting_mid_frame_is_a_bit_error_at_its_bit():
    # a one-bit stuck-dominant pulse on a recessive data bit after bit 35 that is not a stuff
    # bit and makes no run of six dominant bits: the transmitter reads dominant where it sent
    # recessive (a bit error there, rule 3); the receivers see a valid-looking bit and then the
    # transmitter's error flag
    f = Frame(0x100, b"\x01" * 8)
    bits = f.bits.bits
    r = next(
        i
        for i in range(35, len(bits))
        if bits[i] == "1" and "000000" not in bits[i - 5 : i] + "0" + bits[i + 1 : i + 6]
    )
    bus = SimBus(500_000)
    a, b, c = bus.node("a"), bus.node("b"), bus.node("c")
    FaultInjector(bus).stuck("c", "dominant", start=r * 2000, end=(r + 1) * 2000)
    a.send(f)
    bus.run(until=2_000_000)
    err = bus.trace[0]
    assert err.kind == "error" and err.detail["error"] == "bit" and err.detail["bit"] == r
    assert err.detail["seen_by"] == "a" and a.tec == 8 - 1  # rule 3, then rule 7 on the resend
    assert bus.trace[1].kind == "frame" and b.recv()[1] == f


def test_stuck_dominant_starting_on_an_idle_bus_after_a_frame():
    # the fault begins 5 bits after the frame's EOF (intermission done, nothing queued): an
    # episode of its own from that bit — every node sees a SOF and then dominant bits
    f = Frame(0x100, b"\x01" * 8)
    bus = SimBus(500_000)
    a, b, c = bus.node("a"), bus.node("b"), bus.node("c")
    eof_end = f.bits.length * 2000
    FaultInjector(bus).stuck("c", "dominant", start=eof_end + 5 * 2000, end=eof_end + 2_000_000)
    a.send(f)
    bus.run(until=10_000_000)
    assert [r.kind for r in bus.trace] == ["frame", "error"]
    assert bus.trace[1].start == eof_end + 5 * 2000 and bus.trace[1].detail["error"] == "stuff"


def test_stuck_dominant_in_the_intermission_is_an_overload_then_rule_6():
    # dominant at the 2nd intermission bit: an overload flag (no error, so no rule 1 or 2),
    # then the dominant run after the flag counts rule 6. The frame was received before it:
    # rule 8 applies to REC 0 (stays 0), then each rule-6 increment adds 8
    f = Frame(0x100, b"\x01" * 8)
    bus = SimBus(500_000)
    a, b, c = bus.node("a"), bus.node("b"), bus.node("c")
    eof_end = f.bits.length * 2000
    hold = 1000  # bits of dominant from the 2nd intermission bit
    FaultInjector(bus).stuck("c", "dominant", start=eof_end + 2000, end=eof_end + 2000 + hold * 2000)
    a.send(f)
    bus.run(until=10_000_000)
    assert b.recv()[1] == f and bus.frames_ok == 1
    # overload flag: 6 bits of the 1000; dominant run after it: 994 bits, rule 6 at runs 8, 16,
    # ..., 992 = 124 increments
    assert b.rec == c.rec == 124 * 8
    # the transmitter (TEC 0 after rule 7) counts them too: the 32nd increment is TEC 256, bus
    # off (rule 10) inside the episode; it recovers after it (rule 12: counters back to 0)
    assert a.bus_off_count == 1 and a.state is ErrorState.ACTIVE and a.tec == 0


def test_bad_node_fault_specifications():
    bus = SimBus()
    bus.node("a")
    fi = FaultInjector(bus)
    with pytest.raises(ValueError, match="stuck level 'sideways'"):
        fi.stuck("a", "sideways")
    with pytest.raises(ValueError, match="end 5 ns is not after its start 10 ns"):
        fi.stuck("a", "dominant", start=10, end=5)
    with pytest.raises(ValueError, match="reconnect at 5 ns is not after disconnect at 10 ns"):
        fi.disconnect("a", at=10, reconnect_at=5)
    with pytest.raises(ValueError, match="occurrence 0"):
        fi.flip(occurrence=0)
    with pytest.raises(ValueError, match="already has a fault injector"):
        FaultInjector(bus)


def test_flip_of_a_bit_the_frame_does_not_have_is_reported_and_not_an_occurrence():
    # data bit 40 needs 6 data bytes: the 2-byte frame has 16 data bits; the 8-byte one has it
    bus = SimBus(500_000)
    a, b = bus.node("a"), bus.node("b")
    fi = FaultInjector(bus)
    rule = fi.flip(can_id=0x123, field="data", bit=40)
    a.send(F)
    with pytest.warns(RuntimeWarning, match=r"bit 40 of data: frame .* has only 16 such bits"):
        bus.run(frames=1)
    assert rule.skipped == 1 and rule.seen == 0 and rule.fired == 0 and bus.error_frames == 0
    a.send(Frame(0x123, bytes(8)))
    bus.run(frames=1)
    # the flipped attempt and its clean retransmission are occurrences 1 and 2
    assert rule.seen == 2 and rule.fired == 1 and bus.error_frames == 1


@pytest.mark.parametrize("onset_bit", [57, 58])
def test_stuck_dominant_from_the_last_intermission_bit_is_an_episode_of_its_own(onset_bit):
    # a 55-bit frame (EOF ends at bit 54, intermission 55..57): a node stuck dominant from the
    # third intermission bit on is a new SOF, not part of the frame's attempt. The frame ends at
    # bit 55 as without the fault; the episode starts when the bus is idle (bit 58): stuff error
    # at its 6th bit (rule 1: REC 1), active flag, first dominant bit after it (rule 2: +8), then
    # rule 6 at the 8th dominant bit after the flag and each 8 more, up to the release
    f = Frame(0x123, b"\x00")
    assert f.bits.length == 55
    bus = SimBus(500_000)
    a, b, c = bus.node("a"), bus.node("b"), bus.node("c")
    FaultInjector(bus).stuck("c", "dominant", start=onset_bit * 2000 - 1000, end=300_000)
    a.send(f)
    bus.run(until=10_000_000)
    frame, episode = bus.trace[0], bus.trace[1]
    assert frame.kind == "frame" and frame.end == 55 * 2000
    assert episode.start == 58 * 2000 and episode.detail["error"] == "stuff"
    # the fault lasts to 300 us = bit 150: the episode's dominant run after the flag (from its
    # bit 12 = bus bit 70) lasts bits 70..149, 80 bits: rule 6 at runs 8, 16, ..., 80 = 10 times
    assert b.rec == 1 + 8 + 10 * 8


def test_run_guard_ignores_a_stuck_recessive_fault_that_has_not_started():
    bus = SimBus(500_000)
    a, b = bus.node("a"), bus.node("b")
    FaultInjector(bus).stuck("b", "recessive", start=1_000_000_000)
    a.send(F)
    bus.run()  # b acknowledges until then: the run ends
    assert bus.frames_ok == 1
