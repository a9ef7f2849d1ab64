"""CAN FD bit timing: the data phase against can-calc-bit-timing (when the installed one knows CAN
FD) and a brute-force search, transmitter delay compensation from the kernel's rule, CiA 601-1's
recommendations, and the command line."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
from dataclasses import replace

import can
import pytest

from stack.cli import main
from stack.phy.bittiming import FD_DATA, FD_NOMINAL, BitTimingError, BusDelays, cia_sample_point, solve
from stack.phy.bittiming_fd import RULE_DATA_BITRATE, RULE_FD_CONTROLLER, calc_tdco, solve_fd
from stack.phy.controllers import CONTROLLERS, TdcLimits

CALC = shutil.which("can-calc-bit-timing")


def _calc_knows_fd() -> bool:
    """can-utils before 2021 (Debian 12 ships 2020.11) has no data bit rate option and no FD
    controller; its list then lacks mcp251xfd."""
    if CALC is None:
        return False
    out = subprocess.run([CALC, "-l"], capture_output=True, text=True).stdout
    return "mcp251xfd" in out.split()


needs_calc_fd = pytest.mark.skipif(not _calc_knows_fd(), reason="can-calc-bit-timing with CAN FD (-d) not installed")

# our controller -> can-calc-bit-timing's name and nominal limits; its copy of the M_CAN table
# has TSEG2 from 2 where the kernel's m_can_bittiming_const_31X has 1
TOOL = {
    "m_can": ("mcan-v3.1+", replace(CONTROLLERS["m_can"], tseg2_min=2)),
    "mcp251xfd": ("mcp251xfd", CONTROLLERS["mcp251xfd"]),
    "flexcan_fd": ("flexcan-fd", CONTROLLERS["flexcan_fd"]),
}


def _rows(name: str, clock: int, bitrate: int, data_bitrate: int) -> list[list[str]]:
    out = subprocess.run(
        [CALC, "-q", "-c", str(clock), "-b", str(bitrate), "-d", str(data_bitrate), name],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    return [line.split() for line in out.splitlines() if line.strip()]


@pytest.mark.subprocess
@needs_calc_fd
@pytest.mark.parametrize("controller", sorted(TOOL))
@pytest.mark.parametrize("clock", [20_000_000, 24_000_000, 40_000_000, 80_000_000])
@pytest.mark.parametrize(
    "rates", [(500_000, 2_000_000), (1_000_000, 5_000_000), (250_000, 1_000_000), (500_000, 8_000_000)]
)
def test_both_phases_match_can_calc_bit_timing(controller: str, clock: int, rates: tuple[int, int]) -> None:
    name, limits = TOOL[controller]
    nominal_row, data_row = _rows(name, clock, *rates)
    if "possible***" in " ".join(data_row):
        with pytest.raises(BitTimingError):
            solve_fd(clock, *rates, limits=limits)
        return
    s = solve_fd(clock, *rates, limits=limits)
    for sol, row in ((s.nominal, nominal_row), (s.data, data_row)):
        # Bitrate TQ PrS PhS1 PhS2 SJW BRP ...
        assert (sol.prop_seg, sol.phase_seg1, sol.phase_seg2, sol.sjw, sol.brp) == tuple(int(x) for x in row[2:7]), row
    # the NBTP / NBTCFG column of the nominal row: the same register our layout packs
    if controller != "flexcan_fd":
        assert int(nominal_row[-1], 16) == s.nominal.registers[0].value


def _brute_force(clock: int, bitrate: int, sp_permille: int, lim, nbt_min: int = 1) -> tuple[int, int]:
    """The least (bit rate error, sample point error) over every prescaler and split within the
    limits with the sample point at or below the request: the kernel's ranking, searched whole."""
    best = None
    for brp in range(lim.brp_min, lim.brp_max + 1, lim.brp_inc):
        ideal = clock / (brp * bitrate)
        for nbt in {math.floor(ideal), math.ceil(ideal)}:
            if nbt < max(nbt_min, 1 + lim.tseg1_min + lim.tseg2_min) or nbt > 1 + lim.tseg1_max + lim.tseg2_max:
                continue
            br_err = abs(bitrate - clock // (brp * nbt))
            for tseg2 in range(lim.tseg2_min, lim.tseg2_max + 1):
                tseg1 = nbt - 1 - tseg2
                sp = 1000 * (nbt - tseg2) // nbt
                if lim.tseg1_min <= tseg1 <= lim.tseg1_max and sp <= sp_permille:
                    key = (br_err, sp_permille - sp)
                    best = key if best is None or key < best else best
    assert best is not None
    return best


@pytest.mark.parametrize("controller", ["m_can", "mcp251xfd", "flexcan_fd"])
@pytest.mark.parametrize(
    "clock,data_bitrate,sp",
    [
        (40_000_000, 2_000_000, 75.0),
        (80_000_000, 5_000_000, 70.0),
        (24_000_000, 3_000_000, 80.0),
        (60_000_000, 6_000_000, 75.0),
    ],
)
def test_data_phase_is_the_best_the_limits_allow(controller: str, clock: int, data_bitrate: int, sp: float) -> None:
    lim = CONTROLLERS[controller]
    s = solve(clock, data_bitrate, sample_point=sp, limits=lim.data, rules=FD_DATA)
    got = (abs(data_bitrate - clock // (s.brp * s.nbt)), round(sp * 10) - 1000 * (s.nbt - s.tseg2) // s.nbt)
    assert got == _brute_force(clock, data_bitrate, round(sp * 10), lim.data)


@pytest.mark.parametrize("controller", ["m_can", "mcp251xfd", "flexcan_fd"])
@pytest.mark.parametrize("clock,bitrate", [(40_000_000, 500_000), (80_000_000, 1_000_000), (24_000_000, 250_000)])
def test_nominal_phase_is_the_best_the_limits_allow(controller: str, clock: int, bitrate: int) -> None:
    lim = CONTROLLERS[controller]
    s = solve(clock, bitrate, limits=lim, rules=FD_NOMINAL)
    sp = round(cia_sample_point(bitrate) * 10)
    got = (abs(bitrate - clock // (s.brp * s.nbt)), sp - 1000 * (s.nbt - s.tseg2) // s.nbt)
    assert got == _brute_force(clock, bitrate, sp, lim, nbt_min=8)
    # the nominal phase of an FD controller is not held to classical CAN's 25 tq
    assert clock // (s.brp * bitrate) == s.nbt


def test_worked_example_mcp2518fd_40mhz_500k_2m() -> None:
    """40 MHz, 500 kbit/s / 2 Mbit/s on an MCP2518FD, worked out from the datasheet's formulas:
    40 MHz / 500 kbit/s = 80 clocks, brp 1 -> 80 tq, 87.5 % -> TSEG2 10, TSEG1 69, SJW 10 / 2 = 5;
    40 MHz / 2 Mbit/s = 20 clocks, brp 1 -> 20 tq, 75 % -> TSEG2 5, TSEG1 14, SJW 2.
    CiNBTCFG = BRP-1 << 24 | TSEG1-1 << 16 | TSEG2-1 << 8 | SJW-1; CiDBTCFG the same positions;
    CiTDC: TDCMOD 0b10 (auto) << 16 | TDCO << 8 with TDCO = the data sample point in SYSCLK
    periods, (1 + 14) x 1 = 15."""
    s = solve_fd(40_000_000, 500_000, 2_000_000, limits="mcp2518fd")
    regs = {r.name: r.value for r in s.registers}
    assert regs["CiNBTCFG"] == (0 << 24) | (68 << 16) | (9 << 8) | 4
    assert regs["CiDBTCFG"] == (0 << 24) | (13 << 16) | (4 << 8) | 1
    assert regs["CiTDC"] == (0b10 << 16) | (15 << 8)
    assert s.tdc.enabled and s.tdc.tdco == 15 and s.tdco_ns == 375.0
    assert [r.met for r in s.recommendations] == [True, True, True]


# ---------------------------------------------------------------------------------------------
# Transmitter delay compensation (kernel's can_calc_tdco, written here from its description)


def _kernel_tdco(brp: int, tseg1: int, lim: TdcLimits) -> int | None:
    if brp not in (1, 2):
        return None
    sp = (1 + tseg1) * brp
    return None if sp < lim.tdco_min else min(sp, lim.tdco_max)


@pytest.mark.parametrize("controller", ["m_can", "mcp251xfd", "flexcan_fd"])
@pytest.mark.parametrize(
    "clock,data_bitrate",
    [(40_000_000, 2_000_000), (80_000_000, 1_000_000), (80_000_000, 5_000_000), (20_000_000, 500_000)],
)
def test_tdc_follows_the_kernel(controller: str, clock: int, data_bitrate: int) -> None:
    lim = CONTROLLERS[controller]
    s = solve_fd(clock, min(500_000, data_bitrate), data_bitrate, limits=lim)
    want = _kernel_tdco(s.data.brp, s.data.tseg1, lim.tdc)
    assert s.tdc.enabled == (want is not None)
    assert s.tdc.tdco == (want or 0)


def test_tdc_cases() -> None:
    flex = CONTROLLERS["flexcan_fd"]
    # 80 MHz at 2 Mbit/s, 80 %: 40 clocks, brp 1, TSEG2 8 (FlexCAN's most), TSEG1 31; the sample
    # point after 32 clocks is more than TDCOFF's 5 bits hold: capped at 31
    s = solve_fd(80_000_000, 500_000, 2_000_000, data_sample_point=80, limits=flex)
    assert (s.data.brp, s.data.nbt, s.data.tseg1, s.tdc.enabled, s.tdc.tdco) == (1, 40, 31, True, 31)
    # at 1 Mbit/s and 75 % no 40 tq split fits FlexCAN's TSEG2 <= 8: the kernel takes brp 4 x 20
    # tq, and a prescaler above 2 has no TDC
    s = solve_fd(80_000_000, 500_000, 1_000_000, limits=flex)
    assert (s.data.brp, s.data.nbt, s.tdc.enabled, s.tdc.tdco) == (4, 20, False, 0)
    assert "prescaler 4" in s.tdc.reason
    # a controller without TDC
    assert not calc_tdco(s.data, None).enabled


def test_loop_delay_longer_than_a_data_bit_needs_tdc() -> None:
    # 5 Mbit/s at 40 MHz: 8 tq of 25 ns, sample point after 6 tq = 150 ns; a 255 ns loop delay
    # is longer than the whole 200 ns data bit
    s = solve_fd(40_000_000, 500_000, 5_000_000, limits="m_can")
    assert s.tdc.enabled and s.tdc.tdco == 6
    ok, why = s.loop_delay_check(255)
    assert ok and "TDCV 11" in why  # ceil(255 / 25)
    off = replace(s, tdc=s.tdc._replace(enabled=False, tdco=0))
    assert off.loop_delay_check(100)[0] and not off.loop_delay_check(255)[0]


# ---------------------------------------------------------------------------------------------
# CiA 601-1, python-can


def test_same_prescaler_where_possible() -> None:
    # 80 MHz: 500 kbit/s takes brp 1 (160 tq), but 1 Mbit/s cannot be 80 tq on M_CAN (49 at most)
    # and takes brp 2; brp 2 serves both exactly (80 and 40 tq)
    s = solve_fd(80_000_000, 500_000, 1_000_000)
    assert (s.nominal.brp, s.data.brp) == (1, 2)
    same = s.recommendations[0]
    assert not same.met and "brp 2 in both" in same.detail
    t = solve_fd(80_000_000, 500_000, 1_000_000, same_prescaler=True)
    assert (t.nominal.brp, t.data.brp, t.nominal.nbt, t.data.nbt) == (2, 2, 80, 40)
    assert t.nominal.bitrate == 500_000 and t.data.bitrate == 1_000_000 and t.recommendations[0].met


def test_cia_sample_point_and_clock() -> None:
    s = solve_fd(16_000_000, 500_000, 2_000_000, data_sample_point=87.5)
    rec = {r.rule.split()[0] + r.rule.split()[1]: r for r in s.recommendations}
    assert not rec["datasample"].met and not rec["CANclock"].met
    assert rec["sameprescaler"].met


def test_fd_oscillator_tolerance_is_iso_11898_1_2015s() -> None:
    """The five CAN FD conditions (ISO 11898-1:2015), written here, with Prop_Seg covering the
    bus's round trip; the solution's figure is python-can's."""
    d = BusDelays(bus_length_m=20, transceiver_delay_ns=100)
    s = solve_fd(40_000_000, 500_000, 2_000_000, delays=d)
    n, dt = s.nominal, s.data
    prop = math.ceil(d.round_trip_ns / n.tq_ns)
    ps1, ps2 = n.tseg1 - prop, n.tseg2
    nbt, dbt, ratio = n.nbt, dt.nbt, dt.brp / n.brp
    conds = [
        n.sjw / (20 * nbt),
        min(ps1, ps2) / (2 * (13 * nbt - ps2)),
        dt.sjw / (20 * dbt),
        min(ps1, ps2) / (2 * ((6 * dbt - dt.tseg2) * ratio + 7 * nbt)),
        (dt.sjw - max(0.0, 1 / ratio - 1)) / (2 * ((2 * nbt - ps2) / ratio + dt.tseg2 + 4 * dbt)),
    ]
    assert s.oscillator_tolerance == pytest.approx(100 * min(conds))
    assert isinstance(s.timing, can.BitTimingFd) and s.timing.data_bitrate == 2_000_000


# ---------------------------------------------------------------------------------------------
# Command line


def _cli(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    rc = main(["bittiming", *argv])
    out, err = capsys.readouterr()
    return rc, out, err


def test_cli_fd_text(capsys: pytest.CaptureFixture[str]) -> None:
    rc, out, _ = _cli(capsys, "--clock", "40000000", "--bitrate", "500000", "--data-bitrate", "2000000")
    assert rc == 0
    assert "on m_can:" in out and "NBTP 0x08004409" in out  # M_CAN by default for CAN FD
    assert "DBTP 0x00800d41  TDCR 0x00000f00" in out  # TDC bit 23 set, TDCO 15 at 14:8
    assert "TDCO 15 clock periods = 375 ns" in out and "CiA 601-1:" in out


def test_cli_fd_json(capsys: pytest.CaptureFixture[str]) -> None:
    rc, out, _ = _cli(
        capsys,
        "--clock",
        "80000000",
        "--bitrate",
        "1000000",
        "--data-bitrate",
        "8000000",
        "--controller",
        "flexcan_fd",
        "--json",
    )
    d = json.loads(out)
    # 10 tq a data bit; 75 % of 10 tq rounds down to 7 tq (70 %): TSEG1 6, TDCO (1 + 6) x 1
    assert rc == 0 and d["data"]["nbt"] == 10 and d["data"]["brp"] == 1 and d["tdc"]["tdco"] == 7
    assert set(d["registers"]) == {"CBT", "FDCBT", "FDCTRL"} and d["crystal_hz"] == 80_000_000
    assert d["registers"]["FDCTRL"] == (1 << 31) | (1 << 15) | (7 << 8)


@pytest.mark.parametrize(
    "argv,needle",
    [
        (["--data-bitrate", "2000000", "--controller", "sja1000"], RULE_FD_CONTROLLER),
        (["--data-bitrate", "250000"], RULE_DATA_BITRATE),
        (["--data-sjw", "2"], "--data-sjw needs --data-bitrate"),
        (["--data-bitrate", "2000000", "--all"], "--all"),
        (["--data-bitrate", "2000000", "--data-sample-point", "101"], "sample point"),
        (["--data-bitrate", "2000000", "--data-sjw", "40"], "sjw=40"),
        (["--data-bitrate", "2000000", "--limits", "tseg1=1..16,tseg2=1..8,sjw=4,brp=1..64"], "custom"),
    ],
)
def test_cli_fd_errors(capsys: pytest.CaptureFixture[str], argv: list[str], needle: str) -> None:
    rc, out, err = _cli(capsys, "--clock", "40000000", "--bitrate", "500000", *argv)
    assert rc == 2 and out == ""
    assert err.count("\n") == 1 and needle in err and "Traceback" not in err
