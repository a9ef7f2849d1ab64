"""`canstack study bounds`: the analysis' bounds against the simulated bus on random networks
(`profiles.sweeps.bounds`), registered by `profiles.sweeps.cli.register_study`.

    canstack study bounds [--networks N] [--seed S] [--utilisation U] [--nodes N] [--per-node N]
                          [--queues priority=1,fifo=1,mailbox=2] [--patterns all] [--fd [mixed|all]]
                          [--workers N] [--json] [--out FILE.csv] [--plot FILE.png]

Bad arguments are one line and exit status 2 before any run. Exit status 3 when a measured time
exceeds its bound or a deadline miss was not predicted (each printed on stderr with the network
that shows it), 1 when a network could not be run, 130 after Ctrl-C (the networks done are
reported).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from typing import Any

from profiles.sweeps.options_cli import (
    at_most_type,
    check_before_runs,
    int_type,
    run_options,
    run_settings,
    utilisation_type,
)
from stack.cli import plural
from stack.cli.runs import check_plot_output, writing

__all__ = ["register_bounds", "DEFECT", "MESSAGE_COLUMNS"]

#: exit status when the simulation exceeded a bound (or missed a deadline the analysis did not predict)
DEFECT = 3

#: the columns of ``--out``: one row per message
MESSAGE_COLUMNS = (
    "network",
    "message",
    "node",
    "controller",
    "fd",
    "brs",
    "bytes",
    "method",
    "bound_ns",
    "queued_ns",
    "queued_ratio",
    "queued_pattern",
    "response_ns",
    "nominal_ns",
    "nominal_ratio",
    "nominal_pattern",
    "deadline_ns",
    "schedulable",
    "sent",
    "misses",
)

#: the most nodes and messages a node: every message needs its own 11-bit identifier
MAX_NODES, MAX_PER_NODE = 32, 64
#: the lowest --utilisation (the largest utilisation a network may draw)
MIN_UTILISATION = 0.01


def _library(parse: Callable[[str], Any]) -> Callable[[str], Any]:
    """A library parser as an argparse type: its ValueError becomes argparse's one-line error."""

    def typed(text: str) -> Any:
        try:
            return parse(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    return typed


def _bounds(args: argparse.Namespace) -> int:
    from profiles.sweeps.bounds import bounds_json, bounds_plot, bounds_study, bounds_table, defect_text
    from profiles.sweeps.sweep import write_table

    check_before_runs(args, check_plot_output)
    study = bounds_study(
        args.networks,
        seed=args.seed,
        max_util=args.utilisation,
        per_node=args.per_node,
        nodes=args.nodes,
        queues=args.queues,
        patterns=args.patterns,
        drift=args.drift,
        fd=args.fd,
        **run_settings(args),
    )
    if args.out:
        writing(args.out, "--out", lambda: write_table(study.messages, MESSAGE_COLUMNS, args.out))
    print(json.dumps(bounds_json(study)) if args.json else bounds_table(study))
    for r in study.failed[:5]:
        print(f"canstack: network {r['network']} (seed {r['seed']}) failed: {r['error']}", file=sys.stderr)
    if args.plot and study.messages:
        print(f"plot: {writing(args.plot, '--plot', lambda: bounds_plot(study, args.plot))}", file=sys.stderr)
    done = len(study.rows)
    parts = [
        f"{done} of {plural(study.total, 'network')} done" if study.interrupted else plural(done, "network"),
        f"{len(study.failed)} failed" if study.failed else "",
        f"{study.engine}, {study.wall_s:.1f} s",
        f"written to {args.out}" if args.out else "",
    ]
    print(("interrupted: " if study.interrupted else "") + "; ".join(p for p in parts if p), file=sys.stderr)
    defects = study.defects
    if defects:
        print(
            f"canstack: DEFECT: the simulation broke the analysis {plural(len(defects), 'time')} — a bound the "
            "simulated bus exceeds is a defect of the analysis (or of the simulation); report it with what follows",
            file=sys.stderr,
        )
        for d in defects:
            print(defect_text(d), file=sys.stderr)
    if study.interrupted:
        return 130
    if defects:
        return DEFECT
    return 1 if study.failed else 0


def register_bounds(studies: Any) -> None:
    """Add `study bounds` to the `study` subcommands."""
    from profiles.sweeps.bounds import parse_patterns
    from profiles.sweeps.networks import DATA_RATIOS, DEFAULT_QUEUES, FD_NETWORKS, parse_queue_mix, queue_mix_text
    from profiles.sweeps.releases import PATTERNS
    from profiles.sweeps.sweep import MAX_RUNS

    b = studies.add_parser(
        "bounds",
        help="how tight the response-time analysis' bounds are on random networks (priority, FIFO and mailbox "
        "nodes, jitter up to the period, drift), and that the simulation never exceeds them",
        description="Random networks (seeded; classical CAN, or CAN FD with --fd), each analysed (profiles.analysis.rta) and simulated in every release "
        "pattern (" + "; ".join(f"{k}: {v}" for k, v in PATTERNS.items()) + "). Per analysis method (davis2007 for "
        "priority queues, fifo, mailbox): messages, how many exceeded their bound (must be 0), and the measured "
        "worst time over its bound, from queuing (bound_ns) and from the nominal release (response_ns): max, "
        "median, 10th percentile. Exit status 3 when the simulation exceeds a bound.",
    )
    b.add_argument(
        "--networks",
        type=at_most_type("networks", MAX_RUNS),
        default=100,
        help="random networks (default 100; network i is the same whatever N)",
    )
    b.add_argument("--seed", type=int_type, default=1, help="the study seed (default 1)")
    b.add_argument(
        "--utilisation",
        type=utilisation_type(MIN_UTILISATION),
        default=0.85,
        metavar="U",
        help="the largest bus utilisation drawn (worst-case frames; default 0.85): each network's is uniform in "
        "[min(0.15, U/2), U]",
    )
    b.add_argument(
        "--nodes",
        type=at_most_type("nodes a network", MAX_NODES),
        default=5,
        help=f"nodes a network, at most (default 5: each network has 2..5; at most {MAX_NODES})",
    )
    b.add_argument(
        "--per-node",
        type=at_most_type("messages a node", MAX_PER_NODE),
        default=4,
        help=f"messages a node, at most (default 4; at most {MAX_PER_NODE})",
    )
    b.add_argument(
        "--queues",
        type=_library(parse_queue_mix),
        default=DEFAULT_QUEUES,
        metavar="KIND[=W],…",
        help=f"the node queue kinds drawn, with weights (default {queue_mix_text(DEFAULT_QUEUES)}; e.g. fifo for "
        "FIFO nodes only)",
    )
    b.add_argument(
        "--patterns",
        type=_library(parse_patterns),
        default=tuple(PATTERNS),
        metavar="P,…",
        help=f"release patterns each network is simulated in (default all: {', '.join(PATTERNS)})",
    )
    b.add_argument(
        "--drift",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="half the nodes' clocks drift, up to ±5 %% (default on)",
    )
    b.add_argument(
        "--fd",
        nargs="?",
        const="mixed",
        choices=tuple(FD_NETWORKS),
        default=None,
        metavar="mixed|all",
        help="CAN FD networks: a data bit rate of "
        + ", ".join(map(str, DATA_RATIOS))
        + " times the nominal, FD frames of 0..64 bytes with and without BRS; "
        + "; ".join(f"{k}: {v}" for k, v in FD_NETWORKS.items())
        + " (--fd alone: mixed; default classical CAN)",
    )
    run_options(b)
    b.add_argument("--json", action="store_true", help="print one JSON object instead of the text table")
    b.add_argument("--out", help="write one row per message here: .csv, or .parquet (the parquet extra)")
    b.add_argument(
        "--plot",
        metavar="FILE",
        help="draw the distribution of measured/bound per method into FILE (.png, .svg, .pdf; the plot extra)",
    )
    b.set_defaults(func=_bounds)
