"""CAN FD bit timing: the data phase from the same clock, transmitter delay compensation, and
CiA 601-1's recommendations.

Rules (ISO 11898-1:2015; the Linux kernel's CAN FD bit timing):
- Each phase is solved as the kernel does (`stack.phy.bittiming.solve`, its can_calc_bittiming):
  the nominal phase with the controller's bittiming_const, the data phase with its
  data_bittiming_const, each with CiA's default sample point for its bit rate (75 % above
  800 kbit/s) unless one is given. The data bit rate is at least the nominal one.
- Transmitter delay compensation (TDC, ISO 11898-1:2015): in the data phase a transmitter
  checks its own bit at the secondary sample point SSP = measured loop delay (TDCV) + offset
  (TDCO), not at its sample point, so a loop delay longer than a data bit still works. The
  kernel's can_calc_tdco sets it only when the data prescaler is 1 or 2 (the kernel cites ISO
  11898-1 11.3.3), with TDCO = the data sample point in clock periods, (1 + TSEG1) x BRP, not
  below the controller's tdco_min and at most its tdco_max. (M_CAN's driver turns TDC on above
  2.5 Mbit/s instead, with the same offset: clock x sample point / bit rate.)
- CiA 601-1 recommends, for every node of a network: the same prescaler in both phases (the
  same time quantum, so both phases' phase errors stay whole quanta), a data-phase sample point
  of 70..80 %, and a fast CAN clock of 20, 40 or 80 MHz (short quanta, exact bit rates). They are
  reported, not enforced; ``same_prescaler`` picks a timing that keeps the first.

The combined value is python-can's `can.BitTimingFd` (its oscillator tolerance is the five CAN FD
conditions of ISO 11898-1:2015).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import can

from stack.phy.bittiming import format_hz, format_registers, format_segments, solve
from stack.phy.controllers import FD_CONTROLLERS, ControllerLimits, TdcLimits, controller_limits
from stack.phy.registers import RegisterValue, Segments, data_registers, split_note
from stack.phy.timing import FD_DATA, FD_NOMINAL, BitTimingError, BusDelays, Solution

__all__ = [
    "RULE_FD_CONTROLLER",
    "RULE_DATA_BITRATE",
    "CIA_CLOCKS",
    "CIA_DATA_SAMPLE_POINT",
    "Tdc",
    "Recommendation",
    "FdSolution",
    "calc_tdco",
    "solve_fd",
    "format_fd_solution",
]

RULE_FD_CONTROLLER = "a CAN FD controller (data-phase registers)"
RULE_DATA_BITRATE = "data bit rate >= nominal bit rate"
# Solution.as_dict keys that mean nothing for the data phase alone: its bus length (one
# transmitter) and the classical tolerance conditions (`FdSolution.oscillator_tolerance` has FD's)
_NOT_FOR_DATA = frozenset(
    ("max_bus_length_m", "registers", "oscillator_tolerance", "tolerance_resync", "tolerance_error_flag")
)
#: CAN clocks CiA 601-1 recommends (Hz).
CIA_CLOCKS = (20_000_000, 40_000_000, 80_000_000)
#: CiA 601-1's range for the data-phase sample point (percent).
CIA_DATA_SAMPLE_POINT = (70.0, 80.0)


class Tdc(NamedTuple):
    """Transmitter delay compensation as the kernel's can_calc_tdco sets it: ``enabled``, the
    offset ``tdco`` in CAN clock periods (0 when off) and why."""

    enabled: bool
    tdco: int
    reason: str


def calc_tdco(data: Solution, limits: TdcLimits | None) -> Tdc:
    """Linux's can_calc_tdco: TDC only with a data prescaler of 1 or 2; TDCO = the data sample
    point in clock periods, (1 + TSEG1) x BRP, off when below ``limits.tdco_min``, at most
    ``limits.tdco_max``. Off for a controller without TDC (``limits`` None)."""
    if limits is None:
        return Tdc(False, 0, "the controller has no transmitter delay compensation")
    if data.brp not in (1, 2):
        return Tdc(False, 0, f"data prescaler {data.brp}: TDC needs 1 or 2 (ISO 11898-1, as the kernel applies it)")
    sp_clocks = (1 + data.tseg1) * data.brp
    if sp_clocks < limits.tdco_min:
        return Tdc(False, 0, f"sample point {sp_clocks} clock periods, below TDCO's minimum {limits.tdco_min}")
    if sp_clocks > limits.tdco_max:
        return Tdc(
            True, limits.tdco_max, f"the data sample point, {sp_clocks} clock periods, capped at {limits.tdco_max}"
        )
    return Tdc(True, sp_clocks, f"the data sample point: (1 + tseg1 {data.tseg1}) x brp {data.brp}")


class Recommendation(NamedTuple):
    """One of CiA 601-1's recommendations: what it asks, whether the timing meets it, and how."""

    rule: str
    met: bool
    detail: str


@dataclass(frozen=True)
class FdSolution:
    """A CAN FD bit timing: the nominal and data phases (`Solution` each), transmitter delay
    compensation and the controller's limits."""

    nominal: Solution
    data: Solution
    tdc: Tdc
    limits: ControllerLimits
    alternative: FdSolution | None = None

    @property
    def clock(self) -> int:
        """The CAN clock in Hz (the kernel's clock.freq)."""
        return int(self.nominal.timing.f_clock)

    @property
    def tdco_ns(self) -> float:
        """The TDC offset in ns."""
        return self.tdc.tdco * 1e9 / self.clock

    @property
    def timing(self) -> can.BitTimingFd:
        """The python-can value (ValueError when python-can refuses it, e.g. a sample point
        below 50 %)."""
        n, d = self.nominal, self.data
        return can.BitTimingFd(
            f_clock=self.clock,
            nom_brp=n.brp,
            nom_tseg1=n.tseg1,
            nom_tseg2=n.tseg2,
            nom_sjw=n.sjw,
            data_brp=d.brp,
            data_tseg1=d.tseg1,
            data_tseg2=d.tseg2,
            data_sjw=d.sjw,
        )

    @property
    def oscillator_tolerance(self) -> float | None:
        """The largest clock deviation in percent meeting the five CAN FD conditions of ISO
        11898-1:2015 (python-can's, with this bus's delays); None when python-can refuses the
        timing."""
        d = self.nominal.delays
        try:
            timing = self.timing
        except ValueError:
            return None
        # python-can's Prop_Seg is ceil(2 (loop delay + 5 ns/m x L) / tq): the same round trip
        length = d.bus_length_m * d.cable_delay_ns_per_m / 5
        return float(timing.oscillator_tolerance(node_loop_delay_ns=d.node_delay_ns, bus_length_m=length))

    @property
    def data_segments(self) -> Segments:
        """The data phase's register contents, with TDC."""
        return self.data.segments._replace(tdc=self.tdc.enabled, tdco=self.tdc.tdco)

    @property
    def registers(self) -> list[RegisterValue]:
        """Nominal, data-phase and TDC registers of the controller (`stack.phy.registers`)."""
        return self.nominal.registers + data_registers(self.limits.name, self.data_segments)

    def loop_delay_check(self, loop_delay_ns: float) -> tuple[bool, str]:
        """Whether the transmitter checks its own data bits right with this loop delay (TX to
        RX through its transceiver): without TDC the delayed bit must arrive before the data
        sample point; with TDC the measured delay (whole clock periods) must fit TDCV's range."""
        period = 1e9 / self.clock
        if self.tdc.enabled:
            tdcv = math.ceil(loop_delay_ns / period - 1e-9)
            top = self.limits.tdc.tdcv_max if self.limits.tdc else 0
            if tdcv > top:
                return False, f"TDCV {tdcv} clock periods exceeds the controller's {top}: TDC cannot measure it"
            return True, f"TDC measures it (TDCV {tdcv} of at most {top} clock periods)"
        sp_ns = (1 + self.data.tseg1) * self.data.tq_ns
        if loop_delay_ns < sp_ns:
            return True, f"its own bits arrive before the data sample point ({sp_ns:g} ns)"
        return False, f"without TDC its own data bits arrive after the data sample point ({sp_ns:g} ns): bit errors"

    @property
    def recommendations(self) -> list[Recommendation]:
        """CiA 601-1's recommendations and whether this timing meets them (see the module)."""
        n, d = self.nominal, self.data
        same = n.brp == d.brp
        if same:
            detail = f"brp {n.brp}"
        elif self.alternative is not None:
            a = self.alternative
            detail = (
                f"brp {n.brp} and {d.brp}; with brp {a.data.brp} in both: nominal {a.nominal.nbt} tq at "
                f"{a.nominal.sample_point:.1f} %, data {a.data.nbt} tq at {a.data.sample_point:.1f} % (--same-prescaler)"
            )
        else:
            detail = f"brp {n.brp} and {d.brp}; no common prescaler reaches both bit rates"
        lo, hi = CIA_DATA_SAMPLE_POINT
        return [
            Recommendation("same prescaler in both phases", same, detail),
            Recommendation(
                f"data sample point {lo:g}..{hi:g} %", lo <= d.sample_point <= hi, f"{d.sample_point:.1f} %"
            ),
            Recommendation("CAN clock 20, 40 or 80 MHz", self.clock in CIA_CLOCKS, format_hz(self.clock)),
        ]

    def as_dict(self) -> dict[str, Any]:
        """JSON form: ``nominal`` and ``data`` (each `Solution.as_dict`), ``tdc`` {enabled, tdco,
        tdco_ns, reason}, ``registers``, ``oscillator_tolerance`` (%) and ``cia`` (the
        recommendations)."""
        tol = self.oscillator_tolerance
        return {
            "nominal": self.nominal.as_dict(),
            "data": {k: v for k, v in self.data.as_dict().items() if k not in _NOT_FOR_DATA},
            "tdc": {
                "enabled": self.tdc.enabled,
                "tdco": self.tdc.tdco,
                "tdco_ns": round(self.tdco_ns, 3),
                "reason": self.tdc.reason,
            },
            "registers": {r.name: r.value for r in self.registers},
            "oscillator_tolerance": None if tol is None else round(tol, 4),
            "cia": [{"rule": r.rule, "met": r.met, "detail": r.detail} for r in self.recommendations],
        }


def _fd_limits(limits: str | ControllerLimits) -> ControllerLimits:
    lim = controller_limits(limits)
    if lim.data is None:
        raise BitTimingError(
            RULE_FD_CONTROLLER,
            f"controller {lim.name} has no CAN FD data phase: CAN FD controllers are {', '.join(FD_CONTROLLERS)}",
        )
    return lim


def _phases(
    lim: ControllerLimits,
    clock: int,
    bitrate: int,
    data_bitrate: int,
    kw: dict[str, Any],
    data_kw: dict[str, Any],
) -> tuple[Solution, Solution]:
    assert lim.data is not None
    nominal = solve(clock, bitrate, limits=lim, rules=FD_NOMINAL, **kw)
    data = solve(clock, data_bitrate, limits=lim.data, rules=FD_DATA, **data_kw)
    return nominal, data


def _common_prescaler(
    lim: ControllerLimits,
    clock: int,
    bitrate: int,
    data_bitrate: int,
    kw: dict[str, Any],
    data_kw: dict[str, Any],
    worst: tuple[float, float],
) -> tuple[Solution, Solution] | None:
    """The smallest prescaler both phases can share with bit rate errors no worse than ``worst``
    (each phase solved as the kernel with the prescaler fixed to it); None when there is none."""
    assert lim.data is not None
    d = lim.data
    longest = d.tseg1_max + d.tseg2_max + 1
    first = max(lim.brp_min, d.brp_min, clock // (data_bitrate * longest))
    last = min(lim.brp_max, d.brp_max, clock // data_bitrate)
    for brp in range(max(1, first), last + 1):
        pinned = replace(lim, brp_min=brp, brp_max=brp, brp_inc=1, data=replace(d, brp_min=brp, brp_max=brp, brp_inc=1))
        try:
            nominal, data = _phases(pinned, clock, bitrate, data_bitrate, kw, data_kw)
        except BitTimingError:
            continue
        if nominal.bitrate_error <= worst[0] and data.bitrate_error <= worst[1]:
            return replace(nominal, limits=lim), replace(data, limits=d)
    return None


def solve_fd(
    clock: int,
    bitrate: int,
    data_bitrate: int,
    sample_point: float | None = None,
    data_sample_point: float | None = None,
    limits: str | ControllerLimits = "m_can",
    sjw: int | None = None,
    data_sjw: int | None = None,
    delays: BusDelays | None = None,
    min_tolerance: float | None = None,
    legacy: bool = False,
    same_prescaler: bool = False,
) -> FdSolution:
    """The CAN FD bit timing the kernel picks for ``limits`` (an FD controller): each phase by
    can_calc_bittiming (`solve` with `FD_NOMINAL` and `FD_DATA`), TDC by can_calc_tdco
    (`calc_tdco`). ``delays`` and ``min_tolerance`` apply to the nominal phase (the data phase
    has one transmitter: its Prop_Seg need not cover the bus). With ``same_prescaler`` both phases
    get the smallest prescaler they can share without a worse bit rate (CiA 601-1); otherwise
    that timing is only reported beside the kernel's. Raises `BitTimingError` naming the rule:
    not an FD controller, a data bit rate below the nominal, or a phase without a timing."""
    lim = _fd_limits(limits)
    if isinstance(bitrate, int) and isinstance(data_bitrate, int) and 0 < data_bitrate < bitrate:
        raise BitTimingError(
            RULE_DATA_BITRATE,
            f"data bit rate {data_bitrate} bit/s below the nominal {bitrate} bit/s: the data phase switches to a "
            "rate at least the nominal",
        )
    kw: dict[str, Any] = dict(
        sample_point=sample_point, sjw=sjw, delays=delays, min_tolerance=min_tolerance, legacy=legacy
    )
    data_kw: dict[str, Any] = dict(sample_point=data_sample_point, sjw=data_sjw, legacy=legacy)
    nominal, data = _phases(lim, clock, bitrate, data_bitrate, kw, data_kw)
    common = None
    if nominal.brp != data.brp:
        common = _common_prescaler(
            lim, clock, bitrate, data_bitrate, kw, data_kw, (nominal.bitrate_error, data.bitrate_error)
        )
    assert lim.data is not None
    if same_prescaler and common is not None:
        nominal, data = common
        common = None
    alternative = None
    if common is not None:
        alternative = FdSolution(common[0], common[1], calc_tdco(common[1], lim.tdc), lim)
    return FdSolution(nominal, data, calc_tdco(data, lim.tdc), lim, alternative)


def format_fd_solution(sol: FdSolution) -> str:
    """A human-readable description of a CAN FD timing: each phase's segments and registers,
    TDC, oscillator tolerance, the longest bus, the transmitter's loop delay and CiA 601-1."""
    lines = ["nominal phase:"]
    lines += ["  " + x for x in format_segments(sol.nominal)]
    lines += [
        "  " + x for x in format_registers(sol.nominal.registers, split_note(sol.limits.name, sol.nominal.segments))
    ]
    lines.append("data phase:")
    lines += ["  " + x for x in format_segments(sol.data)]
    data_regs = data_registers(sol.limits.name, sol.data_segments)
    lines += ["  " + x for x in format_registers(data_regs, split_note(sol.limits.name, sol.data_segments, data=True))]
    if sol.tdc.enabled:
        lines.append(
            f"transmitter delay compensation: on, TDCO {sol.tdc.tdco} clock periods = {sol.tdco_ns:g} ns "
            f"({sol.tdc.reason}); secondary sample point = measured loop delay + {sol.tdco_ns:g} ns"
        )
    else:
        lines.append(f"transmitter delay compensation: off ({sol.tdc.reason})")
    d = sol.nominal.delays
    if d.node_delay_ns > 0:
        ok, why = sol.loop_delay_check(d.node_delay_ns)
        lines.append(f"transmitter loop delay {d.node_delay_ns:g} ns: {'ok' if ok else 'fails'}, {why}")
    tol = sol.oscillator_tolerance
    if tol is not None:
        lines.append(f"oscillator tolerance {tol:.3f} % (the five CAN FD conditions of ISO 11898-1:2015, python-can)")
    lines.append(
        f"max bus length {sol.nominal.max_bus_length:.1f} m (nominal phase; cable {d.cable_delay_ns_per_m:g} ns/m, "
        f"transceiver {d.transceiver_delay_ns:g} ns, comparator {d.comparator_delay_ns:g} ns)"
    )
    cia = "; ".join(f"{r.rule}: {'yes' if r.met else 'no'} ({r.detail})" for r in sol.recommendations)
    lines.append(f"CiA 601-1: {cia}")
    return "\n".join(lines)
