"""`canstack restbus`: rest-bus simulation of a DBC, on the simulated bus or a python-can bus."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from typing import Any

from stack.cli import CliError, format_id, parse_bitrate, parse_data_bitrate, plural
from stack.cli.runs import MAX_SIM_SECONDS, check_trace_output, trace_note, trc_dropped, writing
from stack.io.progress import run_sliced

from .diag.ecu import DEFAULT_VIN
from .errors import FdNotCarriedError, load_database
from .restbus import BusRecord, RestBus, json_value
from .stimulus import Change, check_changes, parse_assignment, read_stimulus, schedule
from .validate import validate_database

__all__ = ["register", "restbus_command", "positive_ms", "DEFAULT_DATA_BITRATE"]

#: The data bit rate of the simulated bus with ``--fd`` and no ``--data-bitrate`` (the rate ISO
#: 11898-2:2016 transceivers are first specified for, and python-can's canstack interface's default).
DEFAULT_DATA_BITRATE = 2_000_000


def register(subparsers: Any) -> None:
    """Add the ``restbus`` subcommand."""
    p = subparsers.add_parser(
        "restbus",
        help="simulate every node of a DBC except the device under test",
        description="Simulate every node of a DBC except --dut with initial values and the DBC's "
        "interaction layer; print what the DUT sends, decoded (--json: every frame).",
    )
    p.add_argument("dbc", metavar="DBC", help="database file (DBC, or anything cantools loads)")
    p.add_argument("--dut", metavar="NODE", help="device under test: not simulated (default: none, simulate all)")
    p.add_argument(
        "--duration",
        type=float,
        default=10.0,
        metavar="S",
        help=f"seconds to run (default 10; the simulated bus at most {MAX_SIM_SECONDS:g}; Ctrl-C stops "
        "early and prints the summary so far)",
    )
    p.add_argument("--bus", choices=["sim"], default=None, help="the built-in simulated bus (default)")
    p.add_argument("--interface", metavar="NAME", help="python-can interface (socketcan, canstack, ...)")
    p.add_argument("--channel", metavar="CH", help="python-can channel (vcan0, bus0, ...)")
    p.add_argument(
        "--bitrate",
        type=parse_bitrate,
        default=None,
        help="bit/s: the simulated bus's (default 500000), or passed to every python-can "
        "connection (default: the interface's own)",
    )
    p.add_argument(
        "--data-bitrate",
        type=parse_data_bitrate,
        default=None,
        metavar="D",
        help="a CAN FD bus: the data phase's bit/s (CAN FD messages with bit rate switching); on a python-can bus "
        "passed with fd=True",
    )
    p.add_argument(
        "--fd",
        action="store_true",
        help=f"a CAN FD bus: python-can's fd=True (the interface's data bit rate); the simulated bus at "
        f"--data-bitrate, default {DEFAULT_DATA_BITRATE}",
    )
    p.add_argument("--seed", type=int, default=0, help="simulated bus seed")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="MESSAGE.SIGNAL=VALUE",
        help="write a signal of a simulated node at the start (physical value in the DBC's unit, or a choice "
        "name); repeatable",
    )
    p.add_argument(
        "--stimulus",
        metavar="FILE",
        help="timed signal changes: CSV with the header time,message,signal,value (time in s), or the same as "
        "TOML ([[changes]] tables)",
    )
    p.add_argument(
        "--uds",
        action="append",
        default=[],
        type=_uds_spec,
        metavar="NODE:REQ_ID:RESP_ID",
        help="a simulated node answers UDS (ISO 14229) over ISO-TP on these identifiers (e.g. ECM:0x7E0:0x7E8): "
        "session, VIN (0xF190), one DID per signal it sends, DTCs, reset; repeatable",
    )
    p.add_argument(
        "--vin",
        default=DEFAULT_VIN,
        type=_vin,
        help=f"the VIN the --uds nodes give for DID 0xF190 (default {DEFAULT_VIN})",
    )
    p.add_argument(
        "--default-cycle",
        type=positive_ms,
        metavar="MS",
        help="send every message the DBC gives no send type or cycle time every MS ms, and the messages no node "
        "sends (Vector__XXX) from a simulated node Vector__XXX",
    )
    p.add_argument(
        "--trace",
        metavar="FILE",
        help="write the bus trace (.asc, .blf, .log, .csv, .trc, .mf4; "
        ".mf4 needs the mf4 extra, .trc holds no remote or error frames)",
    )
    p.add_argument(
        "--json", action="store_true", help="one JSON object per frame on the bus, per line (id as an integer)"
    )
    p.add_argument(
        "--progress",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="progress bar on stderr for the simulated bus (default: on a terminal, for runs over 2 s)",
    )
    p.set_defaults(func=restbus_command)


def positive_ms(text: str) -> int:
    """A period in whole milliseconds > 0 (the DBC's GenMsgCycleTime unit)."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number of milliseconds") from None
    if not 0 < v <= 3_600_000:
        raise argparse.ArgumentTypeError(f"{v} ms: a period is 1 .. 3600000 ms")
    return v


def _uds_spec(text: str) -> tuple[str, int, int]:
    """NODE:REQ_ID:RESP_ID, the identifiers 11-bit (hexadecimal with 0x, or decimal)."""
    node, _, rest = text.partition(":")
    req, _, resp = rest.partition(":")
    ids = []
    for part in (req, resp):
        try:
            ids.append(int(part, 0))
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r}: give NODE:REQ_ID:RESP_ID, e.g. ECM:0x7E0:0x7E8") from None
    if not node or any(not 0 <= i <= 0x7FF for i in ids):
        raise argparse.ArgumentTypeError(f"{text!r}: give NODE:REQ_ID:RESP_ID with 11-bit identifiers (0..0x7FF)")
    if ids[0] == ids[1]:
        raise argparse.ArgumentTypeError(f"{text!r}: the request and response identifiers must differ")
    return node, ids[0], ids[1]


def _vin(text: str) -> str:
    """A VIN: 17 printable ASCII characters (ISO 3779)."""
    if len(text) != 17 or not text.isascii() or not text.isprintable():
        raise argparse.ArgumentTypeError(f"{text!r}: a VIN has 17 printable ASCII characters (ISO 3779)")
    return text


def _attach_uds(rb: RestBus, specs: list[tuple[str, int, int]], vin: str, info: Any) -> list[Any]:
    """A UDS server on each simulated node named; prints its identifiers and DIDs."""
    from .diag import attach_uds
    from .errors import UnknownNameError

    servers = []
    used: dict[int, str] = {}
    for node, req, resp in specs:
        ecu = rb.ecus.get(node)
        if ecu is None:
            raise UnknownNameError("simulated node", node, rb.ecus, f"(--uds; simulated: {', '.join(rb.ecus)})")
        for i in (req, resp):
            if i in used:
                raise CliError(
                    f"--uds {node}:{format_id(req, False)}:{format_id(resp, False)}: identifier {format_id(i, False)} is "
                    "already used by "
                    f"--uds {used[i]}"
                )
            used[i] = node
        clash = [m.name for m in rb.db.messages if m.frame_id in (req, resp) and not m.is_extended_frame]
        if clash:
            raise CliError(
                f"--uds {node}:{format_id(req, False)}:{format_id(resp, False)}: identifier of message {clash[0]} "
                "in the database"
            )
        srv = attach_uds(ecu, req, resp, vin=vin)
        servers.append(srv)
        print(
            f"UDS: {node} answers requests on {format_id(req, False)}, responds on {format_id(resp, False)}; DIDs:",
            file=info,
        )
        for d in sorted(srv.dids):
            print(f"  0x{d:04X}  {srv.dids[d].name}", file=info)
    return servers


class _Output:
    """Standard output that survives its reader going away (``| head -1``): the first
    BrokenPipeError points stdout at /dev/null, so that the run goes on and the files it
    was asked for (--trace) are still written."""

    def __init__(self) -> None:
        self.closed = False

    def write(self, text: str) -> None:
        if self.closed:
            return
        try:
            sys.stdout.write(text)
            sys.stdout.flush()
        except BrokenPipeError:
            self.closed = True
            _stdout_to_devnull()


def _stdout_to_devnull() -> None:
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, fd)
    os.close(devnull)


def _open_driver(
    interface: str, channel: str | None, bitrate: int | None, fd: bool = False, data_bitrate: int | None = None
) -> Any:
    """The python-can driver of `stack.io.driver` on ``interface``/``channel``: ``open_bus`` if the
    module offers it, else a `PyCanDriver` opening one ``can.Bus`` per node; ``bitrate`` (None:
    the interface's default) is passed to every connection, and for a CAN FD bus (``fd``, or a
    ``data_bitrate``) python-can's ``fd=True`` and the ``data_bitrate`` if given."""
    try:
        from stack.io import driver  # imported here: the simulated bus needs no python-can driver
    except ImportError:
        raise CliError("python-can driver not available yet (stack.io.driver)") from None
    kw: dict[str, Any] = {} if bitrate is None else {"bitrate": bitrate}
    if fd or data_bitrate is not None:
        kw["fd"] = True
    if data_bitrate is not None:
        kw["data_bitrate"] = data_bitrate
    open_bus = getattr(driver, "open_bus", None)
    if open_bus is not None:
        return open_bus(interface, channel, **kw)
    if not hasattr(driver, "PyCanDriver"):
        raise CliError("python-can driver not available yet (stack.io.driver.PyCanDriver)")
    import can

    try:  # open one connection now so a bad interface or channel is one clear line
        can.Bus(interface=interface, channel=channel, **kw).shutdown()
    except (can.CanError, OSError, NotImplementedError, ValueError, ImportError) as exc:
        raise CliError(f"cannot open {interface} channel {channel!r}: {' '.join(str(exc).split())}") from None
    return driver.PyCanDriver(interface=interface, channel=channel, **kw)


def _run_driver(bus: Any, duration: float) -> tuple[float, bool]:
    """Run the driver for ``duration`` s of wall clock, until it records an error (a lost
    connection: every receive fails from then on), or until Ctrl-C; returns the seconds it ran
    and whether it ran the whole duration (False after Ctrl-C, whose frames are kept)."""
    errors = getattr(bus, "errors", None)
    if errors is None or not (hasattr(bus, "start") and hasattr(bus, "stop")):
        bus.run(duration)
        return duration, True
    start = time.monotonic()
    end = start + duration
    complete = True
    bus.start()
    try:
        while not errors and (left := end - time.monotonic()) > 0:
            time.sleep(min(left, 0.05))
    except KeyboardInterrupt:
        complete = False
    finally:
        bus.stop()
    return time.monotonic() - start, complete


def _driver_error(bus: Any, interface: str, channel: str | None, ran: float) -> str | None:
    """One line naming the first error the driver recorded (None if none)."""
    errors = list(getattr(bus, "errors", None) or ())
    if not errors:
        return None
    more = f" ({len(errors)} errors)" if len(errors) > 1 else ""
    first = " ".join(str(errors[0]).split())
    return f"the python-can bus failed after {ran:.2f} s ({interface} channel {channel!r}): {first}{more}"


def _line(rec: BusRecord) -> str:
    ident = format_id(rec.frame.can_id, rec.frame.extended, rec.frame.remote)
    sigs = " ".join(f"{k}={json_value(v)}" for k, v in rec.signals.items())
    return f"{rec.time / 1e9:12.6f}  {rec.sender:<8} {ident}  {rec.name or '?':<20} {sigs}"


def _restbus(args: argparse.Namespace, db: Any, bus: Any, records: bool) -> RestBus:
    """The rest bus of the arguments on ``bus``, not started; a CAN FD message on a bus without
    FD is one line naming the message and the option that makes the bus an FD one."""
    try:
        # on a python-can FD bus the controllers are FD enabled whether or not the data rate is known
        fd = args.interface is not None and (args.fd or args.data_bitrate is not None)
        return RestBus(
            db,
            bus,
            dut=args.dut,
            records=records,
            start=False,
            default_cycle_ms=args.default_cycle,
            node_options={"fd": "fd"} if fd else None,
        )
    except FdNotCarriedError as exc:
        offer = "--data-bitrate D (e.g. 2000000)" if args.interface is None else "--fd or --data-bitrate D"
        raise CliError(
            f"{args.dbc}: message {exc.message} is a CAN FD frame and the bus carries classical frames only: "
            f"give {offer} for a CAN FD bus"
        ) from None


def restbus_command(args: argparse.Namespace) -> int:
    """Run the rest-bus simulation the arguments describe; 0 on success, 130 when Ctrl-C stopped
    it (the summary so far and the trace are still written)."""
    if not (0 < args.duration < math.inf):
        raise CliError(f"--duration {args.duration:g}: must be a number of seconds > 0")
    if args.interface is None and args.duration > MAX_SIM_SECONDS:
        raise CliError(
            f"--duration {args.duration:g}: the simulated bus runs at most {MAX_SIM_SECONDS:g} s "
            "(on a python-can bus any duration runs, until Ctrl-C)"
        )
    if args.interface is not None and args.bus is not None:
        raise CliError("give either --bus sim or --interface/--channel, not both")
    if args.channel is not None and args.interface is None:
        raise CliError("--channel needs --interface")
    data_bitrate = args.data_bitrate
    if args.interface is None:
        if data_bitrate is None and args.fd:
            data_bitrate = DEFAULT_DATA_BITRATE
        nominal = args.bitrate or 500_000
        if data_bitrate is not None and data_bitrate < nominal:
            raise CliError(
                f"--data-bitrate {data_bitrate} below the nominal bit rate {nominal}: the data phase is at least as "
                "fast (give the nominal rate for CAN FD frames without bit rate switching)"
            )
    if args.trace is not None:
        check_trace_output(args.trace)
    db = load_database(args.dbc)
    validate_database(db, args.dbc)
    changes = [parse_assignment(a) for a in args.set]
    if args.stimulus is not None:
        changes += read_stimulus(args.stimulus)
    out = _Output()
    # informational lines go with the summary on stdout, as `demo` prints them; with --json,
    # stdout is one JSON object per frame and they go to stderr
    info = sys.stderr if args.json else sys.stdout
    shown = 0
    stats: dict[tuple[str, str], list[Any]] = {}

    def _count(rec: BusRecord) -> None:
        st = stats.setdefault(
            (rec.sender, rec.name or format_id(rec.frame.can_id, rec.frame.extended)), [0, rec.time, rec.time, rec]
        )
        st[0] += 1
        st[2] = rec.time
        st[3] = rec

    def _summary() -> str:
        lines = [f"{'sender':<10} {'message':<22} {'frames':>6} {'period ms':>9}  last values"]
        for (sender, name), (n, first, last, rec) in sorted(stats.items()):
            period = f"{(last - first) / (n - 1) / 1e6:9.2f}" if n > 1 else f"{'-':>9}"
            sigs = " ".join(f"{k}={json_value(v)}" for k, v in list(rec.signals.items())[:6])
            lines.append(f"{sender:<10} {name:<22} {n:>6} {period}  {sigs}")
        return "\n".join(lines)

    def emit(rec: BusRecord) -> None:
        nonlocal shown
        if args.json:
            out.write(json.dumps(rec.as_json()) + "\n")
        elif args.dut is not None and rec.sender == args.dut:
            out.write(_line(rec) + "\n")
            shown += 1

    def _check_something_to_simulate(rb: RestBus) -> list[tuple[Change, Any]]:
        skipped = rb.skipped_summary()
        if rb.sent_messages == 0 and skipped is not None:
            raise CliError(f"{args.dbc}: nothing to simulate: {skipped}")
        checked = check_changes(rb, changes)
        silent = rb.silent()
        # a write sends a spontaneous message; one with neither send type nor cycle time stays quiet
        if silent is not None and all(e.timing(c.message).on_request_only for c, e in checked):
            offer = "" if args.default_cycle else "; give --default-cycle MS to send them every MS ms"
            raise CliError(f"{args.dbc}: nothing to simulate: {silent}{offer}")
        if skipped is not None:
            # a warning on stderr in every mode, so that a JSON consumer sees it too
            print(f"canstack: warning: {args.dbc}: {skipped}", file=sys.stderr)
        return checked

    def _start(rb: RestBus, checked: list[tuple[Change, Any]]) -> None:
        rb.start()
        schedule(checked, min((e.node.now() for e in rb.ecus.values()), default=0))

    complete = True
    if args.interface is None:
        from stack.bus.sim import SimBus

        bus = SimBus(args.bitrate or 500_000, data_bitrate=data_bitrate, seed=args.seed, record=bool(args.trace))
        rb = _restbus(args, db, bus, records=False)
        checked = _check_something_to_simulate(rb)
        _attach_uds(rb, args.uds, args.vin, info)
        rb.on_record(_count)
        rb.on_record(emit)
        _start(rb, checked)
        complete = run_sliced(bus, int(args.duration * 1e9), progress=args.progress, desc="restbus")
        ran = bus.now() / 1e9
        if args.trace:
            from stack.io.tracefile import save_trace

            n = writing(args.trace, "--trace", lambda: save_trace(bus, args.trace))
            print(
                f"trace: {plural(n, 'record')} written to {args.trace}{trace_note(args.trace, trc_dropped(bus))}",
                file=info,
            )
    else:
        bus = _open_driver(args.interface, args.channel, args.bitrate, args.fd, data_bitrate)
        failure: str | None = None
        try:
            rb = _restbus(args, db, bus, records=bool(args.trace))
            checked = _check_something_to_simulate(rb)
            _attach_uds(rb, args.uds, args.vin, info)
            sys.stdout.flush()
            rb.on_record(_count)
            rb.on_record(emit)
            if hasattr(bus, "submit"):
                bus.submit(lambda: _start(rb, checked))  # ECU timers start on the driver's scheduler thread
            else:
                _start(rb, checked)
            ran, complete = _run_driver(bus, args.duration)
            rb.stop()
            failure = _driver_error(bus, args.interface, args.channel, ran)
        finally:
            for name in ("close", "shutdown"):
                fn = getattr(bus, name, None)
                if callable(fn):
                    fn()
                    break
        if args.trace:
            from stack.io.message import to_message
            from stack.io.tracefile import save_messages

            n = writing(
                args.trace,
                "--trace",
                lambda: save_messages((to_message(r.frame, timestamp=r.time / 1e9) for r in rb.records), args.trace),
            )
            dropped = sum(1 for r in rb.records if r.frame.remote)
            print(f"trace: {plural(n, 'record')} written to {args.trace}{trace_note(args.trace, dropped)}", file=info)
        if failure is not None:
            raise CliError(failure)
    if not args.json:
        if not complete:
            print(f"interrupted at {ran:.3f} s of {args.duration:g} s: the summary so far")
        print(_summary())
        sims = ", ".join(rb.ecus)
        total = sum(st[0] for st in stats.values())
        dut = f", {shown} from DUT {args.dut}" if args.dut else ""
        skipped = rb.skipped_summary()
        print(
            f"simulated: {sims}; {plural(total, 'frame')} on the bus{dut} in {ran:g} s"
            + (f"; {skipped.split(' (')[0]}" if skipped else "")
        )
    if not complete:
        print(f"canstack: interrupted at {ran:.3f} s of {args.duration:g} s", file=sys.stderr)
        return 130
    return 0
