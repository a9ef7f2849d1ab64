"""The classic studies (`profiles.sweeps`): UUniFast and the set generators against their
definitions, the schedulability curves against what theory says of them (the analysis is
sufficient, its fraction falls with utilisation, nothing is guaranteed at 100 %), FIFO queues,
and the profiles study's converter hook."""

from __future__ import annotations

import math
import random
import statistics
import sys
import types

import pytest

from profiles import registry
from profiles.analysis.rta import frame_bits_worst, utilisation
from profiles.message_set import MessageSet, StudyMessage
from profiles.pipeline.runner import run_scenario
from profiles.pipeline.scenario import parse_scenario
from profiles.sweeps.comparison import profiles_study
from profiles.sweeps.converters import converter_for, csma_scenario, message_set_from_scenario, register_converter
from profiles.sweeps.random_sets import PERIOD_RANGES_MS, generate_set, uunifast
from profiles.sweeps.schedulability import breakdown, schedulability_study

# --- UUniFast and the generators ------------------------------------------------------------------


def test_uunifast_sums_to_the_total_and_is_uniform_on_the_simplex():
    rng = random.Random(3)
    n, total = 5, 0.8
    draws = [uunifast(n, total, rng) for _ in range(4000)]
    assert all(len(d) == n and min(d) >= 0 and math.isclose(sum(d), total) for d in draws)
    # uniform on the simplex: each share / total is Beta(1, n - 1), so P(share > x total) = (1 - x)^(n - 1)
    for i in (0, n - 1):
        frac = sum(1 for d in draws if d[i] > 0.2 * total) / len(draws)
        expected = 0.8 ** (n - 1)
        sigma = math.sqrt(expected * (1 - expected) / len(draws))
        assert abs(frac - expected) < 4 * sigma, (i, frac, expected)
        assert abs(statistics.fmean(d[i] for d in draws) - total / n) < 0.01


def test_a_uunifast_set_meets_its_definition():
    s = generate_set(random.Random(11), messages=12, utilisation=0.7, per_node=3)
    msgs = s.messages
    assert len(msgs) == 12 and s.bitrate == 500_000
    assert all(m.deadline_ns == m.period_ns for m in msgs)  # deadlines = periods
    assert len({m.can_id for m in msgs}) == 12 and all(0 <= m.can_id <= 0x7FF for m in msgs)
    assert all(0 <= m.dlc <= 8 for m in msgs)
    assert max([sum(1 for m in msgs if m.node == n) for n in s.nodes]) == 3
    lo, hi = PERIOD_RANGES_MS["uunifast"]
    assert all(lo * 1e6 <= m.period_ns <= hi * 1e6 for m in msgs)
    # the utilisation with worst-case frames (the analysis' own function): the target, never below it
    u = utilisation(s.specs(), s.bitrate)
    assert 0.7 <= u < 0.7 + 1e-6 and math.isclose(s.utilisation(), u)
    # deadline-monotonic identifiers: the shorter the period, the lower the identifier
    by_period = sorted(msgs, key=lambda m: m.period_ns)
    assert [m.can_id for m in by_period] == sorted(m.can_id for m in msgs)
    assert s.duration_s == pytest.approx(2 * max(m.period_ns for m in msgs) / 1e9)


def test_the_same_set_number_is_the_same_set_scaled():
    """Common random numbers: UUniFast's shares scale with U, so the periods scale by 1/U."""
    a = generate_set(random.Random(5), messages=8, utilisation=0.4)
    b = generate_set(random.Random(5), messages=8, utilisation=0.8)
    assert [(m.can_id, m.dlc, m.node) for m in a.messages] == [(m.can_id, m.dlc, m.node) for m in b.messages]
    for ma, mb in zip(a.messages, b.messages):
        assert abs(ma.period_ns - 2 * mb.period_ns) <= 2


def test_random_priorities_keep_the_identifiers_as_drawn():
    sets = [generate_set(random.Random(k), messages=8, utilisation=0.5, priorities="random") for k in range(20)]
    dm = sum(
        1
        for s in sets
        if [m.can_id for m in sorted(s.messages, key=lambda m: m.period_ns)] == sorted(m.can_id for m in s.messages)
    )
    assert dm <= 1  # 8! orders: deadline-monotonic by chance is rare


def test_a_loguniform_set_has_log_uniform_periods_and_the_bit_rate_for_its_utilisation():
    lo, hi = 10.0, 1000.0
    periods = []
    for k in range(60):
        s = generate_set(
            random.Random(k), messages=10, utilisation=0.6, generator="loguniform", period_range_ms=(lo, hi)
        )
        assert 1_000 <= s.bitrate <= 1_000_000
        u = utilisation(s.specs(), s.bitrate)
        assert 0.6 <= u < 0.6 * (1 + 1e-3)
        periods += [m.period_ns / 1e6 for m in s.messages]
    assert lo <= min(periods) and max(periods) <= hi
    # log-uniform: each decade of the range holds half the periods
    below = sum(1 for p in periods if p < math.sqrt(lo * hi)) / len(periods)
    assert abs(below - 0.5) < 4 * math.sqrt(0.25 / len(periods))


def test_generator_errors_name_the_rule():
    with pytest.raises(ValueError, match="widen the range"):
        generate_set(random.Random(1), messages=10, utilisation=0.9, period_range_ms=(100.0, 101.0))
    with pytest.raises(ValueError, match="outside 1 kbit/s"):
        generate_set(
            random.Random(1), messages=10, utilisation=0.1, generator="loguniform", period_range_ms=(0.01, 0.02)
        )
    with pytest.raises(ValueError, match="generator 'x'"):
        generate_set(random.Random(1), messages=3, utilisation=0.5, generator="x")


def test_breakdown_is_the_fifty_percent_crossing():
    assert breakdown([(0.5, 1.0), (0.7, 0.8), (0.9, 0.2)]) == pytest.approx(0.8)  # 0.7 + 0.2 * 0.3 / 0.6
    assert breakdown([(0.5, 1.0), (0.7, 0.5), (0.9, 0.4)]) == pytest.approx(0.7)  # at 50 % exactly there
    assert breakdown([(0.5, 1.0), (1.0, 0.9)]) is None
    assert breakdown([(0.5, 0.4), (1.0, 0.0)]) is None


# --- schedulability ---------------------------------------------------------------------------------

UTILISATIONS = [0.3, 0.6, 0.8, 0.9, 1.0]
SETS = 12


@pytest.fixture(scope="module")
def study():
    return schedulability_study(UTILISATIONS, sets=SETS, messages=6, per_node=2, seed=4)


def test_the_analysis_never_accepts_more_sets_at_a_higher_utilisation(study):
    """With common random numbers a set at a higher utilisation is the same set with shorter
    periods, which the analysis cannot find easier: the fraction may rise by no more than one set
    (the noise the test allows for a set redrawn because its periods left the range)."""
    fractions = [p["analysis"] for p in study.points]
    assert all(p["sets"] == SETS for p in study.points) and not study.failed
    for a, b in zip(fractions, fractions[1:]):
        assert b <= a + 1 / SETS, fractions
    assert fractions[0] == 1.0 and fractions[-1] == 0.0


def test_nothing_is_guaranteed_at_full_utilisation(study):
    # at U = 1 the lowest-priority message's higher-or-equal-priority utilisation is 1 (worst-case
    # frames): the busy-period recurrence does not converge, the analysis cannot bound it
    assert all(not r["rta_schedulable"] for r in study.rows if r["utilisation"] == 1.0)
    assert all(r["u_worst"] >= r["utilisation"] for r in study.rows)


def test_the_analysis_is_sufficient_set_by_set_and_point_by_point(study):
    for r in study.rows:
        if r["rta_schedulable"]:
            assert r["sim_priority_ok"], r  # a guaranteed set shows no miss in simulation
        if r["rta_fifo_schedulable"]:
            assert r["sim_fifo_ok"], r  # and so does one the FIFO analysis guarantees
    for p in study.points:
        assert p["simulation"] >= p["analysis"]


def test_opa_accepts_every_set_deadline_monotonic_order_does(study):
    # Audsley's algorithm finds an order the analysis accepts whenever one exists, and the sets'
    # own (deadline-monotonic) identifiers are one order
    for r in study.rows:
        if r["rta_schedulable"]:
            assert r["rta_opa_schedulable"], r
    for p in study.points:
        assert p["opa"] >= p["analysis"]


def test_fifo_queues_lose_sets_that_priority_queues_keep(study):
    # priority inversion: at the highest loads some set misses with FIFO queues and not with priority ones
    assert any(r["sim_priority_ok"] and not r["sim_fifo_ok"] for r in study.rows)
    assert sum(p["fifo"] for p in study.points) < sum(p["simulation"] for p in study.points)
    assert study.breakdown["analysis"] is not None and 0.8 <= study.breakdown["analysis"] <= 1.0


@pytest.mark.subprocess
def test_the_study_is_the_same_on_a_process_pool(study):
    # the first half of the sets at the last two points: with common random numbers a set is drawn
    # from its own number, whatever the count of sets, so these are the module study's rows (runs
    # numbered from 0), at both points, sets with and without a simulated miss
    half = SETS // 2
    again = schedulability_study(
        UTILISATIONS[-2:], sets=half, messages=6, per_node=2, seed=4, workers=2, engine="processes"
    )
    tail = [r for r in study.rows if r["utilisation"] in UTILISATIONS[-2:] and r["set"] < half]
    assert len(tail) == 2 * half and {r["sim_priority_ok"] for r in tail} == {True, False}
    assert again.rows == [dict(r, run=k) for k, r in enumerate(tail)]


def test_study_plots(study, tmp_path):
    pytest.importorskip("matplotlib")
    from profiles.sweeps.plots import schedulability_plot

    for curves in (("analysis", "opa", "simulation"), ("simulation", "fifo", "fifo_analysis")):
        p = schedulability_plot(study, tmp_path / f"{curves[1]}.png", curves=curves)
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.campaign
def test_schedulability_campaign():
    """The same properties with 100 sets per point, 10 % .. 100 % (opt-in: -m campaign)."""
    big = schedulability_study([u / 10 for u in range(1, 11)], sets=100, workers=2)
    fr = [p["analysis"] for p in big.points]
    assert all(b <= a + 0.02 for a, b in zip(fr, fr[1:]))
    assert all(p["simulation"] >= p["analysis"] for p in big.points)
    assert all(r["sim_priority_ok"] for r in big.rows if r["rta_schedulable"])


# --- profiles -----------------------------------------------------------------------------------------

SMALL_SET = MessageSet(
    500_000,
    (
        StudyMessage("fast", "a", 0x10, 8, 2_000_000, 2_000_000),
        StudyMessage("mid", "b", 0x20, 4, 5_000_000, 5_000_000),
        StudyMessage("slow", "a", 0x30, 8, 10_000_000, 10_000_000),
    ),
    duration_s=0.2,
    seed=3,
)


def test_csma_expresses_the_set_as_a_scenario():
    raw = csma_scenario(SMALL_SET)
    sc = parse_scenario(raw, "set")
    assert [(n.name, n.profile, n.queue) for n in sc.nodes] == [("a", "csma", "priority"), ("b", "csma", "priority")]
    assert [(m.name, m.can_id, m.dlc, m.period_ns, m.offset_ns) for m in sc.messages] == [
        ("fast", 0x10, 8, 2_000_000, 0),
        ("slow", 0x30, 8, 10_000_000, 0),
        ("mid", 0x20, 4, 5_000_000, 0),
    ]
    assert (sc.bitrate, sc.duration_ns, sc.seed) == (500_000, 200_000_000, 3)
    assert message_set_from_scenario(sc).messages == tuple(sorted(SMALL_SET.messages, key=lambda m: m.node))


BUILT_IN = {"master/slave", "tdma"}  # the other profiles shipped with converters (tested in test_converters.py)


def test_profiles_study_with_csma_matches_the_experiment():
    res = profiles_study(SMALL_SET)
    row = next(r for r in res.rows if r["profile"] == "csma")
    direct = run_scenario(parse_scenario(csma_scenario(SMALL_SET), "set"), progress=False)
    assert row["bus_load"] == direct.bus_load
    for m in direct.messages:
        assert row[f"{m['name']}.max_ms"] == m["response_ms"]["max"]
        assert row[f"{m['name']}.jitter_ms"] == m["jitter_ms"]
    compared = {name for r in res.rows for name in r["profile"].split("/")}
    assert set(res.skipped) == set(registry.profile_kinds()) - compared


@pytest.fixture
def second_profile(monkeypatch):
    """A second profile, as the master/slave and TDMA modules will be: a module with a ProfileKind
    and an ``express_message_set`` (here: CSMA/CR with FIFO queues under another name)."""
    from profiles.csma import CsmaProfile

    mod = types.ModuleType("fake_fifo_profile")

    def build(node, decl, context):
        return CsmaProfile(node, decl, context)

    def express_message_set(mset):
        raw = csma_scenario(mset)
        for n in raw["nodes"]:
            n.update(profile="fake_fifo", queue="fifo")
        return raw

    build.__module__ = mod.__name__
    mod.build = build
    mod.express_message_set = express_message_set
    monkeypatch.setitem(sys.modules, mod.__name__, mod)
    monkeypatch.setattr(registry, "_KINDS", dict(registry.profile_kinds()))  # restored after the test
    registry.register(registry.ProfileKind(name="fake_fifo", build=build))
    return mod


def test_a_profile_module_provides_its_converter(second_profile):
    assert converter_for("fake_fifo") is second_profile.express_message_set
    assert converter_for("csma") is csma_scenario
    res = profiles_study(SMALL_SET)
    rows = [r for r in res.rows if r["profile"] not in BUILT_IN]
    assert [r["profile"] for r in rows] == ["csma", "fake_fifo"]
    csma, fifo = rows
    # node a sends 'fast' and 'slow' released together at 0: FIFO sends them in release order
    # (declaration order), priority queues by identifier; either way every frame goes out
    assert fifo["frames"] == csma["frames"] and fifo["bus_load"] == csma["bus_load"]
    assert "fake_fifo" not in res.skipped


def test_a_registered_converter_wins_and_a_failing_one_is_a_row(second_profile):
    def broken(mset):
        raise RuntimeError("no slot for 'fast'")

    register_converter("fake_fifo", broken)
    try:
        res = profiles_study(SMALL_SET)
    finally:
        from profiles.sweeps import converters

        converters._CONVERTERS.pop("fake_fifo")
    row = next(r for r in res.rows if r["profile"] == "fake_fifo")
    assert row["error"] == "converter: RuntimeError: no slot for 'fast'"


def test_profiles_of_one_module_share_one_run(second_profile):
    """master and slave live in one module: its converter runs once, labelled with both names."""

    def build_peer(node, decl, context):
        return second_profile.build(node, decl, context)

    build_peer.__module__ = second_profile.__name__
    registry.register(registry.ProfileKind(name="fake_peer", build=build_peer))
    res = profiles_study(SMALL_SET)
    assert [r["profile"] for r in res.rows if r["profile"] not in BUILT_IN] == ["csma", "fake_fifo/fake_peer"]


def test_a_profile_without_a_converter_is_skipped_with_the_reason(monkeypatch):
    from profiles.csma import CsmaProfile

    def build(node, decl, context):
        return CsmaProfile(node, decl, context)

    monkeypatch.setattr(registry, "_KINDS", dict(registry.profile_kinds()))
    registry.register(registry.ProfileKind(name="mute", build=build))
    res = profiles_study(SMALL_SET)
    assert res.skipped["mute"] == f"no converter ({__name__} has no express_message_set)"
    assert [r["profile"] for r in res.rows if r["profile"] not in BUILT_IN] == ["csma"]


def test_profiles_plot(tmp_path):
    pytest.importorskip("matplotlib")
    from profiles.sweeps.plots import profiles_plot

    assert profiles_plot(profiles_study(SMALL_SET), tmp_path / "p.png").read_bytes()[:4] == b"\x89PNG"


def test_frame_bits_used_by_the_generator_are_the_papers():
    # the generator's C_i is eq. 1 of Davis et al.: 135 bits for 8 bytes, 55 for none (standard ids)
    assert frame_bits_worst(8, False) == 135 and frame_bits_worst(0, False) == 55
