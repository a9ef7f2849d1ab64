"""`canstack experiment SCENARIO.toml`: run a scheduling scenario and print its metrics beside the
response-time analysis (registered under the ``canstack.commands`` entry point group).

Every output named on the command line is checked before the run (a long run must not end in
an error with nothing written), and written before anything is printed (output piped into
``head`` must not lose a file); overrides (``--seed``, ``--bitrate``, ``--data-bitrate``, ``--duration``, ``--set``)
change the scenario as it was read, and its own checks see the result.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path
from typing import Any

from stack.cli import CliError, parse_bitrate, parse_data_bitrate, seconds_type
from stack.cli.runs import check_output, check_plot_dir, check_trace_output, trace_note, writing

__all__ = ["register", "check_samples_output", "scenario_with_overrides", "add_override_options", "warn"]

#: the longest run the command line asks for: a scenario file's own limit (`profiles.schema.MAX_TIME_S`)
MAX_SECONDS = 1e6


def warn(text: str) -> None:
    """One warning line on stderr (what is allowed but likely a mistake)."""
    print(f"canstack: warning: {text}", file=sys.stderr)


#: --out suffixes: the JSON result, or the message rows as CSV
OUT_SUFFIXES = (".json", ".csv")


def check_samples_output(path: str, option: str = "--samples") -> None:
    """A samples file: .csv, or .parquet with pyarrow installed (the ``parquet`` extra), in a
    writable place."""
    import importlib.util

    check_output(path, option)
    suffix = Path(path).suffix.lower()
    if suffix not in (".csv", ".parquet"):
        raise CliError(f"{option} {path!r}: write .csv or .parquet")
    if suffix == ".parquet" and importlib.util.find_spec("pyarrow") is None:
        raise CliError(
            f"{option} {path!r}: Parquet needs pyarrow, which is not installed: "
            "pip install 'canstack[parquet]' (or write .csv)"
        )


def scenario_with_overrides(args: argparse.Namespace) -> Any:
    """The scenario file with ``--set KEY=VALUE``, ``--seed``, ``--bitrate``, ``--data-bitrate``
    and ``--duration`` applied to it as read, then checked by its own rules (a value that breaks one is named as the
    file's own would be)."""
    from profiles.pipeline.examples import scenario_path
    from profiles.pipeline.overrides import KeyPathError, override
    from profiles.pipeline.scenario import parse_scenario, read_toml
    from profiles.schema import ScenarioError

    path = scenario_path(args.scenario)
    raw = read_toml(path)
    specs = list(args.set or [])
    for option, key in (
        ("seed", "bus.seed"),
        ("bitrate", "bus.bitrate"),
        ("data_bitrate", "bus.data_bitrate"),
        ("duration", "bus.duration"),
    ):
        value = getattr(args, option, None)
        if value is not None:
            if any(s.partition("=")[0].strip() == key for s in specs):
                raise CliError(f"--{option.replace('_', '-')} and --set {key}=... both given: give one")
            specs.append(f"{key}={value!r}")
    try:
        scenario = parse_scenario(raw, str(path))
    except ScenarioError as exc:
        if not specs:
            raise
        # a file complete only with its overrides (FD messages, and --data-bitrate for the bus):
        # the changed scenario is checked, and its first broken rule reported
        try:
            changed = override(raw, specs)
        except KeyPathError:
            raise
        except Exception:  # a file too broken to find the keys in: its own first error
            raise exc from None
        return parse_scenario(changed, str(path))
    if not specs:
        return scenario
    return parse_scenario(override(scenario.raw, specs), scenario.source)


def _check_outputs(args: argparse.Namespace) -> None:
    if args.plot:
        check_plot_dir(args.plot)
    if args.out:
        check_output(args.out, "--out")
        if Path(args.out).suffix.lower() not in OUT_SUFFIXES:
            raise CliError(f"--out {args.out!r}: write .json (the result) or .csv (one row per message)")
    if args.trace:
        check_trace_output(args.trace)
    if args.samples:
        check_samples_output(args.samples)
    if (args.interface is None) != (args.channel is None):
        raise CliError("--interface and --channel go together (a python-can bus), or neither (the simulated bus)")
    if args.interface and args.samples:
        raise CliError("--samples needs the simulated bus (a python-can run writes --trace, not samples)")


def _experiment(args: argparse.Namespace) -> int:
    from profiles.pipeline.metrics import format_table
    from profiles.pipeline.runner import run_on_pycan, run_scenario

    _check_outputs(args)
    scenario = scenario_with_overrides(args)
    for w in scenario.warnings:
        warn(w)
    if args.interface:
        result = run_on_pycan(
            scenario, args.interface, args.channel, duration_s=args.duration, trace=args.trace, plot=bool(args.plot)
        )
    else:
        result = run_scenario(
            scenario, plot=bool(args.plot), progress=args.progress, trace=args.trace, samples=args.samples
        )
    data = result.to_json()
    # the files first: a reader that closes stdout early (| head) must not cost one of them; one
    # that cannot be written is reported after the table, which is printed all the same
    files: list[str] = []
    failure: CliError | None = None
    try:
        if args.out:
            writing(args.out, "--out", lambda: _write_out(args.out, data))
        if args.plot:
            from profiles.pipeline.plots import write_plots

            # a python-can run has the frames the monitor received, not the simulation's layers
            extra = None if args.interface else _profile_plots(scenario)
            written = writing(args.plot, "--plot", lambda: write_plots(result, args.plot, extra=extra))
            files.append(f"plots: {', '.join(str(f) for f in written)}")
    except CliError as exc:
        failure = exc
    for kind, what in (("trace", "record"), ("samples", "instance")):
        f = result.files.get(kind)
        if f is not None and f.get("error") and failure is None:
            failure = CliError(f"--{kind} {f['path']!r}: cannot write: {f['error']}")
        elif f is not None:
            n = f["records"] if kind == "trace" else f["rows"]
            note = trace_note(f["path"], f["left_out"]) if kind == "trace" else ""
            files.append(f"{kind}: {n:,} {what}{'' if n == 1 else 's'} written to {f['path']}{note}")
    print(json.dumps(data, indent=2) if args.json else format_table(data))
    for line in files:
        print(line, file=sys.stderr)
    if failure is not None:
        raise failure
    if result.lost is not None:
        print(
            f"canstack experiment: {result.lost.describe()}; the results so far are marked interrupted",
            file=sys.stderr,
        )
        return 1
    if result.interrupted:
        print(f"canstack: interrupted at {result.duration_s:.6g} s: the results so far", file=sys.stderr)
        return 130
    return 0


def _write_out(path: str, data: dict[str, Any]) -> None:
    if Path(path).suffix.lower() == ".csv":
        from profiles.pipeline.metrics import message_csv_rows

        with open(path, "w", newline="", encoding="utf-8") as f:
            csv.writer(f).writerows(message_csv_rows(data))
    else:
        Path(path).write_text(json.dumps(data, indent=2) + "\n")


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


def add_override_options(p: argparse.ArgumentParser, *, duration: bool = True) -> None:
    """--seed, --bitrate, --data-bitrate, --set (and --duration): a scenario changed on the
    command line, as `scenario_with_overrides` applies them."""
    if duration:
        p.add_argument(
            "--duration",
            type=seconds_type(MAX_SECONDS),
            help="run this many simulated seconds instead of the scenario's [bus] duration",
        )
    p.add_argument("--seed", type=int, help="the scenario's [bus] seed instead (jitter, sporadic releases, bit errors)")
    p.add_argument("--bitrate", type=parse_bitrate, help="the scenario's [bus] bitrate instead (bit/s)")
    p.add_argument(
        "--data-bitrate",
        type=parse_data_bitrate,
        help="the scenario's [bus] data_bitrate instead (bit/s of the CAN FD data phase: makes the bus a CAN FD bus)",
    )
    p.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help="set a key of the scenario (repeatable): the keys of sweep --vary, e.g. "
        "nodes.engine.queue=fifo or nodes.engine.messages.EngineData.period_ms=5",
    )


def register(sub: Any) -> None:
    """Add the `experiment` subcommand."""
    p = sub.add_parser(
        "experiment",
        help="run a scheduling scenario (TOML) and compare it with the response-time analysis",
        description="Run a scenario file's nodes and profiles on the simulated bus (or on a python-can bus with "
        "--interface/--channel) and print, per message, the measured response times, jitter and deadline misses "
        "beside the worst case of the CAN schedulability analysis (Davis et al. 2007). Memory stays bounded "
        "however long the run; Ctrl-C (or SIGTERM) stops it and prints the results so far.",
    )
    p.add_argument("scenario", help="the scenario file (TOML; see canstack examples)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    p.add_argument("--out", help="also write the result to this file: .json (the JSON object) or .csv (the messages)")
    p.add_argument(
        "--plot",
        metavar="DIR",
        help="write timeline.png, response_times.png, response_cdf.png, bus_load.png here (created; the plot "
        "extra; on a python-can bus drawn from the frames a monitor received)",
    )
    p.add_argument(
        "--trace",
        metavar="FILE",
        help="write the bus trace, streamed as the run goes (.asc, .blf, .log, .csv, .trc, .mf4; timestamps in "
        "seconds of bus time from the start of the run; on a python-can bus what a monitor received; .mf4 needs "
        "the mf4 extra, .trc holds no remote or error frames)",
    )
    p.add_argument(
        "--samples",
        metavar="FILE",
        help="write every instance of every message (.csv, or .parquet with the parquet extra): message, node, "
        "outcome, nominal release, queued, SOF, EOF, response, missed; makes the p99 exact",
    )
    add_override_options(p)
    p.add_argument(
        "--progress",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="progress bar with the time left on stderr (default: on a terminal, for runs over 2 s)",
    )
    p.add_argument("--interface", help="run on this python-can interface (socketcan, virtual, canstack, ...)")
    p.add_argument("--channel", help="the python-can channel (vcan0, tcp://127.0.0.1:PORT/bus0, ...)")
    p.set_defaults(func=_experiment)
