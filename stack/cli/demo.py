"""`canstack demo` and `canstack frame`: the engine's own subcommands."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from stack.bus.sim import SimBus
from stack.cli import CliError, format_id, parse_bitrate, parse_data_bitrate, parse_int, plural, seconds_type
from stack.cli.runs import (
    MAX_SIM_SECONDS,
    check_output,
    check_plot_output,
    check_trace_output,
    trace_note,
    writing,
)
from stack.io.progress import run_sliced
from stack.wire.coding import INTERMISSION_BITS, Field
from stack.wire.fd import worst_case_bits
from stack.wire.frame import Frame

__all__ = ["register", "build_demo", "build_fault_demo", "format_summary", "summary_json", "write_frames_vcd"]

MS = 1_000_000


def build_demo(bus: SimBus) -> None:
    """The demo network: five ECUs with periodic traffic at different priorities, an extended
    (J1939-style) message, and a remote request answered automatically by a mailbox."""
    brake = bus.node("brake")
    engine = bus.node("engine")
    body = bus.node("body")
    gateway = bus.node("gateway")
    tester = bus.node(
        "tester",
        filters=[
            {"can_id": 0x0C1, "can_mask": 0x7FF, "extended": False},
            {"can_id": 0x700, "can_mask": 0x7FF, "extended": False},
        ],
    )
    # every ECU reads its receive FIFO from an interrupt-like callback, as firmware would
    for ecu in (brake, engine, body, gateway, tester):
        ecu.subscribe(lambda ev: None)
    counter = {"n": 0}

    def wheel_speeds() -> Frame:
        counter["n"] = (counter["n"] + 1) & 0xFF
        return Frame(0x0A0, bytes([0x12, 0x34, 0x56, counter["n"]]))

    brake.send_periodic(wheel_speeds, 5 * MS)
    engine.send_periodic(Frame(0x0C1, bytes.fromhex("4001087500000000")), 10 * MS, offset=1 * MS)
    engine.send_periodic(Frame(0x0C2, bytes.fromhex("0011223344556677")), 10 * MS, offset=1 * MS)
    body.send_periodic(Frame(0x3E8, bytes.fromhex("0102")), 100 * MS)
    body.send_periodic(Frame(0x3E9, bytes.fromhex("00")), 20 * MS, offset=3 * MS)
    gateway.send_periodic(Frame(0x18FEF100, bytes.fromhex("FFFF3C00FFFFFFFF"), extended=True), 20 * MS)
    # a burst every 50 ms: six frames queued at once compete with everyone's periodic traffic
    for i in range(6):
        gateway.send_periodic(Frame(0x500 + i, bytes(8)), 50 * MS, offset=1 * MS)
    body.set_remote_reply(Frame(0x700, bytes.fromhex("5A5A")))
    tester.send_periodic(Frame(0x700, remote=True, dlc=2), 50 * MS, offset=7 * MS)


def build_fault_demo(bus: SimBus, sample_every: int | None = MS // 2) -> list[tuple[int, dict[str, tuple[int, int]]]]:
    """The fault demo: three ECUs; from 100 to 250 ms ecu2's receiver picks up noise (local bit errors)
    and it goes error passive; from 400 ms its transmitter is disconnected (stuck recessive) and
    it goes bus off; the fault clears at 410 ms and it recovers (rule 12). Returns the TEC/REC
    samples the plot is drawn from, one every ``sample_every`` ns (None: no samples; a long run
    takes them further apart so that they do not grow without bound)."""
    from stack.bus.faults import FaultInjector

    ecus = [bus.node(n) for n in ("ecu1", "ecu2", "ecu3")]
    for e in ecus:
        e.subscribe(lambda ev: None)
    ecus[0].send_periodic(Frame(0x100, bytes(8)), 2 * MS)
    ecus[1].send_periodic(Frame(0x200, bytes.fromhex("1122334455667788")), 5 * MS, offset=MS // 2)
    ecus[2].send_periodic(Frame(0x300, bytes(4)), 3 * MS, offset=MS)
    fi = FaultInjector(bus)
    bus.call_at(100 * MS, lambda: fi.bit_errors(3e-3, nodes=["ecu2"]))
    bus.call_at(250 * MS, lambda: fi.bit_errors(0.0, nodes=["ecu2"]))
    fi.stuck("ecu2", "recessive", start=400 * MS, end=410 * MS)
    samples: list[tuple[int, dict[str, tuple[int, int]]]] = []

    if sample_every is not None:
        every = sample_every

        def sample() -> None:
            samples.append((bus.now(), {e.name: (e.tec, e.rec) for e in ecus}))
            bus.call_later(every, sample)

        bus.call_at(0, sample)
    return samples


def plot_counters(samples: list[tuple[int, dict[str, tuple[int, int]]]], path: str) -> None:
    """TEC and REC of each node over time, with the passive (128) and bus-off (256) levels."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise CliError("--plot needs matplotlib: pip install 'canstack[plot]'") from None
    fig, (ax1, ax2) = plt.subplots(2, 1, sharex=True, figsize=(9, 6))
    t = [s[0] / 1e6 for s in samples]
    for name in samples[0][1]:
        ax1.plot(t, [s[1][name][0] for s in samples], label=name)
        ax2.plot(t, [s[1][name][1] for s in samples], label=name)
    ax1.axhline(256, color="red", lw=0.8, ls="--", label="bus off (256)")
    for ax, what in ((ax1, "TEC"), (ax2, "REC")):
        ax.axhline(96, color="gold", lw=0.8, ls="--", label="error warning (96)")
        ax.axhline(128, color="orange", lw=0.8, ls="--", label="error passive (128)")
        ax.set_ylabel(what)
        ax.legend(loc="upper right", fontsize=8)
    ax2.set_xlabel("time (ms)")
    fig.suptitle("canstack fault demo: fault confinement counters")
    fig.tight_layout()
    # without a suffix matplotlib would write PATH.png: write the file that was named
    fig.savefig(path, dpi=100, format=None if Path(path).suffix else "png")
    plt.close(fig)


def summary_json(bus: SimBus) -> dict[str, Any]:
    """`SimBus.summary`: one entry per frame kind on the wire (remote and data frames of one
    identifier apart, each with its integer ``id``)."""
    return bus.summary()


def format_summary(bus: SimBus) -> str:
    """A readable summary: bus load, per-ID latency and arbitration losses (one row per frame
    kind on the wire: the rows add up to the frame count), node counters."""
    s = bus.summary()
    lines = [
        f"bus {bus.name}: {bus.bitrate // 1000} kbit/s, {s['elapsed_s']:.3f} s simulated, "
        f"{s['frames']} frames, {s['error_frames']} error frames, bus load {100 * s['bus_load']:.1f} %",
        "",
        f"{'ID':>14}  {'frames':>6}  {'latency min/mean/max (us)':>27}  {'arb. losses':>11}",
    ]
    for label, st in s["ids"].items():
        lat = f"{st['latency_min_us']:.0f} / {st['latency_mean_us']:.0f} / {st['latency_max_us']:.0f}"
        lines.append(f"{label:>14}  {st['count']:>6}  {lat:>27}  {st['arbitration_losses']:>11}")
    lines += ["", f"{'node':<10} {'tx':>6} {'rx':>6} {'arb.lost':>8} {'retx':>5} {'overrun':>7} {'TEC':>4} {'REC':>4}"]
    for name, c in s["nodes"].items():
        lines.append(
            f"{name:<10} {c['tx_frames']:>6} {c['rx_frames']:>6} {c['arbitration_lost']:>8} "
            f"{c['retransmissions']:>5} {c['rx_overruns']:>7} {c['txerr']:>4} {c['rxerr']:>4}"
        )
    return "\n".join(lines)


def _demo(args: argparse.Namespace) -> int:
    if args.interface:
        if args.faults or args.plot:
            raise CliError("--faults needs the simulated bus (fault injection is a simulation feature)")
        for opt, val in (("--trace", args.trace), ("--vcd", args.vcd), ("--json", args.json or None)):
            if val is not None:
                raise CliError(
                    f"{opt} needs the simulated bus (the trace is the simulation's); "
                    "on a python-can bus record with python -m can.logger"
                )

        kw = {} if args.bitrate is None else {"bitrate": args.bitrate}
        print(run_demo_on_bus(args.interface, args.channel or "vcan0", args.duration, **kw))
        return 0
    if args.plot and not args.faults:
        raise CliError("--plot draws the fault demo's counters: use it with --faults")
    # every output is checked before the run: a long simulation must not end in an error
    if args.trace is not None:
        check_trace_output(args.trace)
    if args.vcd is not None:
        check_output(args.vcd, "--vcd")
    if args.plot is not None:
        check_plot_output(args.plot)
    until = int(args.duration * 1e9)
    # the records stream to the trace file as they are made (memory stays flat however long the
    # run); the waveform keeps the frames it draws; the summary comes from the bus's streaming
    # statistics
    bus = SimBus(args.bitrate or 500_000, seed=args.seed, record=bool(args.trace or args.vcd), keep=False)
    samples: list[tuple[int, dict[str, tuple[int, int]]]] = []
    changes: list[Any] = []
    if args.faults:
        from stack.controller.events import ErrorStateChanged

        # the plot's samples: every 0.5 ms, further apart on a long run (at most ~20,000)
        every = max(MS // 2, until // 20_000) if args.plot else None
        samples = build_fault_demo(bus, sample_every=every)
        for node in bus.nodes:
            node.listen(ErrorStateChanged, changes.append)
    else:
        build_demo(bus)
    frames: list[tuple[int, Frame]] = []
    if args.vcd:
        bus.on_trace(lambda rec: frames.append((rec.start, rec.frame)) if rec.kind == "frame" else None)
    writer = None
    try:
        if args.trace:
            from stack.io.tracefile import TraceWriter

            writer = writing(args.trace, "--trace", lambda: TraceWriter(args.trace, channel=bus.name))
            bus.on_trace(writer.write)
        complete = run_sliced(bus, until, progress=args.progress, desc="demo")
    finally:
        if writer is not None:
            writer.close()
    # every file before anything is printed (output piped into head must not cost one of them);
    # one that cannot be written is reported after the summary, which is printed all the same
    notes = []
    failure: CliError | None = None
    try:
        if args.plot:
            writing(args.plot, "--plot", lambda: plot_counters(samples, args.plot))
            notes.append(f"\nplot: TEC/REC over time written to {args.plot}")
        if writer is not None:
            if writer.error is not None:
                raise CliError(f"--trace {args.trace!r}: cannot write: {writer.error.strerror or writer.error}")
            notes.append(
                f"\ntrace: {plural(writer.written, 'record')} written to {args.trace}"
                f"{trace_note(args.trace, writer.left_out)}"
            )
        if args.vcd:
            n = writing(args.vcd, "--vcd", lambda: write_frames_vcd(frames, bus.bitrate, args.vcd, bus.name))
            notes.append(f"waveform: CAN_RX of {plural(n, 'frame')} written to {args.vcd} (GTKWave, PulseView)")
    except CliError as exc:
        failure = exc
    if args.json:
        print(json.dumps(summary_json(bus), indent=2))
    else:
        if not complete:
            print(f"interrupted at {bus.now() / 1e9:.3f} s of {args.duration:g} s: the summary so far\n")
        if args.faults:
            print("state changes (fault confinement):")
            for ev in changes:
                print(
                    f"  {ev.time / 1e6:9.3f} ms  {ev.node:<5} {ev.old:>13} -> {ev.new:<13} TEC {ev.tec:3d} REC {ev.rec:3d}"
                )
            print()
        print(format_summary(bus))
        for line in notes:
            print(line)
    if failure is not None:
        raise failure
    if not complete:
        print(f"canstack: interrupted at {bus.now() / 1e9:.3f} s of {args.duration:g} s", file=sys.stderr)
        return 130
    return 0


def write_trace_vcd(bus: SimBus, path: str, samples_per_bit: int = 16) -> int:
    """Render the frames of a simulated trace, at their SOF times, as a CAN_RX waveform in VCD
    (`write_frames_vcd`; error attempts are left out: the waveform shows the frames that went
    through)."""
    frames = [(r.start, r.frame) for r in bus.trace if r.kind == "frame"]
    return write_frames_vcd(frames, bus.bitrate, path, bus.name, samples_per_bit)


def write_frames_vcd(
    frames: list[tuple[int, Frame]], bitrate: int, path: str, name: str = "bus0", samples_per_bit: int = 16
) -> int:
    """Render frames (SOF time in ns, frame) as a CAN_RX waveform in VCD. The waveform starts
    with 11 recessive bits of bus idle, so its time 0 is 11 bit times before the simulation's:
    a receiver needs them to join the bus. Returns how many frames it holds."""
    from stack.phy.waveform import IDLE_BITS, render_edges, write_vcd

    lead = IDLE_BITS / bitrate
    runs, _, _ = render_edges(
        [f for _, f in frames], bitrate, bitrate * samples_per_bit, times=[lead + t / 1e9 for t, _ in frames]
    )
    write_vcd(path, runs, bitrate * samples_per_bit, comment=f"canstack demo, bus {name}")
    return len(frames)


def _frame_from_args(args: argparse.Namespace) -> Frame:
    try:
        data = bytes.fromhex(args.data.replace(" ", "")) if args.data else b""
    except ValueError:
        raise CliError(f"--data {args.data!r} is not hex bytes (e.g. 4001087500000000)") from None
    if not args.fd:
        for flag in ("brs", "esi"):
            if getattr(args, flag):
                raise CliError(f"--{flag} needs --fd: {flag.upper()} exists only in CAN FD frames")
        if len(data) > 8:
            raise CliError(f"--data of {len(data)} bytes: a CAN 2.0 frame carries at most 8 (up to 64 with --fd)")
    elif args.remote:
        raise CliError("--remote with --fd: CAN FD has no remote frames (its RRS bit is always dominant)")
    if args.data_bitrate is not None:
        if args.bitrate is None:
            raise CliError("--data-bitrate needs --bitrate (the nominal bit rate)")
        if args.data_bitrate < args.bitrate:
            raise CliError(
                f"--data-bitrate {args.data_bitrate} below --bitrate {args.bitrate}: "
                "the data phase is at least as fast as the arbitration phase"
            )
    frame = Frame(
        args.id, data, extended=args.extended, remote=args.remote, dlc=args.dlc, fd=args.fd, brs=args.brs, esi=args.esi
    )
    if frame.brs and args.bitrate is not None and args.data_bitrate is None:
        raise CliError("--brs with --bitrate needs --data-bitrate: the bits after BRS go at the data bit rate")
    return frame


def _frame(args: argparse.Namespace) -> int:
    frame = _frame_from_args(args)
    fb = frame.bits
    duration = fb.duration_ns(args.bitrate, args.data_bitrate) if args.bitrate is not None else None
    if args.json:
        out: dict[str, Any] = {"bits": fb.bits, "crc": fb.crc, "length": fb.length, "stuff_bits": fb.stuff_count}
        if frame.fd:
            out.update(
                stuff_count=fb.stuff_count % 8,
                stuff_count_bits=f"{fb.stuff_count_bits:04b}",
                fixed_stuff_bits=len(fb.fixed_stuff_positions),
                crc_bits=fb.crc_width,
                nominal_bits=fb.nominal_bits,
                data_bits=fb.data_bits,
            )
        if duration is not None:
            out["duration_ns"] = duration
        print(json.dumps(out))
        return 0
    stuff = set(fb.stuff_positions)
    fixed = set(fb.fixed_stuff_positions)
    worst = worst_case_bits(frame.length, frame.extended, fd=frame.fd, brs=frame.brs).total
    print(f"frame       {frame!r}")
    if frame.fd:
        print(f"CRC         0x{fb.crc:0{(fb.crc_width + 3) // 4}X} (CRC-{fb.crc_width})")
        print(
            f"length      {fb.length} bits SOF..EOF ({fb.stuff_count} stuff bits, {len(fixed)} fixed stuff bits), "
            f"+{INTERMISSION_BITS} intermission; worst case {worst}"
        )
        print(
            f"stuff count {fb.stuff_count % 8} ({fb.stuff_count} mod 8), sent as {fb.stuff_count_bits:04b} (Gray code, parity)"
        )
        if frame.brs:
            print(
                f"bit rates   {fb.nominal_bits} bits at the nominal rate, {fb.data_bits} at the data rate "
                "(after BRS up to the CRC delimiter)"
            )
        else:
            print(f"bit rates   all {fb.length} bits at the nominal rate (no BRS)")
    else:
        print(f"CRC         0x{fb.crc:04X}")
        print(
            f"length      {fb.length} bits SOF..EOF ({fb.stuff_count} stuff bits), +{INTERMISSION_BITS} intermission; "
            f"worst case {worst}"
        )
    if duration is not None:
        rates = f"{args.bitrate} / {args.data_bitrate} bit/s" if frame.brs else f"{args.bitrate} bit/s"
        print(f"duration    {duration / 1000:.3f} us SOF..EOF at {rates}")
    print("bits        (stuff bits in [ ], fixed stuff bits in { })" if frame.fd else "bits        (stuff bits in [ ])")
    for fld, positions in fb.fields.items():
        if not positions or fld is Field.FIXED_STUFF:
            continue
        out_bits = []
        for p in range(positions[0], positions[-1] + 2):
            if p in stuff:
                out_bits.append(f"[{fb.bits[p]}]")
            elif p in fixed:
                out_bits.append(f"{{{fb.bits[p]}}}")
            elif p in positions:
                out_bits.append(fb.bits[p])
        print(f"  {fld.value:<{14 if frame.fd else 10}}{''.join(out_bits)}")
    print(f"stuffed     {fb.bits}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add `demo` and `frame`."""
    p = sub.add_parser(
        "demo",
        help="run the demo network on the simulated bus and print a summary",
        description="Simulate five ECUs (periodic traffic at several priorities, a J1939-style extended "
        "message, a burst every 50 ms and a remote request answered by a mailbox) and print the bus load, "
        "per-identifier latency and arbitration losses, and each node's counters. With --faults, three "
        "ECUs instead, one of which goes error passive, bus off, and recovers. Ctrl-C stops the run and "
        "prints the summary so far.",
    )
    p.add_argument(
        "--duration",
        type=seconds_type(MAX_SIM_SECONDS),
        default=1.0,
        metavar="S",
        help=f"simulated seconds, at most {MAX_SIM_SECONDS:g} (default 1)",
    )
    p.add_argument(
        "--bitrate",
        type=parse_bitrate,
        default=None,
        help="bit/s (default 500000; on --interface, passed to the bus when given)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the simulated bus (the same seed gives the same trace)")
    p.add_argument(
        "--trace",
        metavar="FILE",
        help="write the trace (.asc, .blf, .log, .csv, .trc, .mf4; "
        ".mf4 needs the mf4 extra, .trc holds no remote or error frames)",
    )
    p.add_argument("--vcd", metavar="FILE", help="write the bus as a CAN_RX waveform (VCD, 16 samples a bit)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON (identifiers as integers)")
    p.add_argument(
        "--faults", action="store_true", help="the fault demo: a node goes error passive, bus off, and recovers"
    )
    p.add_argument("--plot", metavar="PNG", help="with --faults: plot TEC/REC over time (needs the plot extra)")
    p.add_argument(
        "--progress",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="progress bar on stderr (default: on a terminal, for runs over 2 s)",
    )
    p.add_argument(
        "--interface",
        help="run the same nodes on a python-can bus instead (e.g. socketcan, virtual, canstack); wall-clock time",
    )
    p.add_argument("--channel", help="the python-can channel (e.g. vcan0)")
    p.set_defaults(func=_demo, duration_given=False)

    p = sub.add_parser(
        "frame",
        help="show a frame's bits on the wire: stuffing, CRC, length",
        description="Build a CAN 2.0 or CAN FD frame and show its bit stream SOF..EOF field by field with the "
        "stuff bits marked, its CRC (CRC-15; FD: CRC-17/21 and the stuff count, ISO 11898-1:2015), its exact "
        "stuffed length and the worst case for its data length; FD frames also the bits at the data bit rate, "
        "and with --bitrate (and --data-bitrate) the frame's duration.",
    )
    p.add_argument("--id", type=parse_int, required=True, help="identifier (0x hex or decimal)")
    p.add_argument(
        "--data", default="", help="data bytes as hex, e.g. 4001087500000000 (spaces allowed); FD: 0..8, 12..64"
    )
    p.add_argument("--extended", action="store_true", help="29-bit identifier")
    p.add_argument("--remote", action="store_true", help="remote frame (give --dlc; not with --fd)")
    p.add_argument("--dlc", type=parse_int, default=None, help="DLC 0..15 (default: data length)")
    p.add_argument("--fd", action="store_true", help="a CAN FD frame (ISO 11898-1:2015)")
    p.add_argument("--brs", action="store_true", help="FD: bit rate switch (the data phase at --data-bitrate)")
    p.add_argument("--esi", action="store_true", help="FD: error state indicator recessive (transmitter error passive)")
    p.add_argument("--bitrate", type=parse_bitrate, default=None, help="nominal bit/s: print the frame's duration")
    p.add_argument("--data-bitrate", type=parse_data_bitrate, default=None, help="FD with --brs: the data-phase bit/s")
    p.add_argument(
        "--json",
        action="store_true",
        help="print bits, crc, length and stuff bits as JSON (FD: also stuff count, fixed stuff bits, CRC bits, "
        "bits at the nominal and data rates; duration_ns with --bitrate)",
    )
    p.set_defaults(func=_frame)


def run_demo_on_bus(interface: str, channel: str, duration_s: float, **kwargs: Any) -> str:
    """Run the demo network (`stack.cli.demo.build_demo`) on a python-can bus for
    ``duration_s`` wall-clock seconds and return a summary: what a monitor connection saw per
    identifier (count, mean period and p99 deviation from it, from the bus's receive timestamps) and each node's counters.

    ``kwargs`` go to every ``can.Bus``; ``pace_bitrate`` (for buses without wire time such as
    ``virtual``) goes to the driver.
    """
    import statistics
    import time

    import can

    from stack.io.driver import PyCanDriver

    if duration_s <= 0:
        raise ValueError(f"duration {duration_s}: must be > 0 seconds")
    pace = kwargs.pop("pace_bitrate", None)
    try:
        monitor = can.Bus(interface=interface, channel=channel, **kwargs)
    except (can.CanError, OSError, NotImplementedError) as exc:
        raise ValueError(f"cannot open {interface} channel {channel!r}: {exc}") from None
    drv = PyCanDriver(interface=interface, channel=channel, pace_bitrate=pace, **kwargs)
    seen: dict[tuple[int, bool, bool], list[float]] = {}
    try:
        # the driver runs while the nodes are built (which takes a while on a loaded machine),
        # and the window starts once they are: a frame sent before it is not counted, so a slow
        # start neither adds a burst of frames due during the build nor shortens the window
        drv.start()
        with drv.lock:
            build_demo(drv)  # type: ignore[arg-type]  # the driver offers SimBus's node() and clock
        start = time.time()
        end = time.monotonic() + duration_s
        while (left := end - time.monotonic()) > 0:
            msg = monitor.recv(min(left, 0.1))
            if msg is not None and msg.timestamp >= start:
                seen.setdefault((msg.arbitration_id, msg.is_extended_id, msg.is_remote_frame), []).append(msg.timestamp)
        drv.stop()
        counters = {n.name: n.counters() for n in drv.nodes}
    finally:
        drv.close()
        monitor.shutdown()
    total = sum(len(v) for v in seen.values())
    lines = [
        f"{interface} {channel}: {duration_s:.2f} s wall clock, {total} frames seen by a monitor"
        + (f", paced at {pace} bit/s" if pace else ""),
        "",
        f"{'ID':>10}  {'frames':>6}  {'mean period (ms)':>16}  {'p99 deviation (ms)':>18}",
    ]
    for (cid, ext, rtr), ts in sorted(seen.items()):
        ident = format_id(cid, ext, rtr)
        gaps = [b - a for a, b in zip(ts, ts[1:])]
        if gaps:
            mean = statistics.fmean(gaps)
            devs = sorted(abs(g - mean) for g in gaps)
            p99 = devs[min(len(devs) - 1, int(0.99 * len(devs)))]
            lines.append(f"{ident:>10}  {len(ts):>6}  {mean * 1e3:>16.2f}  {p99 * 1e3:>18.3f}")
        else:
            lines.append(f"{ident:>10}  {len(ts):>6}  {'-':>16}  {'-':>18}")
    lines += ["", f"{'node':<10} {'tx':>6} {'rx':>6} {'retx':>5} {'failed':>6}"]
    for name, c in counters.items():
        lines.append(
            f"{name:<10} {c['tx_frames']:>6} {c['rx_frames']:>6} {c['retransmissions']:>5} {c['tx_failed']:>6}"
        )
    if drv.errors:
        lines += ["", f"{len(drv.errors)} callback error(s); first: {drv.errors[0]}"]
    return "\n".join(lines)
