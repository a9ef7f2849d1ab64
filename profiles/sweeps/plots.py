"""Plots of sweeps and studies (matplotlib, the optional ``plot`` extra; `profiles.pipeline.plots.pyplot`
gives the non-interactive backend).

- `sweep_plot`: a metric against one varied key (a line, the mean over seeds with their min..max
  as a band), or against two (one line per value of the second key); a key whose values are not
  all numbers is drawn as categories in the order given.
- `schedulability_plot`: fractions of sets against utilisation, with each curve's breakdown
  utilisation (50 % crossing) marked.
- `profiles_plot`: worst response and jitter per message (in priority order), and the bus load,
  per profile, side by side.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from profiles.pipeline.plots import pyplot
from profiles.sweeps.schedulability import breakdown_text

if TYPE_CHECKING:  # pragma: no cover
    from profiles.sweeps.comparison import ProfilesStudy
    from profiles.sweeps.schedulability import SchedulabilityStudy

__all__ = [
    "sweep_plot",
    "write_sweep_plots",
    "schedulability_plot",
    "profiles_plot",
    "metric_label",
    "wants_log",
    "x_scale",
]

_LABELS = {
    "bus_load": "bus load (%)",
    "worst_misses": "deadline misses of the worst message",
    "deadline_misses": "deadline misses (all messages)",
    "unschedulable": "messages the analysis rejects",
}


def metric_label(metric: str) -> str:
    """The axis label of a metric column."""
    if metric in _LABELS:
        return _LABELS[metric]
    name, _, what = metric.rpartition(".")
    units = {
        "max_ms": "worst response (ms)",
        "mean_ms": "mean response (ms)",
        "jitter_ms": "jitter (ms)",
        "misses": "deadline misses",
        "rta_ms": "analysis bound (ms)",
    }
    return f"{name}: {units[what]}" if name and what in units else metric


def _numeric(values: Sequence[Any]) -> bool:
    return all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)


def _distinct(values: Sequence[Any]) -> list[Any]:
    return list(dict.fromkeys(values))


#: values of a varied key spanning this ratio or more go on a logarithmic axis
LOG_SPAN = 100.0


def wants_log(values: Sequence[Any]) -> bool:
    """Whether numbers span two decades or more (all above 0): then a logarithmic axis shows
    them evenly, where a linear one would crowd the small ones into a corner."""
    if not values or not _numeric(values) or min(values) <= 0:
        return False
    return max(values) / min(values) >= LOG_SPAN


def x_scale(values: Sequence[Any], log_x: bool | None = None) -> str:
    """The scale of a sweep plot's varied key: ``"category"`` for values that are not all
    numbers, ``"log"`` when ``log_x`` asks for it (None: when they span two decades or more,
    `wants_log`) and every value is above 0 (a logarithmic axis has no place for 0 or below),
    else ``"linear"``."""
    if not _numeric(values):
        return "category"
    if (wants_log(values) if log_x is None else log_x) and values and min(values) > 0:
        return "log"
    return "linear"


def sweep_plot(
    rows: Sequence[Mapping[str, Any]],
    keys: Sequence[str],
    metric: str,
    path: str | Path,
    *,
    log_x: bool | None = None,
) -> Path:
    """``metric`` against the first varied key, one line per value of the second (if any): the
    mean over the seeds of each combination, their min..max as a band. Failed runs are left out
    (the title says how many). The key's axis is logarithmic when ``log_x`` says so, or (None)
    when its values span two decades or more (`wants_log`); the legend goes beside the axes, off
    the data."""
    if not 1 <= len(keys) <= 2:
        raise ValueError(f"a sweep plot draws one or two varied keys, not {len(keys)}")
    plt = pyplot()
    ok = [r for r in rows if not r.get("error") and isinstance(r.get(metric), (int, float))]
    scale = 100.0 if metric == "bus_load" else 1.0
    xkey = keys[0]
    xs = _distinct([r[xkey] for r in rows])
    numeric = _numeric(xs)
    pos = {x: (x if numeric else i) for i, x in enumerate(xs)}
    series = _distinct([r[keys[1]] for r in rows]) if len(keys) == 2 else [None]
    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    for s in series:
        pts = []
        for x in xs:
            vals = [r[metric] * scale for r in ok if r[xkey] == x and (s is None or r[keys[1]] == s)]
            if vals:
                pts.append((pos[x], sum(vals) / len(vals), min(vals), max(vals)))
        if not pts:
            continue
        label = None if s is None else f"{keys[1]} = {s}"
        line = ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", label=label)[0]
        if any(p[2] != p[3] for p in pts):
            ax.fill_between(
                [p[0] for p in pts],
                [p[2] for p in pts],
                [p[3] for p in pts],
                alpha=0.2,
                color=line.get_color(),
                linewidth=0,
            )
    scale_x = x_scale(xs, log_x)
    if scale_x == "category":
        ax.set_xticks(range(len(xs)), [str(x) for x in xs])
    elif scale_x == "log":
        ax.set_xscale("log")
    ax.set_xlabel(xkey + (" (log scale)" if ax.get_xscale() == "log" else ""))
    ax.set_ylabel(metric_label(metric))
    failed = sum(1 for r in rows if r.get("error"))
    ax.set_title(
        f"{metric_label(metric)} against {xkey}" + (f" ({failed} failed runs left out)" if failed else ""), fontsize=10
    )
    if len(series) > 1:
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    ax.grid(alpha=0.3)
    return _save(fig, path)


def write_sweep_plots(
    rows: Sequence[Mapping[str, Any]],
    keys: Sequence[str],
    metrics: Sequence[str],
    directory: str | Path,
    *,
    log_x: bool | None = None,
) -> list[Path]:
    """One `sweep_plot` per metric, ``<metric>.png`` in ``directory`` (created, with its parents,
    if missing)."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    return [sweep_plot(rows, keys, m, d / f"{m.replace('/', '_')}.png", log_x=log_x) for m in metrics]


_CURVE_STYLE = {
    "analysis": ("analysis, {order}: every message guaranteed (Davis et al. 2007)", "tab:blue", "-"),
    "opa": ("analysis, Audsley's optimal priority order (OPA)", "tab:purple", "-"),
    "simulation": ("simulation, priority queues: no deadline miss", "tab:green", "--"),
    "fifo": ("simulation, FIFO queues: no deadline miss", "tab:red", "-."),
    "fifo_analysis": ("analysis, FIFO queues: every message guaranteed", "tab:orange", ":"),
}
_ORDER_NAMES = {"deadline": "deadline-monotonic identifiers", "random": "identifiers at random"}


def schedulability_plot(
    study: SchedulabilityStudy,
    path: str | Path,
    curves: Sequence[str] = ("analysis", "opa", "simulation"),
    title: str | None = None,
) -> Path:
    """The fraction of sets per utilisation for ``curves`` (analysis — with the sets' own
    identifiers, deadline monotonic unless drawn at random —, opa, simulation, fifo,
    fifo_analysis), each curve's breakdown utilisation (where it falls through 50 %) as a dotted
    vertical line."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 4.5 + 0.3 * len(curves)))
    order = _ORDER_NAMES.get(str(study.settings.get("priorities", "deadline")), "the sets' identifiers")
    for c in curves:
        label, colour, style = _CURVE_STYLE[c]
        label = label.format(order=order)
        pts = [(100 * p["utilisation"], 100 * p[c]) for p in study.points if p[c] is not None]
        b = study.breakdown.get(c)
        label += f" ({breakdown_text(study, c)})"
        ax.plot([p[0] for p in pts], [p[1] for p in pts], style, marker="o", color=colour, label=label)
        if b is not None:
            ax.axvline(100 * b, color=colour, linestyle=":", linewidth=1)
            ax.annotate(
                f"{100 * b:.0f} %",
                (100 * b, 50),
                xytext=(3, 4 + 12 * list(curves).index(c)),
                textcoords="offset points",
                fontsize=8,
                color=colour,
            )
    ax.axhline(50, color="grey", linewidth=0.5)
    s = study.settings
    ax.set_xlabel("bus utilisation, worst-case frames (%)")
    ax.set_ylabel("message sets (%)")
    ax.set_ylim(-3, 103)
    ax.set_title(
        title
        or (
            f"{s.get('sets')} sets per point, {s.get('messages')} messages, "
            f"{s.get('per_node')} per node, {s.get('generator')}; breakdown dotted"
        ),
        fontsize=9,
    )
    # below the axes: inside, it would cover the curves wherever they run
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.15), ncol=1)
    ax.grid(alpha=0.3)
    return _save(fig, path)


def profiles_plot(study: ProfilesStudy, path: str | Path) -> Path:
    """Worst response and jitter of each message (grouped bars, one colour per profile, the
    deadline as a tick) and the bus load of each profile."""
    plt = pyplot()
    rows = [r for r in study.rows if not r.get("error")]
    msgs = sorted(study.mset.messages, key=lambda m: (m.extended, m.can_id))  # priority order
    names = [m.name for m in msgs]
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.2), gridspec_kw={"width_ratios": [3, 3, 1]})
    width = 0.8 / max(1, len(rows))
    cmap = plt.get_cmap("tab10")
    for k, r in enumerate(rows):
        xs = [i - 0.4 + width * (k + 0.5) for i in range(len(names))]
        for ax, col in ((axes[0], "max_ms"), (axes[1], "jitter_ms")):
            ax.bar(xs, [r.get(f"{n}.{col}") or 0.0 for n in names], width=width, color=cmap(k % 10), label=r["profile"])
        axes[2].bar([k], [100 * r["bus_load"]], color=cmap(k % 10))
    deadlines = [m.deadline_ns / 1e6 for m in msgs]
    axes[0].scatter(range(len(names)), deadlines, marker="_", s=200, color="black", label="deadline", zorder=3)
    for ax, label in ((axes[0], "worst response (ms)"), (axes[1], "start-to-start jitter (ms)")):
        ax.set_xticks(range(len(names)), names, rotation=45, ha="right", fontsize=8)
        ax.set_ylabel(label)
        ax.grid(axis="y", alpha=0.3)
    axes[0].set_yscale("log")
    _mark_zeros(axes[0], rows, names, width, "max_ms")
    axes[0].legend(fontsize=8, loc="upper left", bbox_to_anchor=(0.0, -0.3), ncol=min(4, len(rows) + 1))
    axes[2].set_xticks(range(len(rows)), [r["profile"] for r in rows], rotation=45, ha="right", fontsize=8)
    axes[2].set_ylabel("bus load (%)")
    axes[2].set_ylim(0, 100)
    fig.suptitle(
        f"one message set under each profile ({len(names)} messages, {study.mset.bitrate // 1000} kbit/s)", fontsize=10
    )
    return _save(fig, path)


def _mark_zeros(ax: Any, rows: Sequence[Mapping[str, Any]], names: Sequence[str], width: float, col: str) -> None:
    """On a logarithmic axis a bar of 0 has no height: mark each with a '0' at the bottom."""
    bottom = ax.get_ylim()[0]
    for k, r in enumerate(rows):
        for i, n in enumerate(names):
            if r.get(f"{n}.{col}") == 0:
                ax.annotate("0", (i - 0.4 + width * (k + 0.5), bottom), ha="center", va="bottom", fontsize=7)


def _save(fig: Any, path: str | Path) -> Path:
    p = Path(path)
    fig.tight_layout()
    fig.savefig(p, dpi=100, bbox_inches="tight")  # legends beside the axes stay in the image
    pyplot().close(fig)
    return p
