"""`canstack sync`: resynchronisation and bus-length simulations on the command line
(`stack.phy.sync`, `stack.phy.propagation`)."""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import replace
from typing import Any

from stack.cli import CliError, format_id, parse_sample_point
from stack.cli.bittiming import add_timing_arguments, limits_from_args
from stack.phy.bittiming import BusDelays, Solution, format_hz, solve
from stack.phy.bittiming_fd import solve_fd
from stack.phy.propagation import (
    BUS_LENGTH_FRAMES,
    DEFAULT_PHASES,
    ack_exchange,
    arbitration_exchange,
    max_bus_length_simulated,
    one_way_delay_ns,
)
from stack.phy.sync import max_drift, worst_case_frames
from stack.phy.tdc import TDC_FRAMES, max_loop_delay, transmit_fd

__all__ = ["register"]


def _drift_range(text: str) -> tuple[float, float]:
    lo, dots, hi = text.partition("..")
    try:
        a, b = (float(lo), float(hi)) if dots else (0.0, float(lo))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected LOW..HIGH in ppm, e.g. 0..20000") from None
    if not (0 <= a < b and math.isfinite(b)):
        raise argparse.ArgumentTypeError(f"{text!r}: a drift range needs 0 <= LOW < HIGH")
    if b >= 500_000:
        raise argparse.ArgumentTypeError(f"{text!r}: drift beyond 500000 ppm is not a clock offset")
    return a, b


def _length(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"{text!r}: needs a finite number >= 0")
    return v


#: Finest bisection the scan accepts: a drift of 0.01 ppm moves a 160-bit frame's last sample
#: by 1.6e-6 of a bit, far below any time quantum, and keeps the bisection a few dozen steps.
MIN_RESOLUTION_PPM = 0.01


def _count(text: str) -> int:
    """A whole number, also written as 1e3."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(v) and v == int(v) and v >= 1):
        raise argparse.ArgumentTypeError(f"{text!r}: needs a whole number >= 1")
    return int(v)


def _check_scan(steps: int, resolution: float, lo: float, hi: float) -> None:
    """The drift scan's size, bounded before it starts: a scan step finer than the bisection's
    resolution finds nothing the bisection would not (and --steps 1e9 would scan for days); a
    resolution below MIN_RESOLUTION_PPM, or below a float's spacing, never ends."""
    if not (math.isfinite(resolution) and resolution >= MIN_RESOLUTION_PPM):
        raise CliError(f"--resolution {resolution:g} ppm: must be at least {MIN_RESOLUTION_PPM:g} ppm")
    most = max(1, int((hi - lo) / resolution))
    if steps > most:
        raise CliError(
            f"--steps {steps}: a scan step of {(hi - lo) / steps:.3g} ppm is finer than --resolution "
            f"{resolution:g} ppm; at most {most} steps over {lo:g}..{hi:g} ppm"
        )


def _run_bus_length(args: argparse.Namespace, sol: Solution) -> int:
    delays = sol.delays
    at = replace(delays, bus_length_m=args.bus_length)
    fa, fb = BUS_LENGTH_FRAMES
    checks = [ack_exchange(fa, sol.timing, at, phase=ph) for ph in DEFAULT_PHASES]
    checks += [arbitration_exchange(fa, fb, sol.timing, at, phase=ph) for ph in DEFAULT_PHASES]
    bad = next((r for r in checks if not r.ok), None)
    res = max_bus_length_simulated(sol, delays)
    if args.json:
        d = res.as_dict()
        d["bus_length_m"] = args.bus_length
        d["at_bus_length"] = None if bad is None else bad.as_dict()
        d["ok_at_bus_length"] = bad is None
        print(json.dumps(d, indent=2))
        return 0
    s = sol
    print(
        f"{args.bitrate} bit/s, {args.clock} Hz clock: brp {s.brp}, tq {s.tq_ns:g} ns, {s.nbt} tq "
        f"(prop_seg {s.prop_seg}, phase_seg1 {s.phase_seg1}, phase_seg2 {s.phase_seg2}), sjw {s.sjw}, "
        f"sample point {s.sample_point:.1f} %; cable {delays.cable_delay_ns_per_m:g} ns/m, "
        f"node delay {delays.node_delay_ns:g} ns"
    )
    print(
        f"at {args.bus_length:g} m (one-way {one_way_delay_ns(at):g} ns): "
        + ("ACK and arbitration work" if bad is None else bad.describe())
    )
    print(
        f"largest bus length simulated: {res.simulated_m:.1f} m"
        + (f"; beyond it: {res.first_failure.describe()}" if res.first_failure else "")
    )
    print(
        f"round trip reaching the sample point: {res.sample_point_m:.1f} m (1 tq of round trip = {res.quantum_m:.1f} m)"
    )
    print(
        f"formula Prop_Seg >= 2 x (bus + transceiver + comparator): {res.formula_m:.1f} m "
        f"(keeps Sync_Seg + Phase_Seg1 free for phase errors: {res.reserve_m:.1f} m below the simulation)"
    )
    return 0


def _run_tdc(args: argparse.Namespace) -> int:
    """CAN FD: the transmitter's own bit check with a loop delay, without and with TDC."""
    lim = limits_from_args(args)
    fd = solve_fd(
        args.clock,
        args.bitrate,
        args.data_bitrate,
        sample_point=args.sample_point,
        data_sample_point=args.data_sample_point,
        limits=lim,
        sjw=args.sjw,
        data_sjw=args.data_sjw,
    )
    timing, d = fd.timing, fd.data
    tdco = fd.tdc.tdco if fd.tdc.enabled else None
    tdcv_max = lim.tdc.tdcv_max if lim.tdc else None
    loop = args.loop_delay or 0.0
    without = next((r for r in (transmit_fd(f, timing, loop) for f in TDC_FRAMES) if not r.ok), None)
    with_tdc = None
    if tdco is not None:
        runs = [transmit_fd(f, timing, loop, tdco, tdcv_max=tdcv_max) for f in TDC_FRAMES]
        with_tdc = next((r for r in runs if not r.ok), runs[0])
    nominal_ns = fd.nominal.nbt * fd.nominal.tq_ns
    longest, beyond = max_loop_delay(timing, resolution_ns=0.25)
    longest_tdc, beyond_tdc = (
        max_loop_delay(timing, tdco, tdcv_max=tdcv_max, limit_ns=nominal_ns, resolution_ns=0.25)
        if tdco is not None
        else (None, None)
    )
    if args.json:
        out: dict[str, Any] = {
            "loop_delay_ns": loop,
            "data_bit_ns": d.nbt * d.tq_ns,
            "tdc": fd.as_dict()["tdc"],
            "without_tdc": (without or transmit_fd(TDC_FRAMES[0], timing, loop)).as_dict(),
            "with_tdc": None if with_tdc is None else with_tdc.as_dict(),
            "max_loop_delay_ns": longest,
            "max_loop_delay_tdc_ns": longest_tdc,
        }
        print(json.dumps(out, indent=2))
        return 0
    print(
        f"{args.bitrate} bit/s, data {args.data_bitrate} bit/s, {format_hz(args.clock)} clock on {lim.name}: "
        f"data brp {d.brp}, {d.nbt} tq of {d.tq_ns:g} ns (tseg1 {d.tseg1}, tseg2 {d.tseg2}), sjw {d.sjw}, "
        f"sample point {d.sample_point:.1f} %"
    )
    print("frames: " + ", ".join(f"{format_id(f.can_id, f.extended)} [{f.data.hex()}]" for f in TDC_FRAMES))
    print(f"loop delay {loop:g} ns (a data bit is {d.nbt * d.tq_ns:g} ns):")
    print("  without TDC: " + ("ok" if without is None else f"fails: {without.describe()}"))
    if with_tdc is None:
        print(f"  with TDC: off ({fd.tdc.reason})")
    else:
        status = "ok" if with_tdc.ok else f"fails: {with_tdc.describe()}"
        print(
            f"  with TDC (TDCO {tdco}): {status}, TDCV {with_tdc.tdcv}: secondary sample point {with_tdc.ssp} "
            "clock periods after each data bit is sent"
        )
    sp_ns = (1 + d.tseg1) * d.tq_ns
    print(
        f"largest loop delay without TDC: {longest:.0f} ns (the data sample point is {sp_ns:g} ns into the bit)"
        + (f"; beyond it: {beyond.describe()}" if beyond is not None else "")
    )
    if longest_tdc is not None:
        print(
            f"largest loop delay with TDC: {longest_tdc:.0f} ns"
            + (f"; beyond it: {beyond_tdc.describe()}" if beyond_tdc is not None else "")
        )
    return 0


def _run(args: argparse.Namespace) -> int:
    if args.data_bitrate is not None:
        return _run_tdc(args)
    for option in ("loop_delay", "data_sample_point", "data_sjw"):
        if getattr(args, option) is not None:
            raise CliError(f"--{option.replace('_', '-')} needs --data-bitrate (it is about the CAN FD data phase)")
    lim = limits_from_args(args)
    if args.bus_length is not None:
        delays = BusDelays(0.0, args.cable_delay, args.transceiver_delay, args.comparator_delay)
        sol = solve(args.clock, args.bitrate, sample_point=args.sample_point, limits=lim, sjw=args.sjw, delays=delays)
        return _run_bus_length(args, sol)
    sol = solve(args.clock, args.bitrate, sample_point=args.sample_point, limits=lim, sjw=args.sjw)
    if args.samples == 3:
        t = sol.timing
        sol = Solution(
            type(t)(f_clock=t.f_clock, brp=t.brp, tseg1=t.tseg1, tseg2=t.tseg2, sjw=t.sjw, nof_samples=3),
            sol.prop_seg,
            sol.phase_seg1,
            sol.phase_seg2,
            sol.limits,
            sol.delays,
            sol.bitrate_nominal,
            sol.sample_point_nominal,
        )
    lo, hi = args.drift_ppm
    _check_scan(args.steps, args.resolution, lo, hi)
    res = max_drift(sol, lo, hi, steps=args.steps, resolution_ppm=args.resolution)
    if args.json:
        print(json.dumps(res.as_dict(), indent=2))
        return 0
    s = sol
    print(
        f"{args.bitrate} bit/s, {args.clock} Hz clock: brp {s.brp}, {s.nbt} tq (tseg1 {s.tseg1}, tseg2 {s.tseg2}), "
        f"sjw {s.sjw}, sample point {s.sample_point:.1f} %, {s.timing.nof_samples} sample(s)"
    )
    print("frames: " + ", ".join(f"{format_id(f.can_id, f.extended)} [{f.data.hex()}]" for f in worst_case_frames()))
    for d, f in res.scan:
        print(
            f"  drift +-{d:8.0f} ppm: {'ok' if f is None else f'fails ({f.drift_ppm:+.0f} ppm): ' + f.reception.describe()}"
        )
    if math.isnan(res.max_drift_ppm):
        print(f"reception fails already at {lo:g} ppm")
    elif res.first_failure is None:
        print(f"frames received over the whole range, up to {hi:g} ppm")
    else:
        ff = res.first_failure
        print(f"largest drift received: {res.max_drift_ppm:.0f} ppm")
        print(
            f"first failure at {ff.drift_ppm:+.0f} ppm, frame {format_id(ff.frame.can_id, ff.frame.extended)}: {ff.reception.describe()}"
        )
    print(
        f"formula tolerance: {res.formula_ppm:.0f} ppm (SJW/(20 NBT) {s.tolerance_resync * 1e4:.0f}, "
        f"min(PS1,PS2)/(2(13 NBT-PS2)) {s.tolerance_error_flag * 1e4:.0f}); "
        f"simulation reaches {res.margin:.2f} x that"
    )
    return 0


def register(subparsers: Any) -> None:
    """Add the `sync` subcommand."""
    p = subparsers.add_parser(
        "sync",
        help="simulate resynchronisation with a drifting receiver clock",
        description="Find the largest receiver clock drift at which worst-case frames are still "
        "received, against the ISO 11898-1 oscillator tolerance.",
    )
    add_timing_arguments(p)
    p.add_argument("--drift-ppm", type=_drift_range, default=(0.0, 20_000.0), help="range LOW..HIGH in ppm (0..20000)")
    p.add_argument("--samples", type=int, choices=(1, 3), default=1, help="samples per bit (1 or 3)")
    p.add_argument(
        "--steps",
        type=_count,
        default=10,
        help="scan intervals before bisection (10; at most (HIGH - LOW) / --resolution)",
    )
    p.add_argument(
        "--resolution",
        type=float,
        default=10.0,
        help=f"bisection resolution in ppm (10; at least {MIN_RESOLUTION_PPM:g})",
    )
    p.add_argument(
        "--bus-length",
        type=_length,
        help="instead of the drift scan: simulate the ACK round trip and arbitration at this bus "
        "length (m) and report the largest length that works against the Prop_Seg formula",
    )
    p.add_argument("--cable-delay", type=_length, default=5.0, help="with --bus-length: cable delay in ns/m (5)")
    p.add_argument(
        "--transceiver-delay", type=_length, default=0.0, help="with --bus-length: transceiver delay in ns (0)"
    )
    p.add_argument(
        "--comparator-delay", type=_length, default=0.0, help="with --bus-length: comparator delay in ns (0)"
    )
    p.add_argument(
        "--data-bitrate",
        type=_count,
        help="instead: CAN FD frames with BRS at this data bit rate, the transmitter's own bit check with "
        "--loop-delay, without and with transmitter delay compensation",
    )
    p.add_argument("--data-sample-point", type=parse_sample_point, help="CAN FD data-phase sample point (CiA default)")
    p.add_argument("--data-sjw", type=_count, help="CAN FD data-phase SJW in tq (the kernel's default)")
    p.add_argument("--loop-delay", type=_length, help="with --data-bitrate: the transmitter's TX-to-RX delay in ns (0)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=_run)
