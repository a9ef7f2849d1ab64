"""`canstack serve`: one simulated bus in real time for several processes (`stack.io.serve`)."""

from __future__ import annotations

import argparse
import logging
import time

from stack.io.serve import BusServer

__all__ = ["register"]


def _parse_listen(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) < 65536:
        raise argparse.ArgumentTypeError(f"--listen {text!r}: expected HOST:PORT, e.g. 127.0.0.1:29536")
    return host.strip("[]") or "127.0.0.1", int(port)


def _serve(args: argparse.Namespace) -> int:
    from stack.cli import CliError

    if args.listen and args.unix:
        raise CliError("canstack serve: give --listen or --unix, not both")
    listen = args.listen if args.listen or args.unix else ("127.0.0.1", 29536)
    try:
        server = BusServer(args.bitrate, name=args.name, listen=listen, unix=args.unix,
                           allow_remote=args.allow_remote)
    except ValueError as exc:
        raise CliError(f"canstack serve: {exc}") from None
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s")
    print(f"serving {args.name} at {args.bitrate} bit/s on {server.url}", flush=True)
    try:
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
    from stack.cli import parse_int

    def bitrate(text: str) -> int:
        v = parse_int(text)
        if not 1_000 <= v <= 1_000_000:
            raise argparse.ArgumentTypeError(f"{v}: a CAN 2.0 bus runs at 1000..1000000 bit/s")
        return v

    p = sub.add_parser("serve", help="serve a simulated bus in real time to python-can clients")
    p.add_argument("--bitrate", type=bitrate, default=500_000, help="bit/s (default 500000)")
    p.add_argument("--listen", type=_parse_listen, metavar="HOST:PORT",
                   help="TCP address (default 127.0.0.1:29536; port 0 picks a free one)")
    p.add_argument("--unix", metavar="PATH", help="serve on a unix socket instead")
    p.add_argument("--name", default="bus0", help="bus name clients give in the channel (default bus0)")
    p.add_argument("--allow-remote", action="store_true", help="allow a non-loopback listen address")
    p.add_argument("--duration", type=float, default=None, help=argparse.SUPPRESS)
    p.set_defaults(func=_serve)
