"""The TDMA schedule behind the frames: each basic cycle's time windows drawn where the bus put
them — exclusive windows in their owner's row and colour, arbitrating windows across all rows,
free windows hatched, and a dotted line at each reference message's start of frame.

`tdma_schedule` is a layer (`profiles.registry.TimelineLayer`): the experiment pipeline draws the
bus timeline around it (``canstack experiment --plot DIR`` writes ``tdma_schedule.png``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from profiles.tdma.monitor import master_clock, window_bounds
from profiles.tdma.schedule import ARBITRATING, EXCLUSIVE, decode_reference

if TYPE_CHECKING:  # pragma: no cover
    from profiles.registry import FinishedRun

__all__ = ["tdma_schedule", "cycles_of"]


def cycles_of(result: FinishedRun) -> list[tuple[int, int, int]]:
    """The basic cycles of a recorded run: (SOF of the reference message, its Cycle_Count, the
    time master priority), in bus order."""
    s = result.scenario.tables["tdma"]
    out = []
    for rec in result.trace:
        f = rec.frame
        if rec.kind != "frame" or f.remote:
            continue
        prio = s.priority_of(f.can_id, f.extended)
        if prio is None:
            continue
        info = decode_reference(f.data, s.level)
        if info is not None:
            out.append((rec.start, info.cycle_count, prio))
    return out


def tdma_schedule(run: FinishedRun, ax: Any, t0: int, t1: int, colours: Mapping[str, Any]) -> None:
    """Draw the schedule's windows of a recorded run between ``t0`` and ``t1`` behind the frames
    of the timeline, exclusive windows in their owner's row and colour."""
    from matplotlib.patches import Patch, Rectangle

    sc = run.scenario
    s = sc.tables["tdma"]
    rows = {n.name: i for i, n in enumerate(sc.nodes)}
    cycles = cycles_of(run)
    clocks = [master_clock(sc, s, p) for p in range(len(s.masters))]
    for i, (sof, count, prio) in enumerate(cycles):
        if sof > t1:
            break
        nxt = cycles[i + 1][0] if i + 1 < len(cycles) else sof + s.watch_ns
        if nxt < t0:
            continue
        ax.axvline(sof / 1e6, color="black", linewidth=0.6, linestyle=":")
        for w in s.windows:
            if not w.active(count):
                continue
            a, b = window_bounds(clocks[prio], sof, w.start_ns, w.end_ns)
            x, width = a / 1e6, (b - a) / 1e6
            if w.kind == EXCLUSIVE:
                owner = s.owners[w.messages[0]]
                ax.add_patch(
                    Rectangle(
                        (x, rows[owner] - 0.48),
                        width,
                        0.96,
                        facecolor=colours[owner],
                        alpha=0.2,
                        edgecolor=colours[owner],
                        linewidth=0.5,
                    )
                )
            elif w.kind == ARBITRATING:
                ax.axvspan(x, x + width, facecolor="gold", alpha=0.15, edgecolor="goldenrod", linewidth=0.5)
            else:
                ax.axvspan(x, x + width, facecolor="none", edgecolor="grey", hatch="//", alpha=0.3, linewidth=0.0)
    ax.legend(
        handles=[
            Patch(facecolor="grey", alpha=0.3, label="exclusive window (owner's row)"),
            Patch(facecolor="gold", alpha=0.3, label="arbitrating window"),
            Patch(facecolor="none", edgecolor="grey", hatch="//", label="free window"),
        ],
        loc="upper left",
        bbox_to_anchor=(1.0, 1.0),
        fontsize=7,
        framealpha=0.8,
    )
