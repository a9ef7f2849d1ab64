"""The schedule as the bus shows it: every frame that went out, placed against the time windows
of the basic cycle it fell in, and the figures of the ``tdma`` result.

One `Monitor` per scenario (the first TDMA profile makes it; the others find it through the
context). The windows of a basic cycle are placed on the bus from the start of frame of its
reference message, in the time of the time master that sent it (a master whose oscillator drifts
has its windows drift with it — the schedule *is* the master's clock). Each frame is classified
as it completes (the reference message of its cycle is always known by then): inside its window
when it starts no earlier and ends no later than one NTU (the schedule's time resolution) beyond
the window's bounds.

Where the frames' times come from:

- on the simulated bus, from `TxDone`/`TxFailed` of every node: the bus times the requests keep
  (``sof``, ``t_done``) are exact and do not depend on any node being connected;
- on a python-can bus the driver only estimates a request's times (stamped when ``send``
  returns), so frames are observed where they are received: at the first node of the scenario
  (and at the second for the first one's own frames), start of frame and end as the driver
  reports receptions — exact on the canstack interface and SocketCAN, whose timestamps are the
  end of the frame; on python-can's ``virtual`` bus, which has no wire time, starts read one
  frame length early. `TxFailed` still says which instances were withdrawn.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from profiles.base import frame_of
from profiles.tdma.schedule import ARBITRATING, EXCLUSIVE, Window, decode_reference
from stack import LocalClock, Received, TxDone, TxFailed

if TYPE_CHECKING:  # pragma: no cover
    from profiles.base import Context, Profile
    from profiles.declarations import Scenario
    from profiles.tdma.schedule import Schedule

__all__ = ["Monitor", "master_clock", "window_bounds", "message_bounds"]


def master_clock(scenario: Scenario, schedule: Schedule, priority: int) -> LocalClock | None:
    """The oscillator of the time master of ``priority`` (None when it is perfect)."""
    d = scenario.node(schedule.masters[priority])
    if not d.drift_ppm and not d.clock_offset_ns:
        return None
    return LocalClock(offset_ns=d.clock_offset_ns, drift_ppm=d.drift_ppm)


def window_bounds(clock: LocalClock | None, ref_sof: int, start_ns: int, end_ns: int) -> tuple[int, int]:
    """Bus times of cycle times ``start_ns``..``end_ns`` (NTU ns of the master's clock) in the
    basic cycle whose reference message started at bus time ``ref_sof``."""
    if clock is None:
        return ref_sof + start_ns, ref_sof + end_ns
    mark = clock.local(ref_sof)
    return clock.bus(mark + start_ns), clock.bus(mark + end_ns)


def message_bounds(schedule: Schedule, name: str) -> tuple[int | None, int | None, str | None]:
    """The analytic worst case of a TDMA message, ns: (bound on the measured response — release
    at the window's start to the end of EOF —, bound on the latency of data ready at any time,
    why there is none).

    In an exclusive window nothing contends: the frame starts within Tx_Enable and ends one
    worst-case frame later, so response <= Tx_Enable + C (C without the intermission). Data ready
    just after a window waits for the message's next window: latency <= the longest distance
    between consecutive windows of the message over the matrix + that response. In an arbitrating
    window nothing is guaranteed (it may lose every round). Neither bound covers a cycle whose
    reference came late (a backup master's takeover adds its Initial_Ref_Offset once) nor
    errors (exclusive windows do not retransmit).
    """
    ws = schedule.windows_of(name)
    if not ws:
        return None, None, "in no window"
    if any(w.kind != EXCLUSIVE for w in ws):
        return None, None, "arbitrating window: no guarantee (the frame may lose arbitration every time)"
    c = schedule.frame_ns[name] - schedule.bits(3)
    response = schedule.tx_enable_ns + c
    starts = sorted(
        k * schedule.basic_cycle_ns + w.start_ns for k in range(schedule.matrix_cycles) for w in ws if w.active(k)
    )
    span = schedule.matrix_cycles * schedule.basic_cycle_ns
    gaps = [b - a for a, b in zip(starts, starts[1:])] + [starts[0] + span - starts[-1]]
    return response, max(gaps) + response, None


def _stats_us(values: list[int]) -> dict[str, float]:
    """min, mean, p99 (nearest rank) and max of ns values, in µs."""
    v = sorted(values)
    return {
        "min": v[0] / 1000,
        "mean": sum(v) / len(v) / 1000,
        "p99": v[max(0, math.ceil(0.99 * len(v)) - 1)] / 1000,
        "max": v[-1] / 1000,
    }


@dataclass
class _WindowStats:
    frames: int = 0
    late_starts: int = 0
    failed: int = 0
    lost_arbitration: int = 0
    outside: int = 0
    intrusions: int = 0


@dataclass
class _MessageStats:
    frames: int = 0
    late_starts: int = 0
    failed: int = 0
    lost_arbitration: int = 0
    outside: int = 0
    offsets: list[int] = field(default_factory=list)


@dataclass
class _Traffic:
    frames: int = 0
    outside: int = 0
    late_starts: int = 0


class _Cycle:
    """A basic cycle on the bus: its reference message's SOF, Cycle_Count, master, and the bus
    times of its active windows."""

    __slots__ = ("sof", "count", "priority", "bounds")

    def __init__(self, sof: int, count: int, priority: int, bounds: list[tuple[Window, int, int]]) -> None:
        self.sof = sof
        self.count = count
        self.priority = priority
        self.bounds = bounds


class Monitor:
    """Bookkeeping of the schedule on the bus (see the module docstring)."""

    def __init__(self, schedule: Schedule, context: Context) -> None:
        self.schedule = schedule
        self.context = context
        sc = context.scenario
        self.clocks = [master_clock(sc, schedule, p) for p in range(len(schedule.masters))]
        self.gated_names = set(schedule.gated)
        self.gates: dict[str, Any] = {}
        self._tags: dict[Any, tuple[Window, str]] = {}
        self._sent: dict[str, deque[Any]] = {name: deque() for name in schedule.message_windows}
        self._attached = False
        self.observers: list[str] = []
        self.senders = {frame_of(m).key: n.name for n in sc.nodes for m in n.messages}
        self.message_of = {frame_of(m).key: m.name for n in sc.nodes if n.profile == "tdma" for m in n.messages}
        self.senders.update({schedule.reference_frame(p, 0).key: name for p, name in enumerate(schedule.masters)})
        self.cycle: _Cycle | None = None
        self.reference_messages = 0
        self.by_master = [0] * len(schedule.masters)
        self.late_references = 0
        self.missing = 0
        self.switches: list[dict[str, Any]] = []
        self.windows = {w.index: _WindowStats() for w in schedule.windows}
        self.messages = {name: _MessageStats() for name in schedule.message_windows}
        self.gated = {name: _Traffic() for name in schedule.gated}
        self.unscheduled = _Traffic()
        self.profiles: list[Profile] = []
        self.tol = schedule.ntu(1)

    @classmethod
    def of(cls, context: Context, schedule: Schedule) -> Monitor:
        """The scenario's monitor (made by the first TDMA profile built)."""
        for p in context.profiles.values():
            m = getattr(p, "monitor", None)
            if isinstance(m, Monitor):
                return m
        return cls(schedule, context)

    def attach(self, gate_factory: Any) -> None:
        """Listen to every node of the scenario and gate the CSMA nodes the schedule gates
        (``gate_factory(node, name, schedule)`` makes a node's gate); once, at the first TDMA
        start."""
        if self._attached:
            return
        self._attached = True
        simulated = self.context.bus is not None
        for name, node in self.context.nodes.items():
            if simulated:
                node.listen(TxDone, lambda ev, name=name: self._done(name, ev))
            node.listen(TxFailed, lambda ev, name=name: self._failed(name, ev))
        if not simulated:
            self.observers = list(self.context.nodes)[:2]
            for name in self.observers:
                self.context.nodes[name].subscribe(lambda ev, name=name: self._seen(name, ev))
        for name in self.schedule.gated:
            prof = self.context.profiles.get(name)
            if prof is not None and hasattr(prof, "gate"):
                g = gate_factory(self.context.nodes[name], name, self.schedule)
                self.gates[name] = g
                prof.gate = g.gate
                g.start()

    def tag(self, req: Any, window: Window, message: str) -> None:
        """``req`` is an instance of ``message`` sent for ``window``."""
        self._tags[req] = (window, message)
        if self.observers:
            self._sent[message].append(req)

    # ------------------------------------------------------------------ events
    def _reference(self, sof: int, priority: int, data: bytes) -> None:
        s = self.schedule
        info = decode_reference(data, s.level)
        count = info.cycle_count if info is not None else 0
        clock = self.clocks[priority]
        cycle = s.basic_cycle_ns if clock is None else clock.duration_bus(s.basic_cycle_ns)
        last = self.cycle
        if last is not None:
            gap = sof - last.sof
            slack = s.watch_ns - s.basic_cycle_ns
            self.missing += max(0, (gap - slack) // cycle)
            if gap > cycle + s.ntu_length:
                self.late_references += 1
            if priority != last.priority:
                # a reference of the new master inside the cycle the old one started (the old
                # one's was late, or both sent theirs) ends that cycle early: no time after its end
                self.switches.append(
                    {
                        "at_ms": sof / 1e6,
                        "from": s.masters[last.priority],
                        "to": s.masters[priority],
                        "after_reference_us": gap / 1000,
                        "after_cycle_end_us": max(0, gap - cycle) / 1000,
                        "cut_cycle_short": gap < cycle,
                    }
                )
        self.reference_messages += 1
        self.by_master[priority] += 1
        bounds = [(w, *window_bounds(clock, sof, w.start_ns, w.end_ns)) for w in s.windows if w.active(count)]
        self.cycle = _Cycle(sof, count, priority, bounds)

    def _done(self, node: str, ev: TxDone) -> None:
        req = ev.request
        self._frame(node, ev.frame, req.sof, req.t_done, self._tags.pop(req, None))

    def _seen(self, observer: str, ev: Received) -> None:
        """A python-can bus: a frame as an observer received it (the first observer reports every
        frame but its own, which the second reports)."""
        f = ev.frame
        sender = self.senders.get(f.key)
        first = self.observers[0]
        if sender == observer or (observer != first and sender != first):
            return
        tag = None
        q = self._sent.get(self.message_of.get(f.key, ""))
        while q and tag is None:  # the oldest instance handed to the bus (withdrawn ones lost their tag)
            tag = self._tags.pop(q.popleft(), None)
        sof = ev.sof if ev.sof >= 0 else ev.time
        self._frame(sender or "", f, sof, ev.time, tag)

    def _frame(self, node: str, f: Any, sof: int, end: int, tag: tuple[Window, str] | None) -> None:
        """Place a frame that went out (bus times ``sof``..``end``) against the schedule."""
        prio = None if f.remote else self.schedule.priority_of(f.can_id, f.extended)
        if prio is not None:
            self._reference(sof, prio, f.data)
            return
        cyc = self.cycle
        bounds = cyc.bounds if cyc is not None else []
        tol = self.tol  # the schedule's resolution: one NTU either side
        if tag is not None:
            w, name = tag
            ws, ms = self.windows[w.index], self.messages[name]
            ws.frames += 1
            ms.frames += 1
            mine = next(((a, b) for x, a, b in bounds if x is w), None)
            if mine is not None:
                ms.offsets.append(sof - mine[0])
            if mine is None or not (mine[0] - tol <= sof and end <= mine[1] + tol):
                ws.outside += 1
                ms.outside += 1
        else:
            t = self.gated[node] if node in self.gated_names else self.unscheduled
            t.frames += 1
            if not any(x.kind == ARBITRATING and a - tol <= sof and end <= b + tol for x, a, b in bounds):
                t.outside += 1
        for x, a, b in bounds:
            if sof < b - tol and a + tol < end:
                own = tag[0] is x if tag is not None else x.kind == ARBITRATING
                legit = own and a - tol <= sof and end <= b + tol
                if not legit:
                    self.windows[x.index].intrusions += 1

    def _failed(self, node: str, ev: TxFailed) -> None:
        tag = self._tags.pop(ev.request, None)
        if tag is not None:
            w, name = tag
            what = {"expired": "late_starts", "arbitration": "lost_arbitration", "aborted": None}.get(ev.kind, "failed")
            if what is not None:
                for st in (self.windows[w.index], self.messages[name]):
                    setattr(st, what, getattr(st, what) + 1)
        elif node in self.gated_names and ev.kind == "expired":
            self.gated[node].late_starts += 1

    # ------------------------------------------------------------------ results
    def summary(self) -> dict[str, Any]:
        """The ``tdma`` object of the results (see the README section)."""
        s = self.schedule
        bus = self.context.bus
        missing = self.missing
        if bus is not None and self.cycle is not None:
            clock = self.clocks[self.cycle.priority]
            cycle = s.basic_cycle_ns if clock is None else clock.duration_bus(s.basic_cycle_ns)
            missing += max(0, (bus.now() - self.cycle.sof - (s.watch_ns - s.basic_cycle_ns)) // cycle)
        windows = []
        for w in s.windows:
            st = self.windows[w.index]
            windows.append(
                {
                    "window": w.index,
                    "kind": w.kind,
                    "start_us": w.start_ns / 1000,
                    "length_us": w.length_ns / 1000,
                    "base_cycle": w.base_cycle,
                    "repeat": w.repeat,
                    "messages": list(w.messages),
                    "frames": st.frames,
                    "late_starts": st.late_starts,
                    "failed": st.failed,
                    "lost_arbitration": st.lost_arbitration,
                    "outside": st.outside,
                    "intrusions": st.intrusions,
                }
            )
        messages = []
        for name, ms in self.messages.items():
            rta, latency, note = message_bounds(s, name)
            off = ms.offsets
            row: dict[str, Any] = {
                "name": name,
                "node": s.owners[name],
                "windows": [s.windows[i].index for i in s.message_windows[name]],
                "frames": ms.frames,
                "late_starts": ms.late_starts,
                "failed": ms.failed,
                "lost_arbitration": ms.lost_arbitration,
                "outside": ms.outside,
                "start_offset_us": None if not off else _stats_us(off),
                "jitter_us": None if not off else (max(off) - min(off)) / 1000,
                "rta_ms": None if rta is None else rta / 1e6,
                "latency_bound_ms": None if latency is None else latency / 1e6,
            }
            if note:
                row["rta_note"] = note
            messages.append(row)
        nodes = {p.decl.name: p.summary() for p in self.profiles}
        for name, g in self.gates.items():
            nodes[name] = g.state()
        outside = (
            sum(st.outside for st in self.windows.values())
            + sum(t.outside for t in self.gated.values())
            + self.unscheduled.outside
        )
        return {
            "level": s.level,
            "basic_cycle_us": s.basic_cycle_ns / 1000,
            "matrix_cycles": s.matrix_cycles,
            "tx_enable_us": s.tx_enable_ns / 1000,
            "reference_messages": self.reference_messages,
            "references_by_master": dict(zip(s.masters, self.by_master)),
            "cycles_without_reference": missing,
            "late_references": self.late_references,
            "master_switches": len(self.switches),
            "switches": self.switches,
            "outside": outside,
            "windows": windows,
            "messages": messages,
            "gated": {n: vars(t) for n, t in self.gated.items()},
            "unscheduled": vars(self.unscheduled),
            "nodes": nodes,
        }
