"""`canstack bittiming`: the bit-timing solver on the command line (`stack.phy.bittiming`)."""

from __future__ import annotations

import argparse
import json
import math
from typing import Any

from stack.cli import SAMPLE_POINT_HELP, CliError, parse_sample_point
from stack.phy.bittiming import (
    CONTROLLERS,
    BusDelays,
    ControllerLimits,
    all_timings,
    controller_limits,
    format_hz,
    format_solution,
    parse_limits,
    solve,
)
from stack.phy.bittiming_fd import format_fd_solution, solve_fd

__all__ = ["register", "add_timing_arguments", "limits_from_args", "clock_line"]

#: The controller when none is named: the SJA1000 for classical CAN (the kernel's reference
#: controller), Bosch's M_CAN for CAN FD (the IP most FD microcontrollers carry).
DEFAULT_CONTROLLER, DEFAULT_FD_CONTROLLER = "sja1000", "m_can"


def _positive_int(text: str) -> int:
    try:
        v = int(float(text)) if "e" in text.lower() else int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if v <= 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be > 0")
    return v


def _number(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return v


def add_timing_arguments(p: argparse.ArgumentParser) -> None:
    """The options shared by `bittiming` and `sync`: clock, bitrate, sample point, controller, sjw."""
    p.add_argument("--clock", type=_positive_int, required=True, help="controller clock in Hz")
    p.add_argument("--bitrate", type=_positive_int, required=True, help="bitrate in bit/s")
    p.add_argument("--sample-point", type=parse_sample_point, help=SAMPLE_POINT_HELP + "; default: CiA 75/80/87.5 %%")
    p.add_argument(
        "--controller",
        help=f"register limits and layout: {', '.join(CONTROLLERS)} (default {DEFAULT_CONTROLLER}; "
        f"with --data-bitrate {DEFAULT_FD_CONTROLLER})",
    )
    p.add_argument("--limits", help="custom limits 'tseg1=1..16,tseg2=1..8,sjw=4,brp=1..64[,brp_inc=1]'")
    p.add_argument("--sjw", type=_positive_int, help="synchronisation jump width in tq (default: kernel's)")


def limits_from_args(args: argparse.Namespace) -> ControllerLimits:
    """--limits if given, else the --controller's limits (default: the SJA1000, or M_CAN when
    the command has --data-bitrate)."""
    if args.limits:
        return parse_limits(args.limits)
    fd = getattr(args, "data_bitrate", None) is not None
    return controller_limits(args.controller or (DEFAULT_FD_CONTROLLER if fd else DEFAULT_CONTROLLER))


def clock_line(lim: ControllerLimits, clock: int) -> str | None:
    """What ``--clock`` means for this controller: the CAN clock Linux reports (its
    clock.freq), and the crystal that implies (twice it on the SJA1000 and the MCP2515)."""
    if lim.name == "custom":
        return None
    if lim.crystal_divider == 1:
        return f"clock: {format_hz(clock)} is the CAN clock Linux reports for the {lim.name}, its input clock itself"
    crystal = clock * lim.crystal_divider
    return (
        f"clock: {format_hz(clock)} is the CAN clock Linux reports for the {lim.name}: "
        f"1/{lim.crystal_divider} of a {format_hz(crystal)} crystal"
    )


def _run_fd(args: argparse.Namespace, lim: ControllerLimits, delays: BusDelays) -> int:
    if args.all:
        raise CliError("--all lists classical timings; it does not combine with --data-bitrate")
    sol = solve_fd(
        args.clock,
        args.bitrate,
        args.data_bitrate,
        sample_point=args.sample_point,
        data_sample_point=args.data_sample_point,
        limits=lim,
        sjw=args.sjw,
        data_sjw=args.data_sjw,
        delays=delays,
        min_tolerance=args.tolerance,
        legacy=args.legacy,
        same_prescaler=args.same_prescaler,
    )
    if args.json:
        d = sol.as_dict()
        d["crystal_hz"] = args.clock * lim.crystal_divider
        print(json.dumps(d, indent=2))
        return 0
    print(f"{args.bitrate} bit/s, data {args.data_bitrate} bit/s, with a {format_hz(args.clock)} clock on {lim.name}:")
    line = clock_line(lim, args.clock)
    if line:
        print(line)
    print(format_fd_solution(sol))
    return 0


def _run(args: argparse.Namespace) -> int:
    lim = limits_from_args(args)
    delays = BusDelays(args.bus_length, args.cable_delay, args.transceiver_delay, args.comparator_delay)
    if args.data_bitrate is not None:
        return _run_fd(args, lim, delays)
    for option in ("data_sample_point", "data_sjw"):
        if getattr(args, option) is not None:
            raise CliError(f"--{option.replace('_', '-')} needs --data-bitrate (it sets the CAN FD data phase)")
    kw = dict(
        sample_point=args.sample_point,
        limits=lim,
        sjw=args.sjw,
        delays=delays,
        min_tolerance=args.tolerance,
        legacy=args.legacy,
    )
    if args.all:
        sols = all_timings(args.clock, args.bitrate, **kw)  # type: ignore[arg-type]
        if args.json:
            print(json.dumps([s.as_dict() for s in sols], indent=2))
            return 0
        print(
            f"{len(sols)} valid timings for {args.bitrate} bit/s, {format_hz(args.clock)} clock, {lim.name} (best first)"
        )
        print("  brp  tq[ns]  nbt prop ps1 ps2 sjw  sample%   bitrate  err%    df%  maxlen[m]")
        for s in sols:
            print(
                f"{s.brp:5d} {s.tq_ns:7.1f} {s.nbt:4d} {s.prop_seg:4d} {s.phase_seg1:3d} {s.phase_seg2:3d} {s.sjw:3d}"
                f" {s.sample_point:7.2f} {s.bitrate:9.0f} {s.bitrate_error:5.2f} {s.oscillator_tolerance:6.3f} {s.max_bus_length:9.1f}"
            )
        return 0
    sol = solve(args.clock, args.bitrate, **kw)  # type: ignore[arg-type]
    if args.json:
        d = sol.as_dict()
        if lim.name != "custom":
            d["crystal_hz"] = args.clock * lim.crystal_divider
        print(json.dumps(d, indent=2))
    else:
        print(f"{args.bitrate} bit/s with a {format_hz(args.clock)} clock on {lim.name}:")
        line = clock_line(lim, args.clock)
        if line:
            print(line)
        print(format_solution(sol))
    return 0


def register(subparsers: Any) -> None:
    """Add the `bittiming` subcommand."""
    p = subparsers.add_parser(
        "bittiming",
        help="compute CAN (FD) bit timing (BRP/TSEG1/TSEG2/SJW) and controller registers",
        description="Pick BRP/TSEG1/TSEG2/SJW as the Linux kernel does, check the bit timing rules and "
        "print the controller's register values; with --data-bitrate also the CAN FD data phase and "
        "transmitter delay compensation.",
    )
    add_timing_arguments(p)
    p.add_argument("--data-bitrate", type=_positive_int, help="CAN FD data-phase bit rate in bit/s")
    p.add_argument(
        "--data-sample-point",
        type=parse_sample_point,
        help="data-phase sample point (as --sample-point; default CiA: 75 %% above 800 kbit/s)",
    )
    p.add_argument("--data-sjw", type=_positive_int, help="data-phase SJW in tq (default: the kernel's)")
    p.add_argument(
        "--same-prescaler",
        action="store_true",
        help="CAN FD: the smallest prescaler both phases can share (CiA 601-1), when the kernel's differ",
    )
    p.add_argument("--bus-length", type=_number, default=0.0, help="bus length in m (Prop_Seg must cover it)")
    p.add_argument("--cable-delay", type=_number, default=5.0, help="cable propagation delay in ns/m (5)")
    p.add_argument("--transceiver-delay", type=_number, default=0.0, help="transceiver delay in ns, one way (0)")
    p.add_argument("--comparator-delay", type=_number, default=0.0, help="input comparator delay in ns (0)")
    p.add_argument("--tolerance", type=_number, help="required oscillator tolerance in percent")
    p.add_argument("--all", action="store_true", help="list every valid timing, ranked")
    p.add_argument(
        "--legacy",
        action="store_true",
        help="on a tie keep the larger prescaler, as Linux < 5.19 and can-utils until 2022 did",
    )
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=_run)
