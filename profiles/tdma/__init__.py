"""TDMA: time-triggered CAN in the manner of TTCAN (ISO 11898-4), levels 1 and 2.

Every node with ``profile = "tdma"`` follows one schedule, the ``[tdma]`` table of the scenario:
a reference message from the current time master starts each basic cycle, and every message
has its own time window in a system matrix of 1..64 basic cycles. Potential time masters (up to
8, by priority) take over from each other when a reference message does not come; level 2 adds
the global time and the drift correction. CSMA nodes on the same bus are gated into the
arbitrating windows unless ``tdma_gated = false``.

- `profiles.tdma.schedule` — the ``[tdma]`` table, its checks, the reference message layout;
- `profiles.tdma.fse` — a node's frame synchronisation entity (cycle time, sync and master
  states, reference messages, level 2 time unit ratio);
- `profiles.tdma.profile` — the profile on a node (messages in their windows) and the gate of a
  CSMA node;
- `profiles.tdma.monitor` — the schedule as the bus shows it, the ``tdma`` results;
- `profiles.tdma.plots` — the timeline with the windows behind the frames.

Not modelled: gap mode (Next_is_Gap, an event-synchronised cycle), message status counters and
the S1/S2 error levels, external clock synchronisation.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from profiles.registry import ProfileKind, register
from profiles.tdma.convert import express_message_set  # noqa: F401  (the profiles study finds it here)
from profiles.tdma.monitor import message_bounds
from profiles.tdma.plots import tdma_schedule
from profiles.tdma.profile import TdmaProfile
from profiles.tdma.schedule import check_scenario

if TYPE_CHECKING:  # pragma: no cover
    from profiles.base import Context, Profile
    from profiles.declarations import NodeDecl, Scenario
    from stack import NodeAPI

__all__ = ["TdmaProfile", "KIND", "PLOTS"]


def _build(node: NodeAPI, decl: NodeDecl, context: Context) -> TdmaProfile:
    return TdmaProfile(node, decl, context)


def _summarize(profiles: list[Profile], context: Context) -> dict[str, Any]:
    monitor = getattr(profiles[0], "monitor", None) if profiles else None
    return {} if monitor is None else monitor.summary()


def _bounds(scenario: Scenario) -> dict[str, tuple[int | None, str | None]]:
    """Each TDMA message's analytic worst case (`monitor.message_bounds`): release at its window's
    start to the end of EOF, for messages in exclusive windows."""
    schedule = scenario.tables.get("tdma")
    if schedule is None:
        return {}
    out = {}
    for name in schedule.owners:
        response, _, note = message_bounds(schedule, name)
        out[name] = (response, note)
    return out


KIND = register(
    ProfileKind(
        name="tdma",
        build=_build,
        timed_messages=False,
        tables=("tdma",),
        parse=check_scenario,
        result_key="tdma",
        summarize=_summarize,
        bounds=_bounds,
        description="time-triggered CAN (TTCAN-like, ISO 11898-4): windows in a system matrix",
    )
)

PLOTS = {"tdma_schedule": tdma_schedule}
"""Plots `canstack experiment --plot` adds for scenarios with TDMA nodes."""
