"""Plots of a run (matplotlib, the optional ``plot`` extra): the bus timeline, response-time
distributions with their analytic bounds, and the bus load over time.

Each function takes a `profiles.pipeline.runner.Result` (run with ``record=True`` for the timeline and
the load) and writes one image. `write_plots` writes all three into a directory; profiles add
their own (a TDMA schedule behind the frames, a poll cycle) through ``extra``: the layers their
module lists in ``PLOTS``, each drawn behind a timeline by `with_layer`.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover
    from profiles.pipeline.runner import Result
    from profiles.registry import TimelineLayer

__all__ = ["timeline", "response_times", "bus_load", "write_plots", "pyplot", "node_colours", "with_layer"]


def pyplot() -> Any:
    """matplotlib's pyplot on a non-interactive backend (ImportError names the extra)."""
    try:
        import matplotlib
    except ImportError:
        raise ImportError("plots need matplotlib: pip install 'canstack[plot]'") from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def node_colours(names: list[str]) -> dict[str, Any]:
    """A colour per node (tab10, in declaration order)."""
    plt = pyplot()
    cmap = plt.get_cmap("tab10")
    return {n: cmap(i % 10) for i, n in enumerate(names)}


def _window(result: Result) -> tuple[int, int]:
    w = result.scenario.plot.get("window_ms")
    if w:
        return round(w[0] * 1e6), round(w[1] * 1e6)
    end = round(result.duration_s * 1e9)
    return 0, min(end, 50_000_000)  # the first 50 ms: a timeline of seconds is a grey band


def timeline(
    result: Result,
    path: str | Path,
    *,
    behind: Callable[[Any, int, int], None] | None = None,
    window: tuple[int, int] | None = None,
) -> Path:
    """A Gantt chart of frames per node over the plot window (``[plot] window_ms``, default the
    first 50 ms): one bar per frame from SOF to the end of EOF, error frames in red with a cross.
    ``behind(ax, t0, t1)`` may draw something behind the frames (a schedule's windows)."""
    plt = pyplot()
    names = [n.name for n in result.scenario.nodes]
    colours = node_colours(names)
    t0, t1 = window or _window(result)
    fig, ax = plt.subplots(figsize=(11, 0.55 * len(names) + 1.6))
    if behind is not None:
        behind(ax, t0, t1)
    rows = {n: i for i, n in enumerate(names)}
    for rec in result.trace:
        if rec.end < t0 or rec.start > t1:
            continue
        senders = [s for s in rec.sender.split("+") if s in rows] or names[:1]
        for s in senders:
            y = rows[s]
            x, w = rec.start / 1e6, (rec.end - rec.start) / 1e6
            if rec.kind == "frame":
                ax.broken_barh([(x, w)], (y - 0.35, 0.7), facecolors=colours[s], edgecolor="black", linewidth=0.3)
                if w > (t1 - t0) / 1e6 / 60:
                    ax.text(x + w / 2, y, f"{rec.frame.can_id:X}", ha="center", va="center", fontsize=6)
            else:
                ax.broken_barh([(x, w)], (y - 0.35, 0.7), facecolors="#ff9999", edgecolor="red", linewidth=0.6)
                ax.plot([x + w / 2], [y], marker="x", color="red", markersize=6)
    ax.set_yticks(range(len(names)), names)
    ax.set_ylim(-0.6, len(names) - 0.4)
    ax.set_xlim(t0 / 1e6, t1 / 1e6)
    ax.invert_yaxis()
    ax.set_xlabel("bus time (ms)")
    ax.set_title(f"{Path(result.scenario.source).name}: frames on the bus (errors in red)")
    ax.grid(axis="x", alpha=0.3)
    return _save(fig, path)


def with_layer(layer: TimelineLayer) -> Callable[[Result, str | Path], Path]:
    """The plot a profile adds (`profiles.registry.TimelineLayer`): the bus timeline of a recorded
    run with ``layer`` drawn behind its frames in the timeline's node colours."""

    def plot(result: Result, path: str | Path) -> Path:
        colours = node_colours([n.name for n in result.scenario.nodes])
        return timeline(result, path, behind=lambda ax, t0, t1: layer(result, ax, t0, t1, colours))

    return plot


def response_times(result: Result, path: str | Path) -> Path:
    """Each message's response times (release to end of EOF) as a box over its instances, with the
    analysis' bound (`rta_ms`) as a red bar and the deadline as a dashed line."""
    plt = pyplot()
    rows = [m for m in result.messages if m["response_ms"]]
    fig, ax = plt.subplots(figsize=(max(6.0, 0.55 * len(rows) + 2), 4.5))
    data = [result.responses_ms(m["name"]) for m in rows]
    if rows:
        ax.boxplot(data, whis=(0, 100), widths=0.5, showfliers=False)
        top = 1.25 * max(max(max(d) for d in data), max((m["rta_ms"] or 0) for m in rows))
        for i, m in enumerate(rows, 1):
            if m["rta_ms"] is not None:
                ax.hlines(
                    m["rta_ms"],
                    i - 0.35,
                    i + 0.35,
                    colors="red",
                    linewidth=2,
                    label="analysis bound" if i == 1 else None,
                )
            d = m["deadline_ms"]
            if d is not None and d <= top:
                ax.hlines(
                    d,
                    i - 0.4,
                    i + 0.4,
                    colors="grey",
                    linestyles="dashed",
                    linewidth=1,
                    label="deadline" if i == 1 else None,
                )
            elif d is not None:  # far above: say where it is instead of squashing the boxes
                ax.annotate(
                    f"D {d:g} ms ↑",
                    (i, top),
                    xytext=(0, -10),
                    textcoords="offset points",
                    ha="center",
                    fontsize=7,
                    color="grey",
                )
            if m["deadline_misses"]:
                ax.annotate(
                    f"{m['deadline_misses']} missed",
                    (i, 0),
                    xytext=(0, 4),
                    textcoords="offset points",
                    ha="center",
                    fontsize=7,
                    color="red",
                )
        ax.set_ylim(0, top)
        ax.set_xticks(range(1, len(rows) + 1), [m["name"] for m in rows], rotation=45, ha="right", fontsize=8)
        handles, _labels = ax.get_legend_handles_labels()
        if handles:
            ax.legend(loc="best", fontsize=8)
    ax.set_ylabel("response time (ms)")
    ax.set_title("response times (box: min..max, quartiles) against the analysis")
    ax.grid(axis="y", alpha=0.3)
    return _save(fig, path)


def bus_load(result: Result, path: str | Path) -> Path:
    """The bus load over time in bins of ``[plot] bin_ms`` (frames and error frames with their
    intermission, as `SimBus.bus_load` counts them)."""
    plt = pyplot()
    bin_ns = round(result.scenario.plot.get("bin_ms", 10.0) * 1e6)
    end = round(result.duration_s * 1e9)
    n = max(1, -(-end // bin_ns))
    busy = [0] * n
    ifs = round(3 * 1e9 / result.scenario.bitrate)
    for rec in result.trace:
        a, b = rec.start, min(end, rec.end + ifs)
        while a < b:
            i = a // bin_ns
            if i >= n:
                break
            edge = min(b, (i + 1) * bin_ns)
            busy[i] += edge - a
            a = edge
    fig, ax = plt.subplots(figsize=(10, 3.5))
    xs = [(i + 0.5) * bin_ns / 1e6 for i in range(n)]
    ax.step(xs, [100 * b / bin_ns for b in busy], where="mid")
    ax.axhline(100 * result.bus_load, color="grey", linestyle="dashed", linewidth=1, label="mean")
    ax.set_ylim(0, 105)
    ax.set_xlabel("bus time (ms)")
    ax.set_ylabel(f"bus load per {bin_ns / 1e6:g} ms (%)")
    ax.legend(loc="lower right", fontsize=8)
    ax.grid(alpha=0.3)
    return _save(fig, path)


def write_plots(
    result: Result, directory: str | Path, extra: dict[str, Callable[[Result, Path], Path]] | None = None
) -> list[Path]:
    """Write timeline.png, response_times.png and bus_load.png (and ``extra`` plots, name ->
    function) into ``directory`` (created if missing); returns the files written."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    out = [
        timeline(result, d / "timeline.png"),
        response_times(result, d / "response_times.png"),
        bus_load(result, d / "bus_load.png"),
    ]
    for name, fn in (extra or {}).items():
        out.append(fn(result, d / f"{name}.png"))
    return out


def _save(fig: Any, path: str | Path) -> Path:
    p = Path(path)
    fig.tight_layout()
    fig.savefig(p, dpi=110)
    pyplot().close(fig)
    return p
