"""`canstack canopen`: run a CANopen device (CiA 301 NMT slave) on any python-can bus until
interrupted.

    canstack canopen [EDS] --node-id N --interface I [--channel C] [--bitrate B] [--app MODULE:FUNCTION]

The device boots (boot-up message, pre-operational) and answers NMT, SDO (all three transfer
modes), SYNC, PDOs, heartbeat/node guarding like the CANopenNode devices it imitates, so a
master — the ``canopen`` library, a PLC, `CanopenMaster` — can drive it. It prints one line per
NMT state change; Ctrl-C, SIGTERM (or ``--duration``) stops it and prints what it did (``--json``:
the device's metrics as one JSON object). When its bus goes away (a `canstack serve` stopped, an
interface closed) it stops at once, prints its summary and one line naming the bus and the time
on stderr, and exits with status 1. Registered through the ``canstack.commands`` entry point
(stack never imports profiles).

``--app module:function`` runs application code with the device: ``function(device)`` is called
once, on the driver's thread, before the device boots, so it can do what an in-process
application does — register callbacks (``on_time``, ``on_write``, ``on_rpdo``, ``on_state``),
raise and clear EMCYs (``report_error``), change objects (``write``), arm timers on
``device.node`` (``call_later``). Every callback and timer runs on that thread too. The module is
imported from the current directory first, as ``python -m`` would. A bad value (no colon, a module
that cannot be imported, no such function, a function that cannot take one argument) is one line
and exit status 2, before any bus is opened.

The bus is opened with ``receive_own_messages=True``: the device sees its own frames as the bus
timestamps them, so its TPDOs' inhibit time and event timer count from their start on the wire
(`profiles.canopen.pdo.tpdo`).
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

from stack.cli import CliError, int_type, parse_bitrate, plural, seconds_type

__all__ = ["register", "canopen_command", "load_app"]


def register(subparsers: Any) -> None:
    """Add the ``canopen`` subcommand."""
    p = subparsers.add_parser(
        "canopen",
        help="run a CANopen device (CiA 301 slave) on a python-can bus",
        description="Run a CANopen device with the object dictionary of an EDS/DCF (default: canstack's small "
        "default device) on a python-can bus until interrupted: NMT, heartbeat, node guarding, SYNC, "
        "TPDOs/RPDOs, SDO (expedited, segmented, block), EMCY, TIME.",
    )
    p.add_argument(
        "eds",
        metavar="EDS",
        nargs="?",
        default=None,
        help="EDS or DCF file (default: the default device shipped with canstack)",
    )
    p.add_argument("--node-id", required=True, type=_NODE_ID, metavar="N", help="CANopen node-ID, 1..127")
    p.add_argument(
        "--interface",
        required=True,
        metavar="NAME",
        help="python-can interface (socketcan, canstack, virtual, pcan, ...)",
    )
    p.add_argument("--channel", metavar="CH", help="python-can channel (vcan0, tcp://127.0.0.1:PORT/bus0, ...)")
    p.add_argument(
        "--bitrate", type=parse_bitrate, default=None, metavar="B", help="bit/s, passed to the python-can bus"
    )
    p.add_argument(
        "--heartbeat",
        type=_HEARTBEAT_MS,
        default=None,
        metavar="MS",
        help="producer heartbeat time 0x1017 in ms (default: the EDS's; 0: none)",
    )
    p.add_argument("--start", action="store_true", help="start operational without waiting for NMT start")
    p.add_argument(
        "--duration",
        type=seconds_type(1e7),
        default=None,
        metavar="S",
        help="stop after S seconds (default: run until Ctrl-C)",
    )
    p.add_argument("--json", action="store_true", help="print the device's metrics as one JSON object at the end")
    p.add_argument(
        "--app",
        metavar="MODULE:FUNCTION",
        default=None,
        help="application code: FUNCTION(device) is called before the device boots (callbacks, EMCYs, objects, timers)",
    )
    p.set_defaults(func=canopen_command)


_NODE_ID = int_type(1, 127, "an integer", "a CANopen node-ID is 1..127 (CiA 301; 0 addresses all nodes)")
_HEARTBEAT_MS = int_type(
    0, 0xFFFF, "a whole number of ms", "the producer heartbeat time 0x1017 is 0..65535 ms (UNSIGNED16)"
)


def canopen_command(args: argparse.Namespace) -> int:
    """Run the device (see the module docstring); returns the exit status."""
    import can

    from profiles.canopen.device import CanopenDevice
    from profiles.canopen.dictionary import DEFAULT_EDS, load_od
    from stack.io.driver import PyCanDriver

    # a bad EDS is one line (EdsError names the file) before any bus opens; what the canopen library
    # would log about it (no DeviceInfo section, ...) is one warning naming the file
    load_od(args.eds, args.node_id, warn=lambda w: print(f"canstack: warning: {w}", file=sys.stderr))
    app = None if args.app is None else load_app(args.app)
    kw: dict[str, Any] = {} if args.bitrate is None else {"bitrate": args.bitrate}
    try:
        bus = can.Bus(interface=args.interface, channel=args.channel, receive_own_messages=True, **kw)
    except (can.CanError, OSError, NotImplementedError, ValueError, ImportError) as exc:
        raise CliError(f"cannot open {args.interface} channel {args.channel!r}: {' '.join(str(exc).split())}") from None
    driver = PyCanDriver(**kw)
    options: dict[str, Any] = {"start_operational": args.start}
    if args.heartbeat is not None:
        options["heartbeat_ms"] = args.heartbeat
    try:
        node = driver.add(_node(args.node_id), bus)
        device = CanopenDevice(node, args.node_id, args.eds, **options)
    except Exception:
        bus.shutdown()
        raise
    out = sys.stdout
    lock = threading.Lock()

    def say(text: str) -> None:
        with lock:
            print(text, file=out, flush=True)

    if not args.json:
        device.on_state(lambda old, new: say(f"{node.now() / 1e9:10.3f} s  NMT {old.name} -> {new.name}"))
        say(
            f"CANopen device {args.node_id} ({args.eds or DEFAULT_EDS.name}) on {args.interface} "
            f"{args.channel or ''}: Ctrl-C stops it".replace("  :", ":")
        )
    status = 0
    driver.start()
    try:
        if app is not None:
            driver.submit(app, device)
        driver.submit(device.start)
        deadline = None if args.duration is None else time.monotonic() + args.duration
        # short waits: the main thread must come back to Python for Ctrl-C and SIGTERM
        while deadline is None or time.monotonic() < deadline:
            left = 0.2 if deadline is None else max(0.0, min(0.2, deadline - time.monotonic()))
            if driver.gone.wait(left):
                status = 1
                break
    except KeyboardInterrupt:
        status = 130
    finally:
        done = threading.Event()
        final: dict[str, Any] = {}

        def finish() -> None:
            final.update(device.metrics())  # the state it ran in, before it powers off
            device.stop()
            done.set()

        driver.submit(finish)
        done.wait(1.0)
        driver.stop()
        bus.shutdown()
    m = final or device.metrics()
    if args.json:
        print(json.dumps(m), file=out)
    else:
        say(
            f"node {m['node_id']}: {m['nmt_state']}, {plural(m['boot_ups'], 'boot-up')}, "
            f"{plural(m['heartbeats_sent'], 'heartbeat')}, {plural(m['sync_received'], 'SYNC')}, "
            f"{plural(sum(t['sent'] for t in m['tpdos']), 'TPDO')} sent, "
            f"{plural(sum(r['received'] for r in m['rpdos']), 'RPDO')} received, "
            f"{plural(m['sdo']['requests'], 'SDO request')}, {plural(m['emcy_sent'], 'EMCY')}"
        )
    if driver.lost is not None:  # one line: what went before it was that bus failing
        print(f"canstack canopen: {driver.lost.describe()}", file=sys.stderr)
    else:
        for err in driver.errors:
            print(f"canstack canopen: {err}", file=sys.stderr)
    return status


def load_app(spec: str) -> Callable[[Any], Any]:
    """The function ``module:function`` names, ready to be called with the device; `CliError`
    (one line naming the value) when there is none."""
    import importlib
    import inspect
    import os

    mod_name, colon, fn_name = spec.partition(":")
    if not colon or not mod_name or not fn_name:
        raise CliError(f"--app {spec!r}: not module:function (the module, a colon, the function to call)")
    if os.getcwd() not in sys.path:
        sys.path.insert(0, os.getcwd())  # the user's own module, as python -m finds it
    try:
        mod = importlib.import_module(mod_name)
    except ModuleNotFoundError as exc:
        raise CliError(f"--app {spec!r}: no module named {exc.name!r}") from None
    except Exception as exc:
        raise CliError(f"--app {spec!r}: cannot import {mod_name!r}: {type(exc).__name__}: {exc}") from None
    fn = getattr(mod, fn_name, None)
    if fn is None:
        raise CliError(f"--app {spec!r}: module {mod_name!r} has no {fn_name!r}")
    if not callable(fn):
        raise CliError(f"--app {spec!r}: {fn_name!r} is a {type(fn).__name__}, not a function to call with the device")
    try:
        sig = inspect.signature(fn)
    except (TypeError, ValueError):
        return fn  # a builtin without a signature: called as given
    try:
        sig.bind(object())
    except TypeError:
        raise CliError(f"--app {spec!r}: {fn_name}{sig} cannot be called with one argument (the device)") from None
    return fn


def _node(node_id: int) -> Any:
    from stack import Node

    return Node(f"canopen-{node_id}")
