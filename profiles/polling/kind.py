"""What master/slave polling adds to scenario files: ``profile = "master"`` and ``profile = "slave"``,
their keys, the network check, the worst-case traffic, the results and their table.

Results (``master_slave`` in the JSON): per master ``cycles``, ``cycle_ms`` (the measured
cycle, first request's SOF to the end of the last transaction), ``overruns``, the worst case
beside them (``cycle_bound_ms``, how it was found, and per transaction); per slave ``polls``,
``responses``, ``timeouts``, ``missed``, ``lost``, ``response_ms`` (request SOF to response
end), and what the slave saw (requests, loss of master).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from profiles.polling.analysis import cycle_bound_ns, holistic, message_bits, transaction_bound_ns
from profiles.polling.config import MASTER_KEYS, NETWORK_TABLE, SLAVE_KEYS, SLAVE_MESSAGE_KEYS
from profiles.polling.convert import express_message_set  # noqa: F401  (the profiles study finds it here)
from profiles.polling.master import Master
from profiles.polling.parse import parse_network
from profiles.polling.plots import poll_cycle
from profiles.polling.slave import Slave
from profiles.registry import ProfileKind
from profiles.text import intervals_ms, table

if TYPE_CHECKING:  # pragma: no cover
    from profiles.analysis.rta import MessageSpec
    from profiles.base import Context, Profile
    from profiles.declarations import NodeDecl, Scenario
    from profiles.polling.config import Network
    from stack import NodeAPI

__all__ = ["MASTER", "SLAVE", "KINDS", "PLOTS", "summarize", "text"]


def _build_master(node: NodeAPI, decl: NodeDecl, context: Context) -> Master:
    return Master(node, decl, context)


def _build_slave(node: NodeAPI, decl: NodeDecl, context: Context) -> Slave:
    return Slave(node, decl, context)


def _traffic(decl: NodeDecl, scenario: Scenario) -> list[MessageSpec]:
    """The node's streams in the holistic model (`profiles.polling.analysis`)."""
    return holistic(scenario).specs.get(decl.name, [])


def _alone(scenario: Scenario, net: Network, master: str) -> str | None:
    """Why the frame-length bound does not apply to this master's cycle (None: it does) — it needs
    the cycle alone on a fault-free bus."""
    mine = {master, *net.masters[master].slaves}
    for d in scenario.nodes:
        # a silent CSMA node (it only acknowledges) is the one other kind that sends nothing
        if d.name not in mine and not d.listen_only and (d.messages or d.profile != "csma"):
            return f"node {d.name!r} ({d.profile}) sends on the same bus"
    for s in net.masters[master].slaves:
        if net.slaves[s].cos:
            return f"slave {s!r} produces change-of-state / cyclic messages outside the poll"
    if scenario.analysis.get("t_error_ms") is not None:
        return "the error model ([analysis] t_error_ms) adds retransmissions"
    return None


def _ms(v: Any) -> float | None:
    return None if v is None else float(v) / 1e6


def _in_window(scenario: Scenario, windows: list[tuple[int, int, bool]]) -> list[list[Any]]:
    w = scenario.plot.get("window_ms")
    t0, t1 = (round(w[0] * 1e6), round(w[1] * 1e6)) if w else (0, 50_000_000)
    return [[a / 1e6, b / 1e6, ov] for a, b, ov in windows if b >= t0 and a <= t1]


def summarize(profiles: list[Profile], context: Context) -> dict[str, Any]:
    """``master_slave`` of the results: every master's cycle beside its worst case, and every
    slave as its master and itself saw it (see the package docstring)."""
    sc = context.scenario
    net: Network = sc.tables[NETWORK_TABLE]
    stuffing = sc.analysis.get("stuffing", "worst")
    h = holistic(sc)
    out: dict[str, Any] = {"masters": {}, "slaves": {}}
    for p in profiles:
        if not isinstance(p, Master):
            continue
        cfg = p.config
        chain = cycle_bound_ns(cfg, net.slaves, sc.bitrate, stuffing)
        rta = h.cycle_ns.get(cfg.name)
        why = _alone(sc, net, cfg.name)
        fig = p.figures()
        fig["cycle_period_ms"] = cfg.cycle_ns / 1e6
        fig["cycle_bound_ms"] = _ms(chain) if why is None else _ms(rta)
        fig["bound_method"] = (
            "frame lengths, processing delays and inter-frame spaces (the cycle alone on a fault-free bus)"
            if why is None
            else f"holistic response-time analysis ({why})"
            if rta is not None
            else f"none ({why}; " + ("; ".join(h.notes) or "the analysis does not apply") + ")"
        )
        if sc.faults:
            fig["bound_note"] = (
                "the scenario injects faults: the bound is the fault-free cycle's (clean_cycle_ms: "
                "the cycles in which every slave due answered in time)"
            )
        fig["chain_bound_ms"] = _ms(chain)
        fig["rta_cycle_bound_ms"] = _ms(rta)
        fig["rta_notes"] = h.notes
        txs = []
        tau = 1e9 / sc.bitrate
        done = 0.0  # the alone bound on the end of the transactions so far, ns
        for tx in cfg.transactions:
            alone = float(transaction_bound_ns(tx, net.slaves, sc.bitrate, stuffing))
            start = done + (3 * tau if done else 0.0)
            done = start + alone
            offsets: tuple[float, float] | None
            if why is None:
                offsets = (start + message_bits(tx.request, stuffing) * tau, done)
            else:
                offsets = h.offsets_ns.get(tx.request.name)
            worst = [p.links[s].response.figures() for s in tx.slaves]
            measured = max((f[2] for f in worst if f is not None), default=None)
            txs.append(
                {
                    "name": tx.request.name,
                    "style": tx.style,
                    "slaves": list(tx.slaves),
                    "timeout_ms": tx.timeout_ns / 1e6,
                    "retries": tx.retries,
                    "bound_ms": _ms(alone),
                    "rta_bound_ms": _ms(h.transaction_ns.get(tx.request.name)),
                    "response_ms_max": _ms(measured),
                    # from the cycle's start (the master queues its first request): when the
                    # request's data reached the slave(s), and when the last answer came back
                    "request_end_ms_max": _ms(p.stats.offsets[tx.request.name][0] or None),
                    "request_end_bound_ms": None if offsets is None else _ms(offsets[0]),
                    "end_ms_max": _ms(p.stats.offsets[tx.request.name][1] or None),
                    "end_bound_ms": None if offsets is None else _ms(offsets[1]),
                }
            )
        fig["transactions"] = txs
        fig["window_cycles_ms"] = _in_window(sc, p.stats.windows)
        out["masters"][cfg.name] = fig
        for s in cfg.slaves:
            row = {"master": cfg.name}
            row.update(p.link_figures(s))
            slave = context.profiles.get(s)
            if isinstance(slave, Slave):
                row.update(slave.figures())
            out["slaves"][s] = row
    return out


def _f(v: Any, width: int = 7) -> str:
    return f"{v:{width}.3f}" if v is not None else f"{'-':>{width}}"


def _lost(s: dict[str, Any]) -> str:
    """A slave's lost intervals (ms; poll and COS/cyclic connections)."""
    spans = sorted([*s.get("lost_ms", []), *s.get("cos_lost_ms", [])], key=lambda x: x[0])
    if not spans and (s["lost"] or s.get("cos_lost")):
        return "yes"
    return intervals_ms(spans)


def _master_lost(s: dict[str, Any]) -> str:
    """When a slave lost its master (watchdog) and got it back, ms."""
    lost, back = s.get("master_lost_ms", []), s.get("master_back_ms", [])
    spans = [[a, back[i] if i < len(back) else None] for i, a in enumerate(lost)]
    return intervals_ms(spans)


def text(figures: dict[str, Any]) -> list[str]:
    """The readable table's lines of ``master_slave``: per master its measured cycle beside the
    worst case and what happened to it (overruns, unsent requests, stops, slaves lost and back),
    per transaction its slowest exchange beside its bound, per slave what happened — the
    intervals it was lost and those it lost its master included."""
    lines = []
    for name, m in figures.get("masters", {}).items():
        c, clean = m["cycle_ms"] or {}, m["clean_cycle_ms"] or {}
        lines.append(
            f"master {name}: {m['cycles']} cycles of {m['cycle_period_ms']:g} ms, {m['overruns']} overruns, "
            f"{m['unsent']} requests not sent; cycle {_f(c.get('min'), 0)}..{_f(c.get('max'), 0)} ms (answered in "
            f"time: max {_f(clean.get('max'), 0)}), worst case {_f(m['cycle_bound_ms'], 0)} ms by {m['bound_method']}"
        )
        if m.get("bound_note"):
            lines.append(f"  {m['bound_note']}")
        events = ", ".join(f"{k} {v}" for k, v in (m.get("events") or {}).items())
        if events:
            lines.append(f"  events: {events}")
        if m.get("stopped_ms"):
            lines.append(f"  stopped (bus off) at: {', '.join(f'{t:.3f}' for t in m['stopped_ms'])} ms")
        rows = []
        for t in m["transactions"]:
            bound = t["bound_ms"] if m["bound_method"].startswith("frame") else t["rta_bound_ms"]
            rows.append([t["name"], t["style"], _f(t["response_ms_max"], 0), _f(bound, 0)])
        lines += table(["transaction", "style", "exchange max", "bound"], rows, left=2, widest={0: 24})
        lines[-len(rows) - 1] += "  (ms, request SOF -> end of the last answer)"
    slaves = figures.get("slaves", {})
    if slaves:
        rows = []
        for name, s in slaves.items():
            r = s["response_ms"] or {}
            rows.append(
                [
                    name,
                    s["polls"],
                    s["responses"],
                    s["timeouts"],
                    s["missed"],
                    _f(r.get("max"), 0),
                    _f(s["jitter_ms"], 0),
                    s["cos"],
                    _lost(s),
                    _master_lost(s),
                ]
            )
        lines += table(
            ["slave", "polls", "answers", "timeouts", "missed", "resp max", "jitter", "cos", "lost (ms)",
             "master lost (ms)"],
            rows,
            left={0, 8, 9},
            widest={0: 16},
        )  # fmt: skip
    return lines


_FD_NOTE = (
    "master/slave polling sends classical CAN frames only (its fragments and its analysis are for 8-byte "
    "frames); CAN FD messages go on csma nodes"
)

MASTER = ProfileKind(
    name="master",
    build=_build_master,
    node_keys=MASTER_KEYS,
    timed_messages=False,
    parse=parse_network,
    result_key="master_slave",
    summarize=summarize,
    traffic=_traffic,
    text=text,
    description="master/slave polling: the master runs its poll list as a cycle",
    fd_note=_FD_NOTE,
)
"""``profile = "master"``: runs its poll list as a cycle."""

SLAVE = ProfileKind(
    name="slave",
    build=_build_slave,
    node_keys=SLAVE_KEYS,
    message_keys=SLAVE_MESSAGE_KEYS,
    timed_messages=False,
    traffic=_traffic,
    description="master/slave polling: a slave answers its master's requests",
    fd_note=_FD_NOTE,
)
"""``profile = "slave"``: answers its master's requests."""

KINDS = (MASTER, SLAVE)
"""The kinds this package adds (the registry reads them: see `profiles.registry`)."""

PLOTS = {"poll_cycle": poll_cycle}
"""Plots ``canstack experiment --plot`` adds for a scenario with a master."""
