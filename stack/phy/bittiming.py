"""Bit timing: solve BRP/TSEG1/TSEG2/SJW for a controller clock and bitrate, as the Linux kernel.

The solver follows the Linux kernel's can_calc_bittiming: scan the bit lengths from long to short,
take the prescaler that comes closest to the bitrate, keep the candidate with the least bitrate
error, then the least sample-point error with the sample point not above the requested one, and
on a tie the first found — the smallest prescaler (Linux >= 5.19; ``legacy`` for the older rule).
Every candidate must pass `stack.phy.timing.check_timing` (the rules: ISO 11898-1 bit time, SJW,
Prop_Seg for the bus, oscillator tolerance); the value is python-can's `can.BitTiming`.

The rules and the value type live in `stack.phy.timing`, the controllers' register ranges in
`stack.phy.controllers`; both are importable from here as before.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

from stack.phy.controllers import CONTROLLERS, ControllerLimits, controller_limits, parse_limits
from stack.phy.registers import RegisterValue, split_note
from stack.phy.timing import (
    CLASSICAL,
    FD_DATA,
    FD_NOMINAL,
    MAX_BITRATE_ERROR_PERMILLE,
    RULE_BITRATE,
    RULE_LIMITS,
    RULE_NBT,
    RULE_PROP_SEG,
    RULE_SAMPLE_POINT,
    RULE_SJW_PHASE_SEG1,
    RULE_SJW_PHASE_SEG2,
    RULE_SJW_RANGE,
    RULE_TOLERANCE_ERROR_FLAG,
    RULE_TOLERANCE_RESYNC,
    SYNC_SEG,
    BitTimingError,
    BusDelays,
    Solution,
    TimingRules,
    check_timing,
    cia_sample_point,
    make_timing,
    max_bus_length,
    oscillator_tolerance,
    required_prop_seg,
    tolerance_error_flag,
    tolerance_resync,
)

__all__ = [
    "BitTimingError",
    "ControllerLimits",
    "CONTROLLERS",
    "BusDelays",
    "Solution",
    "TimingRules",
    "CLASSICAL",
    "FD_NOMINAL",
    "FD_DATA",
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
    "format_hz",
    "format_segments",
    "format_registers",
    "format_solution",
]

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


def _sjw_for(sjw: int | None, lim: ControllerLimits, tseg1: int, tseg2: int, rules: TimingRules) -> int:
    if sjw is not None:
        return sjw
    # Linux >= 6.3 default (can_sjw_set_default): half of Phase_Seg2, at most Phase_Seg1
    phase_seg1 = tseg1 - tseg1 // 2
    return max(1, min(phase_seg1, tseg2 // 2, rules.sjw_max or lim.sjw_max, lim.sjw_max))


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
    rules: TimingRules,
) -> Solution:
    """`check_timing` of one split. With the default SJW, a Prop_Seg lengthened for the bus
    length can leave Phase_Seg1 shorter than that SJW: the SJW is lowered to that Phase_Seg1
    (the kernel's default min(Phase_Seg1, Phase_Seg2 / 2) on the real Phase_Seg1) rather than
    the timing refused."""
    width = _sjw_for(sjw, lim, tseg1, tseg2, rules)
    try:
        return check_timing(
            make_timing(clock, brp, tseg1, tseg2, width), lim, delays, None, min_tolerance, bitrate, sp, rules
        )
    except BitTimingError as exc:
        if sjw is not None or exc.phase_seg1 is None or exc.phase_seg1 >= width:
            raise
        return check_timing(
            make_timing(clock, brp, tseg1, tseg2, exc.phase_seg1), lim, delays, None, min_tolerance, bitrate, sp, rules
        )


@dataclass
class _Candidate:
    order: int
    bitrate_error: int
    sample_point_error: int
    solution: Solution


def _validate_request(
    clock: int, bitrate: int, sample_point: float | None, sjw: int | None, rules: TimingRules = CLASSICAL
) -> float:
    if not isinstance(clock, int) or clock <= 0:
        raise ValueError(f"clock={clock!r}: the controller clock must be a positive integer in Hz")
    if not isinstance(bitrate, int) or bitrate <= 0:
        raise ValueError(f"bitrate={bitrate!r}: the bitrate must be a positive integer in bit/s")
    sp = cia_sample_point(bitrate) if sample_point is None else float(sample_point)
    if not 50.0 <= sp < 100.0:
        raise BitTimingError(RULE_SAMPLE_POINT, f"sample point {sp:g} % outside 50..<100 %")
    if sjw is not None and (sjw < 1 or (rules.sjw_max is not None and sjw > rules.sjw_max)):
        top = rules.sjw_max if rules.sjw_max is not None else "the controller's maximum"
        raise BitTimingError(rules.sjw_rule, f"sjw={sjw} outside 1..{top}")
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
    rules: TimingRules = CLASSICAL,
) -> tuple[list[_Candidate], Solution | None, dict[str, str]]:
    """Walk the kernel's search: every bit length from long to short with the prescaler rounded
    down (even step) and up (odd step). Returns the candidates passing every rule (in visit
    order), the kernel's pick among them, and, per rule, an example of a rejected candidate."""
    lim = controller_limits(limits)
    sp = _validate_request(clock, bitrate, sample_point, sjw, rules)
    if sjw is not None and sjw > lim.sjw_max:
        raise BitTimingError(rules.sjw_rule, f"sjw={sjw} outside {lim.name}'s 1..{lim.sjw_max}")
    sp_nominal = round(sp * 10)
    rejected: dict[str, str] = {}
    out: list[_Candidate] = []
    best: _Candidate | None = None
    tseg_hi = lim.tseg1_max + lim.tseg2_max
    if rules.nbt_max is not None:
        tseg_hi = min(tseg_hi, rules.nbt_max - SYNC_SEG)
    tseg_lo = max(lim.tseg1_min + lim.tseg2_min, rules.nbt_min - SYNC_SEG)
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
                    sol = _checked(clock, brp, tseg1, tseg2, sjw, lim, delays, min_tolerance, bitrate, sp, rules)
                except ValueError:  # BitTimingError included: not valid, not listed
                    continue
                extra.append(_Candidate(-1, br_err, abs(sp_nominal - sp_p), sol))
        if split is None:
            rejected.setdefault(RULE_SAMPLE_POINT, f"no split of {nbt} tq at or below {sp:g} %")
            continue
        tseg1, tseg2, sp_real = split
        try:
            sol = _checked(clock, brp, tseg1, tseg2, sjw, lim, delays, min_tolerance, bitrate, sp, rules)
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
        *(r for r in rejected if r not in _RULE_ORDER),  # a range rule of the FD phases
        RULE_SJW_RANGE,
        RULE_SAMPLE_POINT,
        RULE_BITRATE,
        RULE_LIMITS,
    ):
        if rule in rejected:
            example = rejected[rule].split(" (rule:")[0]
            return BitTimingError(rule, f"no bit timing for {bitrate} bit/s with a {clock} Hz clock: {example}")
    raise AssertionError  # pragma: no cover


_RULE_ORDER = frozenset(
    (
        RULE_TOLERANCE_ERROR_FLAG,
        RULE_TOLERANCE_RESYNC,
        RULE_PROP_SEG,
        RULE_SJW_PHASE_SEG1,
        RULE_SJW_PHASE_SEG2,
        RULE_SJW_RANGE,
        RULE_SAMPLE_POINT,
        RULE_BITRATE,
        RULE_LIMITS,
    )
)


def longest_bus(
    clock: int,
    bitrate: int,
    sample_point: float | None = None,
    limits: str | ControllerLimits = "sja1000",
    sjw: int | None = None,
    delays: BusDelays | None = None,
    min_tolerance: float | None = None,
    legacy: bool = False,
    rules: TimingRules = CLASSICAL,
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
            clock,
            bitrate,
            sample_point,
            limits,
            sjw,
            replace(base, bus_length_m=length),
            min_tolerance,
            legacy,
            rules=rules,
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


def _search(
    clock: int,
    bitrate: int,
    sample_point: float | None,
    limits: str | ControllerLimits,
    sjw: int | None,
    delays: BusDelays | None,
    min_tolerance: float | None,
    legacy: bool,
    every_split: bool,
    rules: TimingRules,
) -> tuple[list[_Candidate], Solution]:
    """`_candidates` and the kernel's pick; `BitTimingError` naming the rule when none passes."""
    cands, best, rejected = _candidates(
        clock, bitrate, sample_point, limits, sjw, delays, min_tolerance, legacy, every_split=every_split, rules=rules
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
            rules=rules,
        )
    return cands, best


def solve(
    clock: int,
    bitrate: int,
    sample_point: float | None = None,
    limits: str | ControllerLimits = "sja1000",
    sjw: int | None = None,
    delays: BusDelays | None = None,
    min_tolerance: float | None = None,
    legacy: bool = False,
    rules: TimingRules = CLASSICAL,
) -> Solution:
    """The timing the Linux kernel's can_calc_bittiming picks, restricted to timings passing
    `check_timing`: least bitrate error, then least sample point error with the sample point not
    above the requested one (default: `cia_sample_point`), then (Linux >= 5.19) the smallest
    prescaler; ``legacy`` keeps the largest instead, as kernels before 5.19 and can-utils'
    can-calc-bit-timing until 2022 did. ``sjw`` None takes the kernel default (Linux >= 6.3:
    max(1, min(Phase_Seg1, Phase_Seg2 / 2)), lowered if a bus length shortens Phase_Seg1).
    ``rules``: `CLASSICAL` (8..25 tq, SJW 1..4), or for the phases of CAN FD `FD_NOMINAL` and
    `FD_DATA` (the controller's ranges, as the kernel). Raises `BitTimingError` naming the rule
    when no timing passes."""
    return _search(clock, bitrate, sample_point, limits, sjw, delays, min_tolerance, legacy, False, rules)[1]


def all_timings(
    clock: int,
    bitrate: int,
    sample_point: float | None = None,
    limits: str | ControllerLimits = "sja1000",
    sjw: int | None = None,
    delays: BusDelays | None = None,
    min_tolerance: float | None = None,
    legacy: bool = False,
    rules: TimingRules = CLASSICAL,
) -> list[Solution]:
    """Every valid timing of the bit lengths and prescalers the kernel's search visits: each
    split of TSEG1/TSEG2 within the controller's limits with the sample point from 50 % up to the
    requested one that passes every rule, ranked as the kernel ranks them: `solve`'s pick
    first, then by bitrate error, sample point error and longer bit time."""
    cands, best = _search(clock, bitrate, sample_point, limits, sjw, delays, min_tolerance, legacy, True, rules)
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


def format_segments(sol: Solution) -> list[str]:
    """The segments, sample point and bitrate of a timing (three lines)."""
    return [
        f"tq {sol.tq_ns:g} ns (brp {sol.brp}), {sol.nbt} tq per bit: "
        f"sync_seg 1 + prop_seg {sol.prop_seg} + phase_seg1 {sol.phase_seg1} + phase_seg2 {sol.phase_seg2}, sjw {sol.sjw}",
        f"tseg1 {sol.tseg1}, tseg2 {sol.tseg2}; sample point {sol.sample_point:.1f} %"
        + (f" (requested {sol.sample_point_nominal:g} %)" if sol.sample_point_nominal else ""),
        f"bitrate {sol.bitrate:.12g} bit/s" + (f" (error {sol.bitrate_error:.3f} %)" if sol.bitrate_nominal else ""),
    ]


def format_registers(registers: list[RegisterValue], note: str | None = None) -> list[str]:
    """One line of register values ('NAME 0x..' two spaces apart), and the split note if any."""
    if not registers:
        return []
    return ["  ".join(str(r) for r in registers)] + ([note] if note else [])


def format_solution(sol: Solution) -> str:
    """A human-readable description of a timing (several lines): segments, sample point, bitrate,
    the controller's registers, oscillator tolerance and the longest bus."""
    lines = format_segments(sol)
    lines += format_registers(sol.registers, split_note(sol.limits.name, sol.segments))
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
