"""The `canstack` command line (the top layer of `stack`).

Each subcommand lives in a module of this package, beside the library module it drives, and exposes
``register(subparsers) -> None``; the handler it sets with ``set_defaults(func=...)`` takes the
parsed arguments and returns an exit status. Bad input raises `CliError` (or ValueError from the
library), which is printed as one line on stderr with exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import math
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from typing import Any, NoReturn

from stack.wire.frame import id_text

__all__ = [
    "CliError",
    "main",
    "parse_int",
    "parse_bitrate",
    "parse_data_bitrate",
    "int_type",
    "seconds_type",
    "count_type",
    "parse_sample_point",
    "version",
    "format_id",
    "plural",
]

# stack's own modules that contribute subcommands, in the order they are listed in --help;
# packages above stack (dbc, profiles) add theirs through the "canstack.commands" entry point
# group in pyproject.toml, so that stack never imports them (DESIGN.md: imports go one way)
SUBCOMMAND_MODULES = [
    "stack.cli.demo",
    "stack.cli.bittiming",
    "stack.cli.sync",
    "stack.cli.waveform",
    "stack.cli.serve",
]
# which module registers which subcommand: a command line naming one imports only that module
# (`canstack decode` then starts without python-can or cantools); --help imports them all
SUBCOMMANDS = {
    "demo": "stack.cli.demo",
    "frame": "stack.cli.demo",
    "bittiming": "stack.cli.bittiming",
    "sync": "stack.cli.sync",
    "decode": "stack.cli.waveform",
    "render": "stack.cli.waveform",
    "serve": "stack.cli.serve",
}


#: The version when no distribution metadata is installed (a checkout run with PYTHONPATH);
#: kept equal to pyproject.toml's by a test.
__version__ = "0.2.0.dev0"


def version() -> str:
    """canstack's version: the installed distribution's metadata, else this package's
    ``__version__``."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as dist_version

    try:
        return dist_version("canstack")
    except PackageNotFoundError:
        return __version__


class CliError(Exception):
    """A bad command-line argument or input file: printed as one line, exit status 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:  # argparse would print usage + message; keep one line
        raise CliError(f"{self.prog}: {message}")


def parse_int(text: str) -> int:
    """An integer given in decimal or with 0x/0o/0b prefix (CAN identifiers are usually hex)."""
    try:
        return int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer (decimal or 0x hex)") from None


def int_type(low: int, high: int, noun: str, rule: str) -> Callable[[str], int]:
    """An argparse type for a whole number (decimal or 0x hex) in ``low..high``: the errors say
    "'x' is not ``noun``" and "v: ``rule``"."""

    def parse(text: str) -> int:
        try:
            v = int(text, 0)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {noun}") from None
        if not low <= v <= high:
            raise argparse.ArgumentTypeError(f"{v}: {rule}")
        return v

    return parse


#: A CAN 2.0 bit rate: a whole number of bit/s in 1000..1000000 (ISO 11898-1 specifies classical
#: CAN up to 1 Mbit/s; the simulated bus refuses less than 1 kbit/s).
parse_bitrate = int_type(1_000, 1_000_000, "a whole number of bit/s", "a CAN 2.0 bus runs at 1000..1000000 bit/s")

#: A CAN FD data-phase bit rate (ISO 11898-1:2015 sets no upper limit; transceivers of ISO
#: 11898-2:2016 are specified for 2 and 5 Mbit/s, SIC ones up to 8).
parse_data_bitrate = int_type(
    1_000, 16_000_000, "a whole number of bit/s", "a CAN FD data phase runs at 1000..16000000 bit/s"
)


def seconds_type(most: float) -> Callable[[str], float]:
    """An argparse type for a duration: a number of seconds > 0 and at most ``most``."""

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
        if not 0 < v <= most:
            raise argparse.ArgumentTypeError(f"{text}: a duration is > 0 and at most {most:g} s")
        return v

    return parse


def count_type(what: str) -> Callable[[str], int]:
    """An argparse type for a count: a whole number >= 1 (``what`` names it in the error)."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number ({what})") from None
        if v < 1:
            raise argparse.ArgumentTypeError(f"{text!r}: {what} is at least 1")
        return v

    return parse


def parse_sample_point(text: str) -> float:
    """A sample point in percent of the bit time; a number between 0 and 1 is read as a
    fraction of the bit (0.875 = 87.5 %), as controller data sheets and the kernel's
    ``sample-point 0.875`` write it. Whether it is a valid sample point (50..<100 %) is the
    timing rules' business, which name it."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a number (percent, e.g. 87.5, or a fraction, 0.875)"
        ) from None
    if not math.isfinite(v) or v <= 0:
        raise argparse.ArgumentTypeError(f"{text!r}: a sample point is a percentage 50..<100 (or a fraction 0.5..<1)")
    return v * 100 if v < 1 else v


format_id = id_text  # the wire layer's: every text output writes identifiers the same way


def plural(n: int, word: str) -> str:
    """'1 frame', '2 frames': a count with its noun in the right number."""
    return f"{n:,} {word}{'' if n == 1 else 's'}"


#: help text of every --sample-point option
SAMPLE_POINT_HELP = "sample point, %% of the bit (a fraction 0 < x < 1 is read as one: 0.875 = 87.5 %%)"


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser with every available subcommand registered, or only ``command``'s when it
    names one of stack's own subcommands or a ``canstack.commands`` entry point."""
    parser = _Parser(prog="canstack", description="canstack: a CAN data-link engine and protocol stack")
    parser.add_argument("--version", action="store_true", help="print canstack's version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    if command in SUBCOMMANDS:
        importlib.import_module(SUBCOMMANDS[command]).register(sub)
        return parser
    from importlib.metadata import entry_points  # slow to import: only for a plugin's command

    plugins = sorted(entry_points(group="canstack.commands"), key=lambda e: e.name)
    named = [ep for ep in plugins if ep.name == command]
    if named:  # the others' modules (DBC, CANopen, sweeps) would cost every command start-up time
        named[0].load()(sub)
        return parser
    for name in SUBCOMMAND_MODULES:
        try:
            mod = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:
                continue  # subcommand not built yet
            raise
        mod.register(sub)
    for ep in plugins:
        ep.load()(sub)
    return parser


class _StopOnSigterm:
    """SIGTERM (a process manager, ``kill``, a test harness) stops a command as Ctrl-C does: it
    calls the SIGINT handler in place at that moment, so a command that takes Ctrl-C as a flag
    (`stack.cli.runs`) takes SIGTERM the same way, and raises KeyboardInterrupt where SIGINT is
    ignored (a background job inherits SIGINT ignored: without this only SIGKILL could stop the
    command, and nothing of its clean-up would run). Installed on the main thread only."""

    def __init__(self) -> None:
        self.received = False
        self._old: Any = None
        self._installed = False

    def __enter__(self) -> _StopOnSigterm:
        if threading.current_thread() is threading.main_thread():
            self._old = signal.signal(signal.SIGTERM, self._handle)
            self._installed = True
        return self

    def _handle(self, signum: int, frame: Any) -> None:
        self.received = True
        handler = signal.getsignal(signal.SIGINT)
        if callable(handler):
            handler(signal.SIGINT, frame)
        else:  # SIG_IGN or SIG_DFL: stop as Python's default Ctrl-C does
            raise KeyboardInterrupt

    def __exit__(self, *exc: Any) -> None:
        if self._installed:
            signal.signal(signal.SIGTERM, self._old)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `canstack` console script.

    Ctrl-C stops a command with exit status 130; SIGTERM stops it the same way with 143 (128 +
    the signal's number, as a shell reports it)."""
    with _StopOnSigterm() as term:
        status = _main(argv)
    return 128 + signal.SIGTERM if term.received and status == 130 else status


def _main(argv: Sequence[str] | None) -> int:
    try:
        args_list = list(sys.argv[1:] if argv is None else argv)
        if args_list[:1] == ["--version"]:
            print(f"canstack {version()}")
            return 0
        first = next((a for a in args_list if not a.startswith("-")), None)
        parser = build_parser(first)
        args = parser.parse_args(args_list)
        return int(args.func(args) or 0)
    except BrokenPipeError:  # output piped into head: not an error
        sys.stdout = None  # type: ignore[assignment]  # nothing more may be flushed into the closed pipe
        return 0
    except (CliError, ValueError, OSError) as exc:
        print(f"canstack: error: {exc}" if not str(exc).startswith("canstack") else f"{exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
