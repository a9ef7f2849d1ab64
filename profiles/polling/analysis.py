"""Worst-case timing of a master's poll cycle.

**The poll cycle on a bus of its own** (`transaction_bound_ns`, `cycle_bound_ns`). Only the master
starts a transaction and it starts the next one when the last has ended, so the frames of a
cycle never contend and the cycle's length follows from the frame lengths, the slaves'
processing delays and the inter-frame spaces. With tau the bit time, L(f) a frame's length from
SOF to the end of EOF in bits (worst-case stuffing: `profiles.analysis.rta.frame_bits_worst`
less the 3-bit intermission it includes; or the exact length of a fixed payload with
``[analysis] stuffing = "exact"``), and d_k a slave's longest processing delay (from the end of
the request to queuing the response; 0 for a remote-reply mailbox, which the controller answers
itself):

- a request ends L(req)·tau after its SOF; the bus is free 3 tau later (intermission), so a
  response ready at d_k starts at max(d_k, 3 tau) after the request's end;
- the responses to one request (one, or every strobed slave for a bit-strobe) are served by the
  bus as a work-conserving, non-preemptive server: with r_k = max(d_k, 3 tau) and each response
  occupying (L_k + 3)·tau (frame and intermission), the last one ends at
  max over k of (r_k + sum of (L_j + 3)·tau over the j with r_j >= r_k) − 3 tau after the
  request's end (the busy period that starts at the last idle point holds exactly the responses
  ready from then on; arbitration only orders them, by identifier);
- the master queues its next request when it receives the last response (end of EOF), so the
  next SOF is 3 tau later.

A message longer than 8 bytes goes in DeviceNet fragments queued back to back
(`profiles.polling.fragment`): its L is then the sum of its fragments' lengths and the 3-bit
intermissions between them (`message_bits`). A transaction's bound (request SOF to the end of
its last response) is L(req)·tau plus that makespan; the cycle's (first request's SOF to the end of the last response) is the sum of the
transactions' plus 3 tau between consecutive ones. Both grow with every d_k and every L, so the
longest delays and worst-case frames give the worst case. It holds on a fault-free bus that
carries nothing else; a slave that misses a poll adds its timeout (× retries + 1) instead.

**The poll cycle on a shared bus** (`holistic`): with other traffic (CSMA/CR nodes, the slaves'
change-of-state messages and their acknowledgements, another master) the frames of a cycle wait
for arbitration. Two things are needed then: a model of the master/slave frames for the
response-time analysis of the experiments spine (Davis et al. 2007, `profiles.analysis.rta`),
so that the other messages of the bus get sound bounds (the ``traffic`` of the profile kinds),
and a bound on the cycle and on each transaction.

*Model of the streams* (``specs``). Every frame of the chain — request, answer, strobe answer —
occurs at most once per cycle, and a cycle starts at least ``cycle_ms`` after the previous one
(an overrunning cycle delays the next, never the reverse), so each is a sporadic stream with the
cycle as its minimum inter-arrival time T. Its release offset o from the start of its cycle lies
in [o_min, o_max], which makes a release jitter J = o_max − o_min: the first request is queued
at the start (o = 0); an answer d_k after its request ends; the next request when the last
answer ends. o_min adds the shortest frames (no stuff bits), the shortest delays and one
intermission before each answer; o_max is the bound on the window from the cycle's start to that
point (below) plus the longest delay. A slave's change-of-state / cyclic message is a sporadic
or periodic stream as declared; the master's acknowledgement is released when it ends: the same
interval, jitter J_cos + W_cos − L_min (W: the analysis' bound from queuing to the end of the
frame, ``bound_ns``; an acknowledged link has one COS/cyclic message,
as DeviceNet's COS connection has).

*Bound on a window of the chain.* Take the chain's work from the cycle's start to some point —
its frames, each with its intermission (worst-case C), and the time the bus may wait for the
slaves' processing (per transaction max d_k − 3 tau, in at most one idle stretch per answer
ready after the intermission). Every instant of the window is then one of three: a frame of the
chain, a processing wait, or a foreign frame. A foreign frame that overlaps the window ended
after its start, so it was queued at most W before it (the analysis' bound from queuing to the
end of the frame, ``bound_ns``, of the whole bus — not R − J, which a later instance of a busy
period can exceed): at most ceil((L + W + J) / T) frames of each stream, T and J as the analysis
used them (a drifting node's shortest period). A foreign stream
that loses arbitration to every frame of the chain can only get in through a frame already on
the bus when the window opens or one that starts during a processing wait, so it takes at most
(1 + number of waits) × its longest frame — whichever is smaller. The window's bound is the least
L = own work + interference(L) (iterated from the own work; beyond `HORIZON_FACTOR` cycles it
is given up). It counts each foreign frame once for the whole window, not once per frame of the
chain: a per-frame analysis that adds up each frame's own worst case would count a 2 ms message
in every one of sixteen frames of a cycle. A transaction's bound is the window of its own work;
the cycle's is the window of all of it.

Jitters feed the analysis of the whole bus, its W feed the windows, and the windows the jitters,
so the model is iterated from the chains alone on the bus until the jitters stop changing (they
only grow: the least fixed point; given up, with no bound, after `MAX_ITERATIONS` rounds) — the
way Tindell and Clark's holistic analysis inherits jitter along a transaction ("Holistic
schedulability analysis for distributed hard real-time systems", Microprocessing and
Microprogramming 40, 1994). The model assumes every slave answers (a lost slave's transactions are
skipped, which only shortens the cycle), priority queues in the master and the slaves (the
spine's rule: a FIFO or mailbox node leaves the cycle without a bound) and no retries — a
timeout is a fault the analysis does not cover. Bus errors are covered by the spine's simple error
model when ``[analysis] t_error_ms`` is given: (ceil(L / T_error) + 1) error frames (31 tau) and
retransmissions of the longest frame on the bus are added to every window.

The spine's own per-message bounds (``rta_ms`` of each request and answer) treat every frame of
a chain as an independent stream that may be pending with all the others, which a serial chain
never is: sound for the other messages, but much looser than the transaction bounds here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from fractions import Fraction
from typing import TYPE_CHECKING, Any

from profiles.analysis.rta import ERROR_FRAME_BITS, HORIZON_FACTOR, ErrorModel, MessageSpec, analyse, frame_bits_worst
from profiles.base import frame_of
from profiles.polling.fragment import io_frames
from profiles.registry import profile_kind
from stack import Frame, arbitration_key
from stack.wire.coding import INTERMISSION_BITS

if TYPE_CHECKING:  # pragma: no cover
    from profiles.declarations import MessageDecl, Scenario
    from profiles.polling.config import MasterConfig, Network, SlaveConfig, Transaction

__all__ = [
    "frame_bits",
    "frame_bits_min",
    "message_bits",
    "message_bits_min",
    "transaction_bound_ns",
    "cycle_bound_ns",
    "holistic",
    "Holistic",
    "MAX_ITERATIONS",
    "MASTER_SLAVE_PROFILES",
]

MAX_ITERATIONS = 100
"""The holistic iteration gives up (no bound) after this many rounds."""

MASTER_SLAVE_PROFILES = ("master", "slave")


def frame_bits(m: MessageDecl, stuffing: str = "worst") -> int:
    """Bits from SOF to the end of EOF of a declared message's frame: worst-case stuffing (eq. 1 of
    Davis et al. less its 3-bit intermission; a remote frame carries no data bytes) or, with
    ``stuffing="exact"``, the exact length of its fixed payload."""
    if stuffing == "exact":
        return frame_of(m).bits.length
    return frame_bits_worst(0 if m.remote else m.dlc, m.extended) - INTERMISSION_BITS


def frame_bits_min(m: MessageDecl) -> int:
    """The shortest the frame can be: no stuff bits (44 + 8n standard, 64 + 8n extended)."""
    return (64 if m.extended else 44) + (0 if m.remote else 8 * min(m.dlc, 8))


def message_bits(m: MessageDecl, stuffing: str = "worst") -> int:
    """Bits from the first SOF to the last EOF of a message: one frame (`frame_bits`), or the
    DeviceNet fragments of an I/O message longer than 8 bytes, queued back to back — each with
    its own length and the 3-bit intermission between consecutive ones."""
    frames = io_frames(m)
    if len(frames) == 1:
        return frame_bits(m, stuffing)
    if stuffing == "exact":
        bits = [Frame(m.can_id, f, extended=m.extended).bits.length for f in frames]
    else:
        bits = [frame_bits_worst(len(f), m.extended) - INTERMISSION_BITS for f in frames]
    return sum(bits) + INTERMISSION_BITS * (len(frames) - 1)


def message_bits_min(m: MessageDecl) -> int:
    """The shortest a message can be on the bus (`frame_bits_min`, fragments back to back)."""
    frames = io_frames(m)
    if len(frames) == 1:
        return frame_bits_min(m)
    base = 64 if m.extended else 44
    return sum(base + 8 * len(f) for f in frames) + INTERMISSION_BITS * (len(frames) - 1)


def _tau(bitrate: int) -> Fraction:
    return Fraction(10**9, bitrate)


def _delay_max(tx: Transaction, slaves: dict[str, SlaveConfig], k: int) -> int:
    # a remote-reply mailbox answers in the controller: no application delay
    return 0 if tx.style == "remote" else slaves[tx.slaves[k]].processing_max_ns


def _makespan(ready: list[Fraction], occupy: list[Fraction]) -> Fraction:
    """Completion time of a work-conserving non-preemptive server: max over k of r_k plus the
    work of every job ready at or after r_k."""
    return max(r + sum((o for rj, o in zip(ready, occupy) if rj >= r), Fraction(0)) for r in ready)


def transaction_bound_ns(
    tx: Transaction, slaves: dict[str, SlaveConfig], bitrate: int, stuffing: str = "worst"
) -> Fraction:
    """Worst case, in ns, from the request's SOF to the end of its last response on a bus that
    carries nothing else (see the module docstring)."""
    tau = _tau(bitrate)
    ifs = INTERMISSION_BITS * tau
    ready = [max(Fraction(_delay_max(tx, slaves, k)), ifs) for k in range(len(tx.slaves))]
    occupy = [(message_bits(r, stuffing) + INTERMISSION_BITS) * tau for r in tx.responses]
    return message_bits(tx.request, stuffing) * tau + _makespan(ready, occupy) - ifs


def cycle_bound_ns(
    master: MasterConfig, slaves: dict[str, SlaveConfig], bitrate: int, stuffing: str = "worst"
) -> Fraction:
    """Worst case, in ns, of a poll cycle on a bus that carries nothing else: the transactions'
    bounds plus one intermission between consecutive ones."""
    txs = master.transactions
    if not txs:
        return Fraction(0)
    tau = _tau(bitrate)
    return sum(
        (transaction_bound_ns(t, slaves, bitrate, stuffing) for t in txs), Fraction(0)
    ) + INTERMISSION_BITS * tau * (len(txs) - 1)


# ---------------------------------------------------------------------------------------------- shared bus


@dataclass
class Holistic:
    """The analysis of a bus with master/slave traffic (see the module docstring).

    ``specs`` are the `MessageSpec` streams by node name (what ``traffic`` gives the spine);
    ``applies`` is False when another node's traffic has no model (then nothing is bounded);
    ``converged`` whether the release jitters reached a fixed point (in ``iterations`` rounds);
    ``cycle_ns`` the bound on each master's cycle and ``transaction_ns`` on each transaction (by
    request name), ``offsets_ns`` on the end of each transaction's request and of its last answer
    after the cycle's start, None where there is none; ``notes`` say why.
    """

    specs: dict[str, list[MessageSpec]]
    applies: bool
    converged: bool
    iterations: int
    cycle_ns: dict[str, float | None] = field(default_factory=dict)
    transaction_ns: dict[str, float | None] = field(default_factory=dict)
    offsets_ns: dict[str, tuple[float, float] | None] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def _spec(m: MessageDecl, period: int, deadline: int, jitter: Fraction, stuffing: str) -> MessageSpec:
    """The stream of a message. The k fragments of a fragmented one, queued together once per
    period T, are a stream of period floor(T / k) with k − 1 such periods more release jitter: k
    instances can then be released at once, and no window holds fewer instances than the real
    k per T."""
    k = len(io_frames(m))
    if k > 1:
        short = period // k
        jitter += (k - 1) * short
        period = short
        bits: int | None = max(frame_bits_worst(len(f), m.extended) for f in io_frames(m))
        if stuffing == "exact":
            bits = max(Frame(m.can_id, f, extended=m.extended).bits.length for f in io_frames(m)) + INTERMISSION_BITS
    else:
        bits = frame_bits(m, stuffing) + INTERMISSION_BITS
        if stuffing != "exact" and not m.remote:
            bits = None  # eq. 1 from the DLC, as every other stream of the analysis
    return MessageSpec(m.name, m.can_id, m.extended, m.dlc, period, deadline, math.ceil(jitter), bits, remote=m.remote)


class _Unbounded(Exception):
    """A window the analysis cannot bound."""


class _Foreign:
    """The traffic a master's chain shares the bus with: every stream but the chain's own frames,
    with C (ns, intermission included), T, J and W (queuing to the end of the frame: the
    response-time analysis' ``bound_ns`` for the whole bus). Streams that beat at least one frame of the chain
    can delay it at any point; the others ("lower") only by a frame already on the bus when the
    window opens, or one that starts while the chain waits for a slave's processing delay."""

    def __init__(
        self,
        specs: list[MessageSpec],
        rta: dict[str, Any],
        chain_top: int,
        bitrate: int,
        errors: ErrorModel | None = None,
        longest: Fraction = Fraction(0),
    ) -> None:
        self.t_error = None if errors is None else Fraction(errors.t_error_ns)
        self.higher: list[tuple[Fraction, Fraction, Fraction, Fraction]] = []
        self.lower: list[tuple[Fraction, Fraction, Fraction, Fraction]] = []
        for x in specs:
            r = rta[x.name]
            if r.response_ns is None:
                raise _Unbounded(f"no bound for {x.name}: {r.unbounded_reason}")
            c = Fraction(r.c_ns)
            # T and J as the analysis used them (a drifting node's shortest period), and W its
            # bound from queuing to the end of the frame (not R - J: a later instance of the busy
            # period can be queued with no jitter behind one queued late)
            row = (c, Fraction(r.period_used_ns), Fraction(r.jitter_used_ns), Fraction(r.bound_ns))
            key = arbitration_key(x.can_id, x.extended, x.remote)
            (self.higher if key < chain_top else self.lower).append(row)
        self.lower_c = max((row[0] for row in self.lower), default=Fraction(0))
        # the simple error model: an error frame and the longest frame again per error
        self.per_error = ERROR_FRAME_BITS * _tau(bitrate) + max([longest] + [r[0] for r in self.higher + self.lower])

    @staticmethod
    def _count(rows: list[tuple[Fraction, Fraction, Fraction, Fraction]], length: Fraction) -> Fraction:
        # frames of k that overlap [s, s + L) ended after s, so were released in [s − W, s + L):
        # at most ceil((L + W + J) / T) of them
        return sum((math.ceil((length + w + j) / t) * c for c, t, j, w in rows), Fraction(0))

    def interference(self, length: Fraction, gaps: int) -> Fraction:
        """The most the foreign frames can take of a window of ``length`` that holds ``gaps``
        processing delays."""
        lower = min(self._count(self.lower, length), (1 + gaps) * self.lower_c)
        errors = 0 if self.t_error is None else (math.ceil(length / self.t_error) + 1) * self.per_error
        return self._count(self.higher, length) + lower + errors

    def window(self, own: Fraction, gaps: int, horizon: Fraction) -> Fraction:
        """The least L with L = own + interference(L): the chain's work ``own`` (frames with
        their intermission, and the processing delays) done with every foreign frame that can
        get in between."""
        length = own
        while True:
            nxt = own + self.interference(length, gaps)
            if nxt == length:
                return length
            if nxt > horizon:
                raise _Unbounded(f"a poll cycle window beyond {float(horizon) / 1e6:g} ms")
            length = nxt


class _Chain:
    """One master's chain of frames: their release windows relative to the cycle's start, and the
    bounds on the cycle and on each transaction."""

    def __init__(self, master: MasterConfig, net: Network, bitrate: int, stuffing: str) -> None:
        self.master = master
        self.net = net
        self.tau = _tau(bitrate)
        self.stuffing = stuffing
        self.names = {m.name for tx in master.transactions for m in (tx.request, *tx.responses)}
        keys = [frame_of(m).key for tx in master.transactions for m in (tx.request, *tx.responses)]
        self.top = max(keys, default=0)

    def c(self, m: MessageDecl) -> Fraction:
        return (message_bits(m, self.stuffing) + INTERMISSION_BITS) * self.tau

    def gap(self, tx: Transaction) -> tuple[Fraction, int]:
        """How long the bus may wait for the slaves' processing, and in how many idle stretches
        (one per answer that can be ready after the request's intermission)."""
        ifs = INTERMISSION_BITS * self.tau
        delays = [_delay_max(tx, self.net.slaves, k) for k in range(len(tx.slaves))]
        return max(Fraction(0), Fraction(max(delays)) - ifs), sum(1 for d in delays if d > ifs)

    def bounds(
        self, foreign: _Foreign | None
    ) -> tuple[dict[str, tuple[Fraction, Fraction]], Fraction, dict[str, tuple[Fraction, Fraction, Fraction]]]:
        """Release windows [o_min, o_max] of the chain's frames, the bound on the cycle (its first
        request's queuing to the end of its last answer) and on each transaction. Without
        ``foreign`` the chain is alone on the bus. Per transaction: its own bound, and the bounds on
        its request's end and its last answer's end after the cycle's start."""
        tau = self.tau
        ifs = INTERMISSION_BITS * tau
        slaves = self.net.slaves
        horizon = Fraction(HORIZON_FACTOR * max(self.master.cycle_ns, 1))

        def window(own: Fraction, gaps: int) -> Fraction:
            return own if foreign is None else foreign.window(own, gaps, horizon)

        out: dict[str, tuple[Fraction, Fraction]] = {}
        per_tx: dict[str, tuple[Fraction, Fraction, Fraction]] = {}
        lo = Fraction(0)
        own = Fraction(0)
        gaps = 0
        hi = Fraction(0)
        for tx in self.master.transactions:
            req = tx.request
            out[req.name] = (lo, hi)
            req_end_lo = lo + message_bits_min(req) * tau
            req_end_hi = window(own + self.c(req), gaps)
            ends_lo = []
            for k, resp in enumerate(tx.responses):
                d_lo = 0 if tx.style == "remote" else slaves[tx.slaves[k]].processing_min_ns
                out[resp.name] = (req_end_lo + d_lo, req_end_hi + _delay_max(tx, slaves, k))
                # an answer cannot start before the request's intermission is over
                ends_lo.append(req_end_lo + max(Fraction(d_lo), ifs) + message_bits_min(resp) * tau)
            g, n = self.gap(tx)
            mine = self.c(req) + g + sum((self.c(r) for r in tx.responses), Fraction(0))
            own += mine
            gaps += n
            lo, hi = max(ends_lo), window(own, gaps)
            per_tx[req.name] = (window(mine, n), req_end_hi, hi)
        return out, hi, per_tx


def _other_specs(scenario: Scenario) -> tuple[list[MessageSpec], list[str]]:
    specs: list[MessageSpec] = []
    unmodelled = []
    for d in scenario.nodes:
        if d.profile in MASTER_SLAVE_PROFILES:
            continue
        kind = profile_kind(d.profile)
        if kind.traffic is None:
            unmodelled.append(d.name)
            continue
        specs.extend(kind.traffic(d, scenario))
    return specs, unmodelled


def holistic(scenario: Scenario) -> Holistic:
    """The analysis of the scenario's bus with its master/slave traffic (see the module
    docstring), computed once per scenario, bitrate, stuffing and error model (cached in the
    scenario's master/slave network)."""
    net: Network = scenario.tables["master_slave"]
    stuffing = scenario.analysis.get("stuffing", "worst")
    t_err = scenario.analysis.get("t_error_ms")
    key = (scenario.bitrate, stuffing, t_err)
    got = net.cache.get(key)
    if got is None:
        got = net.cache[key] = _holistic(scenario, net, stuffing, t_err)
    return got


def _holistic(scenario: Scenario, net: Network, stuffing: str, t_err: Any) -> Holistic:
    bitrate = scenario.bitrate
    tau = _tau(bitrate)
    others, unmodelled = _other_specs(scenario)
    chains = [_Chain(m, net, bitrate, stuffing) for m in net.masters.values()]
    errors = None if t_err is None else ErrorModel(round(t_err * 1e6))
    result = Holistic(specs={}, applies=not unmodelled, converged=False, iterations=0)
    # round 0: each chain alone on the bus, each COS frame as long as itself
    windows: dict[str, tuple[Fraction, Fraction]] = {}
    w_cos = {m.name: (frame_bits(m, stuffing) + INTERMISSION_BITS) * tau for s in net.slaves.values() for m in s.cos}
    for ch in chains:
        windows.update(ch.bounds(None)[0])
    jitters: dict[str, Fraction] | None = None
    last: dict[str, tuple[Fraction, dict[str, tuple[Fraction, Fraction, Fraction]]]] = {}
    for it in range(1, MAX_ITERATIONS + 1):
        new_j = {name: hi - lo for name, (lo, hi) in windows.items()}
        new_j.update(_ack_jitters(net, w_cos, tau))
        specs = _build_specs(net, new_j, stuffing)
        result.specs = specs
        result.iterations = it
        if unmodelled:
            result.notes.append("no worst-case model of the traffic of " + ", ".join(unmodelled))
            return result
        if new_j == jitters:
            result.converged = True
            break
        jitters = new_j
        flat = others + [x for v in specs.values() for x in v]
        try:
            rta = analyse(flat, bitrate, errors=errors)
            w_cos = {}
            for name in list(_cos_names(net)):
                r = rta[name]
                if r.bound_ns is None:
                    raise _Unbounded(f"no bound for {name}: {r.unbounded_reason}")
                w_cos[name] = Fraction(r.bound_ns)  # queuing to the end of the frame
            windows = {}
            for ch in chains:
                foreign = _Foreign(
                    [x for x in flat if x.name not in ch.names],
                    rta,
                    ch.top,
                    bitrate,
                    errors,
                    max((Fraction(rta[n].c_ns) for n in ch.names), default=Fraction(0)),
                )
                got, end, per_tx = ch.bounds(foreign)
                windows.update(got)
                last[ch.master.name] = (end, per_tx)
        except ValueError as exc:  # e.g. an identifier used twice across profiles
            result.notes.append(f"the analysis refused the bus: {exc}")
            return result
        except _Unbounded as exc:
            result.notes.append(str(exc))
            return result
    else:
        result.notes.append(f"release jitters still growing after {MAX_ITERATIONS} rounds: no bound")
        return result
    inverting = _inversion_note(scenario)
    if inverting:
        result.notes.append(inverting)
    for ch in chains:
        end, per_tx = last[ch.master.name]
        result.cycle_ns[ch.master.name] = None if inverting else float(end)
        for name, (v, req_end, end_) in per_tx.items():
            result.transaction_ns[name] = None if inverting else float(v)
            result.offsets_ns[name] = None if inverting else (float(req_end), float(end_))
    return result


def _cos_names(net: Network) -> list[str]:
    return [m.name for s in net.slaves.values() for m in s.cos]


def _ack_jitters(net: Network, w_cos: dict[str, Fraction], tau: Fraction) -> dict[str, Fraction]:
    """An acknowledgement is released when the COS frame it answers ends: J_cos + W_cos − L_min."""
    out = {}
    for master in net.masters.values():
        for link in master.cos:
            if link.ack is not None:
                m = link.messages[0]
                out[link.ack.name] = Fraction(m.jitter_ns) + w_cos[m.name] - frame_bits_min(m) * tau
    return out


def _build_specs(net: Network, jitter: dict[str, Fraction], stuffing: str) -> dict[str, list[MessageSpec]]:
    """The streams of every master and slave node, with the jitters of this round."""
    specs: dict[str, list[MessageSpec]] = {n: [] for n in list(net.masters) + list(net.slaves)}
    for master in net.masters.values():
        t = master.cycle_ns
        for tx in master.transactions:
            # deadline: within its cycle (the timeout spans request and answer together)
            specs[master.name].append(_spec(tx.request, t, t, jitter[tx.request.name], stuffing))
            for resp, slave in zip(tx.responses, tx.slaves):
                specs[slave].append(_spec(resp, t, t, jitter[resp.name], stuffing))
        for link in master.cos:
            if link.ack is None:
                continue
            # one acknowledgement per frame of the link's one COS/cyclic message: its interval
            m = link.messages[0]
            specs[master.name].append(
                _spec(
                    link.ack, m.interval_ns or 0, m.deadline_ns or m.interval_ns or 0, jitter[link.ack.name], stuffing
                )
            )
    for s in net.slaves.values():
        for m in s.cos:
            specs[s.name].append(
                _spec(m, m.interval_ns or 0, m.deadline_ns or m.interval_ns or 0, Fraction(m.jitter_ns), stuffing)
            )
    return specs


def _inversion_note(scenario: Scenario) -> str | None:
    """The spine's rule: a node without a priority queue breaks the analysis for its messages and
    every one of lower priority — here the cycle gets no bound."""
    for d in scenario.nodes:
        if not d.priority_queue and (d.messages or d.profile in MASTER_SLAVE_PROFILES):
            return (
                f"node {d.name!r} uses a {d.queue} queue (priority inversion): the analysis gives no bound "
                "for the cycle"
            )
    return None
