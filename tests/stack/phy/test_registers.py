"""Controller registers: against can-calc-bit-timing's register columns, and read back with each
datasheet's own formulas (written here: tq from the prescaler and the crystal or input clock, the
bit from the segment fields) to the solution's bit rate, sample point and SJW."""

from __future__ import annotations

import json
import shutil
import subprocess
from collections.abc import Callable

import pytest

from stack.cli import main
from stack.phy.bittiming import BusDelays, solve
from stack.phy.bittiming_fd import solve_fd
from stack.phy.registers import NOMINAL_LAYOUTS, Segments, encode, nominal_registers

CALC = shutil.which("can-calc-bit-timing")


def _tool_rows(controller: str, clock: int) -> list[list[str]]:
    out = subprocess.run([CALC, "-q", "-c", str(clock), controller], capture_output=True, text=True, check=True).stdout
    return [
        line.split() for line in out.splitlines() if line.split() and line.split()[0].isdigit() and "***" not in line
    ]


def _tool_controllers() -> set[str]:
    if CALC is None:
        return set()
    return set(subprocess.run([CALC, "-l"], capture_output=True, text=True).stdout.split())


# can-calc-bit-timing's name -> ours, the register columns it prints
TOOL_REGISTERS = {
    "sja1000": ("sja1000", 2),
    "mcp251x": ("mcp251x", 3),
    "flexcan": ("flexcan", 1),
    "bxcan": ("bxcan", 1),
    "mcan-v3.1+": ("m_can", 1),
    "mcp251xfd": ("mcp251xfd", 1),
}


@pytest.mark.subprocess
@pytest.mark.parametrize("tool_name", sorted(TOOL_REGISTERS))
@pytest.mark.parametrize("clock", [8_000_000, 16_000_000, 24_000_000, 48_000_000])
def test_registers_match_can_calc_bit_timing(tool_name: str, clock: int) -> None:
    """The segments can-calc-bit-timing prints, packed by our layout, give the register values
    it prints (the 2020 can-utils prints SJA1000, MCP2515 and FlexCAN ones; later versions also
    bxCAN, M_CAN and MCP251xFD)."""
    if tool_name not in _tool_controllers():
        pytest.skip(f"can-calc-bit-timing without {tool_name} (or not installed)")
    ours, width = TOOL_REGISTERS[tool_name]
    rows = [r for r in _tool_rows(tool_name, clock) if len(r) >= 12 + width]
    assert rows
    for r in rows:
        prop, ps1, ps2, sjw, brp = (int(x) for x in r[2:7])
        seg = Segments(brp, prop, ps1, ps2, sjw)
        if ours == "sja1000":
            from stack.phy.timing import make_timing

            regs = nominal_registers(ours, seg, make_timing(clock, brp, prop + ps1, ps2, sjw))
        else:
            regs = [encode(layout, seg) for layout in NOMINAL_LAYOUTS[ours]]
        assert [r.value for r in regs] == [int(x, 16) for x in r[12 : 12 + width]], r


# ---------------------------------------------------------------------------------------------
# Read back with the datasheets' formulas


def _bits(value: int, hi: int, lo: int) -> int:
    return (value >> lo) & ((1 << (hi - lo + 1)) - 1)


def _sja1000(r: dict[str, int], crystal: float) -> tuple[float, float, int]:
    # SJA1000 data sheet: tscl = 2 tCLK (32 BRP.5 + ... + BRP.0 + 1), tCLK = 1 / fXTAL;
    # tSYNCSEG = 1 tscl, tTSEG1 = tscl (8 TSEG1.3 + ... + 1), tTSEG2 = tscl (4 TSEG2.2 + ... + 1)
    tq = 2 * (_bits(r["BTR0"], 5, 0) + 1) / crystal
    seg1, seg2 = _bits(r["BTR1"], 3, 0) + 1, _bits(r["BTR1"], 6, 4) + 1
    return 1 / (tq * (1 + seg1 + seg2)), (1 + seg1) / (1 + seg1 + seg2), _bits(r["BTR0"], 7, 6) + 1


def _mcp2515(r: dict[str, int], crystal: float) -> tuple[float, float, int]:
    # MCP2515 data sheet: TQ = 2 (BRP + 1) / FOSC; SyncSeg 1 TQ, PropSeg (PRSEG + 1), PS1
    # (PHSEG1 + 1), PS2 (PHSEG2 + 1) TQ with BTLMODE = 1
    assert r["CNF2"] & 0x80
    tq = 2 * (_bits(r["CNF1"], 5, 0) + 1) / crystal
    prop, ps1, ps2 = _bits(r["CNF2"], 2, 0) + 1, _bits(r["CNF2"], 5, 3) + 1, _bits(r["CNF3"], 2, 0) + 1
    nbt = 1 + prop + ps1 + ps2
    return 1 / (tq * nbt), (1 + prop + ps1) / nbt, _bits(r["CNF1"], 7, 6) + 1


def _bxcan(r: dict[str, int], clock: float) -> tuple[float, float, int]:
    # RM0008: tq = (BRP + 1) tPCLK, tBS1 = tq (TS1 + 1), tBS2 = tq (TS2 + 1), bit = 1 + BS1 + BS2
    v = r["BTR"]
    tq = (_bits(v, 9, 0) + 1) / clock
    bs1, bs2 = _bits(v, 19, 16) + 1, _bits(v, 22, 20) + 1
    return 1 / (tq * (1 + bs1 + bs2)), (1 + bs1) / (1 + bs1 + bs2), _bits(v, 25, 24) + 1


def _flexcan_ctrl1(r: dict[str, int], clock: float) -> tuple[float, float, int]:
    # FlexCAN: Sclock = PE clock / (PRESDIV + 1); bit = SYNC_SEG + (PROPSEG + PSEG1 + 2) +
    # (PSEG2 + 1) time quanta
    v = r["CTRL1"]
    tq = (_bits(v, 31, 24) + 1) / clock
    seg1, seg2 = _bits(v, 2, 0) + _bits(v, 21, 19) + 2, _bits(v, 18, 16) + 1
    return 1 / (tq * (1 + seg1 + seg2)), (1 + seg1) / (1 + seg1 + seg2), _bits(v, 23, 22) + 1


def _flexcan_cbt(r: dict[str, int], clock: float) -> tuple[float, float, int]:
    # CBT (BTF = 1): tq = (EPRESDIV + 1) / PE clock; bit = 1 + (EPROPSEG + 1) + (EPSEG1 + 1) +
    # (EPSEG2 + 1)
    v = r["CBT"]
    assert v >> 31
    tq = (_bits(v, 30, 21) + 1) / clock
    seg1, seg2 = _bits(v, 15, 10) + 1 + _bits(v, 9, 5) + 1, _bits(v, 4, 0) + 1
    return 1 / (tq * (1 + seg1 + seg2)), (1 + seg1) / (1 + seg1 + seg2), _bits(v, 20, 16) + 1


def _m_can(r: dict[str, int], clock: float) -> tuple[float, float, int]:
    # M_CAN user's manual: tq = (NBRP + 1) mtq; bit = (NTSEG1 + 1) + (NTSEG2 + 1) + 1 tq
    v = r["NBTP"]
    tq = (_bits(v, 24, 16) + 1) / clock
    seg1, seg2 = _bits(v, 15, 8) + 1, _bits(v, 6, 0) + 1
    return 1 / (tq * (1 + seg1 + seg2)), (1 + seg1) / (1 + seg1 + seg2), _bits(v, 31, 25) + 1


def _mcp2518fd(r: dict[str, int], clock: float) -> tuple[float, float, int]:
    # MCP2518FD data sheet: TQ = (BRP + 1) / SYSCLK; NBT = 1 + (TSEG1 + 1) + (TSEG2 + 1) TQ
    v = r["CiNBTCFG"]
    tq = (_bits(v, 31, 24) + 1) / clock
    seg1, seg2 = _bits(v, 23, 16) + 1, _bits(v, 14, 8) + 1
    return 1 / (tq * (1 + seg1 + seg2)), (1 + seg1) / (1 + seg1 + seg2), _bits(v, 6, 0) + 1


DECODERS: dict[str, tuple[Callable[[dict[str, int], float], tuple[float, float, int]], int]] = {
    # controller: (datasheet read-back, crystal / CAN clock)
    "sja1000": (_sja1000, 2),
    "mcp2515": (_mcp2515, 2),
    "stm32": (_bxcan, 1),
    "flexcan": (_flexcan_ctrl1, 1),
    "flexcan_fd": (_flexcan_cbt, 1),
    "m_can": (_m_can, 1),
    "mcp2518fd": (_mcp2518fd, 1),
}


@pytest.mark.parametrize("controller", sorted(DECODERS))
@pytest.mark.parametrize(
    "clock,bitrate,bus_m",
    [
        (8_000_000, 500_000, 0),
        (16_000_000, 250_000, 0),
        (16_000_000, 125_000, 550),
        (24_000_000, 1_000_000, 0),
        (40_000_000, 500_000, 60),
    ],
)
def test_registers_read_back_with_the_datasheet_formula(
    controller: str, clock: int, bitrate: int, bus_m: float
) -> None:
    decode, divider = DECODERS[controller]
    s = solve(clock, bitrate, limits=controller, delays=BusDelays(bus_m))
    regs = {r.name: r.value for r in s.registers}
    rate, sp, sjw = decode(regs, clock * divider)
    assert rate == pytest.approx(s.bitrate) and sp * 100 == pytest.approx(s.sample_point) and sjw == s.sjw


def _dbtp(r: dict[str, int], clock: float) -> tuple[float, float, int, int | None]:
    # M_CAN: tq = (DBRP + 1) mtq, bit = 1 + (DTSEG1 + 1) + (DTSEG2 + 1); TDCR.TDCO when DBTP.TDC
    v = r["DBTP"]
    tq = (_bits(v, 20, 16) + 1) / clock
    seg1, seg2 = _bits(v, 12, 8) + 1, _bits(v, 7, 4) + 1
    tdco = _bits(r["TDCR"], 14, 8) if v >> 23 & 1 else None
    return 1 / (tq * (1 + seg1 + seg2)), (1 + seg1) / (1 + seg1 + seg2), _bits(v, 3, 0) + 1, tdco


def _dbtcfg(r: dict[str, int], clock: float) -> tuple[float, float, int, int | None]:
    # MCP2518FD: CiDBTCFG as CiNBTCFG with 5/4/4-bit fields; CiTDC.TDCMOD 0b10 or 0b11 = auto
    v = r["CiDBTCFG"]
    tq = (_bits(v, 31, 24) + 1) / clock
    seg1, seg2 = _bits(v, 20, 16) + 1, _bits(v, 11, 8) + 1
    tdco = _bits(r["CiTDC"], 14, 8) if _bits(r["CiTDC"], 17, 16) >= 2 else None
    return 1 / (tq * (1 + seg1 + seg2)), (1 + seg1) / (1 + seg1 + seg2), _bits(v, 3, 0) + 1, tdco


def _fdcbt(r: dict[str, int], clock: float) -> tuple[float, float, int, int | None]:
    # FlexCAN FDCBT: tq = (FPRESDIV + 1) / PE clock, bit = 1 + FPROPSEG + (FPSEG1 + 1) +
    # (FPSEG2 + 1); FDCTRL.TDCOFF when FDCTRL.TDCEN
    v = r["FDCBT"]
    tq = (_bits(v, 29, 20) + 1) / clock
    seg1, seg2 = _bits(v, 14, 10) + _bits(v, 7, 5) + 1, _bits(v, 2, 0) + 1
    tdco = _bits(r["FDCTRL"], 12, 8) if r["FDCTRL"] >> 15 & 1 else None
    return 1 / (tq * (1 + seg1 + seg2)), (1 + seg1) / (1 + seg1 + seg2), _bits(v, 18, 16) + 1, tdco


@pytest.mark.parametrize("controller,decode", [("m_can", _dbtp), ("mcp2518fd", _dbtcfg), ("flexcan_fd", _fdcbt)])
@pytest.mark.parametrize(
    "clock,rates",
    [(40_000_000, (500_000, 2_000_000)), (80_000_000, (1_000_000, 5_000_000)), (80_000_000, (500_000, 1_000_000))],
)
def test_data_registers_read_back_with_the_datasheet_formula(controller, decode, clock, rates) -> None:
    s = solve_fd(clock, *rates, limits=controller)
    rate, sp, sjw, tdco = decode({r.name: r.value for r in s.registers}, clock)
    assert rate == pytest.approx(s.data.bitrate) and sp * 100 == pytest.approx(s.data.sample_point)
    assert sjw == s.data.sjw and tdco == (s.tdc.tdco if s.tdc.enabled else None)


def test_a_split_too_wide_for_the_fields_moves_to_the_other() -> None:
    # 550 m at 125 kbit/s, 16 MHz: Prop_Seg 11 of TSEG1 13 cannot go in CTRL1's 3-bit PROPSEG:
    # the register holds 8 + 5, the same TSEG1 (read back above to the same sample point)
    s = solve(16_000_000, 125_000, limits="flexcan", delays=BusDelays(550))
    assert s.prop_seg > 8
    v = s.registers[0].value
    assert _bits(v, 2, 0) + 1 == 8 and _bits(v, 2, 0) + _bits(v, 21, 19) + 2 == s.tseg1


def test_a_value_too_wide_for_its_field_is_named() -> None:
    with pytest.raises(ValueError, match=r"CNF1.BRP = 64 does not fit its 6 bits"):
        encode(NOMINAL_LAYOUTS["mcp251x"][0], Segments(65, 1, 1, 2, 1))


@pytest.mark.parametrize(
    "controller,clock,crystal",
    [
        ("mcp2515", "8000000", "16 MHz crystal"),
        ("sja1000", "16000000", "32 MHz crystal"),
        ("stm32", "36000000", "input clock"),
    ],
)
def test_cli_names_the_crystal(capsys: pytest.CaptureFixture[str], controller: str, clock: str, crystal: str) -> None:
    rc = main(["bittiming", "--clock", clock, "--bitrate", "500000", "--controller", controller])
    out = capsys.readouterr().out
    assert rc == 0 and crystal in out.splitlines()[1]
    main(["bittiming", "--clock", clock, "--bitrate", "500000", "--controller", controller, "--json"])
    d = json.loads(capsys.readouterr().out)
    assert d["crystal_hz"] == int(clock) * (2 if controller in ("mcp2515", "sja1000") else 1)
    assert d["registers"]
