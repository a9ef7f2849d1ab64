"""What the sweeps' command lines share (`profiles.sweeps.cli`, `profiles.sweeps.bounds_cli`):
the check of a results table's ``--out`` and of the engine options before any run, the argument
types of seeds, bounded counts and utilisations, and the options that choose where the runs go.
Every refusal is one line and exit status 2 (argparse's, or `CliError`)."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from typing import Any

from stack.cli import count_type, seconds_type

__all__ = [
    "DEFAULT_TIME_LIMIT",
    "check_table_output",
    "check_engine",
    "check_before_runs",
    "int_type",
    "at_most_type",
    "utilisation_type",
    "run_options",
    "run_settings",
]

DEFAULT_TIME_LIMIT = 900.0
"""Wall-clock seconds a run of a sweep or study may take before it is stopped and recorded as
failed (a run that never ends must not stall the others)."""


def check_table_output(path: str, option: str = "--out") -> None:
    """A results table: .csv, or .parquet with pyarrow installed (the ``parquet`` extra), in a
    writable place — checked before anything runs (the rule of the experiment's samples file,
    `profiles.pipeline.cli.check_samples_output`)."""
    from profiles.pipeline.cli import check_samples_output

    check_samples_output(path, option)


def check_engine(args: argparse.Namespace) -> None:
    """--workers, --scheduler and --engine agree, and the engine they choose is installed (the
    engine's own rule, `profiles.sweeps.execute.choose_engine`: its ExecuteError is one line,
    exit status 2)."""
    from profiles.sweeps.execute import choose_engine

    choose_engine(args.workers, args.scheduler, args.engine)


def check_before_runs(args: argparse.Namespace, check_plot: Callable[[str], Any]) -> None:
    """What can be wrong with ``--out``, ``--plot`` (by ``check_plot``: a directory or a file) and
    the engine options, refused before the first run."""
    if args.out:
        check_table_output(args.out)
    if args.plot:
        check_plot(args.plot)
    check_engine(args)


def int_type(text: str) -> int:
    """A seed: an integer, decimal or with a base prefix (0x…), as argparse type."""
    try:
        return int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None


def at_most_type(what: str, most: int) -> Callable[[str], int]:
    """A count of ``what`` (`stack.cli.count_type`) of at most ``most``, as argparse type."""
    base = count_type(what)

    def parse(text: str) -> int:
        v = base(text)
        if v > most:
            raise argparse.ArgumentTypeError(f"{text}: {what} is at most {most:,}")
        return v

    return parse


def utilisation_type(lowest: float) -> Callable[[str], float]:
    """A bus utilisation, a finite fraction from ``lowest`` to 1.5, as argparse type."""

    def parse(text: str) -> float:
        try:
            f = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a utilisation (a fraction, 0.5 for 50 %)") from None
        if not (math.isfinite(f) and lowest <= f <= 1.5):
            raise argparse.ArgumentTypeError(
                f"{text!r}: a utilisation is from {lowest:g} to 1.5 (a fraction: 0.5 is 50 %)"
            )
        return f

    return parse


def run_options(p: argparse.ArgumentParser) -> None:
    """Add the options that say where the runs go and how long each may take: --workers,
    --scheduler, --engine, --progress, --time-limit."""
    p.add_argument(
        "--workers",
        type=count_type("the number of worker processes"),
        default=1,
        help="run on N processes: a standard library process pool, or a Dask LocalCluster with "
        "--engine dask (default 1: in this process)",
    )
    p.add_argument(
        "--scheduler",
        metavar="tcp://HOST:8786",
        help="run on a Dask cluster (the dask extra; canstack installed on every worker)",
    )
    p.add_argument(
        "--engine",
        choices=("auto", "sequential", "processes", "dask"),
        default="auto",
        help="where --workers runs go (default auto: one worker in this process, more on a process pool, "
        "--scheduler on Dask)",
    )
    p.add_argument(
        "--progress",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="progress bar of the runs with the time left on stderr (default: when stderr is a terminal)",
    )
    p.add_argument(
        "--time-limit",
        type=seconds_type(1e6),
        default=DEFAULT_TIME_LIMIT,
        metavar="S",
        help=f"stop a run that takes longer than S seconds of wall clock and record it as failed (default "
        f"{DEFAULT_TIME_LIMIT:g})",
    )


def run_settings(args: argparse.Namespace) -> dict[str, Any]:
    """The runners' keyword arguments from the options `run_options` added: ``workers``,
    ``scheduler``, ``engine``, ``progress``, ``time_limit``."""
    return {
        "workers": args.workers,
        "scheduler": args.scheduler,
        "engine": args.engine,
        "progress": args.progress,
        "time_limit": args.time_limit,
    }
