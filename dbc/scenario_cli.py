"""``canstack scenario from-dbc DBC [--bitrate B] [--out FILE.toml]``: the command of
`dbc.scenario`, registered in the ``canstack.scenario`` entry point group."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from stack.cli import parse_bitrate, parse_data_bitrate

from .cli import positive_ms
from .errors import load_database
from .scenario import scenario_from_dbc
from .validate import validate_database

__all__ = ["register_from_dbc"]


def register_from_dbc(tools: Any) -> None:
    """Add ``from-dbc`` to the ``canstack scenario`` command (``canstack.scenario`` entry point)."""
    p = tools.add_parser(
        "from-dbc",
        help="write a scenario from a DBC: one node per sender, one message per cyclic message",
        description="Write the scenario of a network description: one node per sending ECU, one message per "
        "cyclic or cyclic-if-active message with its identifier, length and period (deadline = period unless "
        "the DBC's CanstackDeadline says otherwise); CAN FD messages as FD messages (fd, brs, length) on a CAN FD "
        "bus. Messages a scenario cannot hold are left out with a note.",
    )
    p.add_argument("dbc", metavar="DBC", help="the database (DBC, or anything cantools loads)")
    p.add_argument("--bitrate", type=parse_bitrate, default=None, help="bit/s (default: the DBC's Baudrate, or 500000)")
    p.add_argument(
        "--data-bitrate",
        type=parse_data_bitrate,
        default=None,
        metavar="D",
        help="[bus] data_bitrate, the CAN FD data phase's bit/s (default: 2000000 when the DBC has CAN FD messages)",
    )
    p.add_argument("--duration", type=_duration, default=1.0, metavar="S", help="simulated seconds (default 1)")
    p.add_argument(
        "--default-cycle",
        type=positive_ms,
        metavar="MS",
        help="the period of the messages the DBC gives no send type or cycle time (default: left out)",
    )
    p.add_argument("--out", metavar="FILE.toml", help="the scenario file to write (default: standard output)")
    p.set_defaults(func=_from_dbc)


def _duration(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not 0 < v <= 1e6:
        raise argparse.ArgumentTypeError(f"{v:g}: must be > 0 and at most 1e6 simulated seconds")
    return v


def _from_dbc(args: argparse.Namespace) -> int:
    from stack.cli.runs import check_output

    if args.out is not None:
        check_output(args.out, "--out")
    db = load_database(args.dbc)
    validate_database(db, args.dbc)
    sc = scenario_from_dbc(
        db,
        args.dbc,
        bitrate=args.bitrate,
        duration=args.duration,
        default_cycle_ms=args.default_cycle,
        data_bitrate=args.data_bitrate,
    )
    _check_readable(sc.text, args.out or "<stdout>")
    for note in sc.notes:
        print(f"canstack: note: {note}", file=sys.stderr)
    if args.out is None:
        sys.stdout.write(sc.text)
    else:
        with open(args.out, "w", encoding="utf-8") as fh:
            fh.write(sc.text)
        print(
            f"{args.out}: {sc.nodes} node{'s' if sc.nodes != 1 else ''}, {sc.messages} message"
            f"{'s' if sc.messages != 1 else ''} from {args.dbc}"
            + (f" ({len(sc.notes)} note{'s' if len(sc.notes) != 1 else ''} on stderr)" if sc.notes else "")
        )
    return 0


def _check_readable(text: str, source: str) -> None:
    """Read the scenario back with the experiment pipeline's reader (a bug here, not bad input,
    if it refuses it)."""
    from profiles.pipeline.scenario import parse_scenario

    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover - Python 3.10
        import tomli as tomllib
    parse_scenario(tomllib.loads(text), source)
