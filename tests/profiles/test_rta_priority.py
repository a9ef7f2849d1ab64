"""Priority assignment (deadline monotonic, Audsley's OPA, Davis and Burns' robust assignment)
against hand-worked examples and an exhaustive oracle: every permutation of small sets analysed
with `profiles.analysis.rta.analyse`."""

from __future__ import annotations

import dataclasses
import itertools

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from profiles.analysis.priority import assign_priorities, identifiers_for
from profiles.analysis.rta import ErrorModel, MessageSpec, analyse

US = 1_000
MS = 1_000_000


def jitter_example() -> list[MessageSpec]:
    # Three 8-byte standard frames at 500 kbit/s: C = 135 bits = 270 us, tau = 2 us.
    return [
        MessageSpec("A", 0x100, False, 8, 1 * MS, 1_200 * US, 0),
        MessageSpec("B", 0x101, False, 8, 4 * MS, 1_200 * US, 400 * US),
        MessageSpec("X", 0x102, False, 8, 1 * MS, 1_500 * US, 400 * US),
    ]


def test_deadline_monotonic_fails_where_opa_succeeds():
    # DM (ties by identifier): A > B > X. B, below A and blocked by X:
    #   w = 270 + ceil((w + 2)/1000)·270: 270 -> 540 -> 540; R_B = 400 + 540 + 270 = 1210 > 1200.
    dm = assign_priorities(jitter_example(), 500_000, order="dm")
    assert dm.order == ("A", "B", "X") and not dm.schedulable
    # OPA, from the lowest level. X there (hp = A, B; no blocking): busy period
    #   270 -> 810 -> 1080 -> 1350 -> 1350, Q = ceil(1750/1000) = 2;
    #   q = 0: w = 270·ceil((w+2)/1000) + 270·ceil((w+402)/4000): 0 -> 540 -> 540, R = 1210;
    #   q = 1: w = 270 + ... from 810: 810, R = 400 + 810 - 1000 + 270 = 480. R_X = 1210 <= 1500.
    # B there fails (R = 400 + 540 + 270 = 1210 > 1200); A fits but X is the least urgent fit.
    # Level 2: A (hp B, blocked by X): w = 270 + 270·ceil((w+402)/4000) = 540, R = 810 <= 1200;
    #   B (hp A) fails as under DM. Top: B, R = 400 + 270 + 270 = 940 <= 1200.
    opa = assign_priorities(jitter_example(), 500_000, order="opa")
    assert opa.order == ("B", "A", "X") and opa.schedulable and opa.unplaced == ()
    ids = identifiers_for(jitter_example(), opa.order)
    assert ids == {"B": 0x100, "A": 0x101, "X": 0x102}
    res = analyse([dataclasses.replace(m, can_id=ids[m.name]) for m in jitter_example()], 500_000)
    assert {n: r.response_ns for n, r in res.items()} == {"B": 940 * US, "A": 810 * US, "X": 1_210 * US}
    assert all(r.schedulable for r in res.values())


def test_unschedulable_set_reports_what_could_not_be_placed():
    # two 1 ms frames (7 bytes at 125 kbit/s) every 1.5 ms with D = 1.5 ms: whichever is lower
    # waits for the other's frame (blocking or interference) and responds in 2 ms > 1.5 ms
    spec = [MessageSpec(n, i, False, 7, 1_500 * US, 1_500 * US) for i, n in enumerate("PQ")]
    for order in ("opa", "rpa"):
        a = assign_priorities(spec, 125_000, order=order)
        assert not a.schedulable and set(a.unplaced) == {"P", "Q"} and sorted(a.order) == ["P", "Q"]


def _schedulable_in(spec: list[MessageSpec], order: tuple[str, ...], bitrate: int, errors=None) -> bool:
    ids = identifiers_for(spec, order)
    res = analyse([dataclasses.replace(m, can_id=ids[m.name]) for m in spec], bitrate, errors=errors)
    return all(r.schedulable for r in res.values())


@st.composite
def small_sets(draw, max_size: int = 5):
    n = draw(st.integers(2, max_size))
    out = []
    for i in range(n):
        period = draw(st.sampled_from([1, 2, 3, 4, 6]))
        out.append(
            MessageSpec(
                f"m{i}",
                0x10 + i,
                False,
                draw(st.sampled_from([0, 4, 8])),
                period * MS,
                draw(st.integers(400, 2 * period * 1_000)) * US,
                draw(st.integers(0, period * 1_000)) * US,
            )
        )
    return out


@settings(max_examples=25)
@given(small_sets())
def test_opa_and_rpa_are_optimal_against_every_permutation(spec):
    exists = any(_schedulable_in(spec, p, 500_000) for p in itertools.permutations(m.name for m in spec))
    opa = assign_priorities(spec, 500_000, order="opa")
    rpa = assign_priorities(spec, 500_000, order="rpa")
    dm = assign_priorities(spec, 500_000, order="dm")
    assert opa.schedulable == exists == rpa.schedulable
    assert opa.schedulable == _schedulable_in(spec, opa.order, 500_000)
    assert rpa.schedulable == _schedulable_in(spec, rpa.order, 500_000)
    assert dm.schedulable == _schedulable_in(spec, dm.order, 500_000)
    if dm.schedulable:
        assert opa.schedulable


def _set_tolerance(spec: list[MessageSpec], order: tuple[str, ...]) -> int | None:
    """The shortest T_error (us) with which every message is schedulable in ``order``."""
    lo, hi = 1, 10**6
    if not _schedulable_in(spec, order, 500_000, ErrorModel(hi * US)):
        return None
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if _schedulable_in(spec, order, 500_000, ErrorModel(mid * US)):
            hi = mid
        else:
            lo = mid
    return hi


@settings(max_examples=8)
@given(small_sets(max_size=4))
def test_rpa_tolerates_the_highest_error_rate_of_all_orders(spec):
    # Davis and Burns 2009: the robust order tolerates errors as frequent as any order does
    # (checked in whole microseconds of T_error against every permutation)
    tolerances = [_set_tolerance(spec, p) for p in itertools.permutations(m.name for m in spec)]
    finite = [t for t in tolerances if t is not None]
    rpa = assign_priorities(spec, 500_000, order="rpa")
    got = _set_tolerance(spec, rpa.order)
    if not finite:
        assert got is None
    else:
        assert got == min(finite)


def test_identifiers_for_refuses_what_it_cannot_permute():
    spec = jitter_example()
    with pytest.raises(ValueError, match="every message exactly once"):
        identifiers_for(spec, ("A", "B"))
    mixed = spec[:2] + [MessageSpec("E", 0x1000, True, 8, MS, MS)]
    with pytest.raises(ValueError, match="'E' \\(extended\\)"):
        identifiers_for(mixed, ("A", "B", "E"))
    remote = spec[:2] + [MessageSpec("R", 0x200, False, 8, MS, MS, remote=True)]
    with pytest.raises(ValueError, match="'R' is a remote frame"):
        identifiers_for(remote, ("A", "B", "R"))
    with pytest.raises(ValueError, match="priority order 'xyz'"):
        assign_priorities(spec, 500_000, order="xyz")
