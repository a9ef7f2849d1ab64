"""`canstack sweep` and `canstack study`: many runs of scenarios, on every core or a Dask cluster
(registered under the ``canstack.commands`` entry point group).

    canstack sweep SCENARIO.toml --vary KEY=V1,V2,… [--vary …] [--seeds N] [--workers N]
                   [--scheduler tcp://HOST:8786] [--out results.csv|.parquet] [--json] [--plot DIR]
    canstack study schedulability [--sets N] [--utilisation 0.1:1:0.1] [--workers N] [--plot DIR] …
    canstack study profiles [--scenario FILE.toml | --messages N --utilisation U] [--plot DIR] …
    canstack study bounds [--networks N] [--seed S] [--queues …] [--plot FILE] …  (`profiles.sweeps.bounds_cli`)

Everything that can be wrong with the command line — a malformed --vary, a key the scenario does
not have, a bad range, an output the installed libraries cannot write, --scheduler without dask —
is one line on stderr and exit status 2 before any run. Single runs that fail are rows with an
``error``; Ctrl-C keeps the rows done, writes them, and exits with 130.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from profiles.sweeps.options_cli import (
    at_most_type,
    check_before_runs,
    check_engine,
    check_table_output,
    int_type,
    run_options,
    run_settings,
    utilisation_type,
)
from stack.cli import CliError, count_type, parse_bitrate, plural, seconds_type
from stack.cli.runs import check_plot_dir, writing

__all__ = ["register", "register_sweep", "register_study"]

DEFAULT_METRICS = ("worst_misses", "bus_load")

#: exit status when some runs failed (their rows carry the error; the table is written)
FAILED_RUNS = 1


#: the longest period a study draws, ms (an hour: a set with longer periods holds no instance in a run)
MAX_PERIOD_MS = 3_600_000.0
#: the fewest utilisation a random set may have: less makes periods longer than `MAX_PERIOD_MS`
MIN_UTILISATION = 0.001
#: messages in a random set: each needs its own 11-bit identifier
MAX_SET_MESSAGES = 0x800


def _period_range(text: str) -> tuple[float, float]:
    lo, sep, hi = text.partition(",")
    try:
        a, b = float(lo), float(hi)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give MIN,MAX in ms (e.g. 0.1,1000)") from None
    if not sep or not (math.isfinite(a) and math.isfinite(b)) or not 0 < a < b:
        raise argparse.ArgumentTypeError(f"{text!r}: give MIN,MAX in ms with 0 < MIN < MAX (finite numbers)")
    if a < 1e-3 or b > MAX_PERIOD_MS:
        raise argparse.ArgumentTypeError(
            f"{text!r}: periods from 0.001 ms (a microsecond) to {MAX_PERIOD_MS:g} ms (an hour)"
        )
    return a, b


def _common(p: argparse.ArgumentParser) -> None:
    run_options(p)
    p.add_argument("--out", help="write the table here: .csv, or .parquet (the parquet extra)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the text table")
    p.add_argument("--plot", metavar="DIR", help="write the plots into DIR (the plot extra)")


# --- sweep -----------------------------------------------------------------------------------------


def _fmt(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


def _sweep_text(res: Any) -> str:
    keys = res.keys
    head = ["run", *keys, "seed", "load %", "misses", "worst", "error"]
    lines = []
    for r in res.rows:
        load = r.get("bus_load")
        lines.append(
            [
                str(r["run"]),
                *(_fmt(r[k]) for k in keys),
                str(r["seed"]),
                "-" if load is None else f"{100 * load:.1f}",
                _fmt(r.get("deadline_misses")),
                _fmt(r.get("worst_misses")),
                r.get("error") or "",
            ]
        )
    widths = [max(len(h), *(len(line[i]) for line in lines)) if lines else len(h) for i, h in enumerate(head)]
    out = ["  ".join(h.ljust(w) for h, w in zip(head, widths)).rstrip()]
    out += ["  ".join(c.ljust(w) for c, w in zip(line, widths)).rstrip() for line in lines]
    return "\n".join(out)


def _expected_metrics(scenario: Any) -> set[str]:
    from profiles.registry import profile_kind
    from profiles.sweeps.sweep import FIXED_METRICS, MESSAGE_METRICS

    names = set(FIXED_METRICS)
    names.update(f"{m.name}.{x}" for m in scenario.messages for x in MESSAGE_METRICS)
    return names | {profile_kind(n.profile).result_key or "" for n in scenario.nodes} - {""}


def _check_metrics(metrics: Sequence[str], scenario: Any) -> None:
    """Each --metric must be a column the sweep will have (a profile's figures: any under its key)."""
    known = _expected_metrics(scenario)
    example = f", {scenario.messages[0].name}.max_ms" if scenario.messages else ""
    for m in metrics:
        if m not in known and not any(m.startswith(k + ".") for k in known):
            raise CliError(
                f"--metric {m!r}: not a column of this sweep (e.g. bus_load, worst_misses, deadline_misses{example})"
            )


def _sweep(args: argparse.Namespace) -> int:
    from profiles.pipeline.cli import warn
    from profiles.pipeline.examples import scenario_path
    from profiles.pipeline.scenario import load_scenario, parse_scenario
    from profiles.sweeps.sweep import parse_vary, resolve_vary, run_sweep, write_table

    if args.out:
        check_table_output(args.out)
    n_keys = len(args.vary or [])
    if args.plot:
        check_plot_dir(args.plot)
        if not 1 <= n_keys <= 2:
            raise CliError(f"--plot draws one or two varied keys; this sweep varies {n_keys}")
    elif args.metric:
        raise CliError("--metric chooses what --plot draws: give --plot DIR too")
    check_engine(args)
    scenario = load_scenario(scenario_path(args.scenario))
    raw = scenario.raw
    if args.duration is not None:
        raw = dict(raw, bus=dict(raw["bus"], duration=args.duration))
        scenario = parse_scenario(raw, scenario.source)  # the scenario's own rule on the duration
    for w in scenario.warnings:
        warn(w)
    varies = [resolve_vary(raw, parse_vary(spec)) for spec in (args.vary or [])]
    metrics = args.metric or list(DEFAULT_METRICS)
    if args.plot:
        _check_metrics(metrics, scenario)
    res = run_sweep(
        raw,
        scenario.source,
        varies,
        seeds=args.seeds,
        sweep_seed=args.seed,
        **run_settings(args),
    )
    if args.out:
        writing(args.out, "--out", lambda: write_table(res.rows, res.columns, args.out))
    if args.json:
        print(
            json.dumps(
                {
                    "scenario": scenario.source,
                    "seed": scenario.seed if args.seed is None else args.seed,
                    "vary": {v.key: list(v.values) for v in varies},
                    "seeds": args.seeds,
                    "runs": res.total,
                    "done": len(res.rows),
                    "failed": len(res.failed),
                    "interrupted": res.interrupted,
                    "engine": res.engine,
                    "columns": res.columns,
                    "rows": res.rows,
                }
            )
        )
    else:
        print(_sweep_text(res))
    if args.plot and res.rows:
        from profiles.sweeps.plots import write_sweep_plots

        files = write_sweep_plots(res.rows, res.keys, metrics, args.plot, log_x=args.log_x)
        print(f"plots: {', '.join(str(f) for f in files)}", file=sys.stderr)
    _report(res.total, len(res.rows), len(res.failed), res.interrupted, res.engine, res.wall_s, args.out)
    if args.seeds > 1 and not res.interrupted:
        same = _same_replicates(res.rows, res.keys)
        if same:
            warn(
                f"{scenario.source}: every one of the {args.seeds} seeds of each combination gave the same row: "
                "nothing in this scenario is drawn at random (no release jitter, sporadic message, random "
                "processing delay or bit errors), so --seeds adds nothing"
            )
    return _status(res.interrupted, res.failed)


def _status(interrupted: bool, failed: list[dict[str, Any]]) -> int:
    """130 after Ctrl-C, `FAILED_RUNS` when a run failed (its row says why), else 0."""
    if interrupted:
        return 130
    return FAILED_RUNS if failed else 0


def _same_replicates(rows: list[dict[str, Any]], keys: list[str]) -> bool:
    """True when the replicates of every combination gave one and the same row (all columns but
    run, replicate and seed): the scenario drew nothing at random."""
    groups: dict[tuple[str, ...], set[str]] = {}
    for r in rows:
        if r.get("error"):
            return False
        combo = tuple(repr(r.get(k)) for k in keys)
        rest = json.dumps(
            {k: v for k, v in r.items() if k not in ("run", "replicate", "seed")}, sort_keys=True, default=str
        )
        groups.setdefault(combo, set()).add(rest)
    return bool(groups) and all(len(v) == 1 for v in groups.values()) and len(rows) > len(groups)


def _report(total: int, done: int, failed: int, interrupted: bool, engine: str, wall_s: float, out: str | None) -> None:
    parts = [
        f"{done} of {plural(total, 'run')} done" if interrupted else f"{plural(done, 'run')}",
        f"{failed} failed (see the error column)" if failed else "",
        f"{engine}, {wall_s:.1f} s",
        f"written to {out}" if out else "",
    ]
    print(("interrupted: " if interrupted else "") + "; ".join(p for p in parts if p), file=sys.stderr)


def register_sweep(sub: Any) -> None:
    """Add the `sweep` subcommand."""
    p = sub.add_parser(
        "sweep",
        help="run a scenario over every combination of varied keys (× seeds), in parallel",
        description="Vary keys of a scenario file, run every combination (× seeds) on the simulated bus, and print "
        "or write one row of summary metrics per run. KEY is a dotted path into the scenario: bus.bitrate, "
        "nodes.engine.queue, nodes.engine.messages.EngineData.period_ms (nodes and messages by name), faults.0.rate "
        "(lists by index). Values: V1,V2,… as in TOML (bare words are strings), or START:END:STEP ranges (END "
        "included when it falls on a step).",
    )
    p.add_argument("scenario", help="the scenario file (TOML)")
    p.add_argument("--vary", action="append", metavar="KEY=V1,V2,…", help="a key and its values (repeatable)")
    p.add_argument(
        "--seeds",
        type=count_type("the number of seeds"),
        default=1,
        help="runs per combination, each with its own derived seed (default 1)",
    )
    p.add_argument("--seed", type=int_type, help="the sweep seed every run's seed derives from (default: [bus] seed)")
    p.add_argument(
        "--duration", type=seconds_type(1e6), help="simulated seconds of every run instead of [bus] duration"
    )
    p.add_argument(
        "--log-x",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="--plot: the varied key on a logarithmic axis (default: when its values span two decades or more)",
    )
    p.add_argument(
        "--metric",
        action="append",
        metavar="COLUMN",
        help="what --plot draws (repeatable; default worst_misses and bus_load)",
    )
    _common(p)
    p.set_defaults(func=_sweep)


# --- studies ---------------------------------------------------------------------------------------


def _utilisations(text: str) -> list[float]:
    from profiles.sweeps.sweep import SweepError, parse_values

    try:
        vals = parse_values(text, "utilisation")
    except SweepError as exc:
        raise argparse.ArgumentTypeError(str(exc).replace("--vary utilisation: ", "")) from None
    out = []
    for v in vals:
        try:
            f = float(v)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{v!r} is not a utilisation (a fraction, 0.1 for 10 %)") from None
        if not (math.isfinite(f) and MIN_UTILISATION <= f <= 1.5):
            raise argparse.ArgumentTypeError(
                f"{v!r}: a utilisation is from {MIN_UTILISATION:g} to 1.5 (a fraction: 0.5 is 50 %)"
            )
        out.append(f)
    return out


def _study_table(study: Any) -> str:
    order = "DM" if study.settings.get("priorities", "deadline") == "deadline" else "ids"
    lines = [
        f"{'U %':>5} {'sets':>5} {'RTA ' + order + ' %':>11} {'RTA OPA %':>10} {'simulated %':>12} "
        f"{'FIFO RTA %':>11} {'FIFO sim %':>11}"
    ]
    for p in study.points:

        def pct(v: float | None) -> str:
            return "-" if v is None else f"{100 * v:.1f}"

        lines.append(
            f"{100 * p['utilisation']:>5.0f} {p['sets']:>5} {pct(p['analysis']):>11} {pct(p['opa']):>10} "
            f"{pct(p['simulation']):>12} {pct(p['fifo_analysis']):>11} {pct(p['fifo']):>11}"
        )
    from profiles.sweeps.schedulability import breakdown_text

    for curve in study.breakdown:
        lines.append(f"{curve} (where 50 % of the sets stop passing): {breakdown_text(study, curve)}")
    return "\n".join(lines)


def _schedulability(args: argparse.Namespace) -> int:
    from profiles.sweeps.schedulability import schedulability_study
    from profiles.sweeps.sweep import table_columns, write_table

    check_before_runs(args, check_plot_dir)
    study = schedulability_study(
        args.utilisation,
        sets=args.sets,
        messages=args.messages,
        per_node=args.per_node,
        bitrate=args.bitrate,
        period_range_ms=args.period_range,
        generator=args.generator,
        priorities=args.priorities,
        seed=args.seed,
        **run_settings(args),
    )
    if args.out:
        cols = table_columns(study.rows, ["utilisation", "set"])
        writing(args.out, "--out", lambda: write_table(study.rows, cols, args.out))
    if args.json:
        print(
            json.dumps(
                {
                    "study": "schedulability",
                    "settings": study.settings,
                    "points": study.points,
                    "breakdown": study.breakdown,
                    "runs": study.total,
                    "done": len(study.rows),
                    "failed": len(study.failed),
                    "interrupted": study.interrupted,
                    "engine": study.engine,
                }
            )
        )
    else:
        print(_study_table(study))
        for r in study.failed[:5]:
            print(f"set {r['set']} at U = {r['utilisation']:g} failed: {r['error']}", file=sys.stderr)
    if args.plot and study.rows:
        from profiles.sweeps.plots import schedulability_plot

        d = Path(args.plot)
        d.mkdir(parents=True, exist_ok=True)
        files = [
            schedulability_plot(study, d / "schedulability.png"),
            schedulability_plot(
                study,
                d / "fifo_vs_priority.png",
                curves=("simulation", "fifo", "fifo_analysis"),
                title="priority inversion: FIFO against priority transmit queues "
                f"({study.settings['per_node']} messages per node)",
            ),
        ]
        print(f"plots: {', '.join(str(f) for f in files)}", file=sys.stderr)
    _report(study.total, len(study.rows), len(study.failed), study.interrupted, study.engine, study.wall_s, args.out)
    return _status(study.interrupted, study.failed)


def _profiles_table(study: Any) -> str:
    from profiles.text import id_text, table

    rows = [r for r in study.rows if not r.get("error")]
    body = []
    for m in sorted(study.mset.messages, key=lambda m: (m.extended, m.can_id)):  # priority order
        cells = []
        for r in rows:
            mx, jt, ms = r.get(f"{m.name}.max_ms"), r.get(f"{m.name}.jitter_ms"), r.get(f"{m.name}.misses")
            cells.append(f"{_fmt3(mx)} / {_fmt3(jt)} / {'-' if ms is None else ms}")
        body.append([m.name, id_text(m.can_id, m.extended), f"{m.period_ns / 1e6:.3f}", *cells])
    body.append(["bus load %", "", "", *(f"{100 * r['bus_load']:.1f}" for r in rows)])
    body.append(["deadline misses", "", "", *(str(r["deadline_misses"]) for r in rows)])
    lines = ["per profile: worst response / start-to-start jitter / deadline misses (ms)"]
    lines += table(["message", "ID", "period ms", *(r["profile"] for r in rows)], body, left=1, widest={0: 24})
    for r in study.rows:
        if r.get("error"):
            lines.append(f"{r['profile']}: failed: {r['error']}")
    for name, why in study.skipped.items():
        lines.append(f"{name}: not compared: {why}")
    return "\n".join(lines)


def _fmt3(v: float | None) -> str:
    return "-" if v is None else f"{v:.3f}"


def _profiles(args: argparse.Namespace) -> int:
    import random

    from profiles.sweeps.comparison import profiles_study
    from profiles.sweeps.converters import message_set_from_scenario
    from profiles.sweeps.random_sets import generate_set
    from profiles.sweeps.sweep import run_seed, table_columns, write_table

    check_before_runs(args, check_plot_dir)
    if args.scenario:
        from profiles.pipeline.examples import scenario_path
        from profiles.pipeline.scenario import load_scenario

        mset = message_set_from_scenario(load_scenario(scenario_path(args.scenario)))
    else:
        seed = run_seed(args.seed, (("set", 0),))
        mset = generate_set(
            random.Random(seed),
            messages=args.messages,
            utilisation=args.utilisation,
            bitrate=args.bitrate,
            per_node=args.per_node,
            period_range_ms=args.period_range,
            generator=args.generator,
            priorities=args.priorities,
            seed=seed,
        )
        if args.duration is None:  # enough instances for a jitter: ten of the longest period, at least 1 s
            longest = max(m.period_ns for m in mset.messages) / 1e9
            mset = dataclasses.replace(mset, duration_s=min(60.0, max(1.0, 10 * longest)))
    if args.duration is not None:  # the set as it was (the data bit rate of an FD scenario too)
        mset = dataclasses.replace(mset, duration_s=args.duration)
    study = profiles_study(
        mset,
        **run_settings(args),
    )
    if args.out:
        cols = table_columns(study.rows, ["profile"])
        cols.remove("replicate")
        cols.remove("seed")
        writing(args.out, "--out", lambda: write_table(study.rows, cols, args.out))
    if args.json:
        print(
            json.dumps(
                {
                    "study": "profiles",
                    "bitrate": mset.bitrate,
                    "data_bitrate": mset.data_bitrate,
                    "duration": mset.duration_s,
                    "messages": [
                        {
                            "name": m.name,
                            "node": m.node,
                            "id": m.can_id,
                            "dlc": m.dlc,
                            "fd": m.fd,
                            "brs": m.brs,
                            "period_ms": m.period_ns / 1e6,
                            "deadline_ms": m.deadline_ns / 1e6,
                        }
                        for m in mset.messages
                    ],
                    "rows": study.rows,
                    "skipped": study.skipped,
                    "interrupted": study.interrupted,
                }
            )
        )
    else:
        print(_profiles_table(study))
    if args.plot and study.rows:
        from profiles.sweeps.plots import profiles_plot

        d = Path(args.plot)
        d.mkdir(parents=True, exist_ok=True)
        print(f"plots: {profiles_plot(study, d / 'profiles.png')}", file=sys.stderr)
    failed = [r for r in study.rows if r.get("error")]
    for r in failed:
        print(f"canstack: {r['profile']}: failed: {r['error']}", file=sys.stderr)
    return _status(study.interrupted, failed)


def _set_options(p: argparse.ArgumentParser, *, messages: int, per_node: int) -> None:
    p.add_argument(
        "--messages",
        type=at_most_type("messages per set (each has its own 11-bit identifier)", MAX_SET_MESSAGES),
        default=messages,
        help=f"messages per set (default {messages}, at most {MAX_SET_MESSAGES})",
    )
    p.add_argument(
        "--per-node",
        type=at_most_type("messages per node", MAX_SET_MESSAGES),
        default=per_node,
        help=f"messages per node (default {per_node})",
    )
    p.add_argument(
        "--bitrate",
        type=parse_bitrate,
        default=500_000,
        help="bit/s (default 500000; the loguniform generator chooses its own)",
    )
    p.add_argument(
        "--period-range",
        type=_period_range,
        metavar="MIN,MAX",
        help="periods in ms: the bound of UUniFast-Discard (default 0.1,1000), or the log-uniform range "
        "(default 10,1000)",
    )
    p.add_argument(
        "--generator",
        choices=("uunifast", "loguniform"),
        default="uunifast",
        help="uunifast: UUniFast shares, periods from the frames; loguniform: log-uniform periods, "
        "the bit rate from the utilisation",
    )
    p.add_argument(
        "--priorities",
        choices=("deadline", "random"),
        default="deadline",
        help="deadline: identifiers in deadline-monotonic order (default); random: as drawn",
    )
    p.add_argument("--seed", type=int_type, default=1, help="the study seed (default 1)")


def register_study(sub: Any) -> None:
    """Add the `study` subcommand (`study schedulability`, `study profiles`, `study bounds`)."""
    p = sub.add_parser(
        "study",
        help="the classic studies: schedulability against utilisation; profiles side by side; the analysis' "
        "bounds against simulation",
        description="Built-in studies over many runs.",
    )
    studies = p.add_subparsers(dest="study", metavar="STUDY", parser_class=type(p))
    studies.required = True
    s = studies.add_parser(
        "schedulability",
        help="fraction of random message sets the analysis guarantees (DM and OPA priority orders) / the "
        "simulation meets, against utilisation; FIFO against priority queues",
        description="Random message sets (UUniFast shares or log-uniform periods, deadlines = periods, random "
        "DLCs and identifiers, priority by identifier) at each utilisation: the fraction the response-time "
        "analysis (Davis et al. 2007) deems schedulable with the sets' identifiers (deadline monotonic) and with "
        "Audsley's optimal priority order (OPA), the fraction the FIFO-queue analysis does, and the fractions "
        "with no deadline miss in simulation (synchronous release) with priority and with FIFO transmit queues.",
    )
    s.add_argument(
        "--utilisation",
        type=_utilisations,
        default=_utilisations("0.1:1.0:0.1"),
        metavar="U1,U2|A:B:S",
        help="utilisation points, fractions (default 0.1:1.0:0.1, i.e. 10 %% .. 100 %%)",
    )
    s.add_argument(
        "--sets", type=at_most_type("sets per point", 100_000), default=100, help="sets per point (default 100)"
    )
    _set_options(s, messages=10, per_node=3)
    _common(s)
    s.set_defaults(func=_schedulability)
    q = studies.add_parser(
        "profiles",
        help="one message set under every profile that can express it: worst latency, jitter, load",
        description="Run one message set under CSMA/CR and every other registered profile that provides a "
        "converter (express_message_set), and compare worst-case latency, jitter and bus load.",
    )
    q.add_argument("--scenario", help="take the message set from this scenario file (default: a random set)")
    q.add_argument(
        "--utilisation",
        type=utilisation_type(MIN_UTILISATION),
        default=0.5,
        help="utilisation of the random set (default 0.5)",
    )
    q.add_argument(
        "--duration",
        type=seconds_type(1e6),
        help="simulated seconds (default: ten of the longest periods, at least 1 s; or the scenario's)",
    )
    _set_options(q, messages=8, per_node=2)
    _common(q)
    q.set_defaults(func=_profiles)
    from profiles.sweeps.bounds_cli import register_bounds

    register_bounds(studies)


def register(sub: Any) -> None:
    """Add both subcommands (`sweep` and `study`)."""
    register_sweep(sub)
    register_study(sub)
