"""Bit timing register values of common CAN controllers, from each reference manual's layout.

A register is a table of bit fields, each a datasheet name, a position and how its value follows
from the segments (most store a length minus 1). The layouts, by controller (``--controller``):

- ``sja1000``: BTR0 (SJW 7:6, BRP 5:0), BTR1 (SAM 7, TSEG2 6:4, TSEG1 3:0) — python-can's
  `can.BitTiming.btr0`/``btr1``, not packed again here.
- ``mcp251x`` (MCP2515): CNF1 (SJW 7:6, BRP 5:0), CNF2 (BTLMODE 7 set: Phase_Seg2 from CNF3, SAM 6,
  PHSEG1 5:3, PRSEG 2:0), CNF3 (PHSEG2 2:0). TQ = 2 (BRP + 1) / FOSC: the kernel's clock is FOSC / 2.
- ``bxcan`` (STM32 bxCAN): BTR (SJW 25:24, TS2 22:20, TS1 19:16, BRP 9:0).
- ``flexcan``: CTRL1 (PRESDIV 31:24, RJW 23:22, PSEG1 21:19, PSEG2 18:16, SMP 7, PROPSEG 2:0).
- ``flexcan_fd``: CBT (BTF 31 set, EPRESDIV 30:21, ERJW 20:16, EPROPSEG 15:10, EPSEG1 9:5,
  EPSEG2 4:0); data phase FDCBT (FPRESDIV 29:20, FRJW 18:16, FPROPSEG 14:10 holding Prop_Seg
  itself, FPSEG1 7:5, FPSEG2 2:0) and FDCTRL (FDRATE 31 set, TDCEN 15, TDCOFF 12:8).
- ``m_can`` (Bosch M_CAN >= 3.1): NBTP (NSJW 31:25, NBRP 24:16, NTSEG1 15:8, NTSEG2 6:0); data
  phase DBTP (TDC 23, DBRP 20:16, DTSEG1 12:8, DTSEG2 7:4, DSJW 3:0) and TDCR (TDCO 14:8).
- ``mcp251xfd`` (MCP2517FD/MCP2518FD): CiNBTCFG (BRP 31:24, TSEG1 23:16, TSEG2 14:8, SJW 6:0);
  data phase CiDBTCFG (BRP 31:24, TSEG1 20:16, TSEG2 11:8, SJW 3:0) and CiTDC (TDCMOD 17:16, 2 =
  auto, TDCO 14:8).

Controllers with separate Prop_Seg and Phase_Seg1 fields (MCP2515, FlexCAN) hold TSEG1 split as
the solution splits it; when a field is too narrow for that split the excess moves to the other
field, as the FlexCAN driver does for CBT and FDCBT (the bit timing is the same: only their sum
places the sample point).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import can

__all__ = [
    "Segments",
    "BitField",
    "Layout",
    "RegisterValue",
    "NOMINAL_LAYOUTS",
    "DATA_LAYOUTS",
    "encode",
    "nominal_registers",
    "data_registers",
    "split_note",
]


class Segments(NamedTuple):
    """What a bit timing register holds: prescaler, segments (tq), SJW, triple sampling, and for
    the data phase whether transmitter delay compensation is on with which offset (clock periods)."""

    brp: int
    prop_seg: int
    phase_seg1: int
    phase_seg2: int
    sjw: int
    triple: bool = False
    tdc: bool = False
    tdco: int = 0

    @property
    def tseg1(self) -> int:
        """Prop_Seg + Phase_Seg1."""
        return self.prop_seg + self.phase_seg1


class BitField(NamedTuple):
    """A register field: its datasheet name, lowest bit, width and value from the segments."""

    name: str
    lsb: int
    width: int
    value: Callable[[Segments], int]


class Layout(NamedTuple):
    """A register: name, width in bits, fields, bits always set, and for separate Prop_Seg and
    Phase_Seg1 fields their ranges ((prop_min, prop_max), (ps1_min, ps1_max)) to fit TSEG1 into."""

    name: str
    bits: int
    fields: tuple[BitField, ...]
    fixed: int = 0
    split: tuple[tuple[int, int], tuple[int, int]] | None = None


class RegisterValue(NamedTuple):
    """A register's value; ``str`` gives 'NAME 0x..' with as many hex digits as the register has."""

    name: str
    value: int
    bits: int

    def __str__(self) -> str:
        return f"{self.name} 0x{self.value:0{self.bits // 4}x}"


def _minus1(attr: str) -> Callable[[Segments], int]:
    return lambda s: getattr(s, attr) - 1


_BRP = _minus1("brp")
_SJW = _minus1("sjw")
_PROP = _minus1("prop_seg")
_PS1 = _minus1("phase_seg1")
_PS2 = _minus1("phase_seg2")
_TSEG1 = _minus1("tseg1")

#: Register layouts of the nominal (classical CAN: the only) bit timing, by controller.
NOMINAL_LAYOUTS: dict[str, tuple[Layout, ...]] = {
    "mcp251x": (
        Layout("CNF1", 8, (BitField("SJW", 6, 2, _SJW), BitField("BRP", 0, 6, _BRP))),
        Layout(
            "CNF2",
            8,
            (
                BitField("SAM", 6, 1, lambda s: int(s.triple)),
                BitField("PHSEG1", 3, 3, _PS1),
                BitField("PRSEG", 0, 3, _PROP),
            ),
            fixed=1 << 7,  # BTLMODE: Phase_Seg2 is CNF3's, not max(Phase_Seg1, IPT)
            split=((1, 8), (1, 8)),
        ),
        Layout("CNF3", 8, (BitField("PHSEG2", 0, 3, _PS2),)),
    ),
    "bxcan": (
        Layout(
            "BTR",
            32,
            (
                BitField("SJW", 24, 2, _SJW),
                BitField("TS2", 20, 3, _PS2),
                BitField("TS1", 16, 4, _TSEG1),
                BitField("BRP", 0, 10, _BRP),
            ),
        ),
    ),
    "flexcan": (
        Layout(
            "CTRL1",
            32,
            (
                BitField("PRESDIV", 24, 8, _BRP),
                BitField("RJW", 22, 2, _SJW),
                BitField("PSEG1", 19, 3, _PS1),
                BitField("PSEG2", 16, 3, _PS2),
                BitField("SMP", 7, 1, lambda s: int(s.triple)),
                BitField("PROPSEG", 0, 3, _PROP),
            ),
            split=((1, 8), (1, 8)),
        ),
    ),
    "flexcan_fd": (
        Layout(
            "CBT",
            32,
            (
                BitField("EPRESDIV", 21, 10, _BRP),
                BitField("ERJW", 16, 5, _SJW),
                BitField("EPROPSEG", 10, 6, _PROP),
                BitField("EPSEG1", 5, 5, _PS1),
                BitField("EPSEG2", 0, 5, _PS2),
            ),
            fixed=1 << 31,  # BTF: the extended fields of CBT, not CTRL1's, time the bits
            split=((1, 64), (1, 32)),
        ),
    ),
    "m_can": (
        Layout(
            "NBTP",
            32,
            (
                BitField("NSJW", 25, 7, _SJW),
                BitField("NBRP", 16, 9, _BRP),
                BitField("NTSEG1", 8, 8, _TSEG1),
                BitField("NTSEG2", 0, 7, _PS2),
            ),
        ),
    ),
    "mcp251xfd": (
        Layout(
            "CiNBTCFG",
            32,
            (
                BitField("BRP", 24, 8, _BRP),
                BitField("TSEG1", 16, 8, _TSEG1),
                BitField("TSEG2", 8, 7, _PS2),
                BitField("SJW", 0, 7, _SJW),
            ),
        ),
    ),
}

#: Register layouts of the CAN FD data phase and transmitter delay compensation, by controller.
DATA_LAYOUTS: dict[str, tuple[Layout, ...]] = {
    "m_can": (
        Layout(
            "DBTP",
            32,
            (
                BitField("TDC", 23, 1, lambda s: int(s.tdc)),
                BitField("DBRP", 16, 5, _BRP),
                BitField("DTSEG1", 8, 5, _TSEG1),
                BitField("DTSEG2", 4, 4, _PS2),
                BitField("DSJW", 0, 4, _SJW),
            ),
        ),
        Layout("TDCR", 32, (BitField("TDCO", 8, 7, lambda s: s.tdco if s.tdc else 0),)),
    ),
    "mcp251xfd": (
        Layout(
            "CiDBTCFG",
            32,
            (
                BitField("BRP", 24, 8, _BRP),
                BitField("TSEG1", 16, 5, _TSEG1),
                BitField("TSEG2", 8, 4, _PS2),
                BitField("SJW", 0, 4, _SJW),
            ),
        ),
        Layout(
            "CiTDC",
            32,
            (
                BitField("TDCMOD", 16, 2, lambda s: 2 if s.tdc else 0),  # 2: automatic, 0: disabled
                BitField("TDCO", 8, 7, lambda s: s.tdco if s.tdc else 0),
            ),
        ),
    ),
    "flexcan_fd": (
        Layout(
            "FDCBT",
            32,
            (
                BitField("FPRESDIV", 20, 10, _BRP),
                BitField("FRJW", 16, 3, _SJW),
                BitField("FPROPSEG", 10, 5, lambda s: s.prop_seg),  # Prop_Seg itself, 0..31
                BitField("FPSEG1", 5, 3, _PS1),
                BitField("FPSEG2", 0, 3, _PS2),
            ),
            split=((0, 31), (1, 8)),
        ),
        Layout(
            "FDCTRL",
            32,
            (
                BitField("TDCEN", 15, 1, lambda s: int(s.tdc)),
                BitField("TDCOFF", 8, 5, lambda s: s.tdco if s.tdc else 0),
            ),
            fixed=1 << 31,  # FDRATE: bit rate switching enabled
        ),
    ),
}


def _fit(seg: Segments, layout: Layout) -> Segments:
    """TSEG1 split to fit the layout's Prop_Seg and Phase_Seg1 fields: the excess of one goes to
    the other (the sample point stays where TSEG1 puts it)."""
    if layout.split is None:
        return seg
    (p_lo, p_hi), (s_lo, s_hi) = layout.split
    prop, ps1 = seg.prop_seg, seg.phase_seg1
    if ps1 > s_hi:
        prop, ps1 = prop + ps1 - s_hi, s_hi
    if prop > p_hi:
        prop, ps1 = p_hi, ps1 + prop - p_hi
    if ps1 < s_lo:
        prop, ps1 = prop - (s_lo - ps1), s_lo
    if prop < p_lo:
        prop, ps1 = p_lo, ps1 - (p_lo - prop)
    if not (p_lo <= prop <= p_hi and s_lo <= ps1 <= s_hi):
        raise ValueError(
            f"{layout.name}: tseg1 {seg.tseg1} tq does not fit Prop_Seg {p_lo}..{p_hi} + Phase_Seg1 {s_lo}..{s_hi}"
        )
    return seg._replace(prop_seg=prop, phase_seg1=ps1)


def encode(layout: Layout, seg: Segments) -> RegisterValue:
    """The register's value: each field's value at its position, with the fixed bits; ValueError
    naming the register and field when a value does not fit the field's width."""
    seg = _fit(seg, layout)
    value = layout.fixed
    for f in layout.fields:
        v = f.value(seg)
        if not 0 <= v < 1 << f.width:
            raise ValueError(f"{layout.name}.{f.name} = {v} does not fit its {f.width} bits")
        value |= v << f.lsb
    return RegisterValue(layout.name, value, layout.bits)


def nominal_registers(controller: str, seg: Segments, timing: can.BitTiming | None = None) -> list[RegisterValue]:
    """The nominal bit timing registers of ``controller`` (none for a controller without a
    layout here); the SJA1000's BTR0/BTR1 come from python-can's ``timing``."""
    if controller == "sja1000":
        if timing is None:
            return []
        return [RegisterValue("BTR0", timing.btr0, 8), RegisterValue("BTR1", timing.btr1, 8)]
    return [encode(layout, seg) for layout in NOMINAL_LAYOUTS.get(controller, ())]


def data_registers(controller: str, seg: Segments) -> list[RegisterValue]:
    """The data-phase bit timing and transmitter delay compensation registers of ``controller``."""
    return [encode(layout, seg) for layout in DATA_LAYOUTS.get(controller, ())]


def split_note(controller: str, seg: Segments, data: bool = False) -> str | None:
    """How the registers split TSEG1 when that differs from ``seg`` (None when it does not)."""
    for layout in (DATA_LAYOUTS if data else NOMINAL_LAYOUTS).get(controller, ()):
        fitted = _fit(seg, layout)
        if fitted != seg:
            return (
                f"{layout.name} holds tseg1 {seg.tseg1} as prop_seg {fitted.prop_seg} + phase_seg1 "
                f"{fitted.phase_seg1} (its fields' widths; the sample point is the same)"
            )
    return None
