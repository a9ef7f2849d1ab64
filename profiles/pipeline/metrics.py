"""Metrics of a run, the response-time analysis beside them, and the readable table.

Per declared message: ``released``, ``sent``, ``received``, ``response_ms`` (min/mean/p99/max,
release — the instance queued at its node — to the end of its successful transmission, the end
of EOF), ``jitter_ms`` (max − min of the start-to-start distance, periodic messages),
``deadline_misses``, and from the analysis of Davis, Burns, Bril and Lukkien (2007,
`profiles.analysis.rta`): ``rta_ms``, the bound on the measured response, and ``schedulable``,
the analysis' verdict (both null where the analysis does not apply), with ``tightness``, the
simulated maximum over the bound.

The analysis' R is measured from the nominal release (jitter included: R = J + w + C); the
simulation measures from the moment the instance is queued, which is J at most after it — so
the bound on what is measured is R − J (`rta_ms`), and R itself is ``rta_release_ms``.

Where the analysis does not apply: a node whose controller does not send its highest-priority
frame first (FIFO queue, mailboxes) breaks its assumption — its own messages can wait behind
its lower-priority ones (priority inversion), and a message delayed that way reaches the bus
later than the analysis assumes, so every message of lower priority than one of that node's is
left without a bound too. Traffic the analysis has no model of (a profile without one) leaves
the whole bus without.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from profiles.analysis.rta import ErrorModel, MessageSpec, analyse
from profiles.base import Recorder, stats_ms
from profiles.registry import profile_kind
from stack import arbitration_key

if TYPE_CHECKING:  # pragma: no cover
    from profiles.declarations import Scenario

__all__ = ["analyse_scenario", "message_rows", "summary_of", "format_table"]


def _key(m: Any) -> int:
    return arbitration_key(m.can_id, m.extended, False)


def analyse_scenario(scenario: Scenario) -> dict[str, Any]:
    """The response-time analysis of the scenario's bus: ``results`` by message name (only
    where it applies) and ``assumptions`` (what was analysed, what was left out and why)."""
    specs: list[MessageSpec] = []
    unmodelled: list[str] = []
    own: dict[str, tuple[int | None, str | None]] = {}  # the profiles' own bounds (ProfileKind.bounds)
    for name in sorted({d.profile for d in scenario.nodes}):
        kind = profile_kind(name)
        if kind.bounds is not None:
            own.update(kind.bounds(scenario))
    for d in scenario.nodes:
        kind = profile_kind(d.profile)
        if kind.traffic is None:
            unmodelled.append(f"{d.name} ({d.profile})")
            continue
        specs.extend(kind.traffic(d, scenario))
    errors = None
    if scenario.analysis.get("t_error_ms") is not None:
        errors = ErrorModel(round(scenario.analysis["t_error_ms"] * 1e6))
    notes: list[str] = []
    excluded: dict[str, str] = {}
    if unmodelled:
        notes.append(
            "no worst-case model of the traffic of "
            + ", ".join(unmodelled)
            + ": the analysis does not apply to this bus"
        )
        if own:
            notes.append("messages with a bound of their own profile (a schedule's window) show it as rta_ms")
        return {"results": {}, "own": own, "assumptions": {"applies": False, "notes": notes, "error_model": None}}
    # nodes that do not send their highest-priority frame first
    lowest_inverting: int | None = None
    for d in scenario.nodes:
        if d.priority_queue:
            continue
        for m in d.messages:
            excluded[m.name] = f"node {d.name!r} uses a {d.queue} queue (priority inversion)"
            k = _key(m)
            lowest_inverting = k if lowest_inverting is None else min(lowest_inverting, k)
    if lowest_inverting is not None:
        for m in scenario.messages:
            if m.name not in excluded and _key(m) > lowest_inverting:
                excluded[m.name] = "lower priority than a message of a node with priority inversion"
        notes.append(
            "FIFO queues and mailboxes break the analysis' assumption that each node sends its "
            "highest-priority pending frame: no bound for their messages nor for any of lower priority"
        )
    results = analyse(specs, scenario.bitrate, errors=errors) if specs else {}
    for name in excluded:
        results.pop(name, None)
    return {
        "results": results,
        "excluded": excluded,
        "own": own,
        "assumptions": {
            "applies": True,
            "notes": notes,
            "excluded": excluded,
            "error_model": None if errors is None else {"t_error_ms": scenario.analysis["t_error_ms"]},
            "method": "Davis, Burns, Bril, Lukkien 2007 (busy period, every instance)",
        },
    }


def message_rows(scenario: Scenario, recorder: Recorder, analysis: dict[str, Any]) -> list[dict[str, Any]]:
    """One JSON object per declared message (see the module docstring)."""
    rows = []
    results = analysis.get("results", {})
    for m in scenario.messages:
        tr = recorder.tracks.get(m.name)
        r = results.get(m.name)
        resp = stats_ms(tr.responses) if tr is not None else None
        rta = None
        rta_release = None
        schedulable = None
        own_note = None
        if r is not None:
            schedulable = r.schedulable
            if r.response_ns is not None:
                rta = (r.response_ns - m.jitter_ns) / 1e6
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
                "period_ms": None if m.period_ns is None else m.period_ns / 1e6,
                "sporadic_ms": None if m.sporadic_ns is None else m.sporadic_ns / 1e6,
                "deadline_ms": None if m.deadline_ns is None else m.deadline_ns / 1e6,
                "released": tr.released if tr else 0,
                "sent": tr.sent if tr else 0,
                "received": (tr.received if tr and tr.received is not None else (tr.sent if tr else 0)),
                "failed": tr.failed if tr else 0,
                "dropped": tr.dropped if tr else 0,
                "response_ms": resp,
                "jitter_ms": None if jitter is None else jitter / 1e6,
                "deadline_misses": tr.misses if tr else 0,
                "rta_ms": rta,
                "rta_release_ms": rta_release,
                "schedulable": schedulable,
                "tightness": None if rta is None or resp is None or rta <= 0 else resp["max"] / rta,
                "rta_note": analysis.get("excluded", {}).get(m.name)
                or own_note
                or (None if r is None or r.response_ns is not None else r.unbounded_reason),
            }
        )
    return rows


def summary_of(bus: Any, t_end: int) -> dict[str, Any]:
    """Bus load, frames and error frames of a simulated bus up to ``t_end`` (zeros without one)."""
    if bus is None:
        return {"bus_load": 0.0, "frames": 0, "error_frames": 0}
    return {"bus_load": bus.bus_load(), "frames": bus.frames_ok, "error_frames": bus.error_frames}


def _ms(v: float | None, width: int = 8) -> str:
    return f"{v:{width}.3f}" if v is not None else f"{'-':>{width}}"


def format_table(result_json: dict[str, Any]) -> str:
    """The readable summary of a run: bus figures, then one line per message, worst offenders
    first (deadline misses, then the largest response relative to the deadline)."""
    r = result_json
    lines = [
        f"{r['scenario']}: {r['driver']} bus, {r['bitrate'] // 1000} kbit/s, {r['duration']:.3f} s, "
        f"{r['frames']} frames, {r['error_frames']} error frames, bus load {100 * r['bus_load']:.1f} %"
        + (" (interrupted)" if r.get("interrupted") else ""),
        "",
    ]

    def badness(m: dict[str, Any]) -> tuple[float, float]:
        worst = m["response_ms"]["max"] if m["response_ms"] else 0.0
        d = m["deadline_ms"] or 0.0
        return (-m["deadline_misses"], -(worst / d if d else 0.0))

    lines.append(
        f"{'message':<16} {'node':<10} {'ID':>10} {'sent':>6} {'miss':>5} "
        f"{'resp min':>8} {'mean':>8} {'p99':>8} {'max':>8} {'RTA':>8} {'max/RTA':>7} {'jitter':>8}  (ms)"
    )
    for m in sorted(r["messages"], key=badness):
        resp = m["response_ms"] or {}
        ident = f"0x{m['id']:08X}" if m["extended"] else f"0x{m['id']:03X}"
        tight = f"{m['tightness']:7.2f}" if m["tightness"] is not None else f"{'-':>7}"
        lines.append(
            f"{m['name'][:16]:<16} {m['node'][:10]:<10} {ident:>10} {m['sent']:>6} {m['deadline_misses']:>5} "
            f"{_ms(resp.get('min'))} {_ms(resp.get('mean'))} {_ms(resp.get('p99'))} {_ms(resp.get('max'))} "
            f"{_ms(m['rta_ms'])} {tight} {_ms(m['jitter_ms'])}"
        )
    from profiles.registry import profile_kinds

    for kind in profile_kinds().values():
        if kind.text is not None and kind.result_key in r and r[kind.result_key]:
            lines.append("")
            lines.extend(kind.text(r[kind.result_key]))
            r = dict(r)
            r.pop(kind.result_key)  # a shared key (a master and its devices) is printed once
    notes = r.get("analysis", {}).get("notes") or []
    for n in notes:
        lines.append(f"analysis: {n}")
    unsched = [m["name"] for m in r["messages"] if m["schedulable"] is False]
    if unsched:
        lines.append("analysis: not schedulable: " + ", ".join(unsched))
    return "\n".join(lines)
