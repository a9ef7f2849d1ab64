"""What TDMA adds to scenario files: ``profile = "tdma"``, the ``[tdma]`` table and its check, the
analytic bound of each message, the ``tdma`` results and the schedule plot."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from profiles.registry import ProfileKind
from profiles.tdma.convert import express_message_set  # noqa: F401  (the profiles study finds it here)
from profiles.tdma.monitor import message_bounds
from profiles.tdma.parse import check_scenario
from profiles.tdma.plots import tdma_schedule
from profiles.tdma.profile import TdmaProfile
from profiles.text import table

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


def _counts(t: dict[str, Any]) -> str:
    return f"{t['frames']} frames, {t['late_starts']} late starts, {t['outside']} outside their windows"


def text(figures: dict[str, Any]) -> list[str]:
    """The readable table's lines of ``tdma``: the reference messages and time masters (master
    switches, late references, cycles without one), per window and per message what was sent in
    it (late starts, failures, lost arbitrations, frames outside, intrusions), the nodes' modes,
    the gated and unscheduled traffic."""
    f = figures
    by = ", ".join(f"{n} {c}" for n, c in f["references_by_master"].items())
    lines = [
        f"TDMA level {f['level']}: basic cycle {f['basic_cycle_us']:g} us x {f['matrix_cycles']}, Tx_Enable "
        f"{f['tx_enable_us']:g} us; {f['reference_messages']} reference messages ({by}), "
        f"{f['late_references']} late, {f['cycles_without_reference']} cycles without one; "
        f"{f['master_switches']} master switches; {f['outside']} frames outside their windows",
    ]
    for sw in f["switches"]:
        when = (
            f"{sw['after_reference_us']:g} us after {sw['from']}'s reference, inside its cycle"
            if sw.get("cut_cycle_short")
            else f"{sw['after_cycle_end_us']:g} us after the end of the cycle"
        )
        lines.append(f"  master switch at {sw['at_ms']:.3f} ms: {sw['from']} -> {sw['to']}, {when}")
    rows = [
        [
            w["window"],
            w["kind"],
            f"{w['start_us']:g}",
            f"{w['length_us']:g}",
            f"{w['base_cycle']}/{w['repeat']}",
            ", ".join(w["messages"]) or "-",
            w["frames"],
            w["late_starts"],
            w["failed"],
            w["lost_arbitration"],
            w["outside"],
            w["intrusions"],
        ]
        for w in f["windows"]
    ]
    lines += table(
        ["window", "kind", "start us", "length us", "base/rep", "messages", "frames", "late", "failed", "lost arb",
         "outside", "intrusions"],
        rows,
        left={0, 1, 5},
        widest={5: 40},
    )  # fmt: skip
    mrows = [
        [
            m["name"],
            m["node"],
            ",".join(map(str, m["windows"])),
            m["frames"],
            m["late_starts"],
            m["failed"],
            m["lost_arbitration"],
            m["outside"],
            "-" if not m["start_offset_us"] else f"{m['start_offset_us']['max']:g}",
            "-" if m["jitter_us"] is None else f"{m['jitter_us']:g}",
            "-" if m["latency_bound_ms"] is None else f"{m['latency_bound_ms']:g}",
        ]
        for m in f["messages"]
    ]
    lines += table(
        ["message", "node", "windows", "frames", "late", "failed", "lost arb", "outside", "offset max us",
         "jitter us", "latency bound ms"],
        mrows,
        left=2,
        widest={0: 24, 1: 16},
    )  # fmt: skip
    nrows = [
        [
            name,
            n["sync_mode"],
            n["master_mode"],
            n["watch_triggers"],
            n["restarts"],
            n.get("references_sent", "-"),
            n.get("reference_retransmissions", "-"),
            n.get("took_over", "-"),
        ]
        for name, n in f["nodes"].items()
    ]
    lines += table(
        ["node", "sync mode", "master mode", "watch triggers", "restarts", "references", "ref retx", "took over"],
        nrows,
        left=3,
        widest={0: 16},
    )
    for name, g in f.get("gated", {}).items():
        lines.append(f"gated node {name}: {_counts(g)}")
    u = f.get("unscheduled") or {}
    if u.get("frames") or u.get("outside") or u.get("late_starts"):
        lines.append(f"unscheduled nodes: {_counts(u)}")
    return lines


TDMA = ProfileKind(
    name="tdma",
    build=_build,
    timed_messages=False,
    tables=("tdma",),
    parse=check_scenario,
    result_key="tdma",
    summarize=_summarize,
    bounds=_bounds,
    text=text,
    description="time-triggered CAN (TTCAN-like, ISO 11898-4): windows in a system matrix",
    fd_note="TDMA nodes send classical CAN frames only (ISO 11898-4 time-triggered CAN: the windows are "
    "sized for them); CAN FD messages go on csma nodes",
)
"""``profile = "tdma"`` and the ``[tdma]`` table: messages in the windows of a system matrix."""

KINDS = (TDMA,)
"""The kinds this package adds (the registry reads them: see `profiles.registry`)."""

PLOTS = {"tdma_schedule": tdma_schedule}
"""Plots `canstack experiment --plot` adds for scenarios with TDMA nodes."""
