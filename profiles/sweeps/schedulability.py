"""The classic studies, built in: schedulability against utilisation (analysis and simulation;
priority against FIFO queues), and one message set under each scheduling profile.

**Random message sets** (`generate_set`). Deadlines equal periods, identifiers are distinct random
11-bit values (priority by identifier, as CAN arbitrates) handed out in deadline-monotonic order
unless ``priorities="random"``, DLCs uniform in 0..8, messages dealt
to nodes ``per_node`` at a time in random order. The utilisation U counts worst-case frames
(Davis et al. 2007, eq. 1). Two generators, because on CAN the two usual ingredients cannot both
hold: a frame's transmission time is fixed by its DLC (55 to 135 bit times, standard
identifiers), so once a UUniFast share u_i and a log-uniform period T_i are drawn, C_i = u_i T_i
is almost never the length of any frame.

- ``uunifast`` (default): UUniFast (Bini and Buttazzo, "Measuring the performance of
  schedulability tests", Real-Time Systems 30, 2005) splits U into u_1..u_n without bias; each
  message's period follows from its frame, T_i = C_i / u_i, on the bus's fixed bit rate. A set
  with a period outside ``period_range_ms`` is drawn again (UUniFast-Discard), so the range
  bounds the periods; they are not log-uniform in it.
- ``loguniform``: periods log-uniform in ``period_range_ms`` (Emberson, Stafford, Davis 2010);
  the bit rate of the set is then the one that makes its utilisation U (b = Σ bits_i / T_i / U),
  which is how a fixed set of periods and frames reaches a given load.

The same set number draws the same random numbers at every utilisation (common random numbers):
with ``uunifast`` a set at a higher U is the same set with shorter periods, so the curves differ
between points by the utilisation, not by sampling noise.

**Schedulability** (`schedulability_study`). For each utilisation point and each set: does the
response-time analysis (`profiles.analysis.rta.analyse`, via the experiments' own
`profiles.metrics.analyse_scenario`) guarantee every message, and does a simulation with
priority queues, and one with FIFO queues, see no deadline miss? Release is synchronous (every
offset 0): that is the analysis' critical instant, less only the blocking by a lower-priority
frame already on the bus, which a simulation that starts on an idle bus cannot have. So the
simulated no-miss fraction is an upper bound the analysis' fraction must stay under (the analysis
is sufficient), and a set the analysis accepts must show no miss. The simulation runs twice the
longest period, which holds every message's first deadline. FIFO queues cannot be analysed that
way (priority inversion); their curve is the simulation's only.

The *breakdown utilisation* of a curve, marked on the plots, is where it falls through 50 % of
the sets (linear between the two points around it).

**Profiles** (`profiles_study`). One message set expressed in each registered profile
(`profiles.registry.profile_kinds`) that knows how: a *converter* takes the `MessageSet` and
returns a scenario dictionary (what a TOML file reads as) in that profile's terms. CSMA/CR's is
`csma_scenario`. Another profile provides its own in one of two ways:

- a module-level function ``express_message_set(mset: MessageSet) -> dict`` in the profile's module
  (the module of its ``ProfileKind.build``; found the way the experiment command finds a module's
  ``PLOTS``), or
- ``register_converter("name", fn)`` from anywhere imported before the study runs.

The scenario it returns keeps every message's ``name`` (the table lines up by name), runs on the
set's ``bitrate`` for ``duration_s`` with ``seed``, and may add its own nodes (a master, a time
master) and tables (a schedule). The study reports per message the worst response, the
start-to-start jitter and the deadline misses, the bus load, and the profile's own figures.
"""

from __future__ import annotations

import importlib
import math
import random
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from profiles.analysis.rta import MessageSpec, frame_bits_worst
from profiles.execute import execute
from profiles.registry import profile_kind, profile_kinds
from profiles.sweep import run_seed

__all__ = [
    "StudyMessage",
    "MessageSet",
    "uunifast",
    "generate_set",
    "GENERATORS",
    "PRIORITIES",
    "SchedTask",
    "schedulability_run",
    "schedulability_study",
    "PERIOD_RANGES_MS",
    "SchedulabilityStudy",
    "breakdown",
    "Converter",
    "register_converter",
    "converter_for",
    "csma_scenario",
    "profiles_study",
    "ProfilesStudy",
    "message_set_from_scenario",
    "csma_fifo_scenario",
]

GENERATORS = ("uunifast", "loguniform")
PRIORITIES = ("deadline", "random")
PERIOD_RANGES_MS = {"uunifast": (0.1, 1000.0), "loguniform": (10.0, 1000.0)}
"""Default period ranges (ms). UUniFast-Discard: periods come out at C_i / u_i >= C_i / U, so the
lower bound rarely matters; the upper one keeps sets with a nearly idle message (and a long
simulation) out. Log-uniform: a range whose bit rates stay within 1 kbit/s .. 1 Mbit/s for 10
messages at 10 .. 100 %."""
MAX_DRAWS = 10_000  # UUniFast-Discard: draws before a set is given up on (a range that cannot be met)


@dataclass(frozen=True)
class StudyMessage:
    """One message of a study's set: name, sending node, identifier, DLC, period and deadline
    (integer ns)."""

    name: str
    node: str
    can_id: int
    dlc: int
    period_ns: int
    deadline_ns: int
    extended: bool = False


@dataclass(frozen=True)
class MessageSet:
    """A message set on one bus: bit rate, messages, and how long and with which seed a converter
    should run it."""

    bitrate: int
    messages: tuple[StudyMessage, ...]
    duration_s: float
    seed: int = 0

    @property
    def nodes(self) -> list[str]:
        """The sending nodes, in the order their first message appears."""
        return list(dict.fromkeys(m.node for m in self.messages))

    def specs(self) -> list[MessageSpec]:
        """The set as the response-time analysis models it (worst-case stuffing)."""
        return [MessageSpec(m.name, m.can_id, m.extended, m.dlc, m.period_ns, m.deadline_ns) for m in self.messages]

    def utilisation(self) -> float:
        """Σ C_i / T_i with worst-case frames (eq. 1 of Davis et al. 2007)."""
        return sum(frame_bits_worst(m.dlc, m.extended) * 1e9 / self.bitrate / m.period_ns for m in self.messages)


def uunifast(n: int, total: float, rng: random.Random) -> list[float]:
    """UUniFast (Bini and Buttazzo 2005): ``n`` utilisations summing to ``total``, uniformly
    distributed over that simplex. u_i = s_i − s_{i+1} with s_{i+1} = s_i · r^(1/(n−i)),
    r uniform in [0, 1)."""
    if n < 1:
        raise ValueError(f"uunifast: n {n} must be >= 1")
    out: list[float] = []
    s = total
    for i in range(1, n):
        nxt = s * rng.random() ** (1.0 / (n - i))
        out.append(s - nxt)
        s = nxt
    out.append(s)
    return out


def _skeleton(rng: random.Random, n: int, per_node: int) -> tuple[list[int], list[int], list[str]]:
    """DLCs, distinct identifiers and nodes of ``n`` messages (``per_node`` to a node, dealt in a
    random order)."""
    dlcs = [rng.randint(0, 8) for _ in range(n)]
    ids = rng.sample(range(0x800), n)
    order = list(range(n))
    rng.shuffle(order)
    nodes = [""] * n
    for pos, i in enumerate(order):
        nodes[i] = f"node{pos // per_node + 1}"
    return dlcs, ids, nodes


def generate_set(
    rng: random.Random,
    *,
    messages: int,
    utilisation: float,
    bitrate: int = 500_000,
    per_node: int = 1,
    period_range_ms: tuple[float, float] | None = None,
    generator: str = "uunifast",
    priorities: str = "deadline",
    seed: int = 0,
) -> MessageSet:
    """A random message set of utilisation ``utilisation`` (see the module docstring for the two
    generators). ``priorities``: ``deadline`` hands the random identifiers out in deadline-monotonic
    order (the shortest deadline gets the lowest identifier, the usual CAN assignment), ``random``
    keeps them as drawn (priorities in no relation to the deadlines). Messages are declared node
    by node in a random order (the order a FIFO queue sees them released together). ValueError when the range cannot be met in `MAX_DRAWS` draws or
    the bit rate a ``loguniform`` set needs is outside 1 kbit/s .. 1 Mbit/s."""
    if generator not in GENERATORS:
        raise ValueError(f"generator {generator!r}: one of {', '.join(GENERATORS)}")
    if priorities not in PRIORITIES:
        raise ValueError(f"priorities {priorities!r}: one of {', '.join(PRIORITIES)}")
    if not 0 < utilisation <= 1.5:
        raise ValueError(f"utilisation {utilisation!r}: must be > 0 and at most 1.5")
    if messages < 1 or per_node < 1:
        raise ValueError("a set needs at least one message and one message per node")
    lo_ms, hi_ms = period_range_ms or PERIOD_RANGES_MS[generator]
    if not 0 < lo_ms < hi_ms:
        raise ValueError(f"period range {lo_ms}..{hi_ms} ms: must be 0 < min < max")
    lo, hi = round(lo_ms * 1e6), round(hi_ms * 1e6)
    for _ in range(MAX_DRAWS):
        if generator == "uunifast":
            shares = uunifast(messages, utilisation, rng)
            dlcs, ids, nodes = _skeleton(rng, messages, per_node)
            rate = bitrate
            if min(shares) <= 0:
                continue
            # whole ns, rounded down: the set's utilisation is never below the target (at 100 % a
            # period rounded up would leave a busy period that converges after millions of steps)
            periods = [math.floor(frame_bits_worst(d, False) * 1e9 / rate / u) for d, u in zip(dlcs, shares)]
        else:
            periods = [round(math.exp(rng.uniform(math.log(lo), math.log(hi)))) for _ in range(messages)]
            dlcs, ids, nodes = _skeleton(rng, messages, per_node)
            bits_per_s = sum(frame_bits_worst(d, False) * 1e9 / t for d, t in zip(dlcs, periods))
            rate = math.floor(bits_per_s / utilisation)  # rounded up, the utilisation would fall below U
            if not 1_000 <= rate <= 1_000_000:
                raise ValueError(
                    f"a log-uniform set at U = {utilisation:g} needs {rate:,} bit/s, outside "
                    "1 kbit/s .. 1 Mbit/s: change the period range or the number of messages"
                )
        if all(lo <= t <= hi for t in periods):
            break
    else:
        raise ValueError(
            f"no UUniFast set of {messages} messages at U = {utilisation:g} has every period in "
            f"{lo_ms:g}..{hi_ms:g} ms at {bitrate:,} bit/s ({MAX_DRAWS:,} draws): widen the range"
        )
    if priorities == "deadline":  # deadlines = periods: the shortest period gets the lowest identifier
        by_deadline = sorted(range(messages), key=lambda k: (periods[k], k))
        drawn = sorted(ids)
        for rank, k in enumerate(by_deadline):
            ids[k] = drawn[rank]
    msgs = [StudyMessage(f"m{k + 1:02d}", nodes[k], ids[k], dlcs[k], periods[k], periods[k]) for k in range(messages)]
    msgs.sort(key=lambda m: (int(m.node[4:]), rng.random()))
    longest = max(m.period_ns for m in msgs)
    return MessageSet(rate, tuple(msgs), duration_s=2 * longest / 1e9, seed=seed)


# --- converters: a message set in a profile's terms ----------------------------------------------

Converter = Callable[[MessageSet], dict]
"""``fn(mset) -> dict``: the message set as a scenario dictionary (what `tomllib` gives for a
scenario file) in one profile's terms."""

_CONVERTERS: dict[str, Converter] = {}


def register_converter(profile: str, fn: Converter) -> Converter:
    """Make ``fn`` the way the profiles study expresses a message set in profile ``profile``."""
    _CONVERTERS[profile] = fn
    return fn


def converter_for(profile: str) -> Converter | None:
    """The converter of ``profile``: registered, else the ``express_message_set`` function of
    the profile's module, else None (the study skips the profile and says so)."""
    if profile in _CONVERTERS:
        return _CONVERTERS[profile]
    kind = profile_kinds().get(profile)
    if kind is None:
        return None
    mod = importlib.import_module(kind.build.__module__)
    fn = getattr(mod, "express_message_set", None)
    return fn if callable(fn) else None


def _csma(mset: MessageSet, queue: str) -> dict:
    nodes: dict[str, list[dict[str, Any]]] = {n: [] for n in mset.nodes}
    for m in mset.messages:
        nodes[m.node].append(
            {
                "name": m.name,
                "id": m.can_id,
                "extended": m.extended,
                "dlc": m.dlc,
                "period_ms": m.period_ns / 1e6,
                "deadline_ms": m.deadline_ns / 1e6,
            }
        )
    return {
        "bus": {"bitrate": mset.bitrate, "duration": mset.duration_s, "seed": mset.seed},
        "nodes": [{"name": n, "profile": "csma", "queue": queue, "messages": ms} for n, ms in nodes.items()],
    }


def csma_scenario(mset: MessageSet) -> dict:
    """CSMA/CR's converter: every node sends its messages periodically from offset 0 (all
    released together: the analysis' critical instant) through a priority queue."""
    return _csma(mset, "priority")


def csma_fifo_scenario(mset: MessageSet) -> dict:
    """The same with FIFO transmit queues (a node sends its frames in release order)."""
    return _csma(mset, "fifo")


register_converter("csma", csma_scenario)


def message_set_from_scenario(scenario: Any) -> MessageSet:
    """The periodic and sporadic messages of a checked scenario as a `MessageSet` (a sporadic
    message at its minimum inter-arrival time; messages without either are left out)."""
    msgs = tuple(
        StudyMessage(m.name, m.node, m.can_id, m.dlc, m.interval_ns, m.deadline_ns or m.interval_ns, m.extended)
        for m in scenario.messages
        if m.interval_ns is not None and not m.remote
    )
    if not msgs:
        raise ValueError(f"{scenario.source}: no periodic or sporadic data message to study")
    return MessageSet(scenario.bitrate, msgs, scenario.duration_ns / 1e9, scenario.seed)


# --- schedulability -------------------------------------------------------------------------------


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
    from profiles.runner import run_scenario
    from profiles.scenario import parse_scenario

    res = run_scenario(parse_scenario(raw, source), progress=False)
    if res.interrupted:
        raise KeyboardInterrupt
    return sum(m["deadline_misses"] for m in res.messages)


def schedulability_run(task: SchedTask) -> dict[str, Any]:
    """One set: the analysis' verdict and the simulated deadline misses with priority and with
    FIFO queues (synchronous release; see the module docstring)."""
    from profiles.metrics import analyse_scenario
    from profiles.scenario import parse_scenario

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
    analysis = analyse_scenario(parse_scenario(raw, source))
    results = analysis["results"]
    rta_ok = len(results) == len(mset.messages) and all(r.schedulable for r in results.values())
    prio = _misses(raw, source)
    fifo = _misses(csma_fifo_scenario(mset), source)
    row = task.head()
    row.update(
        {
            "bitrate": mset.bitrate,
            "u_worst": mset.utilisation(),
            "longest_period_ms": max(m.period_ns for m in mset.messages) / 1e6,
            "rta_schedulable": rta_ok,
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


CURVES = {"analysis": "rta_schedulable", "simulation": "sim_priority_ok", "fifo": "sim_fifo_ok"}
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
) -> SchedulabilityStudy:
    """The schedulability study (see the module docstring): ``sets`` random sets at each
    utilisation, each analysed and simulated; the fraction of sets the analysis accepts, and the
    fractions without a simulated miss (priority and FIFO queues), per utilisation."""
    if sets < 1:
        raise ValueError(f"--sets {sets}: at least 1")
    if not utilisations:
        raise ValueError("no utilisation to study")
    for u in utilisations:
        if not 0 < u <= 1.5:
            raise ValueError(f"utilisation {u!r}: must be > 0 and at most 1.5")
    if generator not in GENERATORS:
        raise ValueError(f"--generator {generator!r}: one of {', '.join(GENERATORS)}")
    if priorities not in PRIORITIES:
        raise ValueError(f"--priorities {priorities!r}: one of {', '.join(PRIORITIES)}")
    lo, hi = period_range_ms or PERIOD_RANGES_MS[generator]
    tasks = []
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


# --- profiles ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ProfileTask:
    """One profile's run of the profiles study."""

    index: int
    profile: str
    raw: Mapping[str, Any]

    def head(self) -> dict[str, Any]:
        """run, profile."""
        return {"run": self.index, "profile": self.profile}


def profile_run(task: ProfileTask) -> dict[str, Any]:
    """Run one profile's scenario; the row holds the bus load, per message ``<name>.max_ms``,
    ``.jitter_ms``, ``.misses``, and the profile's own figures (`profiles.sweep.summary_row`)."""
    from profiles.runner import run_scenario
    from profiles.scenario import parse_scenario
    from profiles.sweep import summary_row

    res = run_scenario(parse_scenario(task.raw, f"study profiles ({task.profile})"), progress=False)
    if res.interrupted:
        raise KeyboardInterrupt
    row = task.head()
    row.update(summary_row(res))
    return row


@dataclass
class ProfilesStudy:
    """One row per compared profile (canonical order: by name; profiles that share a converter
    share a row, labelled ``master/slave``), the message set, and the profiles left out with the
    reason."""

    mset: MessageSet
    rows: list[dict[str, Any]]
    skipped: dict[str, str]
    interrupted: bool
    engine: str
    wall_s: float


def profiles_study(
    mset: MessageSet,
    *,
    workers: int = 1,
    scheduler: str | None = None,
    engine: str = "auto",
    progress: bool | None = None,
) -> ProfilesStudy:
    """Run ``mset`` under every registered profile that has a converter (see the module
    docstring) and return their rows side by side. A converter that raises, or a scenario its
    profile refuses, is that profile's row with an ``error``."""
    tasks: list[ProfileTask] = []
    skipped: dict[str, str] = {}
    failed: list[dict[str, Any]] = []
    # profiles of one module (master and slave, canopen and canopen-master) share its converter:
    # one run, labelled with all their names
    groups: dict[Converter, list[str]] = {}
    for name in sorted(profile_kinds()):
        fn = converter_for(name)
        if fn is None:
            mod = profile_kind(name).build.__module__
            skipped[name] = f"no converter ({mod} has no express_message_set)"
            continue
        groups.setdefault(fn, []).append(name)
    for fn, names in groups.items():
        label = "/".join(names)
        try:
            raw = fn(mset)
        except Exception as exc:
            from profiles.execute import error_text

            failed.append({"run": None, "profile": label, "error": f"converter: {error_text(exc)}"})
            continue
        tasks.append(ProfileTask(len(tasks), label, raw))
    ex = execute(
        profile_run, tasks, workers=workers, scheduler=scheduler, engine=engine, progress=progress, desc="profiles"
    )
    rows = ex.rows + failed
    return ProfilesStudy(mset, rows, skipped, ex.interrupted, ex.engine, ex.wall_s)
