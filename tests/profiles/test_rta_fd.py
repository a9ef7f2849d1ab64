"""CAN FD in the response-time analysis: the worst-case frame time at two bit rates, against a
second computation written here from ISO 11898-1:2015 and against Bordoloi and Samii's closed
form (RTSS 2014); hand-worked responses of a mixed bus; message sets; and bad input.

The standard's frame (DESIGN.md, "CAN FD"): SOF, identifier, RRS, IDE (extended: SRR, IDE, the
18 more identifier bits, RRS), FDF, res, BRS at the nominal rate; with BRS then ESI, DLC, data,
the stuff count (3 Gray-coded bits and parity), the CRC (17 bits up to 16 data bytes, 21 above)
with a fixed stuff bit before the stuff count and after every 4 bits of the CRC field, and the
CRC delimiter at the data rate; ACK slot, ACK delimiter and EOF (9) and the intermission (3) at
the nominal rate. Dynamic stuffing (a complement after 5 equal bits) runs from SOF to the end of
the data field; a run of five that ends the data field gets the fixed stuff bit instead.
"""

from __future__ import annotations

import dataclasses
import itertools
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from profiles.analysis.model import frame_worst, timebase
from profiles.analysis.priority import assign_priorities, identifiers_for
from profiles.analysis.rta import MessageSpec, analyse, utilisation
from profiles.message_set import MessageSet, StudyMessage
from stack import Frame
from stack.wire.fd import FD_LENGTHS, worst_case_fields

US = 1_000
MS = 1_000_000


def most_stuff_bits(pattern: str, level: int, run: int) -> tuple[int, tuple[int, int]]:
    """The most dynamic stuff bits a region of fixed ('0'/'1') and free ('x') bits can get,
    entered with the bus at ``level`` for ``run`` bits (``level`` -1: nothing before), and the
    state it then ends in (the one ending state when the region ends with fixed bits that force
    it). A stuff bit goes after five equal bits, except after the region's last bit."""
    best: dict[tuple[int, int], int] = {(level, run): 0}
    for i, p in enumerate(pattern):
        nxt: dict[tuple[int, int], int] = {}
        for (lvl, r), count in best.items():
            for b in (0, 1) if p == "x" else (int(p),):
                r2 = r + 1 if b == lvl else 1
                c, st = count, (b, r2)
                if r2 == 5 and i < len(pattern) - 1:
                    c, st = count + 1, (1 - b, 1)
                nxt[st] = max(nxt.get(st, -1), c)
        best = nxt
    end = max(best, key=best.__getitem__)
    return best[end], end


def standard_worst_case(n: int, extended: bool, brs: bool) -> tuple[int, int]:
    """(bits at the nominal rate with the intermission, bits at the data rate) of the longest
    FD frame with n data bytes, from the standard's layout (module docstring)."""
    dlc = format(FD_LENGTHS.index(n), "04b")
    if extended:
        head = "0" + "x" * 11 + "1" + "1" + "x" * 18 + "0" + "1" + "0"  # SOF ID SRR IDE ID RRS FDF res
    else:
        head = "0" + "x" * 11 + "0" + "0" + "1" + "0"  # SOF ID RRS IDE FDF res
    head += "1" if brs else "0"  # BRS
    before, state = most_stuff_bits(head, -1, 0)
    # FDF = 1 then res = 0 leave the same state after BRS whatever came before: one frame has both
    after, _ = most_stuff_bits("x" + dlc + "x" * (8 * n), *state)  # ESI DLC data
    width = 17 if n <= 16 else 21
    crc_field = 4 + width
    fixed = 1 + crc_field // 4
    at_nominal = len(head) + before + 9 + 3  # ACK slot, ACK delimiter, EOF; intermission
    at_data = 1 + 4 + 8 * n + after + crc_field + fixed + 1  # ESI DLC data SC+CRC fixed CRC-delim
    return (at_nominal, at_data) if brs else (at_nominal + at_data, 0)


def bordoloi_samii_data_bits(p: int) -> int:
    """Bordoloi and Samii, "The frame packing problem for CAN-FD", RTSS 2014: a frame with p data
    bytes takes 32 tau_arb + (28 + 5 ceil((p - 16) / 64) + 10 p) tau_data — Bosch's CAN FD 1.0
    frame, standard identifier, worst-case stuffing bounded by 2 bits a data byte; this is the
    data-phase part, the 32 arbitration-phase bits include the 3-bit intermission."""
    return 28 + 5 * math.ceil((p - 16) / 64) + 10 * p


@pytest.mark.parametrize("extended", [False, True])
@pytest.mark.parametrize("brs", [False, True])
def test_worst_case_frame_is_the_standards(extended, brs):
    for n in FD_LENGTHS:
        dlc = FD_LENGTHS.index(n)
        assert frame_worst(dlc, extended, fd=True, brs=brs) == standard_worst_case(n, extended, brs), n


def test_worst_case_frame_against_bordoloi_and_samii():
    # Standard identifiers, BRS. The arbitration phase is exactly their 32 bits (SOF..BRS 17, at
    # most 3 stuff bits, ACK slot, ACK delimiter, EOF, intermission). The data phase of an ISO
    # frame carries the stuff count their (non-ISO) frame lacks: 4 bits and the fixed stuff bit
    # after them, 5 more; and their 2 bits a byte is not the exact dynamic stuffing of ESI, DLC
    # and data after BRS: one bit more for 1, 2, 5, 6, 12, 16 and 32 bytes (the DLC's fixed bits
    # break the runs), one less for 48.
    fewer = {1, 2, 5, 6, 12, 16, 32}
    for p in FD_LENGTHS:
        nominal, data = frame_worst(FD_LENGTHS.index(p), False, fd=True, brs=True)
        assert nominal == 32
        expected = bordoloi_samii_data_bits(p) + 5 - (1 if p in fewer else 0) + (1 if p == 48 else 0)
        assert data == expected, p
    # 64 bytes at 500 kbit/s and 2 Mbit/s: their form 64 + 336.5 = 400.5 us, ISO 403 us
    r = analyse(
        [MessageSpec("m", 0x100, False, 15, 10 * MS, 10 * MS, fd=True, brs=True)], 500_000, data_bitrate=2_000_000
    )
    assert r["m"].c_ns == 32 * 2_000 + (bordoloi_samii_data_bits(64) + 5) * 500 == 403 * US


@pytest.mark.parametrize("extended", [False, True])
def test_worst_case_time_is_reached_by_a_real_frame(extended):
    # the wire layer's longest frame of each length: its own time on the bus (SOF..EOF, two bit
    # rates) plus the intermission is C
    for n in FD_LENGTHS:
        cid, esi, data = worst_case_fields(n, extended, brs=True)
        fb = Frame(cid, data, extended=extended, fd=True, brs=True, esi=esi).bits
        spec = MessageSpec("m", cid, extended, FD_LENGTHS.index(n), 10 * MS, 10 * MS, fd=True, brs=True)
        r = analyse([spec], 1_000_000, data_bitrate=5_000_000)["m"]
        assert r.c_ns == fb.duration_ns(1_000_000, 5_000_000) + 3_000
        assert r.response_ns == r.bound_ns == r.c_ns  # alone on the bus


def test_a_mixed_bus_worked_by_hand():
    # 500 kbit/s, data phase 2 Mbit/s (tau = 2 us, 0.5 us). From the standard (above):
    #   B: classical, 8 bytes, 0x080, T = 1 ms: 135 bits = 270 us
    #   A: FD + BRS, 64 bytes, 0x100, T = 2 ms: 32 nominal + 678 data bits = 64 + 339 = 403 us
    #   C: FD, no BRS, 12 bytes, 0x200, T = 10 ms: 184 bits at the nominal rate = 368 us
    # B: blocked by the longest lower frame, A: R = 403 + 270 = 673 us.
    # A: B = C_C = 368; w = 368 + ceil((w + 2)/1000)·270 = 638; R = 638 + 403 = 1041 us;
    #    busy period 403 -> 368 + 403 + 270 = 1041 -> 368 + 403 + 540 = 1311 -> 1311 (Q = 1).
    # C: B = 0; w = ceil((w + 2)/2000)·403 + ceil((w + 2)/1000)·270 = 673; R = 673 + 368 = 1041 us.
    assert standard_worst_case(64, False, True) == (32, 678)
    assert sum(standard_worst_case(12, False, False)) == 184
    spec = [
        MessageSpec("B", 0x080, False, 8, 1 * MS, 1 * MS),
        MessageSpec("A", 0x100, False, 15, 2 * MS, 2 * MS, fd=True, brs=True),
        MessageSpec("C", 0x200, False, 9, 10 * MS, 10 * MS, fd=True),
    ]
    res = analyse(spec, 500_000, data_bitrate=2_000_000)
    assert [res[k].c_ns for k in "BAC"] == [270 * US, 403 * US, 368 * US]
    assert [res[k].response_ns for k in "BAC"] == [673 * US, 1_041 * US, 1_041 * US]
    assert res["A"].busy_period_ns == 1_311 * US and res["A"].instances == 1
    u = 270 / 1000 + 403 / 2000 + 368 / 10_000
    assert utilisation(spec, 500_000, data_bitrate=2_000_000) == pytest.approx(u)


def test_a_data_bit_time_of_a_fraction_of_a_ns_is_rounded_up_once_per_frame():
    # 3 Mbit/s: 333.3 ns a bit. 8 bytes standard with BRS: 32 nominal bits (64 us at 500 kbit/s
    # with the intermission) and 113 at the data rate (37 666.7 ns): the frame SOF..EOF is
    # 29 · 2000 + 37 666.7 = 95 666.7 ns, 95 667 whole ns, and C = 95 667 + 6 000.
    nominal, data = standard_worst_case(8, False, True)
    assert (nominal, data) == (32, 113)
    spec = [MessageSpec("m", 0x100, False, 8, 10 * MS, 10 * MS, fd=True, brs=True)]
    r = analyse(spec, 500_000, data_bitrate=3_000_000)["m"]
    assert r.c_ns == 95_667 + 6_000
    assert timebase(500_000, 3_000_000).per_ns == 3_000_000  # lcm of the two rates


def test_exact_fd_frame_lengths():
    # frame_bits / data_bits of a real frame (stuffing = "exact") replace the worst case
    f = Frame(0x123, bytes(range(20)), fd=True, brs=True)
    fb = f.bits
    exact = MessageSpec(
        "m", 0x123, False, f.dlc, 10 * MS, 10 * MS, fd=True, brs=True, frame_bits=fb.length + 3, data_bits=fb.data_bits
    )
    r = analyse([exact], 500_000, data_bitrate=4_000_000)["m"]
    assert r.c_ns == fb.duration_ns(500_000, 4_000_000) + 3 * 2_000
    worst = analyse([dataclasses.replace(exact, frame_bits=None, data_bits=None)], 500_000, data_bitrate=4_000_000)
    assert r.c_ns < worst["m"].c_ns


def test_fd_without_brs_needs_no_data_bitrate_and_matches_a_classical_frame_of_its_length():
    # FD with up to 8 bytes and no BRS: all at the nominal rate, no data rate needed
    r = analyse([MessageSpec("m", 0x100, False, 8, 10 * MS, 10 * MS, fd=True)], 500_000)["m"]
    assert r.c_ns == sum(standard_worst_case(8, False, False)) * 2_000


def test_message_set_with_fd_messages():
    msgs = (
        StudyMessage("a", "n1", 0x100, 15, 2 * MS, 2 * MS, fd=True, brs=True),
        StudyMessage("b", "n2", 0x200, 8, 1 * MS, 1 * MS),
    )
    mset = MessageSet(500_000, msgs, 1.0, data_bitrate=2_000_000)
    assert mset.fd and msgs[0].length == 64 and msgs[1].length == 8
    assert mset.utilisation() == pytest.approx(403 / 2000 + 270 / 1000)
    res = analyse(mset.specs(), mset.bitrate, data_bitrate=mset.data_bitrate)
    assert res["a"].c_ns == 403 * US and res["a"].response_ns == 403 * US + 270 * US
    with pytest.raises(ValueError, match="message 'a': brs needs the set's data_bitrate"):
        MessageSet(500_000, msgs, 1.0)
    with pytest.raises(ValueError, match="message 'x': brs needs fd"):
        MessageSet(500_000, (StudyMessage("x", "n", 1, 8, MS, MS, brs=True),), 1.0, data_bitrate=2_000_000)
    with pytest.raises(ValueError, match="data_bitrate 250000"):
        MessageSet(500_000, msgs, 1.0, data_bitrate=250_000)


def _fd(**kw: object) -> MessageSpec:
    return dataclasses.replace(MessageSpec("m", 0x100, False, 15, MS, MS, fd=True, brs=True), **kw)


@pytest.mark.parametrize(
    "spec, data_bitrate, words",
    [
        (_fd(), None, ["'m'", "BRS needs the bus's data bit rate"]),
        (_fd(fd=False), 2_000_000, ["'m'", "brs needs fd"]),
        (_fd(brs=False, remote=True), None, ["'m'", "cannot be a remote frame"]),
        (_fd(fd=1), 2_000_000, ["'m'", "fd 1 must be True or False"]),
        (_fd(), 250_000, ["data_bitrate 250000", "500000..16000000"]),
        (_fd(), 20_000_000, ["data_bitrate 20000000"]),
        (_fd(), 2_000_000.0, ["data_bitrate 2000000.0"]),
        (_fd(data_bits=10), 2_000_000, ["'m'", "data_bits needs frame_bits"]),
        (_fd(frame_bits=100), 2_000_000, ["'m'", "needs data_bits"]),
        (_fd(frame_bits=100, data_bits=700), 2_000_000, ["'m'", "data_bits 700 must be 0..678"]),
        (_fd(frame_bits=700, data_bits=600), 2_000_000, ["'m'", "100 bits at the nominal rate: at most 32"]),
        (_fd(brs=False, frame_bits=100, data_bits=10), None, ["'m'", "data_bits is for an FD frame with BRS"]),
    ],
)
def test_bad_fd_input_is_refused_naming_message_and_rule(spec, data_bitrate, words):
    with pytest.raises(ValueError) as exc:
        analyse([spec], 500_000, data_bitrate=data_bitrate)
    for w in words:
        assert w in str(exc.value)


@settings(max_examples=20)
@given(
    st.lists(
        st.tuples(
            st.sampled_from([1, 2, 3, 4, 6]), st.sampled_from([0, 8, 11, 15]), st.booleans(), st.integers(30, 200)
        ),
        min_size=2,
        max_size=4,
    )
)
def test_opa_on_fd_messages_finds_an_order_whenever_one_exists(rows):
    # every permutation of the identifiers, analysed: OPA's verdict is whether any order works
    spec = [
        MessageSpec(f"m{i}", 0x10 + i, False, dlc, p * MS // 4, p * MS * d // 400, fd=True, brs=brs)
        for i, (p, dlc, brs, d) in enumerate(rows)
    ]

    def schedulable(order: tuple[str, ...]) -> bool:
        ids = identifiers_for(spec, order)
        res = analyse([dataclasses.replace(m, can_id=ids[m.name]) for m in spec], 500_000, data_bitrate=2_000_000)
        return all(r.schedulable for r in res.values())

    exists = any(schedulable(p) for p in itertools.permutations(m.name for m in spec))
    opa = assign_priorities(spec, 500_000, order="opa", data_bitrate=2_000_000)
    assert opa.schedulable == exists
    if exists:
        assert schedulable(opa.order)
