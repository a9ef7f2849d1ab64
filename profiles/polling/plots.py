"""The poll-cycle plot: the bus timeline (`profiles.pipeline.plots.timeline`) with each master's cycles
behind the frames — a band from the first request's SOF to the end of the cycle's last
transaction (red when it overran), and a dotted line where the cycle's worst-case bound ends."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from profiles.pipeline.plots import timeline

if TYPE_CHECKING:  # pragma: no cover
    from profiles.pipeline.runner import Result

__all__ = ["poll_cycle"]


def poll_cycle(result: Result, path: str | Path) -> Path:
    """Write the timeline of ``result`` (recorded: ``record=True``) with the poll cycles behind it."""
    block = result.profiles.get("master_slave") or {}
    masters = block.get("masters", {})

    def behind(ax: Any, t0: int, t1: int) -> None:
        first = True
        for name, m in masters.items():
            bound = m.get("cycle_bound_ms")
            for start, end, overrun in m.get("window_cycles_ms", []):
                if end < t0 / 1e6 or start > t1 / 1e6:
                    continue
                colour = "#ffb3b3" if overrun else "#dde8f5"
                ax.axvspan(
                    start, end, color=colour, alpha=0.8, zorder=0, label=f"{name}: poll cycle" if first else None
                )
                ax.axvline(start, color="#4a6f9c", linewidth=0.8, zorder=0)
                if bound is not None:
                    ax.axvline(
                        start + bound,
                        color="#4a6f9c",
                        linewidth=0.8,
                        linestyle=":",
                        zorder=0,
                        label="worst-case cycle (bound)" if first else None,
                    )
                first = False
        if not first:
            ax.legend(loc="upper right", fontsize=7)

    return timeline(result, path, behind=behind)
