"""Bit timing rules and the checked value: BRP/TSEG1/TSEG2/SJW against ISO 11898-1.

Rules (ISO 11898-1 / Bosch CAN 2.0, see DESIGN.md "Bit timing and synchronisation"):
- Bit time = Sync_Seg (1 tq) + Prop_Seg + Phase_Seg1 + Phase_Seg2, 8..25 tq; tq = BRP / f_clock.
  TSEG1 = Prop_Seg + Phase_Seg1, TSEG2 = Phase_Seg2; the sample point ends Phase_Seg1.
- Prop_Seg >= 2 x (bus propagation + transceiver + comparator delays).
- SJW 1..4, SJW <= Phase_Seg2 and SJW <= Phase_Seg1.
- Oscillator tolerance df <= min(PS1, PS2) / (2 (13 NBT - PS2)) and df <= SJW / (20 NBT).
- CAN FD (ISO 11898-1:2015): the nominal phase keeps at least 8 tq, longer bits and SJWs up to
  the controller's ranges (`FD_NOMINAL`); the data phase has only its controller's ranges
  (`FD_DATA`), as the kernel's can_calc_bittiming with the driver's data_bittiming_const.

The value type is python-can's `can.BitTiming` (registers, sample point, BTR0/BTR1). Its register
ranges are the SJA1000's, so timings for controllers with wider ranges (FlexCAN, bxCAN, M_CAN)
use a subclass that checks the controller's own limits instead. `stack.phy.bittiming` solves for
a timing; this module holds what a timing is and the rules it must keep.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import can

from stack.phy.controllers import ControllerLimits, controller_limits
from stack.phy.registers import RegisterValue, Segments, nominal_registers

__all__ = [
    "BitTimingError",
    "BusDelays",
    "Solution",
    "TimingRules",
    "CLASSICAL",
    "FD_NOMINAL",
    "FD_DATA",
    "SYNC_SEG",
    "MAX_BITRATE_ERROR_PERMILLE",
    "RULE_LIMITS",
    "RULE_NBT",
    "RULE_SJW_RANGE",
    "RULE_SJW_PHASE_SEG2",
    "RULE_SJW_PHASE_SEG1",
    "RULE_PROP_SEG",
    "RULE_TOLERANCE_RESYNC",
    "RULE_TOLERANCE_ERROR_FLAG",
    "RULE_BITRATE",
    "RULE_SAMPLE_POINT",
    "cia_sample_point",
    "make_timing",
    "required_prop_seg",
    "tolerance_resync",
    "tolerance_error_flag",
    "oscillator_tolerance",
    "max_bus_length",
    "check_timing",
]

SYNC_SEG = 1
NBT_MIN, NBT_MAX = 8, 25
SJW_MAX = 4
# the kernel refuses a bitrate more than 5.0 % off (CAN_CALC_MAX_ERROR, in tenths of a percent)
MAX_BITRATE_ERROR_PERMILLE = 50

RULE_LIMITS = "controller register limits"
RULE_NBT = "bit time 8..25 tq"
RULE_SJW_RANGE = "SJW 1..4 tq"
RULE_SJW_PHASE_SEG2 = "SJW <= Phase_Seg2"
RULE_SJW_PHASE_SEG1 = "SJW <= Phase_Seg1"
RULE_PROP_SEG = "Prop_Seg >= 2 x (bus + transceiver + comparator delays)"
RULE_TOLERANCE_RESYNC = "oscillator tolerance df <= SJW / (20 NBT)"
RULE_TOLERANCE_ERROR_FLAG = "oscillator tolerance df <= min(PS1, PS2) / (2 (13 NBT - PS2))"
RULE_BITRATE = "bitrate reachable within 5 % with this clock"
RULE_SAMPLE_POINT = "sample point 50..<100 %"


class TimingRules(NamedTuple):
    """The bit time and SJW ranges a timing must keep besides its controller's registers
    (None: the controller's registers alone bound it)."""

    name: str
    nbt_min: int
    nbt_max: int | None
    sjw_max: int | None
    prop_seg_min: int = 1

    @property
    def nbt_rule(self) -> str:
        """The rule's name for `BitTimingError`."""
        if self.nbt_max is None:
            return f"bit time at least {self.nbt_min} tq ({self.name})"
        return RULE_NBT if self == CLASSICAL else f"bit time {self.nbt_min}..{self.nbt_max} tq ({self.name})"

    @property
    def sjw_rule(self) -> str:
        """The SJW range rule's name."""
        return RULE_SJW_RANGE if self.sjw_max == SJW_MAX else "SJW 1..the controller's SJW maximum"


#: CAN 2.0 / ISO 11898-1 for classical CAN: 8..25 tq a bit, SJW 1..4.
CLASSICAL = TimingRules("classical CAN", NBT_MIN, NBT_MAX, SJW_MAX)
#: ISO 11898-1:2015 CAN FD, nominal (arbitration) phase: at least 8 tq; longer bits and larger
#: SJWs as the controller's registers allow (the kernel's can_calc_bittiming with the FD
#: controller's bittiming_const: 80 MHz at 500 kbit/s gives 160 tq with brp 1).
FD_NOMINAL = TimingRules("CAN FD nominal phase", NBT_MIN, None, None)
#: CAN FD data phase: only the controller's data-phase registers bound it, as in the kernel; Prop_Seg
#: may be 0 (one node transmits: there is no round trip to cover).
FD_DATA = TimingRules("CAN FD data phase", 1, None, None, prop_seg_min=0)


class BitTimingError(ValueError):
    """A bit timing (or a request for one) that breaks a rule; ``rule`` names the rule."""

    def __init__(self, rule: str, message: str, *, phase_seg1: int | None = None) -> None:
        self.rule = rule
        # set when the only fault is an SJW longer than the Phase_Seg1 left (the solver lowers
        # its default SJW to it)
        self.phase_seg1 = phase_seg1
        super().__init__(f"{message} (rule: {rule})")


# ---------------------------------------------------------------------------------------------
# Physical layer


@dataclass(frozen=True)
class BusDelays:
    """One-way delays that Prop_Seg must cover twice (Bosch CAN 2.0, 8.3 / ISO 11898-1).

    The bus line delay is ``bus_length_m`` x ``cable_delay_ns_per_m`` (about 5 ns/m for twisted
    pair); the transceiver (output driver) and input comparator delays are per node.
    """

    bus_length_m: float = 0.0
    cable_delay_ns_per_m: float = 5.0
    transceiver_delay_ns: float = 0.0
    comparator_delay_ns: float = 0.0

    def __post_init__(self) -> None:
        for name in ("bus_length_m", "cable_delay_ns_per_m", "transceiver_delay_ns", "comparator_delay_ns"):
            v = getattr(self, name)
            if not (v >= 0 and math.isfinite(v)):
                raise ValueError(f"{name}={v}: a delay or length must be a finite number >= 0")

    @property
    def node_delay_ns(self) -> float:
        """Transceiver plus comparator delay of one node."""
        return self.transceiver_delay_ns + self.comparator_delay_ns

    @property
    def round_trip_ns(self) -> float:
        """2 x (bus propagation + transceiver + comparator delays): the minimum Prop_Seg time."""
        return 2 * (self.bus_length_m * self.cable_delay_ns_per_m + self.node_delay_ns)


def cia_sample_point(bitrate: int) -> float:
    """The CiA-recommended sample point in percent: 75 above 800 kbit/s, 80 above 500 kbit/s,
    87.5 otherwise (the kernel's default when no sample point is given)."""
    if bitrate > 800_000:
        return 75.0
    if bitrate > 500_000:
        return 80.0
    return 87.5


# ---------------------------------------------------------------------------------------------
# The value type


class _WideBitTiming(can.BitTiming):
    """`can.BitTiming` for controllers whose register ranges exceed the SJA1000's; the controller
    limits are checked by `check_timing`, so only the structural rules are checked here."""

    def _validate(self) -> None:
        for key in ("brp", "tseg1", "tseg2", "sjw"):
            if self[key] < 1:
                raise ValueError(f"{key} (={self[key]}) must be >= 1")
        if self.sjw > self.tseg2:
            raise ValueError(f"sjw (={self.sjw}) must not be greater than tseg2 (={self.tseg2}).")
        if self.nof_samples not in (1, 3):
            raise ValueError("nof_samples must be 1 or 3")


def make_timing(f_clock: int, brp: int, tseg1: int, tseg2: int, sjw: int, nof_samples: int = 1) -> can.BitTiming:
    """A `can.BitTiming` for these registers; a subclass with the same API when the values are
    outside python-can's SJA1000 ranges (brp <= 64, tseg1 <= 16, tseg2 <= 8, sjw <= 4) or the
    sample point is below 50 % (the rules are then checked by `check_timing`)."""
    try:
        return can.BitTiming(f_clock=f_clock, brp=brp, tseg1=tseg1, tseg2=tseg2, sjw=sjw, nof_samples=nof_samples)
    except ValueError:
        return _WideBitTiming(f_clock=f_clock, brp=brp, tseg1=tseg1, tseg2=tseg2, sjw=sjw, nof_samples=nof_samples)


def required_prop_seg(tq_ns: float, delays: BusDelays) -> int:
    """Smallest Prop_Seg in tq with Prop_Seg >= 2 x (bus + transceiver + comparator delays),
    and at least 1 tq (Prop_Seg is 1..8 tq in CAN 2.0)."""
    if tq_ns <= 0:
        raise ValueError(f"tq={tq_ns} ns: a time quantum must be > 0")
    # a hair of slack so that e.g. exactly 4 x 125 ns does not round up to 5 on float noise
    return max(1, math.ceil(delays.round_trip_ns / tq_ns - 1e-9))


def tolerance_resync(sjw: int, nbt: int) -> float:
    """Oscillator tolerance condition 1, df <= SJW / (20 NBT): two nodes drifting 2 df apart over
    the 10 bits between resynchronising edges must stay within one SJW (fraction, not percent)."""
    return sjw / (20 * nbt)


def tolerance_error_flag(phase_seg1: int, phase_seg2: int, nbt: int) -> float:
    """Oscillator tolerance condition 2, df <= min(PS1, PS2) / (2 (13 NBT - PS2)): the bit after
    an error flag, 13 bits from the last edge, must still be sampled right (fraction)."""
    return min(phase_seg1, phase_seg2) / (2 * (13 * nbt - phase_seg2))


def oscillator_tolerance(phase_seg1: int, phase_seg2: int, sjw: int, nbt: int) -> float:
    """Largest clock deviation df (fraction) meeting both ISO 11898-1 tolerance conditions."""
    return min(tolerance_resync(sjw, nbt), tolerance_error_flag(phase_seg1, phase_seg2, nbt))


def max_bus_length(prop_seg: int, tq_ns: float, delays: BusDelays) -> float:
    """Longest bus (m) whose round trip fits Prop_Seg: from Prop_Seg x tq >= 2 x (L x cable delay
    + transceiver + comparator), solved for L; 0 when the node delays alone do not fit."""
    if delays.cable_delay_ns_per_m <= 0:
        return math.inf
    return max(0.0, (prop_seg * tq_ns / 2 - delays.node_delay_ns) / delays.cable_delay_ns_per_m)


# ---------------------------------------------------------------------------------------------
# A checked timing


@dataclass(frozen=True)
class Solution:
    """A timing that passed `check_timing`, with the spec's segments and derived figures."""

    timing: can.BitTiming
    prop_seg: int
    phase_seg1: int
    phase_seg2: int
    limits: ControllerLimits
    delays: BusDelays = field(default_factory=BusDelays)
    bitrate_nominal: int | None = None
    sample_point_nominal: float | None = None

    @property
    def brp(self) -> int:
        """Bit rate prescaler."""
        return self.timing.brp

    @property
    def tseg1(self) -> int:
        """Prop_Seg + Phase_Seg1 in tq."""
        return self.timing.tseg1

    @property
    def tseg2(self) -> int:
        """Phase_Seg2 in tq."""
        return self.timing.tseg2

    @property
    def sjw(self) -> int:
        """Synchronisation jump width in tq."""
        return self.timing.sjw

    @property
    def nbt(self) -> int:
        """Nominal bit time in tq."""
        return self.timing.nbt

    @property
    def tq_ns(self) -> float:
        """Time quantum in ns: BRP / f_clock."""
        return self.timing.brp * 1e9 / self.timing.f_clock

    @property
    def bitrate(self) -> float:
        """The real bitrate, f_clock / (BRP x NBT)."""
        return self.timing.f_clock / (self.timing.brp * self.timing.nbt)

    @property
    def bitrate_error(self) -> float:
        """|real - requested| / requested in percent (0 without a requested bitrate)."""
        if not self.bitrate_nominal:
            return 0.0
        return abs(self.bitrate - self.bitrate_nominal) / self.bitrate_nominal * 100

    @property
    def sample_point(self) -> float:
        """Sample point in percent of the bit time."""
        return self.timing.sample_point

    @property
    def sample_point_error(self) -> float:
        """|real - requested| / requested sample point in percent (as can-calc-bit-timing)."""
        if not self.sample_point_nominal:
            return 0.0
        return abs(self.sample_point - self.sample_point_nominal) / self.sample_point_nominal * 100

    @property
    def tolerance_resync(self) -> float:
        """Condition 1, SJW / (20 NBT), in percent."""
        return tolerance_resync(self.sjw, self.nbt) * 100

    @property
    def tolerance_error_flag(self) -> float:
        """Condition 2, min(PS1, PS2) / (2 (13 NBT - PS2)), in percent."""
        return tolerance_error_flag(self.phase_seg1, self.phase_seg2, self.nbt) * 100

    @property
    def oscillator_tolerance(self) -> float:
        """df in percent: the smaller of the two tolerance conditions."""
        return min(self.tolerance_resync, self.tolerance_error_flag)

    @property
    def max_bus_length(self) -> float:
        """Longest bus in metres Prop_Seg covers with these delays."""
        return max_bus_length(self.prop_seg, self.tq_ns, self.delays)

    @property
    def btr(self) -> tuple[int, int] | None:
        """(BTR0, BTR1) for SJA1000-layout controllers, else None."""
        if not self.limits.has_btr:
            return None
        return self.timing.btr0, self.timing.btr1

    @property
    def segments(self) -> Segments:
        """The prescaler, segments, SJW and triple sampling as bit timing registers hold them."""
        return Segments(
            self.brp, self.prop_seg, self.phase_seg1, self.phase_seg2, self.sjw, self.timing.nof_samples == 3
        )

    @property
    def registers(self) -> list[RegisterValue]:
        """This timing in the controller's registers (`stack.phy.registers`; empty for a
        controller without a layout there): SJA1000 BTR0/BTR1, MCP2515 CNF1..CNF3, bxCAN BTR,
        FlexCAN CTRL1 or CBT, M_CAN NBTP, MCP2518FD CiNBTCFG."""
        return nominal_registers(self.limits.name, self.segments, self.timing)

    def as_dict(self) -> dict[str, Any]:
        """The JSON form: brp, tseg1, tseg2, sjw, tq_ns, sample_point (%), bitrate (real),
        bitrate_error (%), oscillator_tolerance (%), plus the segments and bus length."""
        d: dict[str, Any] = {
            "brp": self.brp,
            "tseg1": self.tseg1,
            "tseg2": self.tseg2,
            "sjw": self.sjw,
            "tq_ns": round(self.tq_ns, 3),
            "nbt": self.nbt,
            "prop_seg": self.prop_seg,
            "phase_seg1": self.phase_seg1,
            "phase_seg2": self.phase_seg2,
            "sample_point": round(self.sample_point, 3),
            "bitrate": round(self.bitrate, 3),
            "bitrate_error": round(self.bitrate_error, 4),
            "oscillator_tolerance": round(self.oscillator_tolerance, 4),
            "tolerance_resync": round(self.tolerance_resync, 4),
            "tolerance_error_flag": round(self.tolerance_error_flag, 4),
            "max_bus_length_m": round(self.max_bus_length, 2),
            "controller": self.limits.name,
        }
        if self.btr is not None:
            d["btr0"], d["btr1"] = self.btr
        if self.registers:
            d["registers"] = {r.name: r.value for r in self.registers}
        return d


def check_timing(
    timing: can.BitTiming,
    limits: str | ControllerLimits = "sja1000",
    delays: BusDelays | None = None,
    prop_seg: int | None = None,
    min_tolerance: float | None = None,
    bitrate_nominal: int | None = None,
    sample_point_nominal: float | None = None,
    rules: TimingRules = CLASSICAL,
) -> Solution:
    """Check a timing against every bit timing rule and split TSEG1 into Prop_Seg/Phase_Seg1.

    Rules, in order, each raising `BitTimingError` naming it: controller register limits (BRP a
    multiple of brp_inc); the bit time range of ``rules`` (classical CAN: 8..25 tq); SJW 1..4
    (classical; CAN FD: up to the controller's sjw_max) and <= sjw_max; SJW <= Phase_Seg2;
    Prop_Seg >= 2 x (bus + transceiver + comparator delays); SJW <= Phase_Seg1; and, when
    ``min_tolerance`` (percent) is given, both oscillator tolerance conditions.

    Without ``prop_seg`` the split is the kernel's (Prop_Seg = TSEG1 / 2), moved towards Prop_Seg
    when the delays need more; Phase_Seg1 takes the rest.
    """
    lim = controller_limits(limits)
    delays = delays or BusDelays()
    brp, tseg1, tseg2, sjw, nbt = timing.brp, timing.tseg1, timing.tseg2, timing.sjw, timing.nbt
    for name, value, lo, hi in (
        ("brp", brp, lim.brp_min, lim.brp_max),
        ("tseg1", tseg1, lim.tseg1_min, lim.tseg1_max),
        ("tseg2", tseg2, lim.tseg2_min, lim.tseg2_max),
    ):
        if not lo <= value <= hi:
            raise BitTimingError(RULE_LIMITS, f"{name}={value} outside {lim.name}'s {lo}..{hi}")
    if brp % lim.brp_inc:
        raise BitTimingError(RULE_LIMITS, f"brp={brp} is not a multiple of {lim.name}'s step {lim.brp_inc}")
    if nbt < rules.nbt_min or (rules.nbt_max is not None and nbt > rules.nbt_max):
        span = f"{rules.nbt_min}..{rules.nbt_max}" if rules.nbt_max is not None else f"at least {rules.nbt_min}"
        raise BitTimingError(rules.nbt_rule, f"bit time {nbt} tq (1 + tseg1 {tseg1} + tseg2 {tseg2}) outside {span}")
    sjw_top = lim.sjw_max if rules.sjw_max is None else min(rules.sjw_max, lim.sjw_max)
    if not 1 <= sjw <= sjw_top:
        raise BitTimingError(rules.sjw_rule, f"sjw={sjw} outside 1..{sjw_top}")
    phase_seg2 = tseg2
    if sjw > phase_seg2:
        raise BitTimingError(RULE_SJW_PHASE_SEG2, f"sjw={sjw} > phase_seg2={phase_seg2}")
    tq_ns = brp * 1e9 / timing.f_clock
    need = max(rules.prop_seg_min, required_prop_seg(tq_ns, delays)) if delays.round_trip_ns else rules.prop_seg_min
    if prop_seg is None:
        prop_seg = max(tseg1 // 2, need)
    if prop_seg < need:
        raise BitTimingError(
            RULE_PROP_SEG,
            f"prop_seg={prop_seg} tq = {prop_seg * tq_ns:.0f} ns < {delays.round_trip_ns:.0f} ns round trip "
            f"({delays.bus_length_m:g} m x {delays.cable_delay_ns_per_m:g} ns/m + {delays.node_delay_ns:g} ns node delay, twice)",
        )
    phase_seg1 = tseg1 - prop_seg
    if phase_seg1 < 1 or sjw > phase_seg1:
        detail = f"tseg1={tseg1} leaves phase_seg1={phase_seg1} after prop_seg={prop_seg}"
        if prop_seg > tseg1 // 2:
            rule = RULE_PROP_SEG
            detail += f" (needed for {delays.round_trip_ns:.0f} ns round trip): SJW={sjw} does not fit"
        else:
            rule = RULE_SJW_PHASE_SEG1
            detail += f", less than sjw={sjw}"
        raise BitTimingError(rule, detail, phase_seg1=phase_seg1 if phase_seg1 >= 1 else None)
    sol = Solution(timing, prop_seg, phase_seg1, phase_seg2, lim, delays, bitrate_nominal, sample_point_nominal)
    if min_tolerance is not None:
        if sol.tolerance_resync < min_tolerance:
            raise BitTimingError(
                RULE_TOLERANCE_RESYNC, f"df={sol.tolerance_resync:.4f} % < required {min_tolerance:g} %"
            )
        if sol.tolerance_error_flag < min_tolerance:
            raise BitTimingError(
                RULE_TOLERANCE_ERROR_FLAG, f"df={sol.tolerance_error_flag:.4f} % < required {min_tolerance:g} %"
            )
    return sol
