"""`canstack serve`: one simulated bus in real time for several processes (`stack.io.serve`)."""

from __future__ import annotations

import argparse
import logging
import time

from stack.io.serve import BusServer

__all__ = ["register"]

DEFAULT_PORT = 29536

DESCRIPTION = f"""\
Run one simulated CAN bus paced to the wall clock and share it with other processes: each
client is a node with its own controller; arbitration, ACK and timing happen here, so programs
in several processes contend as on a real bus. Clients join with python-can:

  can.Bus(interface="canstack", channel="tcp://127.0.0.1:{DEFAULT_PORT}/bus0")   (--listen)
  can.Bus(interface="canstack", channel="unix:///path/to/socket/bus0")     (--unix /path/to/socket)

A plain channel such as "bus0" is NOT this bus: it is a bus private to the process that opens
it. Clients joining and leaving are logged (the program and pid they give, node name and
peer). Stop with Ctrl-C or SIGTERM.
"""


def _parse_listen(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) < 65536:
        raise argparse.ArgumentTypeError(f"--listen {text!r}: expected HOST:PORT, e.g. 127.0.0.1:{DEFAULT_PORT}")
    return host.strip("[]") or "127.0.0.1", int(port)


def _duration(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--duration {text!r}: expected seconds, e.g. 60") from None
    if not v > 0:
        raise argparse.ArgumentTypeError(f"--duration {text!r}: must be more than 0 seconds")
    return v


def _data_bitrate(text: str) -> int:
    try:
        v = int(text.replace("_", ""), 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--data-bitrate {text!r}: expected bit/s, e.g. 2000000") from None
    if not 0 < v <= 20_000_000:
        raise argparse.ArgumentTypeError(f"--data-bitrate {text!r}: a data phase runs at 1..20000000 bit/s")
    return v


def _serve(args: argparse.Namespace) -> int:
    from stack.cli import CliError

    if args.listen and args.unix:
        raise CliError("canstack serve: give --listen or --unix, not both")
    listen = args.listen if args.listen or args.unix else ("127.0.0.1", DEFAULT_PORT)
    try:
        server = BusServer(
            args.bitrate,
            name=args.name,
            listen=listen,
            unix=args.unix,
            allow_remote=args.allow_remote,
            data_bitrate=args.data_bitrate,
        )
    except (ValueError, OSError) as exc:
        raise CliError(f"canstack serve: {exc}") from None
    # from here on every way out closes the server (its announcement file goes with it): a
    # SIGTERM that comes as soon as the first line is printed too
    try:
        logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s")
        rates = f"{args.bitrate} bit/s" + (f" (CAN FD, data {args.data_bitrate} bit/s)" if args.data_bitrate else "")
        print(f"serving {args.name} at {rates} on {server.url}", flush=True)
        if args.duration is not None:
            time.sleep(args.duration)
        else:
            while True:
                time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        server.close()
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add `serve`."""
    from stack.cli import parse_bitrate

    p = sub.add_parser(
        "serve",
        help="serve a simulated bus in real time to python-can clients in other processes",
        description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--bitrate",
        type=parse_bitrate,
        default=500_000,
        help="the bus's bit rate in bit/s, 1000..1000000 (default 500000); a client that asks for "
        "another one is refused",
    )
    p.add_argument(
        "--data-bitrate",
        type=_data_bitrate,
        default=None,
        metavar="D",
        help="serve a CAN FD bus whose data phase runs at D bit/s (clients join with fd=True; without it the "
        "bus carries classical frames only)",
    )
    p.add_argument(
        "--listen",
        type=_parse_listen,
        metavar="HOST:PORT",
        help=f"serve over TCP at this address (default 127.0.0.1:{DEFAULT_PORT}; port 0 picks a free "
        "one, printed at start); clients use channel tcp://HOST:PORT/NAME",
    )
    p.add_argument(
        "--unix",
        metavar="PATH",
        help="serve on a unix socket at this absolute path instead; clients use channel "
        "unix://PATH/NAME (a stale socket left there is replaced, nothing else is)",
    )
    p.add_argument(
        "--name",
        default="bus0",
        help="the bus name clients give at the end of the channel (default bus0); 1..64 of A-Z a-z 0-9 _ . -",
    )
    p.add_argument(
        "--allow-remote",
        action="store_true",
        help="allow a --listen address other than loopback (the bus has no authentication: "
        "anyone who reaches the port can join and send)",
    )
    p.add_argument(
        "--duration",
        type=_duration,
        default=None,
        metavar="SECONDS",
        help="stop after this many seconds (default: run until Ctrl-C)",
    )
    p.set_defaults(func=_serve)
