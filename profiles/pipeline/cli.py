"""`canstack experiment SCENARIO.toml`: run a scheduling scenario and print its metrics beside the
response-time analysis (registered under the ``canstack.commands`` entry point group)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from stack.cli import CliError, seconds_type
from stack.cli.runs import check_output, check_plot_dir, check_trace_output, writing

__all__ = ["register"]


def _experiment(args: argparse.Namespace) -> int:
    from profiles.pipeline.metrics import format_table
    from profiles.pipeline.runner import run_on_pycan, run_scenario
    from profiles.pipeline.scenario import load_scenario

    if args.plot:
        check_plot_dir(args.plot)
    if args.out:
        check_output(args.out, "--out")
    if args.trace:
        check_trace_output(args.trace)
    if (args.interface is None) != (args.channel is None):
        raise CliError("--interface and --channel go together (a python-can bus), or neither (the simulated bus)")
    scenario = load_scenario(args.scenario)
    if args.interface:
        result = run_on_pycan(
            scenario, args.interface, args.channel, duration_s=args.duration, trace=args.trace, plot=bool(args.plot)
        )
    else:
        if args.duration is not None:
            scenario.duration_ns = round(args.duration * 1e9)
        result = run_scenario(scenario, record=bool(args.plot or args.trace) or None, progress=args.progress)
    data = result.to_json()
    notes: list[str] = []
    # the files first: a reader that closes stdout early (| head) must not cost one of them
    if args.out:
        writing(args.out, "--out", lambda: Path(args.out).write_text(json.dumps(data, indent=2) + "\n"))
    if args.trace:
        notes.append(_write_trace(result, args.trace))
    if args.plot:
        from profiles.pipeline.plots import write_plots

        # a python-can run has the frames the monitor received, not the simulation's layers
        extra = _profile_plots(scenario) if not args.interface else None
        files = writing(args.plot, "--plot", lambda: write_plots(result, args.plot, extra=extra))
        notes.append(f"plots: {', '.join(str(f) for f in files)}")
    print(json.dumps(data, indent=2) if args.json else format_table(data))
    for line in notes:
        print(line, file=sys.stderr)
    if result.lost is not None:
        print(
            f"canstack experiment: {result.lost.describe()}; the results so far are marked interrupted",
            file=sys.stderr,
        )
        return 1
    return 130 if result.interrupted else 0


def _write_trace(result: Any, path: str) -> str:
    """Write the run's trace (a python-can run streamed it already) and say what was written."""
    from stack.cli.runs import trace_note

    if result.trace_file is not None:  # a python-can run: written as the run went
        f = result.trace_file
        if "trace_error" in result.analysis:
            raise CliError(f"--trace {result.analysis['trace_error']}")
        n, left_out = f["records"], f["left_out"]
    else:
        from stack.io.message import record_to_message
        from stack.io.tracefile import save_messages

        messages = [record_to_message(rec, "bus0") for rec in result.trace]
        n = writing(path, "--trace", lambda: save_messages(messages, path))
        left_out = len(messages) - n
    return f"trace: {n:,} message{'' if n == 1 else 's'} written to {path}{trace_note(path, left_out)}"


def _profile_plots(scenario: Any) -> dict[str, Any]:
    """Plots that the profiles of this scenario add: the timeline with each layer of their
    module's ``PLOTS`` (name -> `profiles.registry.TimelineLayer`) behind the frames."""
    import importlib

    from profiles.pipeline.plots import with_layer
    from profiles.registry import profile_kind

    out: dict[str, Any] = {}
    for kind_name in sorted({n.profile for n in scenario.nodes}):
        mod = importlib.import_module(profile_kind(kind_name).build.__module__)
        for name, layer in getattr(mod, "PLOTS", {}).items():
            out[name] = with_layer(layer)
    return out


def register(sub: Any) -> None:
    """Add the `experiment` subcommand."""
    p = sub.add_parser(
        "experiment",
        help="run a scheduling scenario (TOML) and compare it with the response-time analysis",
        description="Run a scenario file's nodes and profiles on the simulated bus (or on a python-can bus with "
        "--interface/--channel) and print, per message, the measured response times, jitter and deadline misses "
        "beside the worst case of the CAN schedulability analysis (Davis et al. 2007).",
    )
    p.add_argument("scenario", help="the scenario file (TOML; see examples/*.toml)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    p.add_argument("--out", help="also write the JSON result to this file")
    p.add_argument(
        "--plot",
        metavar="DIR",
        help="write timeline.png, response_times.png, bus_load.png here (needs the plot extra; on a python-can "
        "bus drawn from the frames a monitor received)",
    )
    p.add_argument(
        "--trace",
        metavar="FILE",
        help="write the bus trace (.asc, .blf, .log, .csv, .trc, .mf4; timestamps in seconds of bus time from the "
        "start of the run; on a python-can bus what a monitor received, written as the run goes)",
    )
    p.add_argument(
        "--duration", type=seconds_type(1e6), help="run this many seconds instead of the scenario's [bus] duration"
    )
    p.add_argument(
        "--progress",
        action="store_true",
        default=None,
        help="draw a progress bar (default: on a terminal, for runs over 2 s)",
    )
    p.add_argument("--interface", help="run on this python-can interface (socketcan, virtual, canstack, ...)")
    p.add_argument("--channel", help="the python-can channel (vcan0, tcp://127.0.0.1:PORT/bus0, ...)")
    p.set_defaults(func=_experiment)
