"""The busy window of one message: the recurrences every CAN analysis here is built from.

One window describes message m as seen from the bus: its own transmission time C_m, period T_m
and jitter J_m; a blocking time B (one frame already on the wire when the busy period starts);
messages *ahead* of it that are counted by when they were queued before m (the other messages
of its FIFO queue); *interfering* messages counted by how many can start before m does, each
with the jitter at which it can enter arbitration; and optionally an error term. With no
message ahead and hp(m) interfering, it is exactly Davis, Burns, Bril and Lukkien 2007's
analysis (Section 5); `profiles.analysis.rta` says which sets each queue policy gives and proves
the bounds.

Recurrences (integer ticks; tau = one bit time; ceil/floor exact):

- level busy period: t = B + E(t) + sum over m and ahead k of ceil((t + J_k)/T_k) C_k
  + sum over interfering j of ceil((t + J'_j)/T_j) C_j, from t = C_m (Davis 2007, Section 5,
  generalised to the ahead set);
- for a point z >= 0 of the window (the queuing time of the instance, or of its nominal release,
  z after the start of the busy period): the delay to the start of m's transmission
  w(z) = B + E(w) + n_m(z) C_m + sum over ahead k of (floor((z + J_k)/T_k) + 1) C_k
  + sum over interfering j of ceil((w + J'_j + tau)/T_j) C_j, where n_m(z) counts m's own
  predecessors in the busy period;
- the response of that instance: w(z) + C_m − z (from its queuing), maximised over the points
  where a count steps (z = 0, z = p T_k − J_k for ahead k, and m's own steps): between two such
  points w is constant and − z falls. Beyond `MAX_POINTS` points a branch and bound over them
  gives an upper bound of their maximum, exact when its budget suffices (my method, to bound the
  cost of long busy periods; see `Window._maximise`).

E(w) = n (ceil(w / T_error) + 1)(31 tau + max C over the level's messages) with the error model
(n errors per T_error; n = 1 is Tindell and Burns' simple form), else 0.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from fractions import Fraction
from heapq import heappop, heappush

__all__ = ["Term", "Window", "Outcome", "MAX_POINTS", "REFINE_POINTS"]

MAX_POINTS = 256
"""Points of a maximisation computed one by one; beyond, they are bounded by branch and bound
(`Window._maximise`); D07's examples and every test with hand-worked instances stay below it."""

REFINE_POINTS = 512
"""Points the branch and bound computes after the first `MAX_POINTS`, at most."""


def _ceil_div(a: int, b: int) -> int:
    return -(-a // b)


@dataclass(frozen=True)
class Term:
    """A message in a window: transmission time ``c``, period ``t``, jitter ``j`` (ticks)."""

    c: int
    t: int
    j: int


@dataclass(frozen=True)
class Outcome:
    """What a window gives: the busy period ``busy`` (None: unbounded), for each point z of the
    nominal-release maximisation its delay ``delays[i]`` and response from the nominal release
    ``responses[i]``, ``response`` (R: their maximum, None when unbounded), ``worst`` (the index
    of the point attaining it), ``bound`` (the largest queuing-to-end time) and ``reason``
    (why unbounded)."""

    busy: int | None
    delays: tuple[int, ...]
    responses: tuple[int, ...]
    response: int | None
    worst: int | None
    bound: int | None
    reason: str | None


class Window:
    """One message's busy window (see the module docstring).

    ``own`` is m; ``ahead`` the messages counted by queuing time before m (one more instance
    than m's own count: an instance queued at m's instant but before it); ``interfering`` those
    counted by the window length, with the jitter at which they enter arbitration; ``blocking``
    B; ``error`` (t_error, burst, per-error cost) or None; ``horizon`` the recurrence limit;
    ``deadline`` (optional) stops the nominal-release maximisation as soon as a response passes
    it (the outcome is then unbounded, "beyond the deadline": for a yes/no verdict).
    """

    def __init__(
        self,
        own: Term,
        *,
        ahead: Sequence[Term] = (),
        interfering: Sequence[Term] = (),
        blocking: int = 0,
        tau: int,
        error: tuple[int, int, int] | None = None,
        horizon: int,
        deadline: int | None = None,
    ) -> None:
        self.own = own
        self.ahead = tuple(ahead)
        self.interfering = tuple(interfering)
        self.b = blocking
        self.tau = tau
        self.error = error
        self.horizon = horizon
        self.deadline = deadline
        # (J'_k + tau, T_k, C_k) of each interfering message: the inner loop of every recurrence
        self._terms = tuple((k.j + tau, k.t, k.c) for k in self.interfering)
        u = sum((Fraction(k.c, k.t) for k in (own, *self.ahead, *self.interfering)), Fraction(0))
        if error is not None:
            t_err, n, per = error
            u += Fraction(n * per, t_err)
        self.utilisation = u

    def errors(self, t: int) -> int:
        """E(t) = n (ceil(t / T_error) + 1) × per-error cost; 0 without an error model."""
        if self.error is None:
            return 0
        t_err, n, per = self.error
        return n * (_ceil_div(t, t_err) + 1) * per

    def busy_period(self) -> int | None:
        """The level busy period, least fixed point from C_m; None past the horizon."""
        counted = (self.own, *self.ahead, *self.interfering)
        t = self.own.c
        while True:
            nxt = self.b + self.errors(t) + sum(_ceil_div(t + k.j, k.t) * k.c for k in counted)
            if nxt == t:
                return t
            if nxt > self.horizon:
                return None
            t = nxt

    def delay(self, base: int, start: int, limit: int | None = None) -> int | None:
        """w = base + E(w) + interference(w), least fixed point iterated up from ``start`` (which
        must not exceed it); None when w + C_m passes the horizon, or w passes ``limit``."""
        terms = self._terms
        errors = self.errors if self.error is not None else None
        cap = self.horizon - self.own.c
        if limit is not None:
            cap = min(cap, limit)
        w = start
        if w > cap:
            return None
        while True:
            # a plain loop: faster than a generator sum with a call per term (the analysis of an
            # overloaded FIFO bus evaluates it millions of times)
            nxt = base if errors is None else base + errors(w)
            for a, t, c in terms:
                nxt += -(-(w + a) // t) * c
            if nxt == w:
                return w
            if nxt > cap:
                return None
            w = nxt

    def _points(self, span: int, own_offset: int) -> list[int]:
        """z = 0 and every z in (0, span) where a count steps: p T_m − own_offset (m's own) and
        p T_k − J_k (ahead k), p >= 1."""
        pts = {0}
        for t, j in [(self.own.t, own_offset)] + [(k.t, k.j) for k in self.ahead]:
            p = max(1, j // t + 1)
            z = p * t - j
            while z < span:
                if z > 0:
                    pts.add(z)
                z += t
        return sorted(pts)

    def _base(self, z: int, own_offset: int) -> int:
        """The right-hand side of w(z) without interference or errors: B, m's predecessors and
        the instances ahead of it queued by z."""
        own = self.own
        base = self.b + ((z + own_offset) // own.t) * own.c
        return base + sum(((z + k.j) // k.t + 1) * k.c for k in self.ahead)

    def _maximise(self, span: int, own_offset: int, deadline: int | None = None) -> tuple[list[int], list[int]] | None:
        """Delays and responses (w(z) + C_m − z) at the points of ``_points``; None if one is
        unbounded or a response passes ``deadline``.

        Up to `MAX_POINTS` points each is computed. Beyond, the maximum is bounded by branch and
        bound, soundly: w is nondecreasing in z (its base is, and so is the least fixed point of
        a monotone recurrence), so between two computed points z_l < z_r every point z_k in
        between has w(z_k) + C_m − z_k <= w(z_r) + C_m − z_(l+1), the *interval's bound*. First
        the last point of each of `MAX_POINTS` groups of consecutive points is computed; then,
        up to `REFINE_POINTS` times, the interval with the largest bound, while that bound
        exceeds the largest computed response, is split at its middle point, which is computed.
        Intervals whose bound still exceeds that response are reported with it (delay
        w(z_r) at z_(l+1)), so the maximum of what is returned bounds every point's response.
        Before any split each interval's bound is the bound the earlier grouping charged its
        group, and a split only lowers bounds: never looser than that, exact when the worst
        point is found before the budget runs out.
        """
        own = self.own
        pts = self._points(span, own_offset)
        n = len(pts)
        w_at: dict[int, int] = {}

        def compute(i: int, start: int) -> int | None:
            # ``start`` is the delay at a point before i (or 0): never above w(pts[i])
            z = pts[i]
            base = self._base(z, own_offset)
            limit = None if deadline is None else deadline - own.c + z
            w = self.delay(base, max(start, base), limit)
            if w is not None:
                w_at[i] = w
            return w

        size = -(-n // MAX_POINTS)
        prev = 0
        for i in range(size - 1, n + size - 1, size):
            w = compute(min(i, n - 1), prev)
            if w is None:
                return None
            prev = w
        if size == 1:
            return [w_at[i] for i in range(n)], [w_at[i] + own.c - pts[i] for i in range(n)]
        best = max(w + own.c - pts[i] for i, w in w_at.items())
        # intervals (l, r) between computed points with points inside; l = −1 before the first
        heap: list[tuple[int, int, int]] = []
        left = -1
        for r in sorted(w_at):
            if r - left > 1:
                heappush(heap, (-(w_at[r] + own.c - pts[left + 1]), left, r))
            left = r
        for _ in range(REFINE_POINTS):
            if not heap or -heap[0][0] <= best:
                break
            _, left, r = heappop(heap)
            mid = (left + 1 + r) // 2
            w = compute(mid, 0 if left < 0 else w_at[left])
            if w is None:
                return None
            best = max(best, w + own.c - pts[mid])
            if mid - left > 1:
                heappush(heap, (-(w + own.c - pts[left + 1]), left, mid))
            if r - mid > 1:
                heappush(heap, (-(w_at[r] + own.c - pts[mid + 1]), mid, r))
        rows = [(pts[i], w, w + own.c - pts[i]) for i, w in w_at.items()]
        rows += [(pts[left + 1], w_at[r], -ub) for ub, left, r in heap if -ub > best]
        rows.sort()
        if deadline is not None and max(row[2] for row in rows) > deadline:
            return None
        return [row[1] for row in rows], [row[2] for row in rows]

    def solve(self) -> Outcome:
        """Busy period, R from the nominal release (jitter included) and the bound from queuing."""
        if self.utilisation >= 1:
            return Outcome(None, (), (), None, None, None, "utilisation of the level >= 1")
        busy = self.busy_period()
        if busy is None:
            return Outcome(None, (), (), None, None, None, "busy period beyond the horizon")
        j = self.own.j
        # from the nominal release: z is where the nominal release lies (up to J_m before the
        # queuing, so z < busy + J_m), m's predecessors are floor(z / T_m), R = J_m + max(...)
        nominal = self._maximise(busy + j, 0, None if self.deadline is None else self.deadline - j)
        if nominal is None and self.deadline is not None:
            return Outcome(busy, (), (), None, None, None, "beyond its deadline (verdict only)")
        # from the queuing: z < busy, m's predecessors floor((z + J_m) / T_m)
        queued = self._maximise(busy, j)
        if nominal is None or queued is None:
            return Outcome(busy, (), (), None, None, None, "queuing delay beyond the horizon")
        delays, rs = nominal
        responses = [j + r for r in rs]
        response = max(responses)
        return Outcome(
            busy,
            tuple(delays),
            tuple(responses),
            response,
            responses.index(response),
            max(queued[1]),
            None,
        )
