"""Bit timing: solve and check BRP/TSEG1/TSEG2/SJW for a controller clock and bitrate.

Rules (ISO 11898-1 / Bosch CAN 2.0, see DESIGN.md "Bit timing and synchronisation"):
- Bit time = Sync_Seg (1 tq) + Prop_Seg + Phase_Seg1 + Phase_Seg2, 8..25 tq; tq = BRP / f_clock.
  TSEG1 = Prop_Seg + Phase_Seg1, TSEG2 = Phase_Seg2; the sample point ends Phase_Seg1.
- Prop_Seg >= 2 x (bus propagation + transceiver + comparator delays).
- SJW 1..4, SJW <= Phase_Seg2 and SJW <= Phase_Seg1.
- Oscillator tolerance df <= min(PS1, PS2) / (2 (13 NBT - PS2)) and df <= SJW / (20 NBT).

The value type is python-can's `can.BitTiming` (registers, sample point, BTR0/BTR1). Its register
ranges are the SJA1000's, so timings for controllers with wider ranges (FlexCAN, bxCAN, M_CAN)
use a subclass that checks the controller's own limits instead.

The solver follows the Linux kernel's can_calc_bittiming: scan the bit lengths from long to short,
take the prescaler that comes closest to the bitrate, keep the candidate with the least bitrate
error, then the least sample-point error with the sample point not above the requested one, and
on a tie the first found — the smallest prescaler (Linux >= 5.19; ``legacy`` for the older rule).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import can

__all__ = [
    "BitTimingError",
    "ControllerLimits",
    "CONTROLLERS",
    "BusDelays",
    "Solution",
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
    "controller_limits",
    "parse_limits",
    "cia_sample_point",
    "make_timing",
    "required_prop_seg",
    "tolerance_resync",
    "tolerance_error_flag",
    "oscillator_tolerance",
    "max_bus_length",
    "check_timing",
    "solve",
    "all_timings",
    "longest_bus",
    "format_solution",
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


class BitTimingError(ValueError):
    """A bit timing (or a request for one) that breaks a rule; ``rule`` names the rule."""

    def __init__(self, rule: str, message: str, *, phase_seg1: int | None = None) -> None:
        self.rule = rule
        # set when the only fault is an SJW longer than the Phase_Seg1 left (the solver lowers
        # its default SJW to it)
        self.phase_seg1 = phase_seg1
        super().__init__(f"{message} (rule: {rule})")


# ---------------------------------------------------------------------------------------------
# Controller limits


@dataclass(frozen=True)
class ControllerLimits:
    """Register ranges of a CAN controller, as in the kernel's struct can_bittiming_const."""

    name: str
    tseg1_min: int
    tseg1_max: int
    tseg2_min: int
    tseg2_max: int
    sjw_max: int
    brp_min: int
    brp_max: int
    brp_inc: int = 1

    def __post_init__(self) -> None:
        for lo, hi in (("tseg1_min", "tseg1_max"), ("tseg2_min", "tseg2_max"), ("brp_min", "brp_max")):
            a, b = getattr(self, lo), getattr(self, hi)
            if not 1 <= a <= b:
                raise ValueError(f"controller limits {self.name}: {lo}={a}, {hi}={b} need 1 <= min <= max")
        if self.sjw_max < 1 or self.brp_inc < 1:
            raise ValueError(f"controller limits {self.name}: sjw_max and brp_inc must be >= 1")

    @property
    def has_btr(self) -> bool:
        """True if the timing fits the SJA1000 BTR0/BTR1 register layout."""
        return self.name == "sja1000"


# Values from the drivers' can_bittiming_const (Linux drivers/net/can/...).
CONTROLLERS: dict[str, ControllerLimits] = {
    c.name: c
    for c in (
        ControllerLimits("sja1000", 1, 16, 1, 8, 4, 1, 64, 1),
        ControllerLimits("mcp251x", 3, 16, 2, 8, 4, 1, 64, 1),
        ControllerLimits("flexcan", 4, 16, 2, 8, 4, 1, 256, 1),
        ControllerLimits("bxcan", 1, 16, 1, 8, 4, 1, 1024, 1),
        ControllerLimits("m_can", 2, 256, 2, 128, 128, 1, 512, 1),
        ControllerLimits("mscan", 4, 16, 2, 8, 4, 1, 64, 1),
        ControllerLimits("at91", 4, 16, 2, 8, 4, 2, 128, 1),
        ControllerLimits("ti_hecc", 1, 16, 1, 8, 4, 1, 256, 1),
        ControllerLimits("rcar_can", 4, 16, 2, 8, 4, 1, 1024, 1),
    )
}
CONTROLLER_ALIASES = {"stm32": "bxcan", "mcp2515": "mcp251x", "mcan": "m_can"}


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
    return ControllerLimits(name="custom", **values)


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
        return d


def check_timing(
    timing: can.BitTiming,
    limits: str | ControllerLimits = "sja1000",
    delays: BusDelays | None = None,
    prop_seg: int | None = None,
    min_tolerance: float | None = None,
    bitrate_nominal: int | None = None,
    sample_point_nominal: float | None = None,
) -> Solution:
    """Check a timing against every bit timing rule and split TSEG1 into Prop_Seg/Phase_Seg1.

    Rules, in order, each raising `BitTimingError` naming it: controller register limits (BRP a
    multiple of brp_inc); bit time 8..25 tq; SJW 1..4 and <= sjw_max; SJW <= Phase_Seg2;
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
    if not NBT_MIN <= nbt <= NBT_MAX:
        raise BitTimingError(
            RULE_NBT, f"bit time {nbt} tq (1 + tseg1 {tseg1} + tseg2 {tseg2}) outside {NBT_MIN}..{NBT_MAX}"
        )
    if not 1 <= sjw <= min(SJW_MAX, lim.sjw_max):
        raise BitTimingError(RULE_SJW_RANGE, f"sjw={sjw} outside 1..{min(SJW_MAX, lim.sjw_max)}")
    phase_seg2 = tseg2
    if sjw > phase_seg2:
        raise BitTimingError(RULE_SJW_PHASE_SEG2, f"sjw={sjw} > phase_seg2={phase_seg2}")
    tq_ns = brp * 1e9 / timing.f_clock
    need = required_prop_seg(tq_ns, delays)
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


# ---------------------------------------------------------------------------------------------
# The solver


def _split_for_sample_point(lim: ControllerLimits, sp_nominal: int, tseg: int) -> tuple[int, int, int] | None:
    """The kernel's sample point update: try TSEG2 = round-down and one less of the share after
    the requested point, clamp to the limits, keep the split nearest to but not above the request.
    Returns (tseg1, tseg2, sample_point in permille) or None when every split is above it."""
    nbt = tseg + SYNC_SEG
    best: tuple[int, int, int] | None = None
    best_err = None
    for i in (0, 1):
        tseg2 = nbt - (sp_nominal * nbt) // 1000 - i
        tseg2 = min(max(tseg2, lim.tseg2_min), lim.tseg2_max)
        tseg1 = tseg - tseg2
        if tseg1 > lim.tseg1_max:
            tseg1 = lim.tseg1_max
            tseg2 = tseg - tseg1
        sp = 1000 * (nbt - tseg2) // nbt
        err = abs(sp_nominal - sp)
        if sp <= sp_nominal and (best_err is None or err < best_err):
            best, best_err = (tseg1, tseg2, sp), err
    return best


def _sjw_for(sjw: int | None, lim: ControllerLimits, tseg1: int, tseg2: int) -> int:
    if sjw is not None:
        return sjw
    # Linux >= 6.3 default (can_sjw_set_default): half of Phase_Seg2, at most Phase_Seg1
    phase_seg1 = tseg1 - tseg1 // 2
    return max(1, min(phase_seg1, tseg2 // 2, SJW_MAX, lim.sjw_max))


def _checked(
    clock: int,
    brp: int,
    tseg1: int,
    tseg2: int,
    sjw: int | None,
    lim: ControllerLimits,
    delays: BusDelays | None,
    min_tolerance: float | None,
    bitrate: int,
    sp: float,
) -> Solution:
    """`check_timing` of one split. With the default SJW, a Prop_Seg lengthened for the bus
    length can leave Phase_Seg1 shorter than that SJW: the SJW is lowered to that Phase_Seg1
    (the kernel's default min(Phase_Seg1, Phase_Seg2 / 2) on the real Phase_Seg1) rather than
    the timing refused."""
    width = _sjw_for(sjw, lim, tseg1, tseg2)
    try:
        return check_timing(make_timing(clock, brp, tseg1, tseg2, width), lim, delays, None, min_tolerance, bitrate, sp)
    except BitTimingError as exc:
        if sjw is not None or exc.phase_seg1 is None or exc.phase_seg1 >= width:
            raise
        return check_timing(
            make_timing(clock, brp, tseg1, tseg2, exc.phase_seg1), lim, delays, None, min_tolerance, bitrate, sp
        )


@dataclass
class _Candidate:
    order: int
    bitrate_error: int
    sample_point_error: int
    solution: Solution


def _validate_request(clock: int, bitrate: int, sample_point: float | None, sjw: int | None) -> float:
    if not isinstance(clock, int) or clock <= 0:
        raise ValueError(f"clock={clock!r}: the controller clock must be a positive integer in Hz")
    if not isinstance(bitrate, int) or bitrate <= 0:
        raise ValueError(f"bitrate={bitrate!r}: the bitrate must be a positive integer in bit/s")
    sp = cia_sample_point(bitrate) if sample_point is None else float(sample_point)
    if not 50.0 <= sp < 100.0:
        raise BitTimingError(RULE_SAMPLE_POINT, f"sample point {sp:g} % outside 50..<100 %")
    if sjw is not None and not 1 <= sjw <= SJW_MAX:
        raise BitTimingError(RULE_SJW_RANGE, f"sjw={sjw} outside 1..{SJW_MAX}")
    return sp


def _candidates(
    clock: int,
    bitrate: int,
    sample_point: float | None,
    limits: str | ControllerLimits,
    sjw: int | None,
    delays: BusDelays | None,
    min_tolerance: float | None,
    legacy: bool = False,
    every_split: bool = False,
) -> tuple[list[_Candidate], Solution | None, dict[str, str]]:
    """Walk the kernel's search: every bit length from long to short with the prescaler rounded
    down (even step) and up (odd step). Returns the candidates passing every rule (in visit
    order), the kernel's pick among them, and, per rule, an example of a rejected candidate."""
    lim = controller_limits(limits)
    sp = _validate_request(clock, bitrate, sample_point, sjw)
    sp_nominal = round(sp * 10)
    rejected: dict[str, str] = {}
    out: list[_Candidate] = []
    best: _Candidate | None = None
    tseg_hi = min(lim.tseg1_max + lim.tseg2_max, NBT_MAX - SYNC_SEG)
    tseg_lo = max(lim.tseg1_min + lim.tseg2_min, NBT_MIN - SYNC_SEG)
    order = 0
    nearest: int | None = None
    exact = False
    extra: list[_Candidate] = []
    for step in range(2 * tseg_hi + 1, 2 * tseg_lo - 1, -1):
        tseg = step // 2
        nbt = tseg + SYNC_SEG
        brp = clock // (nbt * bitrate) + step % 2
        brp = brp // lim.brp_inc * lim.brp_inc
        if not lim.brp_min <= brp <= lim.brp_max:
            rejected.setdefault(RULE_LIMITS, f"brp={brp} for {nbt} tq outside {lim.brp_min}..{lim.brp_max}")
            continue
        real = clock // (brp * nbt)
        br_err = abs(bitrate - real)
        if br_err * 1000 > MAX_BITRATE_ERROR_PERMILLE * bitrate:
            if nearest is None or br_err < abs(bitrate - nearest):
                nearest = real
                rejected[RULE_BITRATE] = f"the nearest is {real} bit/s ({br_err / bitrate:.1%} off)"
            continue
        split = _split_for_sample_point(lim, sp_nominal, tseg)
        if every_split:
            # --all: the other splits of this bit length at or below the requested sample point
            # (listed, never picked: the kernel considers only its own split)
            for tseg2 in range(lim.tseg2_min, lim.tseg2_max + 1):
                tseg1 = tseg - tseg2
                sp_p = 1000 * (nbt - tseg2) // nbt
                if (
                    not lim.tseg1_min <= tseg1 <= lim.tseg1_max
                    or not 500 <= sp_p <= sp_nominal
                    or (split is not None and (tseg1, tseg2) == split[:2])
                ):
                    continue
                try:
                    sol = _checked(clock, brp, tseg1, tseg2, sjw, lim, delays, min_tolerance, bitrate, sp)
                except ValueError:  # BitTimingError included: not valid, not listed
                    continue
                extra.append(_Candidate(-1, br_err, abs(sp_nominal - sp_p), sol))
        if split is None:
            rejected.setdefault(RULE_SAMPLE_POINT, f"no split of {nbt} tq at or below {sp:g} %")
            continue
        tseg1, tseg2, sp_real = split
        try:
            sol = _checked(clock, brp, tseg1, tseg2, sjw, lim, delays, min_tolerance, bitrate, sp)
        except BitTimingError as exc:
            rejected.setdefault(exc.rule, str(exc))
            continue
        except ValueError as exc:  # structural, e.g. sjw > tseg2
            rejected.setdefault(RULE_SJW_PHASE_SEG2, str(exc))
            continue
        cand = _Candidate(order, br_err, abs(sp_nominal - sp_real), sol)
        order += 1
        out.append(cand)
        # the kernel stops at the first exact hit; the scan goes on only to list the others
        if exact:
            continue
        # kernel rule: a worse bitrate never wins; an equal one needs a smaller sample point
        # error (Linux >= 5.19: on a tie the first, smaller prescaler stays) — before 5.19 an
        # equal error won too, so the last, larger prescaler was kept (legacy=True)
        if best is not None and br_err > best.bitrate_error:
            continue
        if (
            best is not None
            and br_err == best.bitrate_error
            and (
                cand.sample_point_error > best.sample_point_error
                or (cand.sample_point_error == best.sample_point_error and not legacy)
            )
        ):
            continue
        best = cand
        exact = br_err == 0 and cand.sample_point_error == 0
    return out + extra, best.solution if best else None, rejected


def _no_timing(clock: int, bitrate: int, rejected: dict[str, str]) -> BitTimingError:
    if not rejected:
        return BitTimingError(RULE_LIMITS, f"no bit timing for {bitrate} bit/s with a {clock} Hz clock")
    # name the rule that stopped the most promising candidates: the last one in rule order
    for rule in (
        RULE_TOLERANCE_ERROR_FLAG,
        RULE_TOLERANCE_RESYNC,
        RULE_PROP_SEG,
        RULE_SJW_PHASE_SEG1,
        RULE_SJW_PHASE_SEG2,
        RULE_SJW_RANGE,
        RULE_SAMPLE_POINT,
        RULE_BITRATE,
        RULE_LIMITS,
    ):
        if rule in rejected:
            example = rejected[rule].split(" (rule:")[0]
            return BitTimingError(rule, f"no bit timing for {bitrate} bit/s with a {clock} Hz clock: {example}")
    raise AssertionError  # pragma: no cover


def longest_bus(
    clock: int,
    bitrate: int,
    sample_point: float | None = None,
    limits: str | ControllerLimits = "sja1000",
    sjw: int | None = None,
    delays: BusDelays | None = None,
    min_tolerance: float | None = None,
    legacy: bool = False,
) -> Solution | None:
    """The timing `solve` finds for the longest bus it can find one for (its
    ``max_bus_length`` is that length), with ``delays``' cable and node delays; None when there
    is none even for a bus of 0 m.

    Rule Prop_Seg >= 2 x (bus + transceiver + comparator delays): a longer bus only ever needs
    a longer Prop_Seg, so the lengths `solve` succeeds for are an interval from 0 and bisection
    finds its end; the timing found just inside it covers the longest bus exactly."""
    base = delays or BusDelays()

    def at(length: float) -> Solution | None:
        _, best, _ = _candidates(
            clock, bitrate, sample_point, limits, sjw, replace(base, bus_length_m=length), min_tolerance, legacy
        )
        return best

    best = at(0.0)
    if best is None or math.isinf(best.max_bus_length):
        return best
    lo, hi = 0.0, best.max_bus_length * 2 + 1.0
    while at(hi) is not None:  # a node delay of 0 and a long bit: the first guess may fit
        lo, hi = hi, hi * 2
    for _ in range(60):
        mid = (lo + hi) / 2
        if at(mid) is None:
            hi = mid
        else:
            lo = mid
    return at(lo)


def _no_timing_for_bus(
    clock: int, bitrate: int, delays: BusDelays | None, error: BitTimingError, **kw: Any
) -> BitTimingError:
    """When the bus length is what stops every timing, the message states the longest bus a
    timing covers, instead of one candidate's negative Phase_Seg1."""
    if error.rule != RULE_PROP_SEG or delays is None or delays.round_trip_ns <= 0:
        return error
    sol = longest_bus(clock, bitrate, delays=delays, **kw)
    d = delays
    if sol is None:
        if d.node_delay_ns <= 0:
            return error
        return BitTimingError(
            RULE_PROP_SEG,
            f"no bit timing for {bitrate} bit/s with a {format_hz(clock)} clock: the node delays alone "
            f"({d.node_delay_ns:g} ns one way, {2 * d.node_delay_ns:g} ns round trip) need a longer Prop_Seg "
            "than any timing leaves, whatever the bus length",
        )
    return BitTimingError(
        RULE_PROP_SEG,
        f"no bit timing for {bitrate} bit/s with a {format_hz(clock)} clock covers a {d.bus_length_m:g} m bus: "
        f"the longest is {sol.max_bus_length:.1f} m (brp {sol.brp}, prop_seg {sol.prop_seg} of tseg1 {sol.tseg1} tq "
        f"of {sol.tq_ns:g} ns; cable {d.cable_delay_ns_per_m:g} ns/m, node delay {d.node_delay_ns:g} ns)",
    )


def solve(
    clock: int,
    bitrate: int,
    sample_point: float | None = None,
    limits: str | ControllerLimits = "sja1000",
    sjw: int | None = None,
    delays: BusDelays | None = None,
    min_tolerance: float | None = None,
    legacy: bool = False,
) -> Solution:
    """The timing the Linux kernel's can_calc_bittiming picks, restricted to timings passing
    `check_timing`: least bitrate error, then least sample point error with the sample point not
    above the requested one (default: `cia_sample_point`), then (Linux >= 5.19) the smallest
    prescaler; ``legacy`` keeps the largest instead, as kernels before 5.19 and can-utils'
    can-calc-bit-timing until 2022 did. ``sjw`` None takes the kernel default (Linux >= 6.3:
    max(1, min(Phase_Seg1, Phase_Seg2 / 2)), lowered if a bus length shortens Phase_Seg1).
    Raises `BitTimingError` naming the rule when no timing passes."""
    _, best, rejected = _candidates(clock, bitrate, sample_point, limits, sjw, delays, min_tolerance, legacy)
    if best is None:
        raise _no_timing_for_bus(
            clock,
            bitrate,
            delays,
            _no_timing(clock, bitrate, rejected),
            sample_point=sample_point,
            limits=limits,
            sjw=sjw,
            min_tolerance=min_tolerance,
            legacy=legacy,
        )
    return best


def all_timings(
    clock: int,
    bitrate: int,
    sample_point: float | None = None,
    limits: str | ControllerLimits = "sja1000",
    sjw: int | None = None,
    delays: BusDelays | None = None,
    min_tolerance: float | None = None,
    legacy: bool = False,
) -> list[Solution]:
    """Every valid timing of the bit lengths and prescalers the kernel's search visits: each
    split of TSEG1/TSEG2 within the controller's limits with the sample point from 50 % up to the
    requested one that passes every rule, ranked as the kernel ranks them: `solve`'s pick
    first, then by bitrate error, sample point error and longer bit time."""
    cands, best, rejected = _candidates(
        clock, bitrate, sample_point, limits, sjw, delays, min_tolerance, legacy, every_split=True
    )
    if best is None:
        raise _no_timing_for_bus(
            clock,
            bitrate,
            delays,
            _no_timing(clock, bitrate, rejected),
            sample_point=sample_point,
            limits=limits,
            sjw=sjw,
            min_tolerance=min_tolerance,
            legacy=legacy,
        )
    seen: set[tuple[int, int, int]] = set()
    ranked: list[Solution] = []
    for c in sorted(
        cands, key=lambda c: (c.solution is not best, c.bitrate_error, c.sample_point_error, -c.solution.nbt)
    ):
        key = (c.solution.brp, c.solution.tseg1, c.solution.tseg2)
        if key not in seen:
            seen.add(key)
            ranked.append(c.solution)
    return ranked


# ---------------------------------------------------------------------------------------------
# CLI


def format_hz(hz: float) -> str:
    """A clock frequency in MHz or kHz."""
    return f"{hz / 1e6:g} MHz" if hz >= 1e6 else f"{hz / 1e3:g} kHz"


def format_solution(sol: Solution) -> str:
    """A human-readable description of a timing (several lines)."""
    lines = [
        f"tq {sol.tq_ns:g} ns (brp {sol.brp}), {sol.nbt} tq per bit: "
        f"sync_seg 1 + prop_seg {sol.prop_seg} + phase_seg1 {sol.phase_seg1} + phase_seg2 {sol.phase_seg2}, sjw {sol.sjw}",
        f"tseg1 {sol.tseg1}, tseg2 {sol.tseg2}; sample point {sol.sample_point:.1f} %"
        + (f" (requested {sol.sample_point_nominal:g} %)" if sol.sample_point_nominal else ""),
        f"bitrate {sol.bitrate:g} bit/s" + (f" (error {sol.bitrate_error:.3f} %)" if sol.bitrate_nominal else ""),
    ]
    if sol.btr is not None:
        lines.append(f"BTR0 0x{sol.btr[0]:02x}  BTR1 0x{sol.btr[1]:02x}")
    lines.append(
        f"oscillator tolerance {sol.oscillator_tolerance:.3f} % "
        f"(SJW/(20 NBT) {sol.tolerance_resync:.3f} %, min(PS1,PS2)/(2(13 NBT-PS2)) {sol.tolerance_error_flag:.3f} %)"
    )
    d = sol.delays
    lines.append(
        f"max bus length {sol.max_bus_length:.1f} m (cable {d.cable_delay_ns_per_m:g} ns/m, "
        f"transceiver {d.transceiver_delay_ns:g} ns, comparator {d.comparator_delay_ns:g} ns)"
    )
    return "\n".join(lines)
