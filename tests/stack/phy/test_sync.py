"""Synchronisation: the quantum-level receiver's rules and the drift simulation vs the formulas."""

from __future__ import annotations

import json

import pytest

from stack.cli import main
from stack.phy.bittiming import solve
from stack.phy.sync import (
    Node,
    SyncReceiver,
    _edge_gaps,
    frames_received,
    max_drift,
    receive,
    worst_case_frames,
)
from stack.wire.frame import Frame


def _hard_sync(rx: SyncReceiver) -> None:
    for _ in range(3):
        rx.tick(1)
    rx.tick(0)  # the SOF edge: this quantum is Sync_Seg
    assert rx.hard_syncs == 1 and rx.position == 1


def _run(rx: SyncReceiver, level: int, quanta: int) -> None:
    for _ in range(quanta):
        rx.tick(level)


def test_hard_sync_then_nominal_bits() -> None:
    rx = SyncReceiver(tseg1=11, tseg2=4, sjw=2)  # 16 tq, sample at quantum 12
    _hard_sync(rx)
    _run(rx, 0, 15)  # rest of SOF
    assert rx.position == 0 and rx.sampled == [0]
    _run(rx, 1, 16)  # a recessive bit
    assert rx.sampled == [0, 1]
    rx.tick(0)  # edge exactly in Sync_Seg: e = 0, no change
    assert rx.resyncs == 0 and rx.sample_point == 12 and rx.bit_length == 16


@pytest.mark.parametrize("late,expected_sample,expected_len", [(1, 13, 17), (2, 14, 18), (5, 14, 18)])
def test_late_edge_lengthens_phase_seg1_by_min_e_sjw(late: int, expected_sample: int, expected_len: int) -> None:
    rx = SyncReceiver(tseg1=11, tseg2=4, sjw=2)
    _hard_sync(rx)
    _run(rx, 0, 15)
    _run(rx, 1, 16 + late)  # the next edge arrives `late` quanta after Sync_Seg: e = +late
    rx.tick(0)
    assert rx.resyncs == 1 and rx.max_phase_error == late
    assert rx.sample_point == expected_sample and rx.bit_length == expected_len


def test_early_edge_shortens_phase_seg2() -> None:
    # e = -1 <= SJW: the edge quantum becomes the next bit's Sync_Seg at once
    rx = SyncReceiver(tseg1=11, tseg2=4, sjw=2)
    _hard_sync(rx)
    _run(rx, 0, 15)
    _run(rx, 1, 15)
    rx.tick(0)
    assert rx.position == 1 and rx.bit_length == 16 and rx.max_phase_error == 1
    # e = -3 > SJW 2: Phase_Seg2 shortened by SJW only, the bit is 14 tq
    rx = SyncReceiver(tseg1=11, tseg2=4, sjw=2)
    _hard_sync(rx)
    _run(rx, 0, 15)
    _run(rx, 1, 13)
    rx.tick(0)  # quantum 13 of 16: Phase_Seg2 loses SJW, so this bit ends after 14 quanta
    assert rx.position == 0 and rx.bit_length == 16 and rx.max_phase_error == 3 and rx.resyncs == 1


def test_one_synchronisation_between_sample_points() -> None:
    rx = SyncReceiver(tseg1=11, tseg2=4, sjw=2)
    _hard_sync(rx)
    _run(rx, 0, 15)
    _run(rx, 1, 17)
    rx.tick(0)  # e = +1, resync
    rx.tick(1)
    rx.tick(0)  # a second edge before the sample point: ignored
    assert rx.resyncs == 1 and rx.sample_point == 13


def test_no_resync_after_dominant_sample() -> None:
    rx = SyncReceiver(tseg1=11, tseg2=4, sjw=2)
    _hard_sync(rx)
    _run(rx, 0, 13)  # SOF sampled dominant at quantum 12
    rx.tick(1)
    rx.tick(0)  # recessive->dominant glitch after a dominant sample: not a sync edge
    assert rx.resyncs == 0 and rx.sample_point == 12


def test_three_samples_majority() -> None:
    rx = SyncReceiver(tseg1=11, tseg2=4, sjw=1, nof_samples=3)
    _hard_sync(rx)
    _run(rx, 0, 15)
    _run(rx, 1, 11)  # quanta 0..10 of the bit recessive
    rx.tick(0)  # quantum 11 dominant; samples at 10, 11, 12 -> 1, 0, 1
    rx.tick(1)
    assert rx.sampled == [0, 1]


def test_nominal_clock_receives_every_frame() -> None:
    s = solve(16_000_000, 500_000)
    frames = [
        *worst_case_frames(),
        Frame(0x123, b"\x01\x02"),
        Frame(0x1ABCDEF0, b"\xaa" * 8, extended=True),
        Frame(0x55, b"", remote=True, dlc=4),
    ]
    for fr in frames:
        for phase in (0.0, 0.3, 0.99):
            r = receive(fr, s.timing, phase=phase)
            assert r.ok and r.decoded.frame == fr
            assert r.resyncs == 0  # with equal clocks every edge falls in Sync_Seg


def test_propagation_delay_is_absorbed_by_hard_sync() -> None:
    s = solve(16_000_000, 500_000)
    fr = worst_case_frames()[0]
    for drift in (0, 5000, -9000):
        a = receive(fr, s.timing, rx=Node(drift, 0.0))
        b = receive(fr, s.timing, rx=Node(drift, 1234.5), tx=Node(0, 100.0))
        assert (a.ok, a.kind, a.error, a.misread) == (b.ok, b.kind, b.error, b.misread)


def test_worst_case_frames_are_the_classic_pattern() -> None:
    frames = worst_case_frames()
    gaps = _edge_gaps(frames[0].bits.bits)
    # stuffing never lets more than 10 bits pass between recessive->dominant edges ...
    for fr in frames:
        stuffed_region = fr.bits.bits[: fr.bits.crc_delim]
        assert max(_edge_gaps(stuffed_region)) <= 10
    # ... and the worst case runs 00000 11111 00000 ... with that gap edge after edge
    run = best = 0
    for g in gaps:
        run = run + 1 if g == 10 else 0
        best = max(best, run)
    assert best >= 6
    assert "0000011111" * 4 in frames[0].bits.bits


@pytest.mark.parametrize(
    "bitrate,sjw,sample_point",
    [(500_000, None, None), (1_000_000, 1, None), (1_000_000, 2, None), (250_000, 4, 75.0)],
)
def test_largest_drift_is_at_least_the_formula(bitrate: int, sjw: int | None, sample_point: float | None) -> None:
    s = solve(16_000_000, bitrate, sjw=sjw, sample_point=sample_point)
    formula_ppm = s.oscillator_tolerance * 1e4
    assert frames_received(s.timing, formula_ppm) is None  # a guaranteed bound: must work at it
    res = max_drift(s, 0, 40_000, steps=8, resolution_ppm=50)
    assert res.formula_ppm == pytest.approx(formula_ppm)
    assert res.max_drift_ppm >= formula_ppm
    if s.tolerance_resync <= s.tolerance_error_flag:
        # the formula shares 2 df between two nodes; one drifting node with 10-bit edge gaps
        # catches up SJW per 10 NBT, so it reaches about SJW / (10 NBT): twice condition 1
        assert res.max_drift_ppm >= 0.95 * s.sjw / (10 * s.nbt) * 1e6
    assert res.first_failure is not None and res.first_failure.drift_ppm != 0
    f = res.first_failure.reception
    assert f.kind in ("stuff", "crc", "form", "mismatch")
    assert f.misread is not None and (f.error is None or f.misread <= f.error.position)


def test_failure_grows_with_drift() -> None:
    s = solve(16_000_000, 500_000)
    fail = frames_received(s.timing, 20_000)
    assert fail is not None and not fail.reception.ok
    d = fail.as_dict()
    assert d["kind"] in ("stuff", "crc", "form") and d["field"] and d["bit"] is not None


def test_cli_sync_json(capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["sync", "--bitrate", "500000", "--clock", "16000000", "--drift-ppm", "0..20000", "--json"])
    out, _ = capsys.readouterr()
    assert rc == 0
    d = json.loads(out)
    assert d["formula_ppm"] == pytest.approx(3125.0)
    assert d["max_drift_ppm"] >= d["formula_ppm"]
    assert d["timing"] == {
        "brp": 2,
        "tseg1": 13,
        "tseg2": 2,
        "sjw": 1,
        "nbt": 16,
        "sample_point": 87.5,
        "nof_samples": 1,
    }
    ff = d["first_failure"]
    assert ff["kind"] in ("stuff", "crc", "form") and "field" in ff and "bit" in ff
    assert d["max_drift_ppm"] < abs(ff["drift_ppm"]) <= d["max_drift_ppm"] + 10


def test_cli_sync_text(capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["sync", "--bitrate", "1000000", "--clock", "16000000", "--sjw", "2", "--drift-ppm", "0..30000"])
    out, _ = capsys.readouterr()
    assert rc == 0 and "largest drift received" in out and "formula tolerance: 6250 ppm" in out


@pytest.mark.parametrize(
    "argv,needle",
    [
        (["--drift-ppm", "5..1"], "5..1"),
        (["--drift-ppm", "a..b"], "a..b"),
        (["--sjw", "3"], "SJW"),
        (["--samples", "2"], "samples"),
    ],
)
def test_cli_sync_errors(capsys: pytest.CaptureFixture[str], argv: list[str], needle: str) -> None:
    rc = main(["sync", "--bitrate", "500000", "--clock", "16000000", *argv])
    out, err = capsys.readouterr()
    assert rc == 2 and out == ""
    assert err.count("\n") == 1 and needle in err and "Traceback" not in err


# ---------------------------------------------------------------------------------------------
# Two nodes on a bus with propagation delay: ACK round trip, arbitration, max bus length

from stack.phy.bittiming import BusDelays  # noqa: E402
from stack.phy.propagation import (  # noqa: E402
    BUS_LENGTH_FRAMES,
    DEFAULT_PHASES,
    ack_exchange,
    arbitration_exchange,
    max_bus_length_simulated,
)
from stack.wire.coding import Field  # noqa: E402

# Hand arithmetic per timing (tq = brp / clock; one-way delay = L x cable + node delay):
# - formula (Prop_Seg rule):   L_f  = (prop_seg x tq / 2 - node) / cable
# - sample point:              L_sp = ((1 + tseg1) x tq / 2 - node) / cable
#   B synchronises up to 1 tq after the edge reaches it (at `phase` tq, the largest of the
#   default phases being 0.9), so the simulated boundary is L_sp - 0.9 x tq / (2 cable).
# - one tq of round trip:      q = tq / (2 cable)
BUS_CASES = [
    # clock, bitrate, sample point, delays, (brp, tseg1, prop_seg, phase_seg1), L_f, L_sp, q
    (16_000_000, 500_000, None, BusDelays(), (2, 13, 6, 7), 75.0, 175.0, 12.5),
    (16_000_000, 500_000, 75.0, BusDelays(0, 5, 60, 40), (2, 11, 5, 6), 42.5, 130.0, 12.5),
    (16_000_000, 125_000, None, BusDelays(), (8, 13, 6, 7), 300.0, 700.0, 50.0),
    (8_000_000, 125_000, 75.0, BusDelays(0, 5.5, 100, 50), (4, 11, 5, 6), 200.0, 2850 / 5.5, 500 / 11),
    (24_000_000, 1_000_000, None, BusDelays(0, 5, 30, 20), (2, 8, 4, 4), 70 / 3, 65.0, 25 / 3),
]


@pytest.mark.parametrize("clock,bitrate,sp,delays,regs,formula_m,sample_point_m,quantum_m", BUS_CASES)
def test_simulated_bus_length_against_the_formula(
    clock: int,
    bitrate: int,
    sp: float | None,
    delays: BusDelays,
    regs: tuple[int, int, int, int],
    formula_m: float,
    sample_point_m: float,
    quantum_m: float,
) -> None:
    s = solve(clock, bitrate, sample_point=sp, delays=delays)
    assert (s.brp, s.tseg1, s.prop_seg, s.phase_seg1) == regs  # the hand figures assume these
    res = max_bus_length_simulated(s, resolution_m=0.05)
    assert res.formula_m == pytest.approx(formula_m)
    assert res.sample_point_m == pytest.approx(sample_point_m)
    assert res.quantum_m == pytest.approx(quantum_m)
    # where the round trip plus B's synchronisation lag (0.9 tq at the worst default phase)
    # reaches A's sample point
    assert res.simulated_m == pytest.approx(sample_point_m - max(DEFAULT_PHASES) * quantum_m, abs=0.05)
    # within one tq of round trip of the sample-point bound ...
    assert sample_point_m - quantum_m <= res.simulated_m <= sample_point_m
    # ... and above the Prop_Seg formula by Sync_Seg + Phase_Seg1, less up to one tq of sync lag
    ps1 = regs[3]
    assert ps1 * quantum_m <= res.simulated_m - formula_m <= (1 + ps1) * quantum_m
    f = res.first_failure
    assert f is not None and f.kind == "ack" and f.node == "A" and f.field == Field.ACK_SLOT
    assert f.position == BUS_LENGTH_FRAMES[0].bits.position(Field.ACK_SLOT)


def test_zero_delay_everything_works() -> None:
    s = solve(16_000_000, 500_000)
    frames = [Frame(0x123, b"\x01\x02"), Frame(0x1ABCDEF0, b"\xaa" * 8, extended=True), *BUS_LENGTH_FRAMES]
    for ph in (0.0, 0.5, 0.99):
        for fr in frames:
            r = ack_exchange(fr, s.timing, phase=ph)
            assert r.ok and r.kind == "ok", r.describe()
        r = arbitration_exchange(*BUS_LENGTH_FRAMES, s.timing, phase=ph)
        assert r.ok and r.winner == "B"  # 0x652 < 0x65A
        r = arbitration_exchange(BUS_LENGTH_FRAMES[1], BUS_LENGTH_FRAMES[0], s.timing, phase=ph)
        assert r.ok and r.winner == "A"
        # both start at the same instant, each hard-syncing on its own SOF
        r = arbitration_exchange(*BUS_LENGTH_FRAMES, s.timing, phase=ph, b_start_ns=0.0)
        assert r.ok and r.winner == "B"
        # a standard frame beats an extended one with the same base identifier (RTR/SRR vs IDE)
        r = arbitration_exchange(Frame(0x12A << 18, b"", extended=True), Frame(0x12A, b""), s.timing, phase=ph)
        assert r.ok and r.winner == "B"


def test_beyond_the_boundary_ack_and_arbitration_errors() -> None:
    # 500 kbit/s, 16 MHz: tq 125 ns, sample point 14 tq = 1750 ns after the bit starts.
    s = solve(16_000_000, 500_000)
    fa, fb = BUS_LENGTH_FRAMES
    inside = BusDelays(162.0)  # round trip 1620 ns + 0.9 tq (112.5 ns) = 1732.5 ns < 1750 ns
    beyond = BusDelays(176.0)  # round trip 1760 ns > 1750 ns even with no sync lag
    for ph in DEFAULT_PHASES:
        assert ack_exchange(fa, s.timing, inside, phase=ph).ok
        assert arbitration_exchange(fa, fb, s.timing, inside, phase=ph).winner == "B"
        r = ack_exchange(fa, s.timing, beyond, phase=ph)
        assert (r.ok, r.kind, r.node, r.field, r.index) == (False, "ack", "A", Field.ACK_SLOT, 0)
        assert r.position == fa.bits.position(Field.ACK_SLOT)
        assert "ACK_SLOT" in r.describe() and r.as_dict()["kind"] == "ack"
        # B's dominant SOF, delayed past A's sample point, overlaps A's recessive first ID bit
        # (0x65A starts with 1): A wrongly loses arbitration there instead of at ID bit 7
        r = arbitration_exchange(fa, fb, s.timing, beyond, phase=ph)
        assert (r.ok, r.kind, r.node, r.field, r.index, r.position) == (False, "arbitration", "A", Field.ID, 0, 1)
        assert "expected node A at bit 8 from SOF" in r.describe()
    # phase 0.5 puts the boundary at (1750 - 62.5) / 10 = 168.75 m
    assert ack_exchange(fa, s.timing, BusDelays(168.7), phase=0.5).ok
    assert ack_exchange(fa, s.timing, BusDelays(168.8), phase=0.5).kind == "ack"


def test_transmitter_monitoring_sees_a_bit_error_beyond_the_boundary() -> None:
    # 0x001 vs 0x000: SOF and ID bits 0..3 are five dominant bits, so both send a recessive stuff
    # bit at position 5. B's ID bit 3, a round trip late, is still dominant at A's sample point
    # of that stuff bit; a stuff bit is not part of arbitration, so A sees a bit error there.
    s = solve(16_000_000, 500_000)
    r = arbitration_exchange(Frame(0x001, b""), Frame(0x000, b""), s.timing, BusDelays(176.0))
    assert (r.kind, r.node, r.field, r.index, r.position) == ("bit", "A", Field.ID, None, 5)


def test_formula_length_works_with_clocks_at_the_oscillator_tolerance() -> None:
    # the two rules together: Prop_Seg covers the round trip, Phase_Seg1/SJW the drift; nodes
    # each off by the tolerance df (2 df apart) on a bus of the formula's length must still work
    for clock, bitrate, sp in [(16_000_000, 500_000, None), (8_000_000, 125_000, 75.0)]:
        s = solve(clock, bitrate, sample_point=sp, delays=BusDelays(0, 5, 60, 40))
        df_ppm = s.oscillator_tolerance * 1e4
        at = BusDelays(s.max_bus_length, 5, 60, 40)
        for d in (df_ppm, -df_ppm):
            for ph in DEFAULT_PHASES:
                assert ack_exchange(BUS_LENGTH_FRAMES[0], s.timing, at, d, -d, ph).ok
                assert arbitration_exchange(*BUS_LENGTH_FRAMES, s.timing, at, d, -d, ph).winner == "B"
        res = max_bus_length_simulated(s, drift_ppm=2 * df_ppm, resolution_m=1.0)
        assert s.max_bus_length <= res.simulated_m < res.sample_point_m


def test_exchange_bad_input() -> None:
    s = solve(16_000_000, 500_000)
    with pytest.raises(ValueError, match="arbitration"):
        arbitration_exchange(Frame(0x10, b"\x01"), Frame(0x10, b"\x02"), s.timing)
    with pytest.raises(ValueError, match="phase"):
        ack_exchange(Frame(0x10, b""), s.timing, phase=1.0)
    with pytest.raises(ValueError, match="cable"):
        max_bus_length_simulated(s, BusDelays(0, 0.0))


def test_cli_sync_bus_length(capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["sync", "--bitrate", "500000", "--clock", "16000000", "--bus-length", "200", "--json"])
    out, _ = capsys.readouterr()
    assert rc == 0
    d = json.loads(out)
    assert d["formula_m"] == pytest.approx(75.0) and d["sample_point_m"] == pytest.approx(175.0)
    assert 162.5 <= d["simulated_m"] <= 175.0
    assert d["ok_at_bus_length"] is False and d["at_bus_length"]["kind"] == "ack"
    rc = main(
        ["sync", "--bitrate", "125000", "--clock", "16000000", "--bus-length", "100", "--transceiver-delay", "100"]
    )
    out, _ = capsys.readouterr()
    # formula (6 x 500 / 2 - 100) / 5 = 280 m; sample point (14 x 500 / 2 - 100) / 5 = 680 m
    assert rc == 0 and "ACK and arbitration work" in out and "280.0 m" in out and "680.0 m" in out


@pytest.mark.parametrize(
    "argv,needle",
    [
        (["--bus-length", "-1"], "-1"),
        (["--bus-length", "x"], "x"),
        (["--bus-length", "1", "--cable-delay", "0"], "cable"),
    ],
)
def test_cli_sync_bus_length_errors(capsys: pytest.CaptureFixture[str], argv: list[str], needle: str) -> None:
    rc = main(["sync", "--bitrate", "500000", "--clock", "16000000", *argv])
    out, err = capsys.readouterr()
    assert rc == 2 and out == ""
    assert err.count("\n") == 1 and needle in err and "Traceback" not in err
