"""CAN FD on the simulated bus (ISO 11898-1:2015) against independent expectations: frame times
from bit counts worked out in this file from the standard's field layout, arbitration from the
standard's bit order, the protocol exception and the FD-intolerant node with their counters worked
out by hand from the twelve rules, ESI under error passive, and errors in each FD field."""

from fractions import Fraction

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stack.bus.faults import FaultInjector
from stack.bus.sim import SimBus
from stack.controller.events import TxDone
from stack.controller.node import FD_KINDS, Node, NodeError
from stack.wire.coding import Field
from stack.wire.decoder import MODES
from stack.wire.frame import FD_LENGTHS, Frame

# -- the standard, written out here -------------------------------------------------------------


def _ib(v: int, w: int) -> list[int]:
    return [(v >> (w - 1 - i)) & 1 for i in range(w)]


def iso_bit_counts(f: Frame) -> tuple[int, int]:
    """(bits at the nominal rate, bits at the data rate) of a CAN FD frame SOF..EOF, from ISO
    11898-1:2015: SOF, arbitration and control fields, data; dynamic stuffing after five equal bits
    up to the end of the data field (none after its last bit); the CRC field: stuff count (3) and
    parity (1), the CRC (17 bits up to 16 data bytes, else 21), a fixed stuff bit before every 4 of
    those bits; CRC delimiter, ACK slot, ACK delimiter, EOF (7). With BRS the data bit rate runs
    from the sample point of BRS to the sample point of the CRC delimiter: counted as the bits
    after BRS up to and including the CRC delimiter."""
    if f.extended:  # SOF, ID[28:18], SRR, IDE, ID[17:0], RRS, FDF, res
        raw = [0, *_ib(f.can_id >> 18, 11), 1, 1, *_ib(f.can_id & 0x3FFFF, 18), 0, 1, 0]
    else:  # SOF, ID[10:0], RRS, IDE, FDF, res
        raw = [0, *_ib(f.can_id, 11), 0, 0, 1, 0]
    brs = len(raw)
    raw += [int(f.brs), int(f.esi), *_ib(FD_LENGTHS.index(len(f.data)), 4)]
    for byte in f.data:
        raw += _ib(byte, 8)
    out: list[int] = []
    where = []  # the stuffed position of each unstuffed bit
    level, run = -1, 0
    for i, b in enumerate(raw):
        where.append(len(out))
        out.append(b)
        level, run = b, (run + 1 if b == level else 1)
        if run == 5 and i < len(raw) - 1:
            out.append(1 - b)
            level, run = 1 - b, 1
    width = 17 if len(f.data) <= 16 else 21
    crc_field = 4 + width + -(-(4 + width) // 4)
    total = len(out) + crc_field + 1 + 1 + 1 + 7
    if not f.brs:
        return total, 0
    nominal = where[brs] + 1 + 9  # SOF..BRS, then ACK slot, ACK delimiter, EOF
    return nominal, total - nominal


def time_ns(nominal: int, data: int, bitrate: int, data_bitrate: int) -> int:
    """Exact time of that many bits at the two rates, floored to the ns (the bus's clock)."""
    return int((Fraction(nominal, bitrate) + Fraction(data, data_bitrate)) * 10**9)


def arbitration_bits(f: Frame) -> str:
    """The arbitration field in the order ISO 11898-1:2015 sends it (0 dominant): standard ID,
    RTR (a classical remote frame: recessive) or RRS (FD: always dominant), IDE; extended: base ID,
    SRR, IDE, extension, RTR/RRS."""
    rtr = "1" if f.remote else "0"
    if f.extended:
        return format(f.can_id >> 18, "011b") + "11" + format(f.can_id & 0x3FFFF, "018b") + rtr
    return format(f.can_id, "011b") + rtr + "0"


def fd_frames(lengths=FD_LENGTHS):
    return st.builds(
        lambda ext, cid, n, fill, brs, esi: Frame(
            cid & (0x1FFFFFFF if ext else 0x7FF),
            bytes(fill(i) for i in range(n)),
            extended=ext,
            fd=True,
            brs=brs,
            esi=esi,
        ),
        st.booleans(),
        st.integers(0, 0x1FFFFFFF),
        st.sampled_from(lengths),
        st.sampled_from([lambda i: 0, lambda i: 0xFF, lambda i: (i * 37 + 11) & 0xFF, lambda i: 0x55]),
        st.booleans(),
        st.booleans(),
    )


# -- the bus and its nodes ----------------------------------------------------------------------


def test_node_kinds_are_the_decoder_modes_and_default_from_the_bus():
    assert set(FD_KINDS) == set(MODES)
    classical = SimBus(500_000)
    assert classical.data_bitrate is None and classical.node("a").fd == "classic"
    fd_bus = SimBus(500_000, data_bitrate=2_000_000)
    assert fd_bus.node("a").fd == "fd" and fd_bus.node("t", fd="tolerant").fd == "tolerant"
    assert fd_bus.node("c", fd="classic").fd == "classic"
    assert fd_bus.summary()["data_bitrate"] == 2_000_000 and "data_bitrate" not in classical.summary()


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"data_bitrate": 250_000}, r"data bit rate 250000: .* from the nominal bit rate \(500000\)"),
        ({"data_bitrate": 20_000_000}, "data bit rate 20000000"),
        ({"data_bitrate": 2.0e6}, "data bit rate 2000000.0"),
        ({"data_bitrate": True}, "data bit rate True"),
    ],
)
def test_bad_data_bit_rate_names_the_value_and_the_rule(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SimBus(500_000, **kwargs)


def test_bad_kind_and_an_fd_node_without_a_data_bit_rate_are_refused():
    with pytest.raises(ValueError, match="fd 'yes': one of 'fd'"):
        SimBus(500_000, data_bitrate=2_000_000).node("a", fd="yes")
    with pytest.raises(ValueError, match=r"FD enabled .* has no data bit rate"):
        SimBus(500_000).node("a", fd="fd")
    bus = SimBus(500_000)
    node = bus.add(Node("t", fd="tolerant"))  # a classical node is fine anywhere
    assert node.fd == "tolerant"


@pytest.mark.parametrize("kind", ["tolerant", "classic"])
def test_a_node_that_is_not_fd_enabled_refuses_fd_frames(kind):
    bus = SimBus(500_000, data_bitrate=2_000_000)
    node = bus.node("a", fd=kind)
    with pytest.raises(NodeError, match=rf"cannot send the CAN FD frame .*it is '{kind}'"):
        node.send(Frame(0x10, bytes(12), fd=True))
    node.send(Frame(0x10, bytes(8)))  # classical frames go
    plain = SimBus(500_000).node("b")
    with pytest.raises(NodeError, match="has no data bit rate"):
        plain.send(Frame(0x10, b"", fd=True))


@settings(max_examples=150, deadline=None)
@given(
    fd_frames(),
    st.sampled_from([(500_000, 2_000_000), (1_000_000, 5_000_000), (250_000, 1_000_000), (500_000, 500_000)]),
)
def test_fd_frame_time_follows_both_bit_rates(f, rates):
    bitrate, data_bitrate = rates
    bus = SimBus(bitrate, data_bitrate=data_bitrate)
    a, b = bus.node("a"), bus.node("b")
    a.send(f)
    a.send(Frame(0x1FFFFFFF, extended=True, remote=True))  # the lowest priority: goes after it
    bus.run()
    r1, r2 = bus.trace
    sent = Frame(f.can_id, f.data, extended=f.extended, fd=True, brs=f.brs)  # ESI dominant: error active
    nominal, data = iso_bit_counts(sent)
    assert r1.bits == nominal + data
    assert r1.end - r1.start == time_ns(nominal, data, bitrate, data_bitrate) == bus.frame_ns(sent)
    assert r2.start == r1.end + 3 * 10**9 // bitrate  # intermission at the nominal rate
    # the wire layer rounds the same time to the nearest ns: equal here, where bit times are whole ns
    assert r1.end - r1.start == sent.bits.duration_ns(bitrate, data_bitrate)
    assert b.recv() == (r1.end, sent) and r1.frame == sent


def test_fd_frame_time_at_bit_rates_whose_bit_time_is_not_whole_ns():
    f = Frame(0x123, bytes(range(64)), fd=True, brs=True)
    bus = SimBus(333_333, data_bitrate=3_000_000)
    bus.node("a").send(f)
    bus.node("b")
    bus.run()
    nominal, data = iso_bit_counts(f)
    assert bus.trace[0].end == time_ns(nominal, data, 333_333, 3_000_000)


@settings(max_examples=80, deadline=None)
@given(
    st.lists(
        st.one_of(
            fd_frames(lengths=(0, 8, 64)),
            st.builds(
                lambda i, r: Frame(i, remote=True, dlc=1) if r else Frame(i, b"\x01"),
                st.integers(0, 0x7FF),
                st.booleans(),
            ),
            st.builds(
                lambda i, r: Frame(i, extended=True, remote=True, dlc=1) if r else Frame(i, b"\x01", extended=True),
                st.integers(0, 0x1FFFFFFF),
                st.booleans(),
            ),
        ),
        min_size=2,
        max_size=6,
        unique_by=lambda f: f.key,
    )
)
def test_classical_and_fd_frames_arbitrate_by_the_standard_bit_order(frames):
    bus = SimBus(500_000, data_bitrate=2_000_000)
    bus.node("rx")
    for i, f in enumerate(frames):
        bus.node(f"n{i}").send(f)
    bus.run(frames=1)
    won, expected = bus.trace[0].frame, min(frames, key=arbitration_bits)
    assert (won.can_id, won.extended, won.remote, won.fd) == (
        expected.can_id,
        expected.extended,
        expected.remote,
        expected.fd,
    )


@pytest.mark.parametrize("extended", [False, True])
def test_fd_data_frame_beats_a_classical_remote_frame_and_standard_beats_extended(extended):
    # RRS is dominant where a remote frame's RTR is recessive; with the same base identifier a
    # standard frame's IDE (dominant) beats an extended frame's SRR/IDE (recessive)
    cid = 0x1234567 if extended else 0x123
    remote = Frame(cid, remote=True, dlc=8, extended=extended)
    fd = Frame(cid, bytes(16), fd=True, brs=True, extended=extended)
    bus = SimBus(500_000, data_bitrate=2_000_000)
    bus.node("rx")
    bus.node("r").send(remote)
    bus.node("f").send(fd)
    if not extended:
        bus.node("e").send(Frame(0x123 << 18, bytes(64), extended=True, fd=True))
    bus.run()
    assert [r.frame for r in bus.trace] == [fd, remote] + (
        [] if extended else [Frame(0x123 << 18, bytes(64), extended=True, fd=True)]
    )


def test_classical_and_fd_data_frames_with_one_identifier_collide_at_fdf():
    # the same arbitration field (RTR and RRS both dominant): both go on transmitting; at FDF the
    # FD transmitter sends recessive where the classical one sends r0 dominant: a bit error
    classic, fd = Frame(0x100, bytes(8)), Frame(0x100, bytes(8), fd=True)
    bus = SimBus(500_000, data_bitrate=2_000_000)
    bus.node("rx")
    bus.node("a").send(classic)
    bus.node("b").send(fd)
    bus.run(frames=1)
    rec = bus.trace[0]
    assert rec.kind == "collision" and rec.detail["error"] == "bit" and rec.detail["seen_by"] == "b"
    assert rec.detail["field"] == "FDF" and rec.detail["bit"] == fd.bits.position(Field.FDF)


def test_esi_is_recessive_when_the_transmitter_is_error_passive():
    bus = SimBus(500_000, data_bitrate=2_000_000)
    a, b = bus.node("a"), bus.node("b")
    queued = Frame(0x123, bytes(12), fd=True, brs=True)  # ESI as queued: dominant
    done = []
    a.listen(TxDone, done.append)
    a.set_counters(130, 0, 0)  # error passive (rule 9)
    a.send(queued)
    bus.run()
    a.set_counters(0, 0, bus.now())  # error active again
    a.send(Frame(0x124, bytes(12), fd=True, brs=True, esi=True))  # asks for ESI: not its to give
    bus.run()
    got = [b.recv()[1] for _ in range(2)]
    assert [f.esi for f in got] == [True, False]
    assert got[0] == Frame(0x123, bytes(12), fd=True, brs=True, esi=True) and bus.trace[0].frame.esi
    assert done[0].frame is queued  # TxDone reports the frame as it was queued
    # ESI is covered by the CRC and the stuffing: the passive frame's bits are its own
    assert bus.trace[0].bits == sum(iso_bit_counts(got[0]))


# -- mixed networks: the protocol exception and the FD-intolerant node ------------------------


def _mixed(kind):
    bus = SimBus(500_000, data_bitrate=2_000_000)
    a, b, x = bus.node("a"), bus.node("b"), bus.node("x", fd=kind)
    return bus, a, b, x


def test_a_tolerant_node_integrates_through_fd_frames_and_receives_classical_ones():
    bus, a, b, t = _mixed("tolerant")
    fd, classic = Frame(0x123, bytes(64), fd=True, brs=True), Frame(0x124, bytes(8))
    a.send(fd)
    a.send(classic)
    bus.run()
    assert [r.kind for r in bus.trace] == ["frame", "frame"] and bus.error_frames == 0
    assert b.recv()[1] == fd and b.recv()[1] == classic
    assert t.recv()[1] == classic and t.recv() is None  # no FD frame, no error either
    assert (t.tec, t.rec, a.tec) == (0, 0, 0)


def test_a_tolerant_node_alone_cannot_acknowledge_an_fd_frame():
    bus = SimBus(500_000, data_bitrate=2_000_000)
    a, t = bus.node("a"), bus.node("t", fd="tolerant")
    a.send(Frame(0x123, bytes(8), fd=True))
    with pytest.raises(ValueError, match="never end"):
        bus.run()
    bus.run(duration=1_000_000)
    assert bus.frames_ok == 0 and all(r.detail["error"] == "ack" for r in bus.trace)
    assert t.rec == 0


def test_a_classic_node_destroys_fd_frames_until_it_is_error_passive():
    # 0x123, standard: no stuff bit before FDF, which is bit 14. Each attempt: x (CAN 2.0) finds
    # a form error at FDF (rule 1: REC +1) and flags at bits 15..20; a sends res dominant, then BRS
    # recessive at 16, reads dominant: bit error (rule 3: TEC +8), its flag 17..22; b reads six
    # dominant bits from res: a stuff error at 20 (rule 1: +1), its flag 21..26. x reads dominant
    # after its flag (a's and b's flags): rule 2, REC +8. So per attempt a +8, b +1, x +9; the
    # wire is dominant 15..26, then 8 delimiter bits and 3 of intermission.
    bus, a, b, x = _mixed("classic")
    f = Frame(0x123, bytes(8), fd=True, brs=True)
    assert f.bits.position(Field.FDF) == 14
    a.send(f)
    bus.run(frames=1)
    errors = [r for r in bus.trace if r.kind == "error"]
    first = errors[0]
    assert first.detail["error"] == "form" and first.detail["field"] == "r0" and first.detail["bit"] == 14
    assert first.detail["seen_by"] == "x" and first.detail["counters"] == "a:8/0 b:0/1 x:0/9"
    assert first.detail["rules"] == "a:rule 3;b:rule 1;x:rule 1,rule 2"
    assert first.bits == 35 and first.end - first.start == 35 * 2000  # all at the nominal rate
    # x: 14 attempts make REC 126; the 15th 127 (rule 1) then 135: error passive at rule 2.
    # a: 15 x 8 = 120. From then x's flags are passive: the 16th attempt goes through (rule 7 for
    # a, rule 8 for b) and x counts its form error (136)
    assert len(errors) == 15 and "x:error-warning->error-passive" in errors[-1].detail["states"]
    ok = bus.trace[-1]
    assert ok.kind == "frame" and ok.detail["error"] == "form" and ok.detail["accepted_by"] == "b"
    assert (a.tec, b.rec, x.rec) == (119, 14, 136) and b.recv()[1] == f and x.recv() is None
    # x's passive flag completes at the sixth recessive bit from the ACK delimiter, then its
    # delimiter: the attempt ends 6 bits after EOF
    assert ok.bits == f.bits.length + 6


def test_an_fd_node_at_a_recessive_res_bit_integrates_without_error():
    # the protocol exception of an FD node (ISO 11898-1:2015): b alone reads res recessive
    bus, a, b, c = _mixed("fd")
    f = Frame(0x123, bytes(8), fd=True)
    FaultInjector(bus).flip(can_id=0x123, field="res", nodes=["b"])
    a.send(f)
    bus.run(frames=1)
    assert bus.trace[0].kind == "frame" and bus.error_frames == 0
    assert b.recv() is None and c.recv()[1] == f and (b.rec, c.rec, a.tec) == (0, 0, 0)


# -- errors in the FD fields --------------------------------------------------------------------

F20 = Frame(0x123, bytes(range(20)), fd=True, brs=True)  # CRC-21
F8 = Frame(0x123, bytes(range(8)), fd=True, brs=True)  # CRC-17


def _flip(frame, **flip):
    bus = SimBus(500_000, data_bitrate=2_000_000)
    a, b, c = bus.node("a"), bus.node("b"), bus.node("c")
    FaultInjector(bus).flip(can_id=frame.can_id, **flip)
    a.send(frame)
    bus.run(frames=1)
    return bus, bus.trace[0]


def _time(rec, frame, last_data_bit):
    """The attempt's time with the bits after BRS up to ``last_data_bit`` at 2 Mbit/s."""
    data = max(0, last_data_bit - frame.bits.position(Field.BRS))
    return time_ns(rec.bits - data, data, 500_000, 2_000_000)


def test_bit_error_in_the_data_phase_flags_at_the_nominal_rate():
    bus, rec = _flip(F20, field="data", bit=3)  # 0 -> 1: the transmitter reads recessive
    e = F20.bits.position(Field.DATA, 3)
    assert (rec.detail["error"], rec.detail["field"], rec.detail["bit"], rec.detail["seen_by"]) == (
        "bit",
        "DATA",
        e,
        "a",
    )
    assert rec.end - rec.start == _time(rec, F20, e)  # bits after the error at 500 kbit/s


def test_stuff_error_in_the_dynamic_stuffed_part():
    # b reads a stuff bit flipped: six equal bits, a stuff error at that bit, in the data phase
    stuff = next(p for p in F20.bits.stuff_positions if p > F20.bits.position(Field.DATA))
    bus, rec = _flip(F20, field="raw", bit=stuff, nodes=["b"])
    assert (rec.detail["error"], rec.detail["bit"], rec.detail["seen_by"]) == ("stuff", stuff, "b")
    assert rec.end - rec.start == _time(rec, F20, stuff)


@pytest.mark.parametrize("frame, index", [(F8, 0), (F8, 5), (F20, 6)])
def test_fixed_stuff_bit_of_the_wrong_level_is_a_form_error_there(frame, index):
    bus, rec = _flip(frame, field="fixed_stuff", bit=index, nodes=["b"])
    p = frame.bits.fields[Field.FIXED_STUFF][index]
    assert (rec.detail["error"], rec.detail["field"], rec.detail["bit"]) == ("form", "FIXED_STUFF", p)
    assert rec.end - rec.start == _time(rec, frame, p)


@pytest.mark.parametrize(
    "frame, field, bit, where",
    [
        (F8, "stuff_count", 0, "STUFF_COUNT"),
        (F8, "stuff_count", 2, "STUFF_COUNT"),
        (F20, "STUFF_COUNT", 1, "STUFF_COUNT"),
        (F8, "crc", 0, "CRC"),
        (F8, "crc", 16, "CRC"),
        (F20, "crc", 20, "CRC"),
    ],
)
def test_stuff_count_and_crc_errors_are_signalled_after_the_ack_delimiter(frame, field, bit, where):
    # a bit that is not the last before a fixed stuff bit (those are the 4th of each group of 4,
    # below): the stuff count, its parity and the CRC are checked at the CRC delimiter, and a
    # mismatch is a CRC error, signalled after the ACK delimiter
    bus, rec = _flip(frame, field=field, bit=bit, nodes=["b"])
    ack_delim = frame.bits.position(Field.ACK_DELIM)
    assert (rec.detail["error"], rec.detail["field"], rec.detail["bit"]) == ("crc", where, ack_delim)
    assert rec.detail["counters"] == "a:8/0 b:0/9 c:0/1"  # b: rules 1 and 2; a: rule 3
    assert rec.end - rec.start == _time(rec, frame, frame.bits.crc_delim)  # the data phase ran to its end


def test_flipped_brs_is_a_bit_error_before_any_data_phase():
    bus, rec = _flip(F8, field="BRS")
    assert (rec.detail["error"], rec.detail["field"]) == ("bit", "BRS")
    assert rec.end - rec.start == rec.bits * 2000


@pytest.mark.parametrize("frame, field, bit", [(F8, "stuff_count", 3), (F8, "crc", 3), (F20, "crc", 15)])
def test_a_flip_before_a_fixed_stuff_bit_is_caught_by_it(frame, field, bit):
    # the fixed stuff bit after it is the complement of the bit as sent: equal to the flipped bit,
    # a form error at the fixed stuff bit, at once
    bus, rec = _flip(frame, field=field, bit=bit, nodes=["b"])
    flipped = frame.bits.position(
        Field.STUFF_PARITY if field == "stuff_count" else Field.CRC, 0 if field == "stuff_count" else bit
    )
    assert flipped + 1 in frame.bits.fields[Field.FIXED_STUFF]
    assert (rec.detail["error"], rec.detail["field"], rec.detail["bit"]) == ("form", "FIXED_STUFF", flipped + 1)


# -- times inside an FD attempt ------------------------------------------------------------------


@pytest.mark.parametrize("rates", [(500_000, 2_000_000), (333_333, 1_234_567), (1_000_000, 8_000_000)])
def test_bit_times_of_an_attempt_and_their_inverse(rates):
    # bit k of an attempt starts at k_n / bitrate + k_d / data_bitrate (the data bits before it),
    # floored to the ns; the bit of a time is the first that starts at or after it (exact times)
    bitrate, data_bitrate = rates
    bus = SimBus(bitrate, data_bitrate=data_bitrate)
    phase = (17, 400)

    def exact(k):
        data = max(0, min(k, phase[1] + 1) - phase[0])
        return (Fraction(k - data, bitrate) + Fraction(data, data_bitrate)) * 10**9

    for k in (0, 1, 16, 17, 18, 200, 400, 401, 402, 600):
        assert bus.attempt_ns(k, phase) == int(exact(k))
        assert bus.attempt_ns(k) == k * 10**9 // bitrate
    for ns in range(0, 1_000_000, 997):
        k = bus.attempt_bit(ns, phase)
        assert exact(k) >= ns and (k == 0 or exact(k - 1) < ns)


def test_a_fault_that_begins_in_the_data_phase_takes_effect_at_its_bit():
    # c's transmitter sticks dominant 100 us after SOF, inside the data phase (500 kbit/s: BRS
    # ends 17 bits = 34 us in; then 0.5 us a bit): a's bit error comes at its first recessive bit
    # from the bit during which 100 us falls
    f = Frame(0x123, bytes([0x55]) * 32, fd=True, brs=True)
    brs = iso_bit_counts(f)[0] - 9 - 1  # SOF..BRS are the nominal bits before the tail
    onset = brs + 1 + -(-(100_000 - (brs + 1) * 2000) // 500)  # first bit starting at or after 100 us
    expected = next(k for k in range(onset, len(f.bits.bits)) if f.bits.bits[k] == "1")
    bus = SimBus(500_000, data_bitrate=2_000_000)
    a, b, c = bus.node("a"), bus.node("b"), bus.node("c")
    FaultInjector(bus).stuck("c", "dominant", start=100_000, end=1_000_000)
    a.send(f)
    bus.run(until=2_000_000)
    rec = bus.trace[0]
    assert (rec.detail["error"], rec.detail["bit"], rec.detail["seen_by"]) == ("bit", expected, "a")
