"""Metrics of a run, the response-time analysis beside them, and the readable table.

Per declared message: ``released``, ``sent``, ``received``, ``response_ms`` (min/mean/p99/max,
from queuing — the instance entering its node's transmit queue — to the end of its successful
transmission, the end of EOF), ``release_response_max_ms`` (the longest time from an instance's
nominal release to the end of its EOF), ``jitter_ms`` (max − min of the start-to-start
distance, periodic messages), ``deadline_misses`` (instances that end more than their deadline
after their *nominal* release — the release jitter counts — or fail, are dropped, or are left
pending past it), and from the response-time analysis (`profiles.analysis.rta`: Davis, Burns,
Bril, Lukkien 2007 for priority queues, bounds for FIFO queues and mailboxes):

- ``rta_ms`` — the bound on what ``response_ms`` measures: queuing to the end of the frame, over
  every instance of the busy period (the 3-bit intermission included, so at least 3 bit times
  above any measured maximum). Not R − J: an instance queued without jitter right behind one
  queued late waits longer than that.
- ``rta_release_ms`` — R, from the nominal release (jitter included), the bound on
  ``release_response_max_ms``; ``schedulable`` is R <= deadline, the same reference as
  ``deadline_misses``: a message that misses in the simulation is never schedulable.
- ``tightness`` — the simulated maximum over ``rta_ms``; ``rta_method`` the analysis used
  (``davis2007``, ``fifo``, ``mailbox``); ``rta_note`` why a message has no bound.

Nodes use their scenario queue (priority, FIFO, mailboxes with or without abort) and their
clock's drift (the analysis takes the shortest real period); ``[analysis] t_error_ms`` and
``error_burst`` give the error model. Traffic the analysis has no model of (a profile without
one) leaves the whole bus without a bound; a profile's own bound (a schedule's window) shows in
``rta_ms`` where the analysis gives none.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

from profiles.analysis.rta import ErrorModel, MessageSpec, NodeQueue, analyse
from profiles.base import Recorder
from profiles.registry import profile_kind
from profiles.text import id_text, ms, table

if TYPE_CHECKING:  # pragma: no cover
    from profiles.declarations import Scenario

__all__ = ["analyse_scenario", "message_rows", "summary_of", "format_table", "message_csv_rows", "CSV_COLUMNS"]


DEADLINE_REFERENCE = "nominal release (release jitter included)"
"""What deadlines, ``deadline_misses``, ``schedulable`` and ``rta_release_ms`` count from."""

BOUND_REFERENCE = "queuing to the end of the frame (intermission included)"
"""What ``rta_ms`` bounds (and ``response_ms`` measures, to the end of EOF)."""


def analyse_scenario(scenario: Scenario, *, verdict_only: bool = False) -> dict[str, Any]:
    """The response-time analysis of the scenario's bus: ``results`` by message name (only
    where it applies) and ``assumptions`` (what was analysed, what was left out and why).
    ``verdict_only``: see `profiles.analysis.rta.analyse` (for whether every message is
    schedulable, quicker)."""
    specs: list[MessageSpec] = []
    unmodelled: list[str] = []
    own: dict[str, tuple[int | None, str | None]] = {}  # the profiles' own bounds (ProfileKind.bounds)
    for name in sorted({d.profile for d in scenario.nodes}):
        kind = profile_kind(name)
        if kind.bounds is not None:
            own.update(kind.bounds(scenario))
    queues: dict[str, NodeQueue] = {}
    for d in scenario.nodes:
        kind = profile_kind(d.profile)
        if kind.traffic is None:
            unmodelled.append(f"{d.name} ({d.profile})")
            continue
        queues[d.name] = NodeQueue(d.policy, d.mailboxes, d.abort)
        # a profile's streams are its node's: that node's queue and clock
        specs.extend(
            dataclasses.replace(x, node=d.name, drift_ppm=d.drift_ppm) if not x.node else x
            for x in kind.traffic(d, scenario)
        )
    errors = None
    error_model = None
    if scenario.analysis.get("t_error_ms") is not None:
        burst = scenario.analysis.get("error_burst") or 1
        errors = ErrorModel(round(scenario.analysis["t_error_ms"] * 1e6), burst)
        error_model = {"t_error_ms": scenario.analysis["t_error_ms"], "burst": burst}
    notes: list[str] = []
    classic = [d.name for d in scenario.nodes if d.fd == "classic" and not d.listen_only]
    if classic and any(m.fd for m in scenario.messages):
        # ISO 11898-1:2015's FD-intolerant node: its error flags destroy FD frames (stack.bus.fdnodes)
        notes.append(
            f"node{'s' if len(classic) > 1 else ''} {', '.join(classic)} (fd = 'classic'): a CAN 2.0 controller "
            "destroys every CAN FD frame with an error frame until it is error passive, which no error model "
            "bounds: the analysis does not apply to this bus"
        )
        return {"results": {}, "own": own, "assumptions": {"applies": False, "notes": notes, "error_model": None}}
    if unmodelled:
        notes.append(
            "no worst-case model of the traffic of "
            + ", ".join(unmodelled)
            + ": the analysis does not apply to this bus"
        )
        if own:
            notes.append("messages with a bound of their own profile (a schedule's window) show it as rta_ms")
        return {"results": {}, "own": own, "assumptions": {"applies": False, "notes": notes, "error_model": None}}
    results = (
        analyse(
            specs,
            scenario.bitrate,
            errors=errors,
            queues=queues,
            verdict_only=verdict_only,
            data_bitrate=scenario.data_bitrate,
        )
        if specs
        else {}
    )
    methods = sorted({r.method for r in results.values()})
    if "fifo" in methods or "mailbox" in methods:
        notes.append(
            "FIFO queues and mailboxes without abort: their messages wait behind their queue's "
            "content at the priority of its lowest message, and other messages see them enter "
            "arbitration late (profiles.analysis.rta)"
        )
    return {
        "results": results,
        "own": own,
        "assumptions": {
            "applies": True,
            "notes": notes,
            "error_model": error_model,
            "method": "Davis, Burns, Bril, Lukkien 2007 (busy period, every instance); FIFO and mailbox "
            "bounds of profiles.analysis.rta",
            "methods": methods,
            "rta_ms": BOUND_REFERENCE,
            "deadlines_from": DEADLINE_REFERENCE,
        },
    }


def message_rows(scenario: Scenario, recorder: Recorder, analysis: dict[str, Any]) -> list[dict[str, Any]]:
    """One JSON object per declared message (see the module docstring)."""
    rows = []
    results = analysis.get("results", {})
    for m in scenario.messages:
        tr = recorder.tracks.get(m.name)
        r = results.get(m.name)
        resp = tr.response_stats_ms() if tr is not None else None
        rta = None
        rta_release = None
        schedulable = None
        own_note = None
        if r is not None:
            schedulable = r.schedulable
            if r.response_ns is not None and r.bound_ns is not None:
                rta = r.bound_ns / 1e6
                rta_release = r.response_ns / 1e6
        elif m.name in analysis.get("own", {}):
            bound, own_note = analysis["own"][m.name]
            if bound is not None:
                rta = bound / 1e6
                schedulable = None if m.deadline_ns is None else bound <= m.deadline_ns
        jitter = tr.jitter_ns() if tr is not None else None
        rows.append(
            {
                "name": m.name,
                "node": m.node,
                "id": m.can_id,
                "extended": m.extended,
                "dlc": m.dlc,
                "fd": m.fd,
                "brs": m.brs,
                "period_ms": None if m.period_ns is None else m.period_ns / 1e6,
                "sporadic_ms": None if m.sporadic_ns is None else m.sporadic_ns / 1e6,
                "deadline_ms": None if m.deadline_ns is None else m.deadline_ns / 1e6,
                "released": tr.released if tr else 0,
                "sent": tr.sent if tr else 0,
                "received": (tr.received if tr and tr.received is not None else (tr.sent if tr else 0)),
                "failed": tr.failed if tr else 0,
                "dropped": tr.dropped if tr else 0,
                "response_ms": resp,
                "release_response_max_ms": None if tr is None or tr.worst_release is None else tr.worst_release / 1e6,
                "jitter_ms": None if jitter is None else jitter / 1e6,
                "deadline_misses": tr.misses if tr else 0,
                "rta_ms": rta,
                "rta_release_ms": rta_release,
                "rta_method": None if r is None else r.method,
                "schedulable": schedulable,
                "tightness": None if rta is None or resp is None or rta <= 0 else resp["max"] / rta,
                "rta_note": own_note or (None if r is None or r.response_ns is not None else r.unbounded_reason),
            }
        )
    return rows


def summary_of(bus: Any, t_end: int) -> dict[str, Any]:
    """Bus load, frames and error frames of a simulated bus up to ``t_end`` (zeros without one)."""
    if bus is None:
        return {"bus_load": 0.0, "frames": 0, "error_frames": 0}
    return {"bus_load": bus.bus_load(), "frames": bus.frames_ok, "error_frames": bus.error_frames}


#: the columns of ``experiment --out r.csv`` (one row per message), in the JSON's own words
CSV_COLUMNS = (
    "name", "node", "id", "extended", "dlc", "period_ms", "sporadic_ms", "deadline_ms", "released", "sent",
    "received", "failed", "dropped", "deadline_misses", "response_min_ms", "response_mean_ms", "response_p99_ms",
    "response_max_ms", "response_p99_error", "release_response_max_ms", "jitter_ms", "rta_ms", "rta_release_ms",
    "rta_method", "schedulable", "tightness", "rta_note",
)  # fmt: skip


def message_csv_rows(result_json: dict[str, Any]) -> list[list[Any]]:
    """The messages of a result as CSV rows (header first; `CSV_COLUMNS`; empty cells for none)."""
    rows: list[list[Any]] = [list(CSV_COLUMNS)]
    for m in result_json["messages"]:
        resp = m["response_ms"] or {}
        flat = dict(m)
        for k in ("min", "mean", "p99", "max"):
            flat[f"response_{k}_ms"] = resp.get(k)
        flat["response_p99_error"] = resp.get("p99_error")
        rows.append(["" if flat.get(c) is None else flat[c] for c in CSV_COLUMNS])
    return rows


def _badness(m: dict[str, Any]) -> tuple[float, float]:
    """Worst offenders first: deadline misses, then the largest response relative to the deadline."""
    worst = m["response_ms"]["max"] if m["response_ms"] else 0.0
    d = m["deadline_ms"] or 0.0
    return (-m["deadline_misses"], -(worst / d if d else 0.0))


def _message_lines(messages: list[dict[str, Any]]) -> list[str]:
    headers = [
        "message", "node", "ID", "period", "deadline", "released", "sent", "received", "failed", "dropped",
        "miss", "resp min", "mean", "p99", "max", "from release", "RTA", "R", "sched", "max/RTA", "jitter",
    ]  # fmt: skip
    rows = []
    approx = False
    for m in sorted(messages, key=_badness):
        resp = m["response_ms"] or {}
        inexact = bool(resp.get("p99_error"))
        approx |= inexact
        interval = m["period_ms"] if m["period_ms"] is not None else m["sporadic_ms"]
        sched = {True: "yes", False: "NO", None: "-"}[m["schedulable"]]
        rows.append(
            [
                m["name"],
                m["node"],
                id_text(m["id"], m["extended"]),
                ("" if m["period_ms"] is not None or interval is None else ">=") + ms(interval, 3),
                ms(m["deadline_ms"]),
                m["released"],
                m["sent"],
                m["received"],
                m["failed"],
                m["dropped"],
                m["deadline_misses"],
                ms(resp.get("min")),
                ms(resp.get("mean")),
                ms(resp.get("p99"), mark="~" if inexact else ""),
                ms(resp.get("max")),
                ms(m["release_response_max_ms"]),
                ms(m["rta_ms"]),
                ms(m["rta_release_ms"]),
                sched,
                "-" if m["tightness"] is None else f"{m['tightness']:.2f}",
                ms(m["jitter_ms"]),
            ]
        )
    out = table(headers, rows, left=2, widest={0: 24, 1: 16})
    out.append(
        "times in ms; period '>=' a sporadic message's minimum inter-arrival; resp: queued -> end of EOF; from "
        "release: nominal release -> end of EOF; RTA bounds resp, R bounds from release"
        + ("; p99~: within ±0.5 % (a DDSketch: --samples keeps every instance for an exact one)" if approx else "")
    )
    return out


_NODE_COLUMNS = (
    ("tx", "tx_frames"), ("rx", "rx_frames"), ("rx overruns", "rx_overruns"),
    ("arb lost", "arbitration_lost"), ("retransmissions", "retransmissions"), ("tx failed", "tx_failed"),
    ("TEC", "txerr"), ("REC", "rxerr"),
)  # fmt: skip


def _node_lines(nodes: dict[str, dict[str, Any]]) -> list[str]:
    """The controllers' counters of the JSON's ``nodes``, one row per node: frames sent and
    received, receive FIFO overruns, arbitrations lost, retransmissions, requests given up, and
    the error counters (TEC, REC) at the end of the run; a counter the JSON adds is a column too."""
    known = {key for _, key in _NODE_COLUMNS}
    extra = sorted({k for c in nodes.values() for k in c} - known)
    headers = ["node"] + [h for h, _ in _NODE_COLUMNS] + extra
    keys = [key for _, key in _NODE_COLUMNS] + extra
    rows = [[name] + ["-" if c.get(k) is None else c[k] for k in keys] for name, c in nodes.items()]
    return table(headers, rows, left=1, widest={0: 16})


def _rate(bitrate: int) -> str:
    return f"{bitrate / 1e6:g} Mbit/s" if bitrate >= 1_000_000 else f"{bitrate // 1000} kbit/s"


def format_table(result_json: dict[str, Any]) -> str:
    """The readable summary of a run: bus figures, one line per message (every figure of the
    JSON's message objects), worst offenders first (deadline misses, then the largest response
    relative to the deadline), then each profile's own section, the analysis' notes and the
    messages with no bound and why."""
    r = result_json
    lines = [
        f"{r['scenario']}: {r['driver']} bus, {r['bitrate'] // 1000} kbit/s"
        + (f" (data {_rate(r['data_bitrate'])})" if r.get("data_bitrate") else "")
        + f", {r['duration']:.3f} s, "
        f"{r['frames']} frames, {r['error_frames']} error frames, bus load {100 * r['bus_load']:.1f} %"
        + (" (interrupted)" if r.get("interrupted") else ""),
        "",
    ]
    if r["messages"]:
        lines.extend(_message_lines(r["messages"]))
    else:
        lines.append("no messages declared in the scenario: the profiles' own traffic is below")
    from profiles.registry import profile_kinds

    for kind in profile_kinds().values():
        if kind.text is not None and kind.result_key in r and r[kind.result_key]:
            lines.append("")
            lines.extend(kind.text(r[kind.result_key]))
            r = dict(r)
            r.pop(kind.result_key)  # a shared key (a master and its devices) is printed once
    if any(m["rta_ms"] is not None for m in r["messages"]):
        lines.append(
            f"RTA: bound on {BOUND_REFERENCE}, as resp measures it (to the end of EOF); "
            f"deadlines, misses and schedulable: from the {DEADLINE_REFERENCE}"
        )
    a = r.get("analysis", {})
    methods = {m["rta_method"] for m in r["messages"] if m["rta_method"]}
    if len(methods) > 1:
        for method in sorted(methods):
            names = [m["name"] for m in r["messages"] if m["rta_method"] == method]
            lines.append(f"analysis: {method}: {', '.join(names)}")
    if a.get("error_model"):
        e = a["error_model"]
        lines.append(f"analysis: errors: at most {e['burst']} every {e['t_error_ms']:g} ms")
    for n in a.get("notes") or []:
        lines.append(f"analysis: {n}")
    for m in r["messages"]:
        if m["rta_note"]:
            lines.append(f"analysis: {m['name']}: {m['rta_note']}")
    unsched = [m["name"] for m in r["messages"] if m["schedulable"] is False]
    if unsched:
        lines.append("analysis: not schedulable: " + ", ".join(unsched))
    if r.get("nodes"):
        lines.append("")
        lines.extend(_node_lines(r["nodes"]))
        lines.append(
            "controllers at the end of the run: rx counts frames taken into the receive FIFO, rx overruns those "
            "lost to a full FIFO (a profile that does not read its receptions fills it); TEC/REC the error counters"
        )
    if r.get("driver_errors"):
        lines.append(f"driver errors: {'; '.join(r['driver_errors'])}")
    return "\n".join(lines)
