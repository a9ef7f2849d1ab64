"""What TDMA adds to scenario files: ``profile = "tdma"``, the ``[tdma]`` table and its check, the
analytic bound of each message, the ``tdma`` results and the schedule plot."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from profiles.registry import ProfileKind
from profiles.tdma.convert import express_message_set  # noqa: F401  (the profiles study finds it here)
from profiles.tdma.monitor import message_bounds
from profiles.tdma.plots import tdma_schedule
from profiles.tdma.profile import TdmaProfile
from profiles.tdma.schedule import check_scenario

if TYPE_CHECKING:  # pragma: no cover
    from profiles.base import Context, Profile
    from profiles.declarations import NodeDecl, Scenario
    from stack import NodeAPI

__all__ = ["TDMA", "KINDS", "PLOTS"]


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


TDMA = ProfileKind(
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
"""``profile = "tdma"`` and the ``[tdma]`` table: messages in the windows of a system matrix."""

KINDS = (TDMA,)
"""The kinds this package adds (the registry reads them: see `profiles.registry`)."""

PLOTS = {"tdma_schedule": tdma_schedule}
"""Plots `canstack experiment --plot` adds for scenarios with TDMA nodes."""
