"""The analysis beyond priority queues and nominal clocks — the bound from queuing, FIFO and
mailbox nodes, drifting clocks, the burst error model — against hand-worked values (in the
comments) and against the engine's own clock (`stack.LocalClock`)."""

from __future__ import annotations

import dataclasses

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from profiles.analysis.model import used_period_jitter
from profiles.analysis.rta import ErrorModel, MessageSpec, NodeQueue, analyse
from stack import LocalClock

US = 1_000
MS = 1_000_000


def m8(name: str, can_id: int, period_ns: int, *, jitter_ns: int = 0, node: str = "", deadline_ns: int | None = None):
    """An 8-byte standard frame: 135 bits, 270 us at 500 kbit/s (tau = 2 us)."""
    return MessageSpec(
        name, can_id, False, 8, period_ns, period_ns if deadline_ns is None else deadline_ns, jitter_ns, node=node
    )


# --- the bound from queuing ---------------------------------------------------------------------


def test_bound_from_queuing_with_jitter_beyond_the_period():
    # One message, T = 1 ms, J = 1.5 ms, C = 270 us.
    # Busy period t = ceil((t + 1500)/1000)·270: 270 -> 540 -> 810 -> 810; Q = ceil(2310/1000) = 3.
    # From the nominal release (z = q T, q predecessors): R(0) = 1500 + 0 + 270 = 1770,
    #   R(1) = 1500 + 270 + 270 - 1000 = 1040, R(2) = 1500 + 540 + 270 - 2000 = 310; R = 1770.
    # From queuing: x = 0 has floor(1500/1000) = 1 predecessor (two instances queued at once):
    #   270 + 270 - 0 = 540; x = 2000 - 1500 = 500 has 2: 540 + 270 - 500 = 310. bound = 540.
    r = analyse([m8("m", 0x100, 1 * MS, jitter_ns=1_500 * US)], 500_000)["m"]
    assert r.busy_period_ns == 810 * US
    assert r.responses_ns == (1_770 * US, 1_040 * US, 310 * US)
    assert r.response_ns == 1_770 * US
    assert r.bound_ns == 540 * US


def test_bound_from_queuing_of_the_issue_example():
    # T = 1 ms, J = 0.9 ms: R - J of instance 0 is 270 us, but instance 1 queued on time right
    # after instance 0 queued late waits for it: R(1) = 900 + 270 - 1000 + 270 = 440 us.
    r = analyse([m8("m", 0x100, 1 * MS, jitter_ns=900 * US)], 500_000)["m"]
    assert (r.response_ns, r.bound_ns) == (1_170 * US, 440 * US)


@settings(max_examples=100)
@given(
    st.lists(
        st.tuples(st.integers(1, 20), st.integers(0, 8), st.integers(0, 20), st.integers(1, 40)),
        min_size=1,
        max_size=6,
    )
)
def test_bound_never_exceeds_r_and_equals_it_without_jitter(rows):
    # From queuing the instance is never worse off than from its nominal release (up to J_m
    # earlier); with no jitter the two references coincide.
    spec = [
        MessageSpec(f"m{i}", 0x10 + i, False, dlc, p * MS // 4, d * MS // 4, j * p * MS // 80)
        for i, (p, dlc, j, d) in enumerate(rows)
    ]
    for r, m in zip(analyse(spec, 500_000).values(), sorted(spec, key=lambda m: m.can_id)):
        if r.response_ns is None:
            assert r.bound_ns is None
            continue
        assert r.c_ns <= r.bound_ns <= r.response_ns
        if m.jitter_ns == 0:
            assert r.bound_ns == r.response_ns
    no_jitter = [dataclasses.replace(m, jitter_ns=0) for m in spec]
    for r in analyse(no_jitter, 500_000).values():
        assert r.bound_ns == r.response_ns


# --- FIFO queues --------------------------------------------------------------------------------


def test_fifo_node_and_the_jitter_others_see():
    # 500 kbit/s, every frame 270 us, no jitter. FIFO node F: L (0x700, T = 10 ms) and
    # H (0x080, T = 1 ms); priority node P: M (0x100, T = 10 ms).
    # H (FIFO, lowest of its queue L = 0x700): ahead = {L}, interfering = {M}, B = 0.
    #   busy: 270 -> 810 -> 810; x = 0: base = C_L = 270, w = 270 + ceil((w + 2)/10000)·270 = 540;
    #   bound = 540 + 270 = 810. L likewise (H ahead): 810.
    # M (priority) sees H enter arbitration up to E_H = 810 - 270 = 540 after its queuing:
    #   hp = {H} with J' = 540, B = C_L = 270; busy 270 -> 810 -> 1080 -> 1080, Q = 1;
    #   w = 270 + ceil((w + 540 + 2)/1000)·270: 270 -> 540 -> 810 -> 810; R_M = 1080.
    #   (On a priority queue H would cost M one frame only: R_M = 810.)
    spec = [m8("L", 0x700, 10 * MS, node="F"), m8("H", 0x080, 1 * MS, node="F"), m8("M", 0x100, 10 * MS, node="P")]
    res = analyse(spec, 500_000, queues={"F": NodeQueue("fifo")})
    assert (res["H"].method, res["L"].method, res["M"].method) == ("fifo", "fifo", "davis2007")
    assert res["H"].bound_ns == res["L"].bound_ns == 810 * US
    assert res["H"].arbitration_jitter_ns == 540 * US
    assert res["M"].response_ns == 1_080 * US
    plain = analyse(spec, 500_000)
    assert plain["M"].response_ns == 810 * US and plain["H"].arbitration_jitter_ns == 0


def test_fifo_with_one_message_is_a_priority_queue():
    spec = [m8("A", 0x100, 2 * MS, node="a", jitter_ns=300 * US), m8("B", 0x200, 3 * MS, node="b")]
    for q in (NodeQueue("fifo"), NodeQueue("mailbox", 1), NodeQueue("mailbox", 2, abort=False)):
        assert analyse(spec, 500_000, queues={"a": q, "b": q}) == analyse(spec, 500_000)


def test_fifo_can_make_a_message_unbounded_that_a_priority_queue_bounds():
    # FIFO node F: H (0x080, 0.6 ms) and L (0x700); node P saturates the bus below H but above
    # L with M (0x100, C = 270 us every 300 us): L, and H behind it, may wait for ever.
    spec = [m8("H", 0x080, 600 * US, node="F"), m8("L", 0x700, 10 * MS, node="F"), m8("M", 0x100, 300 * US, node="P")]
    fifo = analyse(spec, 500_000, queues={"F": NodeQueue("fifo")})
    assert fifo["H"].response_ns is None and fifo["H"].bound_ns is None and not fifo["H"].schedulable
    assert fifo["M"].response_ns is None  # it cannot be bounded without H's bound
    assert "'H'" in fifo["M"].unbounded_reason
    prio = analyse(spec, 500_000)
    assert prio["H"].response_ns == 540 * US  # blocking 270 + its own 270


# --- mailboxes ----------------------------------------------------------------------------------


def test_mailboxes_without_abort_that_may_fill():
    # Node K, 2 mailboxes, no abort: A (0x100), B (0x200), C (0x300); node P: X (0x150). All
    # 270 us every 10 ms. Three frames can be pending and only two fit: the mailbox bound.
    # A: ahead = {B, C} (below A: queued before it, they may hold both mailboxes), interfering
    #   X (hp of the queue's lowest C from another node); B = 0 (nothing lower elsewhere).
    #   base = 270 + 270, w = 540 + ceil((w + 2)/10000)·270 = 810; bound = 1080 us.
    # With 3 mailboxes every pending frame has one: a priority queue, R_A = B + C = 540 us.
    spec = [m8(n, i, 10 * MS, node="K") for n, i in (("A", 0x100), ("B", 0x200), ("C", 0x300))]
    spec.append(m8("X", 0x150, 10 * MS, node="P"))
    two = analyse(spec, 500_000, queues={"K": NodeQueue("mailbox", 2)})
    assert two["A"].method == "mailbox" and two["A"].bound_ns == 1_080 * US
    three = analyse(spec, 500_000, queues={"K": NodeQueue("mailbox", 3)})
    assert three["A"].method == "davis2007" and three["A"].bound_ns == 540 * US
    assert three == analyse(spec, 500_000)


def test_mailboxes_with_abort_are_a_priority_queue():
    spec = [m8(n, i, 10 * MS, node="K") for n, i in (("A", 0x100), ("B", 0x200), ("C", 0x300))]
    assert analyse(spec, 500_000, queues={"K": NodeQueue("mailbox", 1, abort=True)}) == analyse(spec, 500_000)


# --- drifting clocks ----------------------------------------------------------------------------


def test_drift_uses_the_shortest_real_period():
    # T = 10 ms, J = 1 ms. Fast by 2 %: T / 1.02 = 9 803 921.57 ns -> floor - 3 = 9 803 918;
    # J / 1.02 = 980 392.16 -> ceil + 3 = 980 396. Slow by 2 %: T / 0.98 = 10 204 081.63 ->
    # 10 204 078; J / 0.98 = 1 020 408.16 -> 1 020 412.
    assert used_period_jitter(10 * MS, 1 * MS, 20_000.0) == (9_803_918, 980_396)
    assert used_period_jitter(10 * MS, 1 * MS, -20_000.0) == (10_204_078, 1_020_412)
    assert used_period_jitter(10 * MS, 1 * MS, 0.0) == (10 * MS, 1 * MS)
    r = analyse([dataclasses.replace(m8("m", 0x100, 10 * MS, jitter_ns=1 * MS), drift_ppm=20_000.0)], 500_000)["m"]
    assert (r.period_used_ns, r.jitter_used_ns) == (9_803_918, 980_396)


@settings(max_examples=80)
@given(
    st.integers(0, 10**9),
    st.sampled_from([-100_000.0, -50_000.0, -1.5, 3.0, 20_000.0, 99_999.0]),
    st.integers(1_000, 50 * MS),
    st.integers(0, 100),
    st.lists(st.tuples(st.integers(0, 200), st.booleans()), min_size=2, max_size=6, unique_by=lambda x: x[0]),
)
def test_drift_margins_hold_for_the_engines_clock(offset, drift, period, jitter_pct, instances):
    # The engine's clock (stack.LocalClock) maps each local release N_i + j_i to the first bus
    # time whose local time reaches it. Whatever the jitters (0 or J), any two releases i < k are
    # at least (k - i) T_used - J_used apart on the bus, and each is within J_used after its
    # nominal release.
    jitter = period * jitter_pct // 100
    clock = LocalClock(offset, drift)
    t_used, j_used = used_period_jitter(period, jitter, drift)
    base = offset + 12_345
    rel = sorted(
        (i, clock.bus(base + i * period + (jitter if late else 0)), clock.bus(base + i * period))
        for i, late in instances
    )
    for _, a, n in rel:
        assert n <= a <= n + j_used
    for (i, a, _), (k, b, _) in zip(rel, rel[1:]):
        assert b - a >= (k - i) * t_used - j_used


# --- the burst error model ----------------------------------------------------------------------


def test_burst_error_model():
    # One 8-byte message at 500 kbit/s, T = 10 ms, T_error = 100 ms, bursts of 3 errors.
    # Per error 31 tau + C = 62 + 270 = 332 us; E(t) = 3 (ceil(t / 100 ms) + 1)·332 us.
    # w = E(w): 0 -> 996 -> 3·2·332 = 1992 -> 1992. R = 1992 + 270 = 2262 us.
    # (burst = 1 is the simple form: 664 + 270 = 934 us.)
    spec = [m8("m", 0x100, 10 * MS)]
    assert analyse(spec, 500_000, errors=ErrorModel(100 * MS, burst=3))["m"].response_ns == 2_262 * US
    assert analyse(spec, 500_000, errors=ErrorModel(100 * MS))["m"].response_ns == 934 * US


# --- bad inputs ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "queues, words",
    [
        ({"n": NodeQueue("lifo")}, ["'n'", "'lifo'"]),
        ({"n": NodeQueue("mailbox")}, ["'n'", "mailboxes None"]),
        ({"n": NodeQueue("mailbox", 0)}, ["'n'", "mailboxes 0"]),
        ({"n": "fifo"}, ["'n'", "NodeQueue"]),
    ],
)
def test_bad_queue_is_refused(queues, words):
    with pytest.raises(ValueError) as exc:
        analyse([m8("m", 0x100, MS, node="n")], 500_000, queues=queues)
    for w in words:
        assert w in str(exc.value)


@pytest.mark.parametrize(
    "change, words",
    [
        (dict(drift_ppm=200_000.0), ["'m'", "drift_ppm 200000.0"]),
        (dict(drift_ppm=float("nan")), ["'m'", "drift_ppm nan"]),
        (dict(period_ns=2, drift_ppm=10.0), ["'m'", "period_ns 2", "10 ppm"]),
    ],
)
def test_bad_drift_is_refused(change, words):
    with pytest.raises(ValueError) as exc:
        analyse([dataclasses.replace(m8("m", 0x100, MS), **change)], 500_000)
    for w in words:
        assert w in str(exc.value)


def test_bad_burst_is_refused():
    with pytest.raises(ValueError, match="burst 0"):
        analyse([m8("m", 0x100, MS)], 500_000, errors=ErrorModel(MS, burst=0))


# --- the verdict-only mode ----------------------------------------------------------------------


@settings(max_examples=60)
@given(
    st.lists(
        st.tuples(
            st.integers(0, 3),  # node
            st.integers(0, 8),  # dlc
            st.integers(1, 30),  # period, 0.25 ms steps
            st.integers(0, 100),  # jitter, % of the period
            st.integers(20, 200),  # deadline, % of the period
        ),
        min_size=1,
        max_size=8,
    ),
    st.lists(st.sampled_from(["priority", "fifo", "mailbox1", "mailbox2", "mailbox2a"]), min_size=4, max_size=4),
)
def test_verdict_only_gives_the_same_verdict(rows, kinds):
    # It only stops recurrences of messages that cannot meet their deadline, so whether every
    # message is schedulable is the same, and where they all are the results are identical.
    spec = [
        MessageSpec(
            f"m{i}", 0x10 + i, False, dlc, p * 250 * US, p * 250 * US * d // 100, p * 250 * US * j // 100, node=f"n{n}"
        )
        for i, (n, dlc, p, j, d) in enumerate(rows)
    ]
    make = {
        "priority": NodeQueue(),
        "fifo": NodeQueue("fifo"),
        "mailbox1": NodeQueue("mailbox", 1),
        "mailbox2": NodeQueue("mailbox", 2),
        "mailbox2a": NodeQueue("mailbox", 2, abort=True),
    }
    queues = {f"n{i}": make[k] for i, k in enumerate(kinds)}
    full = analyse(spec, 500_000, queues=queues)
    quick = analyse(spec, 500_000, queues=queues, verdict_only=True)
    assert all(r.schedulable for r in full.values()) == all(r.schedulable for r in quick.values())
    if all(r.schedulable for r in full.values()):
        assert full == quick
    for name, r in quick.items():  # and it is never the more optimistic of the two
        if full[name].response_ns is None:
            assert r.response_ns is None
        elif r.response_ns is not None:
            assert r.response_ns >= full[name].response_ns and r.bound_ns >= full[name].bound_ns
