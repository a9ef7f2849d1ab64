"""Parameter sweeps: one scenario, some of its keys varied, every combination run (× seeds), one
row of summary metrics per run.

A varied key is a dotted path into the scenario file as TOML reads it: tables by name
(``bus.bitrate``, ``analysis.t_error_ms``), nodes and messages by their ``name``
(``nodes.engine.queue``, ``nodes.engine.messages.EngineData.period_ms``), other lists by index
from 0 (``faults.0.rate``). Values are written as in TOML (``500000``, ``2.5``, ``0x100``,
``true``) or bare words for strings (``fifo``, ``mailboxes:2``); ``START:END:STEP`` is a numeric
range whose END is included when it falls on a step (``5:50:5`` is 5, 10, … 50; ``0:1:0.3`` is 0,
0.3, 0.6, 0.9), computed in decimal so that 0.1 steps land exactly.

Each run changes the scenario's raw TOML dictionary and checks it with the scenario's own schema
(`profiles.pipeline.scenario.parse_scenario`): a value that breaks a rule fails that run only, with the
schema's usual one-line error in the ``error`` column. A key the scenario does not have is refused
before anything runs (`SweepError`).

Runs are independent and deterministic: run k's seed is derived from the sweep seed (the
scenario's ``bus.seed`` unless given) and the run's parameter values and replicate number by
SHA-256 (`run_seed`; never Python's salted ``hash``), so the table is the same whether the runs
went through one process, a process pool or a Dask cluster (`profiles.sweeps.execute`), and rows come in
the canonical order — the cartesian product of the values in the order given, the last key
varying fastest, then the replicates — whatever order they finished in.
"""

from __future__ import annotations

import csv
import hashlib
import itertools
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from decimal import Decimal, InvalidOperation, Overflow, localcontext
from pathlib import Path
from typing import Any

from profiles.declarations import Scenario
from profiles.pipeline.overrides import KeyPathError, apply_values, resolve_key, typed_value
from profiles.pipeline.scenario import parse_scenario
from profiles.sweeps.execute import Execution, execute

__all__ = [
    "SweepError",
    "Vary",
    "parse_vary",
    "parse_values",
    "resolve_vary",
    "run_seed",
    "RunTask",
    "plan_runs",
    "run_one",
    "summary_row",
    "run_sweep",
    "SweepResult",
    "table_columns",
    "write_table",
    "TABLE_SUFFIXES",
    "FIXED_METRICS",
    "MESSAGE_METRICS",
    "MAX_RUNS",
]

MAX_VALUES = 100_000
"""Most values one --vary may expand to: more is a typo in a range (a step in the wrong unit)."""

MAX_RUNS = 1_000_000
"""Most runs one sweep or study plans: more is a typo in a range or a count."""

TABLE_SUFFIXES = (".csv", ".parquet")

FIXED_METRICS = ("bus_load", "frames", "error_frames", "deadline_misses", "worst_misses", "unschedulable")
"""Columns every run has: the bus figures, the deadline misses of all messages (``deadline_misses``)
and of the worst message (``worst_misses``), and how many messages the analysis cannot guarantee
(``unschedulable``; empty where the analysis does not apply)."""

MESSAGE_METRICS = ("max_ms", "mean_ms", "jitter_ms", "misses", "rta_ms")
"""Columns per message, named ``<message>.<metric>``: worst and mean response (release to end of
EOF), start-to-start jitter, deadline misses and the analysis' bound."""


class SweepError(ValueError):
    """A sweep that cannot start: a malformed --vary, an unknown key, a bad range. One line."""


@dataclass(frozen=True)
class Vary:
    """One varied key: the dotted ``key`` as given, its ``values`` (typed once resolved) and the
    concrete ``path`` into the raw scenario (names replaced by list indices)."""

    key: str
    texts: tuple[str, ...]
    values: tuple[Any, ...] = ()
    path: tuple[str | int, ...] = ()


# --- values ------------------------------------------------------------------------------------

_NUMBER = re.compile(r"[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+)?$")


def _decimal(text: str) -> Decimal | None:
    return Decimal(text) if _NUMBER.match(text.strip()) else None


def _range(token: str, key: str) -> list[int | float]:
    """``START:END[:STEP]`` (STEP 1 when left out): START, START+STEP, … up to END, END included
    when it falls on a step. Decimal arithmetic, so 0.1:0.5:0.1 ends on 0.5; integers stay
    integers."""
    parts = token.split(":")
    nums = [_decimal(p) for p in parts]
    if len(parts) not in (2, 3) or any(n is None for n in nums):
        raise SweepError(f"--vary {key}: {token!r} is not a range START:END:STEP of numbers")
    start, end = nums[0], nums[1]
    step = nums[2] if len(parts) == 3 else Decimal(1)
    assert start is not None and end is not None and step is not None
    if step == 0:
        raise SweepError(f"--vary {key}: {token!r}: the step of a range must not be 0")
    try:
        # in a context of its own: a range of 1e1000000 overflows the default one, and the count
        # is compared before it is made an integer (int() of a 10**999999 would take minutes)
        with localcontext() as ctx:
            ctx.traps[InvalidOperation] = True
            if (end - start) * step < 0:
                raise SweepError(f"--vary {key}: {token!r}: a step of {step} never goes from {start} to {end}")
            span = (end - start) / step
            too_many = span >= MAX_VALUES
            counted = f"{int(span) + 1:,}" if too_many and span < 10**15 else f"more than {MAX_VALUES:,}"
    except (Overflow, InvalidOperation):
        too_many, counted = True, f"more than {MAX_VALUES:,}"
    if too_many:
        raise SweepError(f"--vary {key}: {token!r} gives {counted} values (at most {MAX_VALUES:,})")
    count = int(span) + 1
    integral = all("." not in p and "e" not in p.lower() for p in (parts if len(parts) == 3 else parts[:2]))
    out: list[int | float] = []
    for i in range(count):
        v = start + i * step
        out.append(int(v) if integral else float(v))
    return out


def parse_values(text: str, key: str = "KEY") -> list[Any]:
    """The comma-separated values of one --vary, ranges expanded; single values stay text (they
    are typed against the scenario's schema by `resolve_vary`). A token is a range when it holds
    ':' and starts with a number (``mailboxes:2`` stays a word)."""
    if not text.strip():
        raise SweepError(f"--vary {key}: no values after '=' (give V1,V2,… or START:END:STEP)")
    out: list[Any] = []
    for token in text.split(","):
        token = token.strip()
        if not token:
            raise SweepError(f"--vary {key}={text}: an empty value between commas")
        if ":" in token and _decimal(token.split(":", 1)[0]) is not None:
            out.extend(_range(token, key))
        else:
            out.append(token)
    if len(out) > MAX_VALUES:
        raise SweepError(f"--vary {key}: {len(out):,} values (at most {MAX_VALUES:,})")
    return out


def parse_vary(spec: str) -> Vary:
    """``KEY=V1,V2,…`` (see the module docstring) as a `Vary` whose values are not yet typed."""
    key, eq, text = spec.partition("=")
    key = key.strip()
    if not eq or not key:
        raise SweepError(f"--vary {spec!r}: expected KEY=V1,V2,… (e.g. bus.bitrate=250000,500000)")
    if any(c.isspace() for c in key) or any(not part for part in key.split(".")):
        raise SweepError(f"--vary {spec!r}: {key!r} is not a dotted key (e.g. nodes.engine.queue)")
    return Vary(key, tuple(parse_values(text, key)))


# --- keys ----------------------------------------------------------------------------------------


def resolve_vary(raw: Mapping[str, Any], vary: Vary) -> Vary:
    """Find ``vary.key`` in the raw scenario and type its values by the schema
    (`profiles.pipeline.overrides.resolve_key`: every segment but the last must exist, the last
    must be a key the schema allows there). Raises `SweepError` naming the key and what exists
    instead."""
    if vary.key == "bus.seed":
        raise SweepError(
            "--vary bus.seed: each run's seed is derived from the sweep seed and its parameters; "
            "use --seed S for the sweep seed and --seeds N for N seeds per combination"
        )
    try:
        path, types = resolve_key(raw, vary.key, "--vary")
    except KeyPathError as exc:
        raise SweepError(str(exc)) from None
    return Vary(vary.key, vary.texts, tuple(typed_value(v, types) for v in vary.texts), path)


# --- runs --------------------------------------------------------------------------------------


def run_seed(sweep_seed: int, params: Sequence[tuple[str, Any]], replicate: int = 0) -> int:
    """The seed of one run: SHA-256 of the sweep seed, the run's (key, value) pairs in key order and
    its replicate number, first 4 bytes (0 .. 2**32 - 1). Stable across processes, machines and
    Python versions, unlike the salted built-in ``hash``."""
    text = repr((int(sweep_seed), tuple(sorted((str(k), v) for k, v in params)), int(replicate)))
    return int.from_bytes(hashlib.sha256(text.encode()).digest()[:4], "big")


@dataclass(frozen=True)
class RunTask:
    """One run of a sweep, ready to ship to a worker: the base raw scenario, where its varied
    values go, its parameters (key, value), replicate and seed, and its index in canonical order."""

    index: int
    source: str
    raw: Mapping[str, Any]
    paths: tuple[tuple[str | int, ...], ...]
    params: tuple[tuple[str, Any], ...]
    replicate: int
    seed: int

    def head(self) -> dict[str, Any]:
        """The row's first columns: run index, parameters, replicate, seed."""
        row: dict[str, Any] = {"run": self.index}
        row.update(self.params)
        row["replicate"] = self.replicate
        row["seed"] = self.seed
        return row


def plan_runs(
    raw: Mapping[str, Any], source: str, varies: Sequence[Vary], *, seeds: int = 1, sweep_seed: int | None = None
) -> list[RunTask]:
    """The runs of a sweep in canonical order: the cartesian product of the values (the last key
    varying fastest), each with ``seeds`` replicates. ``varies`` must be resolved."""
    if seeds < 1:
        raise SweepError(f"--seeds {seeds}: at least 1")
    keys = [v.key for v in varies]
    dup = next((k for k in keys if keys.count(k) > 1), None)
    if dup is not None:
        raise SweepError(f"--vary {dup}: given twice (give every value in one --vary)")
    if sweep_seed is None:
        bus = raw.get("bus", {})
        sweep_seed = bus.get("seed", 0) if isinstance(bus, Mapping) else 0
        if not isinstance(sweep_seed, int) or isinstance(sweep_seed, bool):
            sweep_seed = 0  # the scenario check reports the bad seed in every run
    total = seeds
    for v in varies:
        total *= len(v.values)
    if total > MAX_RUNS:
        raise SweepError(
            f"the sweep would make {total:,} runs ({' × '.join(str(len(v.values)) for v in varies)}"
            f"{f' × {seeds} seeds' if seeds > 1 else ''}): at most {MAX_RUNS:,}"
        )
    paths = tuple(v.path for v in varies)
    tasks: list[RunTask] = []
    for combo in itertools.product(*(v.values for v in varies)):
        params = tuple(zip(keys, combo))
        for r in range(seeds):
            tasks.append(RunTask(len(tasks), source, raw, paths, params, r, run_seed(sweep_seed, params, r)))
    return tasks


def _flat(prefix: str, value: Any, out: dict[str, Any]) -> None:
    """Nested profile figures as dotted columns; lists as JSON text (a table cell holds one value)."""
    if isinstance(value, Mapping):
        for k, v in value.items():
            _flat(f"{prefix}.{k}", v, out)
    elif isinstance(value, (list, tuple)):
        import json

        out[prefix] = json.dumps(value)
    else:
        out[prefix] = value


def summary_row(result: Any) -> dict[str, Any]:
    """A run's `profiles.pipeline.runner.Result` as table columns (`FIXED_METRICS`, `MESSAGE_METRICS` per
    message, each profile's own figures flattened under its result key, e.g. ``master_slave.cycles``)."""
    msgs = result.messages
    misses = [m["deadline_misses"] for m in msgs]
    applies = result.analysis.get("applies", False)
    row: dict[str, Any] = {
        "bus_load": result.bus_load,
        "frames": result.frames,
        "error_frames": result.error_frames,
        "deadline_misses": sum(misses),
        "worst_misses": max(misses, default=0),
        "unschedulable": sum(1 for m in msgs if m["schedulable"] is False) if applies else None,
    }
    for m in msgs:
        resp = m["response_ms"] or {}
        n = m["name"]
        row[f"{n}.max_ms"] = resp.get("max")
        row[f"{n}.mean_ms"] = resp.get("mean")
        row[f"{n}.jitter_ms"] = m["jitter_ms"]
        row[f"{n}.misses"] = m["deadline_misses"]
        row[f"{n}.rta_ms"] = m["rta_ms"]
    for key, figures in result.profiles.items():
        _flat(key, figures, row)
    return row


def scenario_of(task: RunTask) -> Scenario:
    """The checked scenario of one run: the varied values and the run's seed put into the raw
    dictionary, then the scenario's own checks (`parse_scenario`; a broken rule raises its usual
    `ScenarioError`)."""
    assignments = list(zip(task.paths, (v for _, v in task.params)))
    assignments.append((("bus", "seed"), task.seed))
    return parse_scenario(apply_values(task.raw, assignments), task.source)


def run_one(task: RunTask) -> dict[str, Any]:
    """Run one task of a sweep on the simulated bus and return its row. Errors propagate (the
    executor records them in the row); a run stopped by Ctrl-C raises KeyboardInterrupt, so that
    a partial run never enters the table as if it were complete."""
    from profiles.pipeline.runner import run_scenario

    result = run_scenario(scenario_of(task), progress=False)
    if result.interrupted:
        raise KeyboardInterrupt
    row = task.head()
    for k, v in summary_row(result).items():
        # a profile's figure may have the name of a varied key (tdma.basic_cycle_us): the
        # parameter keeps its column, the figure gets one of its own
        row[f"{k} (result)" if k in row else k] = v
    return row


# --- the sweep -----------------------------------------------------------------------------------


@dataclass
class SweepResult:
    """What a sweep produced: the rows done in canonical order (failed runs included, with their
    ``error``), the varied keys, how many runs were planned, whether Ctrl-C stopped it, and the
    engine that ran it (sequential, processes, dask), its wall time and, of it, the seconds spent
    starting a pool or cluster."""

    rows: list[dict[str, Any]]
    keys: list[str]
    total: int
    interrupted: bool
    engine: str
    wall_s: float
    columns: list[str] = field(default_factory=list)
    startup_s: float = 0.0

    @property
    def failed(self) -> list[dict[str, Any]]:
        """The rows of runs that failed."""
        return [r for r in self.rows if r.get("error")]


def run_sweep(
    raw: Mapping[str, Any],
    source: str,
    varies: Sequence[Vary],
    *,
    seeds: int = 1,
    sweep_seed: int | None = None,
    workers: int = 1,
    scheduler: str | None = None,
    engine: str = "auto",
    progress: bool | None = None,
    time_limit: float | None = None,
) -> SweepResult:
    """Run every combination of the varied values × ``seeds`` (see the module docstring) and
    return the table. ``varies`` are resolved here if they are not yet; ``workers``/``scheduler``/
    ``engine`` choose where the runs go and ``time_limit`` bounds each run's wall-clock time
    (`profiles.sweeps.execute.execute`)."""
    resolved = [v if v.path else resolve_vary(raw, v) for v in varies]
    tasks = plan_runs(raw, source, resolved, seeds=seeds, sweep_seed=sweep_seed)
    ex: Execution = execute(
        run_one,
        tasks,
        workers=workers,
        scheduler=scheduler,
        engine=engine,
        progress=progress,
        desc="sweep",
        time_limit=time_limit,
    )
    keys = [v.key for v in resolved]
    return SweepResult(
        rows=ex.rows,
        keys=keys,
        total=len(tasks),
        interrupted=ex.interrupted,
        engine=ex.engine,
        wall_s=ex.wall_s,
        columns=table_columns(ex.rows, keys),
        startup_s=ex.startup_s,
    )


# --- tables ----------------------------------------------------------------------------------------


def table_columns(rows: Sequence[Mapping[str, Any]], keys: Sequence[str]) -> list[str]:
    """The table's columns: run, the varied keys, replicate, seed, then every metric in the order
    the rows (canonical order) first name them, and ``error`` last."""
    head = ["run", *keys, "replicate", "seed"]
    seen = set(head) | {"error"}
    rest: list[str] = []
    for r in rows:
        for k in r:
            if k not in seen:
                seen.add(k)
                rest.append(k)
    return head + rest + ["error"]


def _cell(v: Any) -> Any:
    if v is None:
        return ""
    if isinstance(v, float) and not math.isfinite(v):
        return repr(v)
    return v


def write_table(rows: Sequence[Mapping[str, Any]], columns: Sequence[str], path: str | Path) -> Path:
    """Write the rows as CSV (empty cells for missing values) or, for a ``.parquet`` path, as
    Parquet with pyarrow (each column one type: booleans, integers, numbers, else text)."""
    p = Path(path)
    if p.suffix.lower() == ".parquet":
        return _write_parquet(rows, columns, p)
    with open(p, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(columns)
        for r in rows:
            w.writerow([_cell(r.get(c)) for c in columns])
    return p


def _column_values(rows: Sequence[Mapping[str, Any]], c: str) -> list[Any]:
    vals = [r.get(c) for r in rows]
    present = [v for v in vals if v is not None]
    if all(isinstance(v, bool) for v in present):
        return vals
    if all(isinstance(v, int) and not isinstance(v, bool) for v in present):
        return vals
    if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in present):
        return [None if v is None else float(v) for v in vals]
    return [None if v is None else str(v) for v in vals]  # a column of mixed kinds: text


def _write_parquet(rows: Sequence[Mapping[str, Any]], columns: Sequence[str], p: Path) -> Path:
    import pyarrow as pa
    import pyarrow.parquet as pq

    arrays = {}
    for c in columns:
        vals = _column_values(rows, c)
        if all(v is None for v in vals):
            arrays[c] = pa.array(vals, type=pa.string())  # an all-empty column (no failures): text
        else:
            arrays[c] = pa.array(vals)
    pq.write_table(pa.table(arrays), p)
    return p
