"""Bit timing solver and rules: against can-calc-bit-timing, python-can and hand-derived values."""

from __future__ import annotations

import json
import shutil
import subprocess

import can
import pytest

from stack.cli import main
from stack.phy import bittiming as bt
from stack.phy.bittiming import (
    BitTimingError,
    BusDelays,
    all_timings,
    check_timing,
    cia_sample_point,
    make_timing,
    max_bus_length,
    solve,
)

CALC = shutil.which("can-calc-bit-timing")


def _calc(controller: str, clock: int) -> list[dict[str, int | float]]:
    """Rows of `can-calc-bit-timing -q -c CLOCK CONTROLLER` (its default bitrate table)."""
    out = subprocess.run([CALC, "-q", "-c", str(clock), controller], capture_output=True, text=True, check=True).stdout
    rows = []
    for line in out.splitlines():
        f = line.split()
        if len(f) < 12 or not f[0].isdigit():
            continue
        rows.append(
            dict(
                bitrate=int(f[0]),
                prop_seg=int(f[2]),
                phase_seg1=int(f[3]),
                phase_seg2=int(f[4]),
                sjw=int(f[5]),
                brp=int(f[6]),
                real_sp=float(f[10].rstrip("%")),
            )
        )
    return rows


def _calc_is_legacy() -> bool:
    """Which tie rule the installed tool follows: at 16 MHz, 1 Mbit/s, 80 % both 16 tq (brp 1)
    and 8 tq (brp 2) reach 75 % exactly; Linux >= 5.19 (and can-utils since 2022) keeps brp 1."""
    out = subprocess.run(
        [CALC, "-q", "-c", "16000000", "-b", "1000000", "-s", "800", "sja1000"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    return int(out.split()[6]) == 2


@pytest.mark.subprocess
@pytest.mark.skipif(CALC is None, reason="can-calc-bit-timing (can-utils) not installed")
@pytest.mark.parametrize("controller", ["sja1000", "mcp251x", "flexcan", "at91", "rcar_can"])
@pytest.mark.parametrize("clock", [8_000_000, 16_000_000, 24_000_000, 33_333_333])
def test_matches_can_calc_bit_timing(controller: str, clock: int) -> None:
    rows = _calc(controller, clock)
    assert rows, "can-calc-bit-timing printed no table"
    compared = 0
    for r in rows:
        nbt = 1 + r["prop_seg"] + r["phase_seg1"] + r["phase_seg2"]
        try:
            # the installed tool predates Linux 6.3 and always uses SJW 1
            s = solve(clock, int(r["bitrate"]), limits=controller, sjw=1, legacy=_calc_is_legacy())
        except BitTimingError:
            assert not 8 <= nbt <= 25  # only the 8..25 tq rule may make us refuse what it found
            continue
        if not 8 <= nbt <= 25:
            # the kernel's search goes below 8 tq; ours must not
            assert 8 <= s.nbt <= 25
            continue
        got = (s.brp, s.prop_seg, s.phase_seg1, s.phase_seg2, s.sjw)
        assert got == (r["brp"], r["prop_seg"], r["phase_seg1"], r["phase_seg2"], r["sjw"]), r
        # the tool prints the sample point truncated to 0.1 %
        assert 0 <= s.sample_point - r["real_sp"] < 0.1
        compared += 1
    assert compared >= len(rows) // 2


@pytest.mark.subprocess
@pytest.mark.skipif(CALC is None, reason="can-calc-bit-timing (can-utils) not installed")
@pytest.mark.parametrize(
    "bitrate,sp_tenths",
    [(500_000, 750), (250_000, 850), (125_000, 700), (1_000_000, 700), (100_000, 750), (50_000, 833)],
)
def test_matches_can_calc_bit_timing_with_sample_point(bitrate: int, sp_tenths: int) -> None:
    out = subprocess.run(
        [CALC, "-q", "-c", "16000000", "-b", str(bitrate), "-s", str(sp_tenths), "sja1000"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    f = out.split()
    exp = dict(brp=int(f[6]), tseg1=int(f[2]) + int(f[3]), tseg2=int(f[4]), btr0=int(f[12], 16), btr1=int(f[13], 16))
    s = solve(16_000_000, bitrate, sample_point=sp_tenths / 10, sjw=1, legacy=_calc_is_legacy())
    assert (s.brp, s.tseg1, s.tseg2) == (exp["brp"], exp["tseg1"], exp["tseg2"])
    assert s.btr == (exp["btr0"], exp["btr1"])
    assert s.sample_point <= sp_tenths / 10


def test_tie_keeps_the_smaller_prescaler_as_linux_5_19() -> None:
    # 16 MHz, 1 Mbit/s, at most 80 %: 16 tq (brp 1) splits 12+4 = 75 % (13+3 = 81.25 % is
    # above), 8 tq (brp 2) splits 6+2 = 75 %: equal bitrate and sample point errors. Linux
    # >= 5.19 keeps the first found (the longer bit, brp 1); older kernels the last (brp 2)
    s = solve(16_000_000, 1_000_000, sample_point=80)
    assert (s.brp, s.tseg1, s.tseg2, s.sample_point) == (1, 11, 4, 75.0)
    old = solve(16_000_000, 1_000_000, sample_point=80, legacy=True)
    assert (old.brp, old.tseg1, old.tseg2, old.sample_point) == (2, 5, 2, 75.0)


def test_default_sjw_shrinks_to_fit_a_long_bus() -> None:
    # 120 m at 5 ns/m: round trip 1200 ns = 9.6 tq of 125 ns -> Prop_Seg 10 of TSEG1 11 leaves
    # Phase_Seg1 1: the default SJW (min(PS1, PS2 / 2) = 2 before the bus length) must drop to 1
    s = solve(16_000_000, 500_000, sample_point=75, delays=BusDelays(120))
    assert (s.brp, s.prop_seg, s.phase_seg1, s.phase_seg2, s.sjw) == (2, 10, 1, 4, 1)


def test_worked_example_16mhz_500k() -> None:
    # 16 MHz / 500 kbit/s = 32 clocks per bit: brp 2 gives 16 tq of 125 ns; 87.5 % of 16 tq is
    # 14 tq to the sample point, so tseg1 = 13, tseg2 = 2; SJA1000 BTR0 = (sjw-1)<<6 | brp-1.
    s = solve(16_000_000, 500_000)
    assert (s.brp, s.tseg1, s.tseg2, s.nbt) == (2, 13, 2, 16)
    assert s.tq_ns == 125.0
    assert (s.prop_seg, s.phase_seg1, s.phase_seg2) == (6, 7, 2)
    assert s.sample_point == 87.5 and s.bitrate_error == 0.0
    assert s.sjw == 1  # Linux >= 6.3 default: max(1, min(PS1, PS2 // 2)) = 1
    assert s.btr == (0x01, 0x1C)
    assert isinstance(s.timing, can.BitTiming)


def test_reference_sja1000_tq() -> None:
    # reference: "clk = 16 MHz and BRP = 0: Tclk = 62.5 ns and Tscl = 125 ns" -- the SJA1000 CAN
    # clock is half the oscillator, register BRP 0 means prescaler 1
    t = make_timing(8_000_000, brp=1, tseg1=13, tseg2=2, sjw=1)
    assert t.tq == 125 and t.btr0 == 0x00


def test_default_sjw_follows_kernel() -> None:
    s = solve(16_000_000, 1_000_000)  # 75 %: tseg1 11, tseg2 4 -> sjw = min(6, 4 // 2) = 2
    assert (s.tseg1, s.tseg2, s.sjw) == (11, 4, 2)


@pytest.mark.parametrize(
    "bitrate,sp",
    [(1_000_000, 75.0), (800_001, 75.0), (800_000, 80.0), (500_001, 80.0), (500_000, 87.5), (125_000, 87.5)],
)
def test_cia_sample_point(bitrate: int, sp: float) -> None:
    assert cia_sample_point(bitrate) == sp


def test_oscillator_tolerance_hand_values() -> None:
    s = solve(16_000_000, 500_000)  # NBT 16, PS1 7, PS2 2, SJW 1
    assert s.tolerance_resync == pytest.approx(100 * 1 / (20 * 16))  # 0.3125 %
    assert s.tolerance_error_flag == pytest.approx(100 * 2 / (2 * (13 * 16 - 2)))  # 0.4854 %
    assert s.oscillator_tolerance == pytest.approx(0.3125)


def test_oscillator_tolerance_agrees_with_python_can() -> None:
    # python-can puts Prop_Seg = ceil(2 x (loop delay + 5 ns/m x L) / tq): 70 m at 125 ns -> 6 tq
    s = solve(16_000_000, 500_000, sjw=2, delays=BusDelays(bus_length_m=70))
    assert s.prop_seg == 6
    assert s.oscillator_tolerance == pytest.approx(s.timing.oscillator_tolerance(node_loop_delay_ns=0, bus_length_m=70))


def test_max_bus_length_hand_value() -> None:
    # Prop_Seg 6 x 125 ns = 750 ns round trip -> 375 ns one way, minus 100 + 25 ns node delay,
    # leaves 250 ns of cable at 5 ns/m = 50 m
    d = BusDelays(transceiver_delay_ns=100, comparator_delay_ns=25)
    assert max_bus_length(6, 125.0, d) == pytest.approx(50.0)
    assert solve(16_000_000, 500_000, delays=BusDelays(50, 5, 100, 25)).prop_seg == 6
    # one metre more needs 2 x (255 + 125) = 760 ns > 750: Prop_Seg grows into Phase_Seg1
    s = solve(16_000_000, 500_000, delays=BusDelays(51, 5, 100, 25))
    assert (s.prop_seg, s.phase_seg1) == (7, 6)


def test_rule_nbt() -> None:
    t = make_timing(80_000_000, brp=4, tseg1=20, tseg2=6, sjw=1)  # 27 tq
    with pytest.raises(BitTimingError) as ei:
        check_timing(t, "m_can")
    assert ei.value.rule == bt.RULE_NBT and "27 tq" in str(ei.value)


def test_rule_sjw_phase_seg2() -> None:
    with pytest.raises(ValueError, match="sjw"):
        make_timing(16_000_000, brp=2, tseg1=13, tseg2=2, sjw=3)
    with pytest.raises(BitTimingError) as ei:
        solve(16_000_000, 500_000, sjw=3)  # every candidate near 87.5 % has Phase_Seg2 2
    assert "SJW" in ei.value.rule


def test_rule_sjw_phase_seg1() -> None:
    t = make_timing(8_000_000, brp=1, tseg1=4, tseg2=4, sjw=3)  # split 2 + 2: Phase_Seg1 2 < 3
    with pytest.raises(BitTimingError) as ei:
        check_timing(t)
    assert ei.value.rule == bt.RULE_SJW_PHASE_SEG1


def test_rule_prop_seg() -> None:
    # 100 m: 2 x 500 ns = 1000 ns = 16 tq of 62.5 ns, more than TSEG1 can give
    t = make_timing(16_000_000, brp=1, tseg1=11, tseg2=4, sjw=1)
    with pytest.raises(BitTimingError) as ei:
        check_timing(t, delays=BusDelays(bus_length_m=100))
    assert ei.value.rule == bt.RULE_PROP_SEG and "1000 ns" in str(ei.value)
    with pytest.raises(BitTimingError) as ei:
        solve(16_000_000, 1_000_000, delays=BusDelays(bus_length_m=100))
    assert ei.value.rule == bt.RULE_PROP_SEG


def test_rule_oscillator_tolerance() -> None:
    t = make_timing(16_000_000, brp=2, tseg1=13, tseg2=2, sjw=1)
    with pytest.raises(BitTimingError) as ei:
        check_timing(t, min_tolerance=0.4)  # SJW/(20 NBT) = 0.3125 %
    assert ei.value.rule == bt.RULE_TOLERANCE_RESYNC
    t = make_timing(16_000_000, brp=2, tseg1=13, tseg2=2, sjw=2)
    with pytest.raises(BitTimingError) as ei:
        check_timing(t, min_tolerance=0.5)  # resync 0.625 % ok, error flag 0.485 % not
    assert ei.value.rule == bt.RULE_TOLERANCE_ERROR_FLAG
    assert check_timing(t, min_tolerance=0.48).oscillator_tolerance == pytest.approx(100 / 206)


def test_rule_controller_limits() -> None:
    t = make_timing(16_000_000, brp=2, tseg1=14, tseg2=1, sjw=1)
    check_timing(t, "sja1000")
    with pytest.raises(BitTimingError) as ei:
        check_timing(t, "mcp251x")  # mcp251x Phase_Seg2 is 2..8
    assert ei.value.rule == bt.RULE_LIMITS and "tseg2=1" in str(ei.value)


def test_unreachable_bitrate_and_bad_sample_point() -> None:
    with pytest.raises(BitTimingError) as ei:
        solve(16_000_000, 3_000_000)
    assert ei.value.rule == bt.RULE_BITRATE and "2000000" in str(ei.value)
    with pytest.raises(BitTimingError) as ei:
        solve(16_000_000, 500_000, sample_point=40)
    assert ei.value.rule == bt.RULE_SAMPLE_POINT
    with pytest.raises(ValueError, match="sja1000"):
        solve(16_000_000, 500_000, limits="nosuch")


def test_wide_controller_timing() -> None:
    # 80 MHz, 10 kbit/s: 8000 clocks per bit = brp 320 x 25 tq, beyond python-can's brp <= 64
    s = solve(80_000_000, 10_000, limits="m_can")
    assert s.brp * s.nbt == 8000 and s.brp > 64 and s.bitrate == 10_000
    assert s.btr is None
    with pytest.raises(BitTimingError) as ei:
        solve(80_000_000, 10_000, limits="sja1000")
    assert ei.value.rule == bt.RULE_LIMITS and "1..64" in str(ei.value)


def test_custom_limits_equal_named() -> None:
    lim = bt.parse_limits("tseg1=3..16, tseg2=2..8, sjw=4, brp=1..64")
    a = solve(20_000_000, 250_000, limits=lim)
    b = solve(20_000_000, 250_000, limits="mcp251x")
    assert (a.brp, a.tseg1, a.tseg2, a.sjw) == (b.brp, b.tseg1, b.tseg2, b.sjw)
    with pytest.raises(ValueError, match="brp"):
        bt.parse_limits("tseg1=3..16,tseg2=2..8,sjw=4")


def test_all_timings_ranked() -> None:
    sols = all_timings(24_000_000, 250_000, limits="flexcan")
    best = solve(24_000_000, 250_000, limits="flexcan")
    assert (sols[0].brp, sols[0].tseg1, sols[0].tseg2) == (best.brp, best.tseg1, best.tseg2)
    assert len(sols) > 3
    keys = [(round(s.bitrate_error, 9), round(s.sample_point_error, 9)) for s in sols[1:]]
    assert keys == sorted(keys)
    for s in sols:
        assert 8 <= s.nbt <= 25 and s.sample_point <= 87.5
        assert 24_000_000 / (s.brp * s.nbt) == pytest.approx(s.bitrate)


def _cli(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    rc = main(["bittiming", *argv])
    out, err = capsys.readouterr()
    return rc, out, err


def test_cli_json(capsys: pytest.CaptureFixture[str]) -> None:
    rc, out, _ = _cli(capsys, "--clock", "16000000", "--bitrate", "500000", "--json")
    assert rc == 0
    d = json.loads(out)
    assert {
        k: d[k]
        for k in (
            "brp",
            "tseg1",
            "tseg2",
            "sjw",
            "tq_ns",
            "sample_point",
            "bitrate",
            "bitrate_error",
            "oscillator_tolerance",
        )
    } == dict(
        brp=2,
        tseg1=13,
        tseg2=2,
        sjw=1,
        tq_ns=125.0,
        sample_point=87.5,
        bitrate=500000.0,
        bitrate_error=0.0,
        oscillator_tolerance=0.3125,
    )
    rc, out, _ = _cli(capsys, "--clock", "16000000", "--bitrate", "500000", "--all", "--json")
    rows = json.loads(out)
    assert isinstance(rows, list) and rows[0]["brp"] == 2 and all("oscillator_tolerance" in r for r in rows)


def test_cli_text(capsys: pytest.CaptureFixture[str]) -> None:
    rc, out, _ = _cli(capsys, "--clock", "16000000", "--bitrate", "500000", "--bus-length", "40")
    assert rc == 0
    assert "BTR0 0x01  BTR1 0x1c" in out and "prop_seg 6" in out and "max bus length 75.0 m" in out


@pytest.mark.parametrize(
    "argv,needle",
    [
        (["--clock", "16000000", "--bitrate", "3000000"], "3000000"),
        (["--clock", "16000000", "--bitrate", "500000", "--sample-point", "120"], "sample point 120"),
        (["--clock", "16000000", "--bitrate", "500000", "--controller", "foo"], "mcp251x"),
        (["--clock", "16MHz", "--bitrate", "500000"], "16MHz"),
        (["--clock", "16000000", "--bitrate", "500000", "--bus-length", "-3"], "bus_length_m=-3"),
    ],
)
def test_cli_errors(capsys: pytest.CaptureFixture[str], argv: list[str], needle: str) -> None:
    rc, out, err = _cli(capsys, *argv)
    assert rc == 2 and out == ""
    assert err.count("\n") == 1 and needle in err and "Traceback" not in err


def test_all_lists_every_split_at_or_below_the_sample_point() -> None:
    # 16 MHz, 500 kbit/s: brp 2 gives 16 tq; every TSEG2 from 2 (87.5 %) to 8 (50 %, SJA1000's
    # TSEG2 max) is a valid split: 7 rows with brp 2, first the kernel's pick
    sols = all_timings(16_000_000, 500_000)
    assert sols[0] == solve(16_000_000, 500_000)
    brp2 = sorted((s.tseg2, s.sample_point) for s in sols if s.brp == 2)
    assert brp2 == [(t2, 100 * (16 - t2) / 16) for t2 in range(2, 9)]
    assert len({(s.brp, s.tseg1, s.tseg2) for s in sols}) == len(sols)
    assert all(50 <= s.sample_point <= 87.5 for s in sols)
