"""The poll-cycle plot: each master's cycles behind the frames of the bus timeline — a band from
the first request's SOF to the end of the cycle's last transaction (red when it overran), and a
dotted line where the cycle's worst-case bound ends.

`poll_cycle` is a layer (`profiles.registry.TimelineLayer`): the experiment pipeline draws the
timeline around it (``canstack experiment --plot DIR`` writes ``poll_cycle.png``)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover
    from profiles.registry import FinishedRun

__all__ = ["poll_cycle"]


def poll_cycle(run: FinishedRun, ax: Any, t0: int, t1: int, colours: Mapping[str, Any]) -> None:
    """Draw the poll cycles of ``run`` (its ``master_slave`` figures) between ``t0`` and ``t1``."""
    block = run.profiles.get("master_slave") or {}
    masters = block.get("masters", {})
    first = True
    for name, m in masters.items():
        bound = m.get("cycle_bound_ms")
        for start, end, overrun in m.get("window_cycles_ms", []):
            if end < t0 / 1e6 or start > t1 / 1e6:
                continue
            colour = "#ffb3b3" if overrun else "#dde8f5"
            ax.axvspan(start, end, color=colour, alpha=0.8, zorder=0, label=f"{name}: poll cycle" if first else None)
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
