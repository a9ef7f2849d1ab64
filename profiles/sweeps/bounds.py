"""The bounds study: how tight the response-time analysis' bounds are on random networks, and
that the simulated bus never exceeds them.

Each of N random networks (`profiles.sweeps.networks.random_network`, network i drawn from a
seed derived from the study seed and i, so that it is the same network whatever N) is analysed
by `profiles.analysis.rta.analyse` and simulated once in each release pattern
(`profiles.sweeps.releases.PATTERNS`); with ``fd`` the networks are CAN FD ones
(`profiles.sweeps.networks.FD_NETWORKS`). Per message, the worst measured time over the patterns is
set against the analysis:

- from queuing to the end of EOF against ``bound_ns`` (queuing to the end of the frame's
  intermission, 3 bit times later: a ratio just under 1 is a bound reached);
- from the nominal release to the end of EOF against ``response_ns`` (R_m);
- a simulated deadline miss (an instance ending more than D after its nominal release) against
  ``schedulable``: the analysis must have predicted it.

A measured time above its bound, or a miss the analysis did not predict, is a *defect* (of the
analysis, or of the simulation): the study keeps the network, the pattern and the simulation seed
that show it, so that `measure` on them shows it again. An error frame on a network without an
error model is neither: the run left what the analysis assumes (`ModelAssumptionError`), and the
network is reported as failed. The tightness per analysis method
(``davis2007`` for priority queues, ``fifo``, ``mailbox``: `profiles.analysis.rta` says which
bounds are quoted from Davis et al. 2007 and which are derived there) is summarised as the
maximum, median and 10th percentile of measured/bound over the messages with a bound.
"""

from __future__ import annotations

import random
import statistics
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from profiles.analysis.rta import analyse
from profiles.sweeps.execute import execute
from profiles.sweeps.networks import DATA_RATIOS, DEFAULT_QUEUES, FD_NETWORKS, Network, queue_mix_text, random_network
from profiles.sweeps.releases import PATTERNS, ModelAssumptionError, run_network
from profiles.sweeps.sweep import MAX_RUNS, run_seed
from stack.controller.node import TOLERANT

__all__ = [
    "METHODS",
    "BoundsTask",
    "BoundsStudy",
    "measure",
    "bounds_run",
    "bounds_study",
    "summarise",
    "frames",
    "bounds_table",
    "bounds_json",
    "defect_text",
    "bounds_plot",
    "parse_patterns",
]

METHODS = ("davis2007", "fifo", "mailbox")
"""The analysis methods, as ``RtaResult.method`` names them."""

#: what a defect is about: the time from queuing, from the nominal release, or a deadline miss
QUEUING, NOMINAL, MISS = "queuing", "nominal", "miss"
_DEFECT_WORDS = {
    QUEUING: "from queuing to the end of EOF {measured:.10g} ns > bound_ns {bound:.10g} ns",
    NOMINAL: "from the nominal release to the end of EOF {measured:.10g} ns > response_ns {bound:.10g} ns",
    MISS: "{measured} simulated deadline misses, but the analysis says schedulable (R = {bound:.10g} ns <= D)",
}


def parse_patterns(text: str) -> tuple[str, ...]:
    """``P1,P2,…`` of `profiles.sweeps.releases.PATTERNS` (``all`` for every one); ValueError
    naming an unknown one."""
    if text.strip() == "all":
        return tuple(PATTERNS)
    out: list[str] = []
    for p in (s.strip() for s in text.split(",")):
        if p not in PATTERNS:
            raise ValueError(f"{p!r}: a release pattern is one of {', '.join(PATTERNS)} (or all)")
        if p not in out:
            out.append(p)
    return tuple(out)


def measure(
    net: Network, patterns: Sequence[str], seed: int, *, network: int = 0
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Analyse ``net``, simulate it in each of ``patterns`` (the simulation seed of pattern p is
    `run_seed`(``seed``, p)), and return (one row per message, the defects found); see the module
    docstring. ``network`` numbers the rows and defects. `ModelAssumptionError` when a run without
    an error model saw an error frame."""
    res = analyse(net.specs(), net.bitrate, queues=net.queues(), errors=net.errors, data_bitrate=net.data_bitrate)
    worst: dict[str, dict[str, Any]] = {
        m.name: {"queued_ns": 0, "queued_pattern": None, "nominal_ns": 0, "nominal_pattern": None, "sent": 0}
        for m in net.messages
    }
    misses: dict[str, list[tuple[str, int, int]]] = {m.name: [] for m in net.messages}
    seeds = {p: run_seed(seed, (("pattern", p),)) for p in patterns}
    for p in patterns:
        run = run_network(net, p, seeds[p])
        if net.errors is None and run.error_frames:
            raise ModelAssumptionError(
                f"{net.label or 'network'}: {run.error_frames} error frames in pattern {p} (simulation seed "
                f"{seeds[p]}) on a bus without an error model: the analysis assumes none"
            )
        for name, got in run.measured.items():
            w = worst[name]
            if got.queued > w["queued_ns"] or w["queued_pattern"] is None:
                w["queued_ns"], w["queued_pattern"] = got.queued, p
            if got.nominal > w["nominal_ns"] or w["nominal_pattern"] is None:
                w["nominal_ns"], w["nominal_pattern"] = got.nominal, p
            w["sent"] += got.sent
            if got.misses:
                misses[name].append((p, seeds[p], got.misses))
    rows: list[dict[str, Any]] = []
    defects: list[dict[str, Any]] = []

    def defect(name: str, method: str, what: str, measured: float, bound: float | None, p: str) -> None:
        defects.append(
            {
                "network": network,
                "message": name,
                "method": method,
                "what": what,
                "measured": measured,
                "bound": bound,
                "pattern": p,
                "simulation_seed": seeds[p],
                "description": net.describe(),
                "definition": net.as_dict(),
            }
        )

    controller = {n.name: n.fd for n in net.nodes}
    for m in net.messages:
        r, w = res[m.name], worst[m.name]
        total_misses = sum(k for _, _, k in misses[m.name])
        row = {
            "network": network,
            "message": m.name,
            "node": m.node,
            "controller": controller[m.node] or ("fd" if net.data_bitrate else "classic"),
            "fd": m.fd,
            "brs": m.brs,
            "bytes": len(m.data),
            "method": r.method,
            "bound_ns": r.bound_ns,
            "response_ns": r.response_ns,
            "deadline_ns": m.deadline_ns,
            "schedulable": r.schedulable,
            **w,
            "misses": total_misses,
            "queued_ratio": None if not r.bound_ns else w["queued_ns"] / r.bound_ns,
            "nominal_ratio": None if not r.response_ns else w["nominal_ns"] / r.response_ns,
        }
        rows.append(row)
        if r.bound_ns is not None and w["queued_ns"] > r.bound_ns:
            defect(m.name, r.method, QUEUING, w["queued_ns"], r.bound_ns, w["queued_pattern"])
        if r.response_ns is not None and w["nominal_ns"] > r.response_ns:
            defect(m.name, r.method, NOMINAL, w["nominal_ns"], r.response_ns, w["nominal_pattern"])
        if total_misses and r.schedulable:
            defect(m.name, r.method, MISS, total_misses, r.response_ns, misses[m.name][0][0])
    return rows, defects


@dataclass(frozen=True)
class BoundsTask:
    """One network of the bounds study."""

    index: int
    seed: int
    max_util: float
    per_node: int
    nodes: int
    queues: tuple[tuple[str, int], ...]
    patterns: tuple[str, ...]
    drift: bool = True
    fd: str | None = None

    def head(self) -> dict[str, Any]:
        """run, network, seed."""
        return {"run": self.index, "network": self.index, "seed": self.seed}

    def network(self) -> Network:
        """The task's network: the same for the same seed and settings."""
        net = random_network(
            random.Random(self.seed),
            max_util=self.max_util,
            drift=self.drift,
            per_node=self.per_node,
            nodes=self.nodes,
            queues=self.queues,
            fd=self.fd,
        )
        net.label = f"network {self.index} (seed {self.seed})"
        return net


def bounds_run(task: BoundsTask) -> dict[str, Any]:
    """One network: its row holds the bit rates, node and message counts, the per-message rows
    (``messages``) and the defects found (``defects``; see `measure`)."""
    net = task.network()
    rows, defects = measure(net, task.patterns, task.seed, network=task.index)
    row = task.head()
    row.update(
        {
            "bitrate": net.bitrate,
            "data_bitrate": net.data_bitrate,
            "nodes": len(net.nodes),
            "tolerant_nodes": sum(1 for n in net.nodes if n.fd == TOLERANT),
            "message_count": len(rows),
            "messages": rows,
            "defects": defects,
        }
    )
    return row


@dataclass
class BoundsStudy:
    """One row per network (canonical order), the settings, and how the runs went."""

    rows: list[dict[str, Any]]
    total: int
    interrupted: bool
    engine: str
    wall_s: float
    settings: dict[str, Any] = field(default_factory=dict)

    @property
    def failed(self) -> list[dict[str, Any]]:
        """Rows of networks that could not be run (their ``error``)."""
        return [r for r in self.rows if r.get("error")]

    @property
    def messages(self) -> list[dict[str, Any]]:
        """Every message's row, network by network."""
        return [m for r in self.rows if not r.get("error") for m in r["messages"]]

    @property
    def defects(self) -> list[dict[str, Any]]:
        """Every defect found (see the module docstring): there must be none."""
        return [d for r in self.rows if not r.get("error") for d in r["defects"]]


def bounds_study(
    networks: int,
    *,
    seed: int = 1,
    max_util: float = 0.85,
    per_node: int = 4,
    nodes: int = 5,
    queues: Sequence[tuple[str, int]] = DEFAULT_QUEUES,
    patterns: Sequence[str] = tuple(PATTERNS),
    drift: bool = True,
    fd: str | None = None,
    workers: int = 1,
    scheduler: str | None = None,
    engine: str = "auto",
    progress: bool | None = None,
    time_limit: float | None = None,
) -> BoundsStudy:
    """The bounds study (see the module docstring) over ``networks`` random networks (CAN FD ones
    of the kind ``fd`` names, `FD_NETWORKS`; classical when None); ValueError for settings out of
    range (before any run)."""
    if not 1 <= networks <= MAX_RUNS:
        raise ValueError(f"--networks {networks}: from 1 to {MAX_RUNS:,}")
    if not patterns or any(p not in PATTERNS for p in patterns):
        raise ValueError(f"patterns {patterns!r}: one or more of {', '.join(PATTERNS)}")
    if fd is not None and fd not in FD_NETWORKS:
        raise ValueError(f"fd {fd!r}: one of {', '.join(FD_NETWORKS)} (None: classical networks)")
    tasks = [
        BoundsTask(
            i,
            run_seed(seed, (("network", i),)),
            float(max_util),
            per_node,
            nodes,
            tuple(queues),
            tuple(patterns),
            drift,
            fd,
        )
        for i in range(networks)
    ]
    tasks[0].network()  # the settings' own errors (ValueError) before any run
    ex = execute(
        bounds_run,
        tasks,
        workers=workers,
        scheduler=scheduler,
        engine=engine,
        progress=progress,
        desc="bounds",
        time_limit=time_limit,
    )
    settings = {
        "networks": networks,
        "seed": seed,
        "max_utilisation": float(max_util),
        "per_node": per_node,
        "nodes": nodes,
        "queues": queue_mix_text(queues),
        "patterns": list(patterns),
        "drift": drift,
        "fd": fd,
    }
    return BoundsStudy(ex.rows, len(tasks), ex.interrupted, ex.engine, ex.wall_s, settings)


def _quantile(sorted_values: Sequence[float], q: float) -> float:
    """The q-quantile, linear between order statistics (numpy's default, `statistics.quantiles`'
    inclusive method)."""
    pos = q * (len(sorted_values) - 1)
    i = int(pos)
    if i + 1 >= len(sorted_values):
        return sorted_values[-1]
    return sorted_values[i] + (sorted_values[i + 1] - sorted_values[i]) * (pos - i)


def _figures(values: list[float]) -> dict[str, float | None]:
    if not values:
        return {"max": None, "median": None, "p10": None}
    v = sorted(values)
    return {"max": v[-1], "median": statistics.median(v), "p10": _quantile(v, 0.1)}


def summarise(messages: Sequence[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per method (`METHODS`, then ``all``): messages, unbounded (no bound), exceeded (measured
    above ``bound_ns`` or ``response_ns``), missed (a simulated deadline miss) and
    unpredicted_misses (a miss on a message the analysis deems schedulable), and the max, median
    and 10th percentile of measured/bound from queuing and from the nominal release."""
    out: dict[str, dict[str, Any]] = {}
    for method in (*METHODS, "all"):
        ms = [m for m in messages if method in ("all", m["method"])]
        out[method] = {
            "messages": len(ms),
            "unbounded": sum(1 for m in ms if m["bound_ns"] is None),
            "exceeded": sum(
                1
                for m in ms
                if (m["bound_ns"] is not None and m["queued_ns"] > m["bound_ns"])
                or (m["response_ns"] is not None and m["nominal_ns"] > m["response_ns"])
            ),
            "missed": sum(1 for m in ms if m["misses"]),
            "unpredicted_misses": sum(1 for m in ms if m["misses"] and m["schedulable"]),
            "queuing": _figures([m["queued_ratio"] for m in ms if m["queued_ratio"] is not None]),
            "nominal": _figures([m["nominal_ratio"] for m in ms if m["nominal_ratio"] is not None]),
        }
    return out


def frames(study: BoundsStudy) -> dict[str, int]:
    """What the study's networks carried: messages sent as classical frames, as CAN FD frames,
    FD with BRS, and the tolerant classical nodes (ISO 11898-1:2015's protocol exception)."""
    msgs = study.messages
    return {
        "classical": sum(1 for m in msgs if not m["fd"]),
        "fd": sum(1 for m in msgs if m["fd"]),
        "brs": sum(1 for m in msgs if m["brs"]),
        "tolerant_nodes": sum(r["tolerant_nodes"] for r in study.rows if not r.get("error")),
    }


def bounds_json(study: BoundsStudy) -> dict[str, Any]:
    """The study as JSON data: settings, the summary per method, the defects, how the runs went
    (nothing that depends on the wall clock: the same seed gives the same object)."""
    return {
        "study": "bounds",
        "settings": study.settings,
        "messages": len(study.messages),
        "frames": frames(study),
        "methods": summarise(study.messages),
        "defects": study.defects,
        "networks": study.total,
        "done": len(study.rows),
        "failed": len(study.failed),
        "interrupted": study.interrupted,
        "engine": study.engine,
    }


def _r(v: float | None) -> str:
    return "-" if v is None else f"{v:.3f}"


def bounds_table(study: BoundsStudy) -> str:
    """The text table: per method, message counts and measured/bound (max, median, 10th
    percentile) from queuing and from the nominal release."""
    s = study.settings
    msgs = study.messages
    summary = summarise(msgs)
    lines = [
        f"{len(study.rows) - len(study.failed)} networks, {len(msgs)} messages (seed {s['seed']}, utilisation up to "
        f"{s['max_utilisation']:g}, queues {s['queues']})",
        *([_fd_line(study)] if s.get("fd") else []),
        f"each simulated with releases {', '.join(s['patterns'])}",
        f"{'':>38}{'measured / bound_ns':^23}  {'measured / response_ns':^22}",
        f"{'method':<10}{'messages':>9}{'unbounded':>10}{'exceeded':>9}"
        f"{'max':>8}{'median':>8}{'p10':>7}  {'max':>7}{'median':>8}{'p10':>7}",
    ]
    for method, f in summary.items():
        q, n = f["queuing"], f["nominal"]
        lines.append(
            f"{method:<10}{f['messages']:>9}{f['unbounded']:>10}{f['exceeded']:>9}"
            f"{_r(q['max']):>8}{_r(q['median']):>8}{_r(q['p10']):>7}  {_r(n['max']):>7}{_r(n['median']):>8}"
            f"{_r(n['p10']):>7}"
        )
    a = summary["all"]
    if a["unpredicted_misses"]:
        lines.append(f"simulated deadline misses: {a['missed']} messages, {a['unpredicted_misses']} NOT predicted")
    else:
        lines.append(f"simulated deadline misses: {a['missed']} messages, each one the analysis deems unschedulable")
    return "\n".join(lines)


def _fd_line(study: BoundsStudy) -> str:
    f = frames(study)
    ratios = f"{DATA_RATIOS[0]}..{DATA_RATIOS[-1]}"
    return (
        f"CAN FD, {study.settings['fd']}: data phase {ratios} times the nominal bit rate; {f['fd']} FD frames "
        f"({f['brs']} with BRS), {f['classical']} classical; {f['tolerant_nodes']} tolerant node"
        + ("" if f["tolerant_nodes"] == 1 else "s")
    )


def defect_text(d: dict[str, Any]) -> str:
    """One defect in words: the network, message, method, what was exceeded, how to see it again,
    and the network itself."""
    what = _DEFECT_WORDS[d["what"]].format(measured=d["measured"], bound=d["bound"])
    return (
        f"network {d['network']}: message {d['message']} ({d['method']}): {what}; "
        f"pattern {d['pattern']}, simulation seed {d['simulation_seed']}\n{d['description']}"
    )


_COLOURS = {"davis2007": "tab:blue", "fifo": "tab:orange", "mailbox": "tab:green"}


def bounds_plot(study: BoundsStudy, path: str | Path) -> Path:
    """The empirical distribution (CDF) of measured/bound per method: from queuing (against
    ``bound_ns``) and from the nominal release (against ``response_ns``), side by side; the
    bound is the line at 1. Legends below the axes, off the data (the ``plot`` extra)."""
    from profiles.pipeline.plots import pyplot

    plt = pyplot()
    msgs = study.messages
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6), sharey=True)
    panels = (
        ("queued_ratio", "from queuing: measured / bound_ns"),
        ("nominal_ratio", "from the nominal release: measured / response_ns"),
    )
    for ax, (col, label) in zip(axes, panels):
        for method in METHODS:
            v = sorted(m[col] for m in msgs if m["method"] == method and m[col] is not None)
            if not v:
                continue
            ys = [(i + 1) / len(v) for i in range(len(v))]
            ax.step([0.0, *v], [0.0, *ys], where="post", color=_COLOURS[method], label=f"{method} ({len(v)} messages)")
        ax.axvline(1.0, color="black", linewidth=1, linestyle="--", label="the bound")
        ax.set_xlim(0, 1.05)
        ax.set_ylim(0, 1.01)
        ax.set_xlabel(label)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("fraction of messages at or below")
    s = study.settings
    fig.suptitle(
        f"worst measured time over its bound, per message: {len(study.rows) - len(study.failed)} random "
        f"{'CAN FD (' + s['fd'] + ') ' if s.get('fd') else ''}networks "
        f"(seed {s['seed']}), released {', '.join(s['patterns'])}",
        fontsize=10,
    )
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    # one legend for both panels, below them: inside, it would cover the curves near 1
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=8, loc="lower center", bbox_to_anchor=(0.5, 0.0), ncol=4)
    p = Path(path)
    fig.savefig(p, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return p
