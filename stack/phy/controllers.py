"""The CAN controllers the bit timing solver knows: register ranges as the Linux drivers declare
them (struct can_bittiming_const, and for CAN FD the data phase's and struct can_tdc_const), and
how the CAN clock the kernel reports relates to the crystal.

Values from the drivers in Linux drivers/net/can (mainline, 2025): sja1000, mcp251x, flexcan
(classical CTRL1 and the CAN FD CBT/FDCBT layout), bxcan, m_can (IP >= 3.1), mcp251xfd, mscan,
at91, ti_hecc, rcar_can. Where a controller's CAN clock is half its crystal (SJA1000: "the system
clock is half the oscillator"; MCP2515: TQ = 2 (BRP + 1) / FOSC), the kernel's clock is the halved
one, and so is ``--clock``.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "TdcLimits",
    "ControllerLimits",
    "CONTROLLERS",
    "CONTROLLER_ALIASES",
    "FD_CONTROLLERS",
    "controller_limits",
    "parse_limits",
]


@dataclass(frozen=True)
class TdcLimits:
    """Transmitter delay compensation ranges, as the kernel's struct can_tdc_const: the offset
    TDCO and the measured loop delay TDCV, both in CAN clock periods (minimum time quanta)."""

    tdco_min: int
    tdco_max: int
    tdcv_max: int

    def __post_init__(self) -> None:
        if not 0 <= self.tdco_min <= self.tdco_max or self.tdcv_max < 0:
            raise ValueError(f"TDC limits: tdco {self.tdco_min}..{self.tdco_max}, tdcv ..{self.tdcv_max}")


@dataclass(frozen=True)
class ControllerLimits:
    """Register ranges of a CAN controller, as in the kernel's struct can_bittiming_const.

    A CAN FD controller also has ``data`` (the data phase's ranges) and ``tdc`` (its transmitter
    delay compensation offset range). ``crystal_divider``: the CAN clock the Linux driver reports
    is the crystal divided by this (2 for the SJA1000 and the MCP2515).
    """

    name: str
    tseg1_min: int
    tseg1_max: int
    tseg2_min: int
    tseg2_max: int
    sjw_max: int
    brp_min: int
    brp_max: int
    brp_inc: int = 1
    data: ControllerLimits | None = None
    tdc: TdcLimits | None = None
    crystal_divider: int = 1

    def __post_init__(self) -> None:
        for lo, hi in (("tseg1_min", "tseg1_max"), ("tseg2_min", "tseg2_max"), ("brp_min", "brp_max")):
            a, b = getattr(self, lo), getattr(self, hi)
            if not 1 <= a <= b:
                raise ValueError(f"controller limits {self.name}: {lo}={a}, {hi}={b} need 1 <= min <= max")
        if self.sjw_max < 1 or self.brp_inc < 1 or self.crystal_divider < 1:
            raise ValueError(f"controller limits {self.name}: sjw_max, brp_inc and crystal_divider must be >= 1")

    @property
    def has_btr(self) -> bool:
        """True if the timing fits the SJA1000 BTR0/BTR1 register layout."""
        return self.name == "sja1000"

    @property
    def fd(self) -> bool:
        """True for a CAN FD controller (it has data-phase limits)."""
        return self.data is not None


_Ranges = tuple[int, int, int, int, int, int, int, int]


def _fd(name: str, nominal: _Ranges, data: _Ranges, tdc: TdcLimits) -> ControllerLimits:
    return ControllerLimits(name, *nominal, data=ControllerLimits(f"{name} data phase", *data), tdc=tdc)


CONTROLLERS: dict[str, ControllerLimits] = {
    c.name: c
    for c in (
        ControllerLimits("sja1000", 1, 16, 1, 8, 4, 1, 64, 1, crystal_divider=2),
        ControllerLimits("mcp251x", 3, 16, 2, 8, 4, 1, 64, 1, crystal_divider=2),
        ControllerLimits("flexcan", 4, 16, 2, 8, 4, 1, 256, 1),
        ControllerLimits("bxcan", 1, 16, 1, 8, 4, 1, 1024, 1),
        # M_CAN >= 3.1 (m_can_bittiming_const_31X / m_can_data_bittiming_const_31X); TDCR.TDCO
        # is 7 bits, TDSR.TDCV 7 bits
        _fd("m_can", (2, 256, 1, 128, 128, 1, 512, 1), (1, 32, 1, 16, 16, 1, 32, 1), TdcLimits(0, 127, 127)),
        # MCP2517FD/MCP2518FD/MCP251863: CiTDC.TDCO 0..63 as the driver uses it, TDCV 6 bits
        _fd("mcp251xfd", (2, 256, 1, 128, 128, 1, 256, 1), (1, 32, 1, 16, 16, 1, 256, 1), TdcLimits(0, 63, 63)),
        # FlexCAN with CAN FD (CBT/FDCBT): FDCTRL.TDCOFF 5 bits, TDCVAL 6 bits
        _fd("flexcan_fd", (2, 96, 2, 32, 16, 1, 1024, 1), (2, 39, 2, 8, 4, 1, 1024, 1), TdcLimits(0, 31, 63)),
        ControllerLimits("mscan", 4, 16, 2, 8, 4, 1, 64, 1),
        ControllerLimits("at91", 4, 16, 2, 8, 4, 2, 128, 1),
        ControllerLimits("ti_hecc", 1, 16, 1, 8, 4, 1, 256, 1),
        ControllerLimits("rcar_can", 4, 16, 2, 8, 4, 1, 1024, 1),
    )
}
CONTROLLER_ALIASES = {
    "stm32": "bxcan",
    "mcp2515": "mcp251x",
    "mcan": "m_can",
    "mcp2518fd": "mcp251xfd",
    "mcp2517fd": "mcp251xfd",
    "flexcan-fd": "flexcan_fd",
}
#: The controllers with a CAN FD data phase.
FD_CONTROLLERS = tuple(name for name, c in CONTROLLERS.items() if c.fd)


def controller_limits(name: str | ControllerLimits) -> ControllerLimits:
    """The register limits of a named controller; ValueError listing the known names otherwise."""
    if isinstance(name, ControllerLimits):
        return name
    key = CONTROLLER_ALIASES.get(name.lower(), name.lower())
    try:
        return CONTROLLERS[key]
    except KeyError:
        known = ", ".join(sorted(CONTROLLERS) + sorted(CONTROLLER_ALIASES))
        raise ValueError(f"unknown controller {name!r}: known controllers are {known}") from None


def parse_limits(text: str) -> ControllerLimits:
    """Custom limits from 'tseg1=1..16,tseg2=1..8,sjw=4,brp=1..64[,brp_inc=1]'."""
    values: dict[str, int] = {"brp_inc": 1}
    for part in filter(None, (p.strip() for p in text.split(","))):
        key, sep, val = part.partition("=")
        key = key.strip().lower()
        if not sep or key not in ("tseg1", "tseg2", "sjw", "brp", "brp_inc"):
            raise ValueError(
                f"limits item {part!r}: expected tseg1=MIN..MAX, tseg2=MIN..MAX, sjw=MAX, brp=MIN..MAX, brp_inc=N"
            )
        try:
            if key in ("sjw", "brp_inc"):
                values[key if key == "brp_inc" else "sjw_max"] = int(val)
            else:
                lo, dots, hi = val.partition("..")
                if not dots:
                    raise ValueError
                values[f"{key}_min"], values[f"{key}_max"] = int(lo), int(hi)
        except ValueError:
            raise ValueError(
                f"limits item {part!r}: {key} needs {'N' if key in ('sjw', 'brp_inc') else 'MIN..MAX'} integers"
            ) from None
    missing = [k for k in ("tseg1_min", "tseg2_min", "sjw_max", "brp_min") if k not in values]
    if missing:
        raise ValueError(f"limits {text!r}: missing {', '.join(m.rsplit('_', 1)[0] for m in missing)}")
    v = values
    return ControllerLimits(
        "custom",
        v["tseg1_min"],
        v.get("tseg1_max", 0),
        v["tseg2_min"],
        v.get("tseg2_max", 0),
        v["sjw_max"],
        v["brp_min"],
        v.get("brp_max", 0),
        v["brp_inc"],
    )
