"""Priority assignment for CAN messages: deadline monotonic, Audsley's optimal algorithm and the
robust priority assignment of Davis and Burns — pure functions from a message set to an order.

References
- [A91] N. C. Audsley, "Optimal priority assignment and feasibility of static priority tasks
  with arbitrary start times", University of York, Dept. of Computer Science, Report YCS 164,
  1991 (also Information Processing Letters 79(1), 2001).
- [DB09] R. I. Davis, A. Burns, "Robust priority assignment for messages on Controller Area
  Network (CAN)", Real-Time Systems 41(2):152-180, 2009.
- [D07] Davis, Burns, Bril, Lukkien 2007 (`profiles.analysis.rta`): deadline-monotonic order is
  not optimal for CAN once messages have jitter or deadlines beyond their periods, and
  Audsley's algorithm applies. (Recalled, not re-checked against the text; the conditions are
  checked here instead.)

Audsley's algorithm (``opa``): for each priority level from the lowest up, give it to any
unassigned message that the test finds schedulable there, assuming every other unassigned
message has a higher priority; fail when none is. It is optimal for a test — finds an order the
test accepts whenever one exists — if the test is OPA-compatible (the three conditions of Davis
and Burns, restated): the verdict for m may depend on the *set* of higher-priority messages and
on the *set* of lower-priority ones but not on their orders, and m cannot become unschedulable by
moving up one level. D07's exact (busy-period) test, used here, meets them (my check): R_m depends
on hp(m) through sums over it and on lp(m) through B_m = max C (and the error cost through a max
over hep(m)), orders nowhere; and moving m above its neighbour k replaces B_m by max(B_m, C_k) <=
B_m + C_k while removing k's interference, at least C_k from every recurrence (ceil(...) >= 1),
so every right-hand side shrinks pointwise, every least fixed point and the busy period with it,
and R_m cannot grow. The test is the *priority-queue* analysis: FIFO and mailbox nodes (whose
bounds depend on which messages share a queue, not only on priority sets) are refused.

Robust priority assignment (``rpa``, DB09): Audsley's loop, but at each level, among the messages
schedulable there, the one that tolerates the most additional interference takes it. DB09 measure
that interference with an error model, as done here: the tolerance of m at a level is the
shortest T_error (errors of the model's burst size, `profiles.analysis.rta`'s error term) with
which m stays schedulable there; the message with the shortest takes the level. Like OPA it
finds a schedulable order when one exists (the tolerance only chooses among schedulable
candidates), and DB09 show it maximises the error rate the set tolerates.

Deadline monotonic (``dm``): shorter deadline first (D07's reference: from the nominal release),
ties by the current arbitration order.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from profiles.analysis.model import ErrorModel, MessageSpec, Stream, Timebase, prepare, timebase
from profiles.analysis.rta import error_term
from profiles.analysis.window import Term, Window

__all__ = ["ORDERS", "Assignment", "assign_priorities", "identifiers_for"]

ORDERS = ("dm", "opa", "rpa")


@dataclass(frozen=True)
class Assignment:
    """A priority order: ``order`` the message names, highest priority first; ``schedulable``
    whether D07's test accepts every message in it; ``unplaced`` (OPA, RPA) the messages no level
    could take, put at the top in deadline-monotonic order; ``tolerance_ns`` (RPA) the shortest
    T_error each message tolerated at its level (None: not even the longest tried)."""

    method: str
    order: tuple[str, ...]
    schedulable: bool
    unplaced: tuple[str, ...] = ()
    tolerance_ns: dict[str, int | None] | None = None


def _fits(
    m: Stream, higher: Sequence[Stream], lower: Sequence[Stream], tb: Timebase, errors: ErrorModel | None
) -> bool:
    """D07's test for m with ``higher`` above it and ``lower`` below (orders irrelevant)."""
    win = Window(
        Term(m.c, m.t, m.j),
        interfering=[Term(k.c, k.t, k.j) for k in higher],
        blocking=max((k.c for k in lower), default=0),
        tau=tb.bit,
        error=error_term(errors, tb, (*higher, m)),
        horizon=m.horizon,
        deadline=m.d,  # a verdict: stop as soon as a response passes the deadline
    )
    r = win.solve().response
    return r is not None and r <= m.d


def _tolerance(m: Stream, higher: list[Stream], lower: list[Stream], tb: Timebase, burst: int) -> int | None:
    """The shortest T_error (ns) with which m stays schedulable (binary search: a longer T_error
    never hurts); None if not even at the longest tried, the message's horizon."""
    hi = max(1, m.horizon // tb.per_ns)
    if not _fits(m, higher, lower, tb, ErrorModel(hi, burst)):
        return None
    lo = 1  # not schedulable with an error every ns (the bus utilisation would exceed 1)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if _fits(m, higher, lower, tb, ErrorModel(mid, burst)):
            hi = mid
        else:
            lo = mid
    return hi


def assign_priorities(
    messages: Sequence[MessageSpec],
    bitrate: int,
    *,
    order: str = "opa",
    errors: ErrorModel | None = None,
    data_bitrate: int | None = None,
) -> Assignment:
    """A priority order for ``messages`` (see the module docstring) by ``order``: ``dm``,
    ``opa`` or ``rpa``; the verdicts are D07's priority-queue test, with ``errors`` when given
    (CAN FD frames with BRS at ``data_bitrate``). Raises ValueError for an unknown order and for
    the inputs `profiles.analysis.rta.analyse` refuses."""
    if order not in ORDERS:
        raise ValueError(f"priority order {order!r}: one of {', '.join(ORDERS)}")
    msgs = prepare(messages, bitrate, errors, data_bitrate)
    tb = timebase(bitrate, data_bitrate)
    dm = sorted(msgs, key=lambda k: (k.d, k.key))
    if order == "dm":
        names = tuple(k.name for k in dm)
        ok = all(_fits(k, dm[:i], dm[i + 1 :], tb, errors) for i, k in enumerate(dm))
        return Assignment("dm", names, ok)
    unassigned = list(dm)
    lowest_first: list[Stream] = []
    tolerance: dict[str, int | None] = {}
    burst = errors.burst if errors is not None else 1
    while unassigned:
        fits = [k for k in unassigned if _fits(k, [x for x in unassigned if x is not k], lowest_first, tb, errors)]
        if not fits:
            break
        if order == "opa":
            chosen = fits[-1]  # the least urgent that fits: DM among the candidates, from below
        else:
            tol = {k.name: _tolerance(k, [x for x in unassigned if x is not k], lowest_first, tb, burst) for k in fits}
            # shortest tolerated T_error wins; None (tolerates no error rate tried) comes last
            chosen = min(fits, key=lambda k: (tol[k.name] is None, tol[k.name] or 0, -fits.index(k)))
            tolerance[chosen.name] = tol[chosen.name]
        unassigned.remove(chosen)
        lowest_first.append(chosen)
    names = tuple(k.name for k in unassigned) + tuple(k.name for k in reversed(lowest_first))
    return Assignment(
        order,
        names,
        not unassigned,
        tuple(k.name for k in unassigned),
        tolerance if order == "rpa" else None,
    )


def identifiers_for(messages: Sequence[MessageSpec], order: Sequence[str]) -> dict[str, int]:
    """The messages' own identifiers handed out again in ``order`` (highest priority first gets
    the lowest): the set of identifiers stays, who has which changes. ValueError when the
    messages mix standard and extended identifiers (a frame's length, hence the analysis, would
    change with its identifier), when one is a remote frame (its identifier must stay its data
    frame's), or when ``order`` is not a permutation of the message names."""
    by_name = {m.name: m for m in messages}
    if sorted(order) != sorted(by_name) or len(set(order)) != len(order):
        raise ValueError("the order must name every message exactly once")
    formats = {m.extended for m in messages}
    if len(formats) > 1:
        std = next(m.name for m in messages if not m.extended)
        ext = next(m.name for m in messages if m.extended)
        raise ValueError(
            f"messages {std!r} (standard) and {ext!r} (extended): identifiers can be reassigned only "
            "among messages of one format (the frame length depends on it)"
        )
    for m in messages:
        if m.remote:
            raise ValueError(f"message {m.name!r} is a remote frame: its identifier must stay its data frame's")
    pool = sorted(m.can_id for m in messages)
    return dict(zip(order, pool))
