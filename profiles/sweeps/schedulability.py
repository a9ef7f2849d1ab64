"""The schedulability study: random message sets against utilisation, each analysed and simulated.

For each utilisation point and each set (`schedulability_study`): does the
response-time analysis (`profiles.analysis.rta.analyse`, via the experiments' own
`profiles.pipeline.metrics.analyse_scenario`) guarantee every message with the set's own
identifiers (deadline monotonic, or random with ``priorities="random"``), does it with the
identifiers in Audsley's optimal priority order (`profiles.analysis.priority`: OPA finds an
order the analysis accepts whenever one exists, so its curve is never below the other), does the
FIFO-queue analysis guarantee the set sent from FIFO queues, and does a simulation with priority
queues, and one with FIFO queues, see no deadline miss? Release is synchronous (every offset 0):
that is the analysis' critical instant, less only the blocking by a lower-priority frame already
on the bus, which a simulation that starts on an idle bus cannot have. So the simulated no-miss
fraction is an upper bound the analysis' fraction (with the same identifiers) must stay under
(the analysis is sufficient), and a set the analysis accepts must show no miss. The simulation
runs twice the longest period, which holds every message's first deadline.

The *breakdown utilisation* of a curve, marked on the plots, is where it falls through 50 % of
the sets (linear between the two points around it).

The sets are drawn by `profiles.sweeps.random_sets`; the runs go through `profiles.sweeps.execute`.
"""

from __future__ import annotations

import random
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from profiles.analysis.priority import assign_priorities
from profiles.sweeps.converters import csma_fifo_scenario, csma_scenario
from profiles.sweeps.execute import execute
from profiles.sweeps.random_sets import GENERATORS, PERIOD_RANGES_MS, PRIORITIES, generate_set
from profiles.sweeps.sweep import MAX_RUNS, run_seed

__all__ = [
    "SchedTask",
    "schedulability_run",
    "schedulability_study",
    "SchedulabilityStudy",
    "breakdown",
    "breakdown_text",
    "CURVES",
]


@dataclass(frozen=True)
class SchedTask:
    """One set at one utilisation point of the schedulability study."""

    index: int
    utilisation: float
    set_number: int
    seed: int
    messages: int
    per_node: int
    bitrate: int
    period_range_ms: tuple[float, float]
    generator: str
    priorities: str = "deadline"

    def head(self) -> dict[str, Any]:
        """run, utilisation, set, seed."""
        return {"run": self.index, "utilisation": self.utilisation, "set": self.set_number, "seed": self.seed}


def _misses(raw: dict, source: str) -> int:
    from profiles.pipeline.runner import run_scenario
    from profiles.pipeline.scenario import parse_scenario

    res = run_scenario(parse_scenario(raw, source), progress=False)
    if res.interrupted:
        raise KeyboardInterrupt
    return sum(m["deadline_misses"] for m in res.messages)


def schedulability_run(task: SchedTask) -> dict[str, Any]:
    """One set: the analysis' verdicts (its own identifiers, OPA's order, FIFO queues) and the
    simulated deadline misses with priority and with FIFO queues (synchronous release; see the
    module docstring)."""
    from profiles.pipeline.metrics import analyse_scenario
    from profiles.pipeline.scenario import parse_scenario

    rng = random.Random(task.seed)
    mset = generate_set(
        rng,
        messages=task.messages,
        utilisation=task.utilisation,
        bitrate=task.bitrate,
        per_node=task.per_node,
        period_range_ms=task.period_range_ms,
        generator=task.generator,
        priorities=task.priorities,
        seed=task.seed,
    )
    source = f"study set {task.set_number} at U = {task.utilisation:g}"
    raw = csma_scenario(mset)
    analysis = analyse_scenario(parse_scenario(raw, source), verdict_only=True)
    results = analysis["results"]
    rta_ok = len(results) == len(mset.messages) and all(r.schedulable for r in results.values())
    opa_ok = assign_priorities(mset.specs(), mset.bitrate, order="opa").schedulable
    fifo_raw = csma_fifo_scenario(mset)
    fifo_results = analyse_scenario(parse_scenario(fifo_raw, source), verdict_only=True)["results"]
    fifo_rta_ok = len(fifo_results) == len(mset.messages) and all(r.schedulable for r in fifo_results.values())
    prio = _misses(raw, source)
    fifo = _misses(fifo_raw, source)
    row = task.head()
    row.update(
        {
            "bitrate": mset.bitrate,
            "u_worst": mset.utilisation(),
            "longest_period_ms": max(m.period_ns for m in mset.messages) / 1e6,
            "rta_schedulable": rta_ok,
            "rta_opa_schedulable": opa_ok,
            "rta_fifo_schedulable": fifo_rta_ok,
            "sim_priority_ok": prio == 0,
            "sim_fifo_ok": fifo == 0,
            "priority_misses": prio,
            "fifo_misses": fifo,
        }
    )
    return row


def breakdown(points: Sequence[tuple[float, float]], level: float = 0.5) -> float | None:
    """Where a curve of (utilisation, fraction) falls through ``level``: linear between the last
    point at or above it and the first below. None when it never does, or starts below."""
    prev: tuple[float, float] | None = None
    for u, f in points:
        if f < level:
            if prev is None:
                return None
            (u0, f0) = prev
            return u0 + (u - u0) * (f0 - level) / (f0 - f) if f0 != f else u
        prev = (u, f)
    return None


def breakdown_text(study: SchedulabilityStudy, curve: str) -> str:
    """What a curve's breakdown utilisation is, in words: ``breakdown 71.3 %``, or why it has
    none — below 50 % from the first point, or never below 50 % up to the last."""
    pts = [(p["utilisation"], p[curve]) for p in study.points if p[curve] is not None]
    b = study.breakdown.get(curve)
    if b is not None:
        return f"breakdown {100 * b:.1f} %"
    if not pts:
        return "no sets ran"
    if pts[0][1] < 0.5:
        return f"below 50 % from the first point ({100 * pts[0][0]:g} %)"
    return f"never below 50 % up to {100 * pts[-1][0]:g} %"


@dataclass
class SchedulabilityStudy:
    """Per-set rows (canonical order: utilisation point, then set), per-point fractions, and the
    breakdown utilisation of each curve."""

    rows: list[dict[str, Any]]
    points: list[dict[str, Any]]
    breakdown: dict[str, float | None]
    total: int
    interrupted: bool
    engine: str
    wall_s: float
    settings: dict[str, Any] = field(default_factory=dict)

    @property
    def failed(self) -> list[dict[str, Any]]:
        """Rows of sets that could not be run (their ``error``)."""
        return [r for r in self.rows if r.get("error")]


CURVES = {
    "analysis": "rta_schedulable",
    "opa": "rta_opa_schedulable",
    "simulation": "sim_priority_ok",
    "fifo": "sim_fifo_ok",
    "fifo_analysis": "rta_fifo_schedulable",
}
"""The study's curves and the per-set column each is the fraction of."""


def schedulability_study(
    utilisations: Sequence[float],
    *,
    sets: int = 100,
    messages: int = 10,
    per_node: int = 3,
    bitrate: int = 500_000,
    period_range_ms: tuple[float, float] | None = None,
    generator: str = "uunifast",
    priorities: str = "deadline",
    seed: int = 1,
    workers: int = 1,
    scheduler: str | None = None,
    engine: str = "auto",
    progress: bool | None = None,
    time_limit: float | None = None,
) -> SchedulabilityStudy:
    """The schedulability study (see the module docstring): ``sets`` random sets at each
    utilisation, each analysed and simulated; the fractions of sets the analysis accepts (with
    the set's identifiers, in OPA's order, from FIFO queues) and the fractions without a simulated
    miss (priority and FIFO queues), per utilisation."""
    if sets < 1:
        raise ValueError(f"--sets {sets}: at least 1")
    if not utilisations:
        raise ValueError("no utilisation to study")
    if len(utilisations) * sets > MAX_RUNS:
        raise ValueError(
            f"the study would make {len(utilisations) * sets:,} runs ({len(utilisations)} utilisations × {sets} "
            f"sets): at most {MAX_RUNS:,}"
        )
    for u in utilisations:
        if not 0 < u <= 1.5:
            raise ValueError(f"utilisation {u!r}: must be > 0 and at most 1.5")
    if generator not in GENERATORS:
        raise ValueError(f"--generator {generator!r}: one of {', '.join(GENERATORS)}")
    if priorities not in PRIORITIES:
        raise ValueError(f"--priorities {priorities!r}: one of {', '.join(PRIORITIES)}")
    lo, hi = period_range_ms or PERIOD_RANGES_MS[generator]
    tasks: list[SchedTask] = []
    for u in utilisations:
        for s in range(sets):
            tasks.append(
                SchedTask(
                    len(tasks),
                    float(u),
                    s,
                    run_seed(seed, (("set", s),)),
                    messages,
                    per_node,
                    bitrate,
                    (lo, hi),
                    generator,
                    priorities,
                )
            )
    ex = execute(
        schedulability_run,
        tasks,
        workers=workers,
        scheduler=scheduler,
        engine=engine,
        progress=progress,
        desc="schedulability",
        time_limit=time_limit,
    )
    points = []
    for u in utilisations:
        done = [r for r in ex.rows if r["utilisation"] == float(u) and not r.get("error")]
        p: dict[str, Any] = {"utilisation": float(u), "sets": len(done)}
        for curve, col in CURVES.items():
            p[curve] = sum(1 for r in done if r[col]) / len(done) if done else None
        points.append(p)
    bd = {curve: breakdown([(p["utilisation"], p[curve]) for p in points if p[curve] is not None]) for curve in CURVES}
    settings = {
        "sets": sets,
        "messages": messages,
        "per_node": per_node,
        "bitrate": bitrate,
        "period_range_ms": [lo, hi],
        "generator": generator,
        "priorities": priorities,
        "seed": seed,
        "release": "synchronous (offsets 0)",
    }
    return SchedulabilityStudy(ex.rows, points, bd, len(tasks), ex.interrupted, ex.engine, ex.wall_s, settings)
