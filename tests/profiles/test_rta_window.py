"""The busy window's maximisation beyond `MAX_POINTS` points: against a second computation of
every point, written here from the recurrences (`profiles.analysis.window`'s docstring), and
against the earlier grouping (each group of consecutive points charged the counts of its last
point against its first z), written here too. The branch and bound must stay an upper bound of
the exact maximum, never be looser than the grouping, equal it with no refinement, and reach
the exact value when its budget suffices."""

from __future__ import annotations

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

import profiles.analysis.window as window
from profiles.analysis.window import Term, Window

TAU = 10  # ticks per bit time in these windows


def _ceil(a: int, b: int) -> int:
    return -(-a // b)


class Reference:
    """Every point of a window computed on its own: busy period, w(z) at each point, the
    responses from the nominal release and from the queuing, exact and grouped."""

    def __init__(self, own: Term, ahead: list[Term], interfering: list[Term], b: int, error, tau: int = TAU):
        self.own, self.ahead, self.interfering, self.b, self.error = own, ahead, interfering, b, error
        self.tau = tau

    def e(self, t: int) -> int:
        if self.error is None:
            return 0
        t_err, n, per = self.error
        return n * (_ceil(t, t_err) + 1) * per

    def busy(self) -> int:
        t = self.own.c
        while True:
            nxt = (
                self.b + self.e(t) + sum(_ceil(t + k.j, k.t) * k.c for k in [self.own, *self.ahead, *self.interfering])
            )
            if nxt == t:
                return t
            t = nxt

    def w(self, z: int, offset: int) -> int:
        base = self.b + (z + offset) // self.own.t * self.own.c
        base += sum(((z + k.j) // k.t + 1) * k.c for k in self.ahead)
        w = base
        while True:
            nxt = base + self.e(w) + sum(_ceil(w + k.j + self.tau, k.t) * k.c for k in self.interfering)
            if nxt == w:
                return w
            w = nxt

    def points(self, span: int, offset: int) -> list[int]:
        pts = {0}
        for t, j in [(self.own.t, offset)] + [(k.t, k.j) for k in self.ahead]:
            p = 1
            while p * t - j < span:
                if p * t - j > 0:
                    pts.add(p * t - j)
                p += 1
        return sorted(pts)

    def responses(self, span: int, offset: int, groups: int | None) -> list[int]:
        pts = self.points(span, offset)
        size = 1 if groups is None else _ceil(len(pts), groups)
        return [
            self.w(pts[min(i + size, len(pts)) - 1], offset) + self.own.c - pts[i] for i in range(0, len(pts), size)
        ]

    def figures(self, groups: int | None = None) -> tuple[int, int]:
        """(R from the nominal release, the bound from queuing), exact or grouped."""
        busy, j = self.busy(), self.own.j
        return j + max(self.responses(busy + j, 0, groups)), max(self.responses(busy, j, groups))


terms = st.builds(
    lambda c, t, jp: Term(c * TAU, t * TAU, t * TAU * jp // 100),
    st.integers(40, 160),
    st.integers(150, 3_000),
    st.integers(0, 200),
)


@settings(max_examples=150, deadline=None)
@given(
    terms,
    st.lists(terms, max_size=2),
    st.lists(terms, max_size=3),
    st.integers(0, 160),
    st.one_of(st.none(), st.tuples(st.integers(5_000, 50_000), st.integers(1, 3))),
    st.integers(1, 6),
    st.integers(0, 12),
)
def test_beyond_max_points_the_maximum_stays_an_upper_bound_and_never_loosens(
    own, ahead, interfering, blocking, error, max_points, refine
):
    # MAX_POINTS of 1..6 puts these small windows (up to a few hundred points) past it
    err = None if error is None else (error[0] * TAU, error[1], 31 * TAU + max(k.c for k in [own, *ahead]))
    ref = Reference(own, ahead, interfering, blocking * TAU, err)
    win = Window(own, ahead=ahead, interfering=interfering, blocking=blocking * TAU, tau=TAU, error=err, horizon=10**15)
    assume(win.utilisation < 1)
    assume(ref.busy() < 400 * own.t)  # a few hundred points at most: the reference computes each

    exact = ref.figures()
    grouped = ref.figures(max_points)
    full = win.solve()
    assert (full.response, full.bound) == exact  # every point computed: the exact values
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(window, "MAX_POINTS", max_points)
        mp.setattr(window, "REFINE_POINTS", refine)
        got = win.solve()
        assert exact[0] <= got.response <= grouped[0]
        assert exact[1] <= got.bound <= grouped[1]
        mp.setattr(window, "REFINE_POINTS", 0)
        plain = win.solve()
        assert (plain.response, plain.bound) == grouped  # no split: the grouping's own figures
        mp.setattr(window, "REFINE_POINTS", 10**6)
        done = win.solve()
        assert (done.response, done.bound) == exact  # budget enough: the exact maximum


def test_a_long_busy_period_gets_its_exact_bound():
    # m (8-byte frames, 135 bits) every 1 ms with J = 0.9 ms under 73 % of higher-priority load
    # at 500 kbit/s (ticks of 1 ns here, tau = 2 us): utilisation 0.9996, a busy period of about
    # 700 of m's periods, past MAX_POINTS points. The grouping charged its first group the
    # counts of its last point against z = 0: about twice the exact figures.
    tau = 2_000
    own = Term(135 * tau, 1_000_000, 900_000)
    hp = [Term(135 * tau, 407_761, 0), Term(114 * tau, 3_379_828, 0)]
    ref = Reference(own, [], hp, 0, None, tau)
    exact, grouped = ref.figures(), ref.figures(window.MAX_POINTS)
    got = Window(own, interfering=hp, tau=tau, horizon=10**15).solve()
    assert len(ref.points(ref.busy() + own.j, 0)) > window.MAX_POINTS
    assert grouped[0] > 1.5 * exact[0] and grouped[1] > 1.5 * exact[1]
    assert (got.response, got.bound) == exact
