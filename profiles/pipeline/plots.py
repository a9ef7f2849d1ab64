"""Plots of a run (matplotlib, the optional ``plot`` extra): the bus timeline, response-time
distributions with their analytic bounds, and the bus load over time.

Each function takes a `profiles.pipeline.runner.Result` (run with ``plot=True``: the timeline
window's records and the load bins, or ``record=True``) and writes one image. `write_plots` writes all three into a directory; profiles add
their own (a TDMA schedule behind the frames, a poll cycle) through ``extra``: the layers their
module lists in ``PLOTS``, each drawn behind a timeline by `with_layer`.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from profiles.pipeline.recording import MAX_BINS

if TYPE_CHECKING:  # pragma: no cover
    from profiles.pipeline.runner import Result
    from profiles.registry import TimelineLayer

__all__ = [
    "timeline",
    "response_times",
    "response_cdf",
    "bus_load",
    "write_plots",
    "pyplot",
    "node_colours",
    "with_layer",
    "ERROR_COLOUR",
]


def pyplot() -> Any:
    """matplotlib's pyplot on a non-interactive backend (ImportError names the extra)."""
    try:
        import matplotlib
    except ImportError:
        raise ImportError("plots need matplotlib: pip install 'canstack[plot]'") from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


#: the colour of error frames on the timeline, kept out of the nodes' palette
ERROR_COLOUR = "#d62728"


def node_colours(names: list[str]) -> dict[str, Any]:
    """A colour per node (tab10 without its red, which marks error frames; in declaration
    order, repeating after nine)."""
    plt = pyplot()
    cmap = plt.get_cmap("tab10")
    palette = [cmap(i) for i in range(10) if i != 3]  # tab10's 3 is the error red
    return {n: palette[i % len(palette)] for i, n in enumerate(names)}


def _window(result: Result) -> tuple[int, int]:
    from profiles.pipeline.recording import plot_window

    return plot_window(result.scenario.plot, round(result.duration_s * 1e9))


def timeline(
    result: Result,
    path: str | Path,
    *,
    behind: Callable[[Any, int, int], None] | None = None,
    window: tuple[int, int] | None = None,
) -> Path:
    """A Gantt chart of frames per node over the plot window (``[plot] window_ms``, default the
    first 50 ms): one bar per frame from SOF to the end of EOF with its identifier where the bar
    has room for it, error frames in red (no node has that colour) with a cross.
    ``behind(ax, t0, t1)`` may draw something behind the frames (a schedule's windows)."""
    plt = pyplot()
    names = [n.name for n in result.scenario.nodes]
    colours = node_colours(names)
    t0, t1 = window or _window(result)
    width_in = 11.0
    fig, ax = plt.subplots(figsize=(width_in, 0.55 * len(names) + 1.6))
    if behind is not None:
        behind(ax, t0, t1)
    rows = {n: i for i, n in enumerate(names)}
    # the axes take about 85 % of the figure: ms per point of text at fontsize 6 (a character
    # is about 3.6 points wide)
    ms_per_pt = (t1 - t0) / 1e6 / (0.85 * width_in * 72)
    errors = False
    for rec in result.trace:
        if rec.end < t0 or rec.start > t1:
            continue
        senders = [s for s in rec.sender.split("+") if s in rows] or names[:1]
        for s in senders:
            y = rows[s]
            x, w = rec.start / 1e6, (rec.end - rec.start) / 1e6
            if rec.kind == "frame":
                ax.broken_barh([(x, w)], (y - 0.35, 0.7), facecolors=colours[s], edgecolor="black", linewidth=0.3)
                label = f"{rec.frame.can_id:X}"
                if w > (len(label) * 3.6 + 2) * ms_per_pt:
                    ax.text(x + w / 2, y, label, ha="center", va="center", fontsize=6)
            else:
                errors = True
                ax.broken_barh(
                    [(x, w)], (y - 0.35, 0.7), facecolors="white", edgecolor=ERROR_COLOUR, hatch="xxx", linewidth=0.8
                )
                ax.plot([x + w / 2], [y], marker="x", color=ERROR_COLOUR, markersize=6)
    ax.set_yticks(range(len(names)), names)
    ax.set_ylim(-0.6, len(names) - 0.4)
    ax.set_xlim(t0 / 1e6, t1 / 1e6)
    ax.invert_yaxis()
    ax.set_xlabel("bus time (ms)")
    ax.set_title(
        f"{Path(result.scenario.source).name}: frames on the bus, identifiers in hex"
        + ("; error frames hatched red" if errors else "")
    )
    ax.grid(axis="x", alpha=0.3)
    return _save(fig, path)


def with_layer(layer: TimelineLayer) -> Callable[[Result, str | Path], Path]:
    """The plot a profile adds (`profiles.registry.TimelineLayer`): the bus timeline of a recorded
    run with ``layer`` drawn behind its frames in the timeline's node colours."""

    def plot(result: Result, path: str | Path) -> Path:
        colours = node_colours([n.name for n in result.scenario.nodes])
        return timeline(result, path, behind=lambda ax, t0, t1: layer(result, ax, t0, t1, colours))

    return plot


def _box(track: Any, label: str) -> dict[str, Any]:
    """matplotlib's box statistics of a message's response times (ms): quartiles and median from
    every value kept, or from the sketch (within its accuracy); whiskers at min and max."""
    st = track.stats
    q1, med, q3 = (v / 1e6 for v in st.quantiles((0.25, 0.5, 0.75)))
    figures = st.figures()
    assert figures is not None  # a message with responses
    _n, lo, hi, mean, _p99 = figures
    return {"label": label, "whislo": lo / 1e6, "q1": q1, "med": med, "q3": q3, "whishi": hi / 1e6, "mean": mean / 1e6}


def response_times(result: Result, path: str | Path) -> Path:
    """Each message's response times (queued to end of EOF) as a box over its instances (min..max,
    quartiles), with the analysis' bound (`rta_ms`) as a red bar and the deadline as a dashed
    line. A scenario without declared messages (a CANopen network) shows the latency of each
    identifier on the bus instead (queued to end of EOF: min, mean, max)."""
    plt = pyplot()
    rows = [m for m in result.messages if m["response_ms"] and m["name"] in result.tracks]
    if not rows:
        return _identifier_latency(result, path)
    fig, ax = plt.subplots(figsize=(max(6.0, 0.55 * len(rows) + 2), 4.8))
    boxes = [_box(result.tracks[m["name"]], m["name"]) for m in rows]
    ax.bxp(boxes, widths=0.5, showfliers=False)
    top = 1.25 * max(max(b["whishi"] for b in boxes), max((m["rta_ms"] or 0) for m in rows))
    for i, m in enumerate(rows, 1):
        if m["rta_ms"] is not None:
            ax.hlines(
                m["rta_ms"], i - 0.35, i + 0.35, colors="red", linewidth=2, label="analysis bound" if i == 1 else None
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
                f"D {d:g} ms ↑", (i, top), xytext=(0, -10), textcoords="offset points", ha="center", fontsize=7,
                color="grey",
            )  # fmt: skip
        if m["deadline_misses"]:
            ax.annotate(
                f"{m['deadline_misses']} missed", (i, 0), xytext=(0, 4), textcoords="offset points", ha="center",
                fontsize=7, color="red",
            )  # fmt: skip
    ax.set_ylim(0, top)
    ax.set_xticks(range(1, len(rows) + 1), [m["name"] for m in rows], rotation=45, ha="right", fontsize=8)
    _legend_beside(ax)
    ax.set_ylabel("response time, queued -> end of EOF (ms)")
    ax.set_title("response times (box: min..max, quartiles) against the analysis")
    ax.grid(axis="y", alpha=0.3)
    return _save(fig, path)


def _identifier_latency(result: Result, path: str | Path) -> Path:
    plt = pyplot()
    ids = result.id_latency
    fig, ax = plt.subplots(figsize=(max(6.0, 0.45 * len(ids) + 2), 4.5))
    labels = list(ids)
    for i, label in enumerate(labels, 1):
        s = ids[label]
        ax.vlines(i, s["latency_min_us"] / 1e3, s["latency_max_us"] / 1e3, colors="tab:blue", linewidth=3)
        ax.plot([i], [s["latency_mean_us"] / 1e3], marker="o", color="black", markersize=4)
    if labels:
        ax.set_xticks(range(1, len(labels) + 1), labels, rotation=60, ha="right", fontsize=7)
        ax.set_xlim(0.3, len(labels) + 0.7)
    else:
        ax.text(0.5, 0.5, "no frame was sent", ha="center", va="center", transform=ax.transAxes)
    ax.set_ylim(bottom=0)
    ax.set_ylabel("latency, queued -> end of EOF (ms)")
    ax.set_title("no declared messages: latency of each identifier on the bus (min..max, mean as a dot)", fontsize=9)
    ax.grid(axis="y", alpha=0.3)
    return _save(fig, path)


def response_cdf(result: Result, path: str | Path) -> Path:
    """Per message, the cumulative distribution of its response times (every value kept, or the
    sketch's quantiles) with the analysis' bound (`rta_ms`) and the deadline as vertical lines
    (their values in the title): small multiples, four to a row, one legend above them all."""
    plt = pyplot()
    rows = [m for m in result.messages if m["response_ms"] and m["name"] in result.tracks]
    if not rows:
        fig, ax = plt.subplots(figsize=(6, 3))
        ax.text(0.5, 0.5, "no declared message was sent", ha="center", va="center", transform=ax.transAxes)
        ax.set_axis_off()
        return _save(fig, path)
    cols = min(4, len(rows))
    nrows = -(-len(rows) // cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(3.2 * cols, 2.4 * nrows), squeeze=False)
    legend: dict[str, Any] = {}
    for ax, m in zip(axes.flat, rows):
        st = result.tracks[m["name"]].stats
        if st.exact:
            xs = sorted(v / 1e6 for v in st.values)
            ys = [(k + 1) / len(xs) for k in range(len(xs))]
            how = "every instance"
        else:
            qs = [k / 200 for k in range(201)]
            xs = [v / 1e6 for v in st.quantiles(qs)]
            ys = qs
            how = "sketch, ±0.5 %"
        ax.step(xs, ys, where="post", color="tab:blue", linewidth=1.2)
        marks = []
        if m["rta_ms"] is not None:
            ax.axvline(m["rta_ms"], color="red", linewidth=1.2, label="analysis bound")
            marks.append(f"bound {m['rta_ms']:.3g}")
        if m["deadline_ms"] is not None:
            ax.axvline(m["deadline_ms"], color="grey", linestyle="dashed", linewidth=1, label="deadline")
            marks.append(f"D {m['deadline_ms']:g}")
        ax.set_title(f"{m['name']} ({how})" + (f"\n{', '.join(marks)} ms" if marks else ""), fontsize=8)
        ax.set_ylim(0, 1.02)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
        for h, label in zip(*ax.get_legend_handles_labels()):
            legend.setdefault(label, h)
    for ax in list(axes.flat)[len(rows) :]:
        ax.set_axis_off()
    fig.supxlabel("response time, queued -> end of EOF (ms)", fontsize=9)
    fig.supylabel("fraction of instances", fontsize=9)
    fig.tight_layout()
    if legend:  # one legend above the plots: inside one, a line at its right edge runs under it
        fig.legend(legend.values(), legend.keys(), loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=2, fontsize=8)
    return _save(fig, path, laid_out=True)


def bus_load(result: Result, path: str | Path) -> Path:
    """The bus load over time in bins of ``[plot] bin_ms`` (frames and error frames with their
    intermission, as `SimBus.bus_load` counts them), widened on a long run to a 1-2-5 width
    (`profiles.pipeline.recording.readable_bin_ns`) so that there are at most
    `profiles.pipeline.recording.MAX_BINS` bins (the title says so)."""
    plt = pyplot()
    load = result.load
    if load is None:  # a result made without plot=True: from the trace it kept
        from profiles.pipeline.recording import PlotRecords

        end = round(result.duration_s * 1e9)
        load = PlotRecords(
            _window(result), round(result.scenario.plot.get("bin_ms", 10.0) * 1e6), end, result.scenario.bitrate
        )
        for rec in result.trace:
            load(rec)
    bin_ns, busy = load.bin_ns, load.busy
    n = len(busy)
    last = load.end_ns - (n - 1) * bin_ns  # the last bin may be shorter than the others
    fractions = [b / (bin_ns if i < n - 1 else max(1, last)) for i, b in enumerate(busy)]
    fig, ax = plt.subplots(figsize=(10, 3.8))
    edges = [i * bin_ns / 1e6 for i in range(n)] + [load.end_ns / 1e6]
    ax.stairs([100 * f for f in fractions], edges, fill=True, alpha=0.5)
    ax.axhline(
        100 * result.bus_load,
        color="black",
        linestyle="dashed",
        linewidth=1,
        label=f"mean {100 * result.bus_load:.1f} %",
    )
    ax.set_ylim(0, 105)
    ax.set_xlim(0, load.end_ns / 1e6)
    ax.set_xlabel("bus time (ms)")
    widened = f" (bin_ms {load.requested_bin_ns / 1e6:g} widened: at most {MAX_BINS} bins)" if load.widened else ""
    ax.set_ylabel("bus load (%)")
    ax.set_title(f"bus load per {bin_ns / 1e6:g} ms{widened}", fontsize=10)
    _legend_beside(ax)
    ax.grid(alpha=0.3)
    return _save(fig, path)


def write_plots(
    result: Result, directory: str | Path, extra: dict[str, Callable[[Result, Path], Path]] | None = None
) -> list[Path]:
    """Write timeline.png, response_times.png, response_cdf.png and bus_load.png (and ``extra``
    plots, name -> function) into ``directory`` (created, with its parents, if missing); returns
    the files written."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    out = [
        timeline(result, d / "timeline.png"),
        response_times(result, d / "response_times.png"),
        response_cdf(result, d / "response_cdf.png"),
        bus_load(result, d / "bus_load.png"),
    ]
    for name, fn in (extra or {}).items():
        out.append(fn(result, d / f"{name}.png"))
    return out


def _legend_beside(ax: Any) -> None:
    """The legend to the right of the axes, where it covers no data (when there is one)."""
    handles, _labels = ax.get_legend_handles_labels()
    if handles:
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)


def _save(fig: Any, path: str | Path, *, laid_out: bool = False) -> Path:
    p = Path(path)
    if not laid_out:  # a figure laid out already (its legend placed after) is not laid out again
        fig.tight_layout()
    fig.savefig(p, dpi=110, bbox_inches="tight")  # a legend beside the axes stays in the image
    pyplot().close(fig)
    return p
