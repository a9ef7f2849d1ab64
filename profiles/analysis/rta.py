"""Worst-case response times of CAN messages (fixed priority, non-preemptive): Davis et al. 2007
for priority queues, and bounds for FIFO queues and transmit mailboxes.

References
- [D07] R. I. Davis, A. Burns, R. J. Bril, J. J. Lukkien, "Controller Area Network (CAN)
  schedulability analysis: Refuted, revisited and revised", Real-Time Systems 35(3):239-272, 2007
  (doi:10.1007/s11241-007-9012-7).
- [T95] K. Tindell, A. Burns, A. Wellings, "Calculating Controller Area Network (CAN) message
  response times", Control Engineering Practice 3(8), 1995: the first-instance analysis D07
  refutes (``analyse_1994``).
- [D11] R. I. Davis, S. Kollmann, V. Pollex, F. Slomka, "Controller Area Network (CAN)
  schedulability analysis with FIFO queues", ECRTS 2011, 45-56; extended in Real-Time Systems
  49(1), 2013 (FIFO queues, priority queues and gateways).
- [K10] D. A. Khan, R. J. Bril, N. Navet, "Integrating hardware limitations in CAN
  schedulability analysis", WFCS 2010, 207-210; [K11] D. A. Khan, R. I. Davis, N. Navet,
  "Schedulability analysis of CAN with non-abortable transmission requests", ETFA 2011.

What is quoted and what is derived. D07's formulas below are checked by hand-worked examples in
tests/profiles/test_rta.py (section numbers of the journal version; its equation numbers were not
re-checked against the text). The texts of D11, K10 and K11 could not be consulted when this was
written (their abstracts only), so none of their equations is quoted: the FIFO and mailbox
bounds are my derivation, proved below, in D11's approach as its abstract and the literature
describe it (a FIFO's messages wait behind the FIFO's content at the priority of its lowest
message, and other messages see them with the extra jitter of their time in the queue). K10/K11
analyse non-abortable buffers refilled from a *priority-ordered* software queue; the engine's
mailboxes (`stack.controller.queues.MailboxQueue`) are refilled from a *FIFO* backlog, which
their analysis does not describe, so the mailbox bound is derived here for the engine's policy.

The figures (`RtaResult`), per message m:
- ``response_ns`` — D07's R_m, from the nominal release (the initiating event; the release
  jitter counts) to the end of the frame *including* the 3-bit intermission that C_m counts.
  ``schedulable`` is R_m <= D_m: one deadline, one reference.
- ``bound_ns`` — the worst time from queuing (the instance entering its controller's queue, up
  to J_m after its nominal release) to the end of the frame, intermission included: what a
  simulation measures as a response (to the end of EOF, 3 bit times earlier) never exceeds it.
  It is *not* R_m − J_m: D07's instance q >= 1 of a busy period is queued with no jitter
  right behind instance 0 queued late, so its time from queuing is all of R_m(q). One message,
  500 kbit/s (C = 270 us), T = 1 ms, J = 0.9 ms: R − J = 270 us, but instance 0 queued at 0.9
  ends at 1.17 ms and instance 1, queued at 1.0, waits for it and ends at 1.44: 440 us
  (= R_m(1)); ``bound_ns`` is 440 us.

Model ([D07]): message m has a priority (lower arbitration key wins), a worst-case transmission
time C_m (worst-case stuffing, 3-bit intermission included, or its exact length), a period or
minimum inter-arrival time T_m, a deadline D_m (any size) and a queuing jitter J_m. On priority
queues each node enters its highest-priority pending frame into arbitration, so the bus is one
priority queue served non-preemptively.

D07's equations (priority queues; tau = one bit time):
- C_m = (g + 8 s_m + 13 + floor((g + 8 s_m - 1) / 4)) tau, g = 34 (11-bit) or 54 (29-bit)
  identifiers, s_m data bytes (Section 3, eq. 1). ``frame_bits_worst``. A CAN FD message's C_m
  is its worst-case frame at the nominal and the data bit rate (`profiles.analysis.model`); the
  equations below take C_m as given, so they hold for mixed classical and FD buses unchanged
  (arbitration, the tau term and error frames stay at the nominal rate).
- B_m = max over k in lp(m) of C_k (Section 3).
- Original (Section 3): w_m = B_m + sum over hp(m) of ceil((w_m + J_k + tau) / T_k) C_k,
  R_m = J_m + w_m + C_m. ``analyse_1994``; optimistic.
- Revised (Section 5): busy period t_m = B_m + sum over hep(m) of ceil((t_m + J_k) / T_k) C_k
  from C_m; Q_m = ceil((t_m + J_m) / T_m); for q < Q_m, w_m(q) = B_m + q C_m + sum over hp(m) of
  ceil((w_m(q) + J_k + tau) / T_k) C_k, R_m(q) = J_m + w_m(q) − q T_m + C_m, R_m = max R_m(q).
- The bound from queuing (my derivation, the case S = {m} of the proof below): an instance
  queued x after the start of the busy period has at most floor((x + J_m) / T_m) predecessors
  in it, so ``bound_ns`` = max over x in [0, t_m) of w_m(floor((x + J_m)/T_m)) + C_m − x, taken
  where the count steps (x = 0 and x = q T_m − J_m > 0). For q T_m >= J_m the term is R_m(q),
  for instance 0 R_m(0) − J_m, and with J_m > T_m the first instances give w_m(q) + C_m; it
  never exceeds R_m.

Node queues. Call a frame *contending* from the moment its node could offer it: when queued on
a priority queue, when at the head of a FIFO, when in a mailbox. Each node offers its best
contending frame (lowest key, then oldest), so every arbitration is won by the best contending
frame on the bus. A frame contends at most E_k = bound_k − C_k after its queuing (it starts by
then); other messages see it with the arbitration jitter J'_k = J_k + E_k (E_k = 0 on priority
queues). Per queue (window sets as in `profiles.analysis.window`):
- priority, and a node with a single message: D07 with hp(m) at their arbitration jitters.
- mailboxes with abort: the engine aborts at once and keeps the best pending frames in the
  mailboxes (`MailboxQueue._rebalance`), so the node is a priority queue (a real controller's
  abort takes time, K10's concern: not modelled because the engine has none).
- FIFO, and one mailbox without abort: S = the node's messages, L its lowest-priority one;
  ahead = S \\ {m}; interfering = hp(L) of other nodes at J'; B = max C over lp(L) of other
  nodes.
- n >= 2 mailboxes without abort: as FIFO, except that S's messages above m are interfering at
  their own jitter (a frame queued after m reaches a mailbox after m but may pass it there) and
  only S's messages below m are ahead. A node whose mailboxes hold every frame it can have
  pending, sum over its messages of (floor((bound_k + J_k) / T_k) + 1) <= n, never uses its
  backlog and is analysed as a priority queue (checked after the analysis, and dropped to the
  mailbox bound where the check fails).

Proof of the FIFO/mailbox bound (D07's is the case S = {m}, ahead empty). Level work: frames of
S pending (queued, unfinished) and contending frames of interfering messages. (i) While level
work is pending, each arbitration is won by level work: S, if it has a frame, offers one with
key <= key_L and only a contending frame with a lower key, from another node, can beat it —
an interfering one; otherwise a contending interfering frame is pending and its node offers one
at least as good, interfering too. So a level busy period starting at t0 (level work pending,
none just before) is delayed by at most one other frame, on the wire at t0, of lp(L) of another
node: B. (ii) No S frame is pending at t0, so S frames sent before m starts (at s) were queued in
[t0, s]: on a FIFO exactly those queued before m, in [t0, t0 + x] (m queued at t0 + x): at most
floor((x + J_k) / T_k) + 1 of k != m and floor((x + J_m) / T_m) of m (queuings in a closed window
of length x, nominal releases T_k apart, each within J_k); with mailboxes also frames queued after
m that are better than m, counted over [t0, s]. (iii) Interfering frames sent in [t0, s)
contended in [t0, s]: at most ceil((w + J'_j + tau) / T_j) with w = s − t0 (>= floor + 1 for any
tau > 0: D07's form). The bus is never idle in [t0, s), so s − t0 is at most the least fixed point
w(x) of the recurrence, and m ends by t0 + w(x) + C_m: w(x) + C_m − x after its queuing. (iv) x is
below the busy-period bound (D07's argument with the same counts). (v) From the nominal release,
y = release − t0 >= −J_m: m has at most floor((y + J_m) / T_m) predecessors and the others are
counted at x <= y + J_m; with z = y + J_m, the end is at most J_m + w(z) + C_m − z after the
release, m's count being floor(z / T_m) — D07's R_m(q) at z = q T_m.
The arbitration jitters depend on other nodes' bounds: iterate from E = 0, E := max(E, F(E)),
until nothing grows, so that bound_k − C_k <= E_k for every k (bounds only grow with E; past
`WIDEN_AFTER` passes the E still growing are doubled, which may overshoot the least fixed point
by up to twice; whatever still grows after `MAX_ROUNDS` passes is left unbounded). Any such E is
safe: if a run broke a bound, take the first instant at which some frame k has been pending E_k
after its queuing without contending, or bound_k after it. Every count above, for a window that
ends by then, uses contention instants before it, which respect J'; so that frame's own bound
holds, and with it bound_k − C_k <= E_k — a contradiction.

Errors (``ErrorModel``), my statement of Tindell and Burns' simple model and a burst form: at most
n errors in any window of T_error (n = 1: errors at least T_error apart), each costing an error
frame (31 tau worst case) and the retransmission of the longest frame it destroys, a frame of the
level: E(t) = n (ceil(t / T_error) + 1)(31 tau + max C over the level's messages), added to the
busy-period and queuing recurrences. At most n ceil(w / T_error) errors fall in a window w; the
extra n covers those striking m's own transmission. Nodes are assumed to stay error active, and
a node to choose its queue's head again after a failed attempt, as the engine does
(`stack.controller.node.Node.retry`): a priority queue does not retransmit a lower frame before
a better one queued meanwhile, whose retransmission the term would not cover.

Drift: see `profiles.analysis.model` (the shortest real period, a widened jitter).

Termination: a window whose utilisation (with the error overhead) is >= 1 is unbounded; every
recurrence stops with "unbounded" past ``HORIZON_FACTOR`` x max(D_m, T_m + J_m) of the message
under analysis. Arithmetic is exact (integer ticks, `profiles.analysis.model`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from fractions import Fraction

from profiles.analysis.model import (
    ERROR_FRAME_BITS,
    HORIZON_FACTOR,
    ErrorModel,
    MessageSpec,
    NodeQueue,
    Stream,
    Timebase,
    check_queues,
    frame_bits_worst,
    prepare,
    timebase,
)
from profiles.analysis.window import Outcome, Term, Window

__all__ = [
    "MessageSpec",
    "ErrorModel",
    "NodeQueue",
    "RtaResult",
    "frame_bits_worst",
    "analyse",
    "analyse_1994",
    "utilisation",
    "ERROR_FRAME_BITS",
    "HORIZON_FACTOR",
    "MAX_ROUNDS",
    "WIDEN_AFTER",
]

MAX_ROUNDS = 64
"""Passes of the arbitration-jitter iteration before what still grows is left unbounded."""

WIDEN_AFTER = 8
"""Passes of the arbitration-jitter iteration before the delays still growing are doubled."""

_PRIORITY, _FIFO, _MAILBOX = "priority", "fifo", "mailbox"
_METHOD = {_PRIORITY: "davis2007", _FIFO: "fifo", _MAILBOX: "mailbox"}


@dataclass(frozen=True)
class RtaResult:
    """The analysis of one message. Times are nanoseconds.

    ``response_ns`` is R_m from the nominal release (None when unbounded: ``unbounded_reason``
    says why) and ``schedulable`` R_m <= ``deadline_ns``; ``bound_ns`` bounds the time from
    queuing to the end of the frame (see the module docstring for both). ``busy_period_ns`` is the
    level busy period (None when it does not converge, and from ``analyse_1994``);
    ``instances`` the number of points examined (D07's Q_m on a priority queue; 1 from
    ``analyse_1994``); ``queuing_delays_ns`` and ``responses_ns`` hold w and R at each (w_m(q)
    and R_m(q)); ``worst_instance`` the one attaining R_m; ``response_1994_ns`` the original
    first-instance value (priority queues only); ``priority`` the rank, 0 = highest;
    ``utilisation_hep`` the utilisation of the messages the window counts (error overhead
    included). ``method`` is ``davis2007``, ``fifo`` or ``mailbox``; ``period_used_ns`` and
    ``jitter_used_ns`` the T and J used (drift applied); ``arbitration_jitter_ns`` J + E, the
    jitter with which other messages see it enter arbitration.
    """

    name: str
    c_ns: float
    blocking_ns: float
    busy_period_ns: float | None
    instances: int
    response_ns: float | None
    worst_instance: int | None
    schedulable: bool
    deadline_ns: int
    priority: int
    queuing_delays_ns: tuple[float, ...]
    responses_ns: tuple[float, ...]
    response_1994_ns: float | None
    utilisation_hep: float
    unbounded_reason: str | None = None
    bound_ns: float | None = None
    method: str = "davis2007"
    period_used_ns: float = 0.0
    jitter_used_ns: float = 0.0
    arbitration_jitter_ns: float | None = None


def utilisation(messages: Sequence[MessageSpec], bitrate: int, *, data_bitrate: int | None = None) -> float:
    """Bus utilisation with worst-case frames: sum over m of C_m / T_m (T as used: drift applied;
    CAN FD frames with BRS at ``data_bitrate``)."""
    msgs = prepare(messages, bitrate, data_bitrate=data_bitrate)
    return float(sum((Fraction(m.c, m.t) for m in msgs), Fraction(0)))


def error_term(errors: ErrorModel | None, tb: Timebase, level: Sequence[Stream]) -> tuple[int, int, int] | None:
    """The window's error term (T_error, n, per-error cost) in ticks: an error frame at the nominal
    rate (31 tau) and the longest frame of ``level``; None without an error model."""
    if errors is None:
        return None
    return (errors.t_error_ns * tb.per_ns, errors.burst, ERROR_FRAME_BITS * tb.bit + max(k.c for k in level))


def _first_instance(msgs: list[Stream], i: int, tb: Timebase, errors: ErrorModel | None) -> int | None:
    """T95's R_m = J_m + w_m + C_m (D07 Section 3), None when unbounded; its guard is the
    utilisation of hp(m) (the recurrence ranges over hp(m) only)."""
    m = msgs[i]
    hp = msgs[:i]
    win = Window(
        Term(m.c, m.t, m.j),
        interfering=[Term(k.c, k.t, k.j) for k in hp],
        blocking=max((k.c for k in msgs[i + 1 :]), default=0),
        tau=tb.bit,
        error=error_term(errors, tb, msgs[: i + 1]),
        horizon=m.horizon,
    )
    if win.utilisation - Fraction(m.c, m.t) >= 1:
        return None
    w = win.delay(win.b, win.b)
    return None if w is None else m.j + w + m.c


class _Bus:
    """The whole bus: streams in priority order, each node's policy as analysed."""

    def __init__(
        self,
        msgs: list[Stream],
        queues: dict[str, NodeQueue],
        tb: Timebase,
        errors: ErrorModel | None,
        verdict_only: bool = False,
    ):
        self.msgs = msgs
        self.verdict_only = verdict_only
        self.tb = tb
        self.errors = errors
        self.by_node: dict[str, list[Stream]] = {}
        for m in msgs:
            self.by_node.setdefault(m.node, []).append(m)
        self.mode: dict[str, str] = {}
        self.tentative: set[str] = set()  # mailbox nodes analysed as priority queues, to be checked
        for node, own in self.by_node.items():
            q = queues.get(node)
            if q is None or q.kind == _PRIORITY or len(own) == 1 or (q.kind == _MAILBOX and q.abort):
                self.mode[node] = _PRIORITY
            elif q.kind == _FIFO or q.mailboxes == 1:
                self.mode[node] = _FIFO
            else:
                self.mode[node] = _PRIORITY
                self.tentative.add(node)
        self.queues = queues

    def depends(self, m: Stream) -> tuple[str, ...]:
        """The messages whose contention delay m's window reads (those of FIFO and mailbox
        nodes among its interfering messages)."""
        if self.mode[m.node] == _PRIORITY:
            others = [k for k in self.msgs if k.key < m.key]
        else:
            low = self.by_node[m.node][-1].key
            others = [k for k in self.msgs if k.node != m.node and k.key < low]
        return tuple(k.name for k in others if self.mode[k.node] != _PRIORITY)

    def window(self, m: Stream, extra: Mapping[str, int | None]) -> Window | str:
        """m's window given the contention delays E (None: unbounded); or why there is none."""
        mode = self.mode[m.node]
        tau = self.tb.bit

        def seen(k: Stream) -> Term | str:
            e = extra[k.name]
            if e is None:
                return f"no bound for {k.name!r} (node {k.node!r}, {self.mode[k.node]} queue), which can delay it"
            return Term(k.c, k.t, k.j + e)

        if mode == _PRIORITY:
            hp = [k for k in self.msgs if k.key < m.key]
            blocking = max((k.c for k in self.msgs if k.key > m.key), default=0)
            ahead: list[Term] = []
            interfering = [seen(k) for k in hp]
            level = hp + [m]
        else:
            own = self.by_node[m.node]
            low = own[-1].key  # the node's lowest-priority message L
            others_hp = [k for k in self.msgs if k.node != m.node and k.key < low]
            blocking = max((k.c for k in self.msgs if k.node != m.node and k.key > low), default=0)
            if mode == _FIFO:
                ahead = [Term(k.c, k.t, k.j) for k in own if k is not m]
                interfering = []
            else:
                ahead = [Term(k.c, k.t, k.j) for k in own if k.key > m.key]
                interfering = [Term(k.c, k.t, k.j) for k in own if k.key < m.key]
            interfering += [seen(k) for k in others_hp]
            level = own + others_hp
        for term in interfering:
            if isinstance(term, str):
                return term
        return Window(
            Term(m.c, m.t, m.j),
            ahead=ahead,
            interfering=[t for t in interfering if isinstance(t, Term)],
            blocking=blocking,
            tau=tau,
            error=error_term(self.errors, self.tb, level),
            horizon=m.horizon,
            deadline=m.d if self.verdict_only else None,
        )

    def solve(self) -> tuple[dict[str, Outcome | str], dict[str, int | None], dict[str, Window | str]]:
        """Outcomes with the arbitration-jitter iteration to its least fixed point."""
        extra: dict[str, int | None] = {m.name: 0 for m in self.msgs}
        deps = {m.name: self.depends(m) for m in self.msgs}
        # A window changes only with the contention delays of the messages it depends on, so a
        # pass recomputes only those; and each delay found is used at once by the windows after
        # it in the same pass (Gauss-Seidel). E only grows (E := max(E, F(E))), and a pass that
        # grows nothing ends it: then F(E) <= E, all the proof needs. From E = 0 that is the
        # least fixed point; past `WIDEN_AFTER` passes the delays still growing are doubled
        # each `WIDEN_AFTER` passes (widening: bounds up to twice the least fixed point, but an
        # overloaded FIFO bus creeping up a frame a pass ends in a few passes, not `MAX_ROUNDS`).
        done: dict[str, tuple[tuple[int | None, ...], Window | str, Outcome | str]] = {}
        rounds = 0
        while True:
            grown: list[str] = []
            for m in self.msgs:
                key = tuple(extra[d] for d in deps[m.name])
                got = done.get(m.name)
                if got is None or got[0] != key:
                    w = self.window(m, extra)
                    got = done[m.name] = (key, w, w if isinstance(w, str) else w.solve())
                if self.mode[m.node] == _PRIORITY:
                    continue
                o = got[2]
                e = None if isinstance(o, str) or o.bound is None else o.bound - m.c
                old = extra[m.name]
                if old is not None and (e is None or e > old):
                    extra[m.name] = None if rounds >= MAX_ROUNDS else e
                    grown.append(m.name)
            if not grown:
                return (
                    {name: got[2] for name, got in done.items()},
                    extra,
                    {name: got[1] for name, got in done.items()},
                )
            rounds += 1
            if rounds >= WIDEN_AFTER and rounds % WIDEN_AFTER == 0:
                for name in grown:
                    e = extra[name]
                    if e is not None:
                        extra[name] = 2 * e + 1

    def fits(self, node: str, outs: Mapping[str, Outcome | str]) -> bool:
        """Whether a mailbox node's mailboxes hold every frame it can have pending at once."""
        need = 0
        for k in self.by_node[node]:
            o = outs[k.name]
            if isinstance(o, str) or o.bound is None:
                return False
            need += (o.bound + k.j) // k.t + 1
        n = self.queues[node].mailboxes
        return n is not None and need <= n


def analyse(
    messages: Sequence[MessageSpec],
    bitrate: int,
    *,
    errors: ErrorModel | None = None,
    queues: Mapping[str, NodeQueue] | None = None,
    verdict_only: bool = False,
    data_bitrate: int | None = None,
) -> dict[str, RtaResult]:
    """Worst-case response times and bounds (see the module docstring), keyed by message name,
    in priority order (highest first; lower ``arbitration_key`` wins).

    ``queues`` gives the queue policy of nodes by name (``MessageSpec.node``); nodes not named
    use priority queues. ``verdict_only`` stops each message's recurrences once it cannot meet
    its deadline: it is then reported unbounded, with every message it can delay from a FIFO or
    mailbox queue — much quicker on overloaded FIFO buses, and whether *every* message is
    schedulable comes out the same (the jitter iteration and the mailbox check only grow bounds,
    so where all end within their deadlines no cut ever happens). ``data_bitrate`` is the bus's
    CAN FD data bit rate, which messages with ``brs`` need (`profiles.analysis.model`: their
    C_m is the wire layer's worst-case FD frame at both rates).

    Raises ValueError naming the message (or node) and the rule for what
    `profiles.analysis.model.prepare` refuses (periods, deadlines, jitter, DLC, identifiers,
    names, drift, FD flags, bit rates, the error model) or a bad queue declaration.
    """
    msgs = prepare(messages, bitrate, errors, data_bitrate)
    tb = timebase(bitrate, data_bitrate)
    bus = _Bus(msgs, check_queues(queues), tb, errors, verdict_only)
    while True:
        outs, extra, windows = bus.solve()
        failed = [n for n in sorted(bus.tentative) if not bus.fits(n, outs)]
        if not failed:
            break
        for n in failed:
            bus.mode[n] = _MAILBOX
            bus.tentative.discard(n)
    out: dict[str, RtaResult] = {}
    for i, m in enumerate(msgs):
        mode = bus.mode[m.node]
        r1994 = _first_instance(msgs, i, tb, errors) if mode == _PRIORITY else None
        out[m.name] = _result(m, i, tb, outs[m.name], windows[m.name], mode, extra[m.name], r1994)
    return out


def _result(
    m: Stream,
    i: int,
    tb: Timebase,
    o: Outcome | str,
    win: Window | str,
    mode: str,
    extra: int | None,
    r1994: int | None,
) -> RtaResult:
    def ns(x: int) -> float:
        return x / tb.per_ns

    if isinstance(o, str):
        o = Outcome(None, (), (), None, None, None, o)
    return RtaResult(
        name=m.name,
        c_ns=ns(m.c),
        blocking_ns=ns(win.b) if isinstance(win, Window) else 0.0,
        busy_period_ns=None if o.busy is None else ns(o.busy),
        instances=len(o.delays),
        response_ns=None if o.response is None else ns(o.response),
        worst_instance=o.worst,
        schedulable=o.response is not None and o.response <= m.d,
        deadline_ns=m.spec.deadline_ns,
        priority=i,
        queuing_delays_ns=tuple(ns(w) for w in o.delays),
        responses_ns=tuple(ns(x) for x in o.responses),
        response_1994_ns=None if r1994 is None else ns(r1994),
        utilisation_hep=float(win.utilisation) if isinstance(win, Window) else float("nan"),
        unbounded_reason=o.reason,
        bound_ns=None if o.bound is None else ns(o.bound),
        method=_METHOD[mode],
        period_used_ns=ns(m.t),
        jitter_used_ns=ns(m.j),
        arbitration_jitter_ns=None if extra is None else ns(m.j + extra),
    )


def analyse_1994(
    messages: Sequence[MessageSpec],
    bitrate: int,
    *,
    errors: ErrorModel | None = None,
    data_bitrate: int | None = None,
) -> dict[str, RtaResult]:
    """The original, optimistic analysis (T95; D07 Section 3): the first instance only, every
    node a priority queue.

    For comparison and for the refutation example; do not use it to decide schedulability.
    ``busy_period_ns`` is None (the analysis has none), ``instances`` 1 and ``worst_instance`` 0
    when bounded; ``bound_ns`` is R − J (what it wrongly took for the bound from queuing).
    """
    msgs = prepare(messages, bitrate, errors, data_bitrate)
    tb = timebase(bitrate, data_bitrate)
    out: dict[str, RtaResult] = {}
    for i, m in enumerate(msgs):
        r = _first_instance(msgs, i, tb, errors)
        win = Window(
            Term(m.c, m.t, m.j),
            interfering=[Term(k.c, k.t, k.j) for k in msgs[:i]],
            blocking=max((k.c for k in msgs[i + 1 :]), default=0),
            tau=tb.bit,
            error=error_term(errors, tb, msgs[: i + 1]),
            horizon=m.horizon,
        )
        if r is None:
            o = Outcome(
                None, (), (), None, None, None, "higher-priority utilisation >= 1 or queuing delay beyond the horizon"
            )
        else:
            o = Outcome(None, (r - m.j - m.c,), (r,), r, 0, r - m.j, None)
        out[m.name] = _result(m, i, tb, o, win, _PRIORITY, 0, r)
    return out
