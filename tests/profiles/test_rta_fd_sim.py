"""The analysis' bounds against the simulated CAN FD bus: no simulated instance may exceed them.

Random CAN FD and mixed classical/FD networks (seeded; `profiles.sweeps.networks.random_network`
with ``fd``) at 125 kbit/s .. 1 Mbit/s nominal and 1 .. 8 times that in the data phase: FD frames
of 0..64 bytes with and without BRS beside classical frames, nodes with priority, FIFO and
mailbox queues (with and without abort), some classical senders ISO 11898-1:2015 tolerant
controllers, release jitter up to the period, drifting clocks, exact or worst-case frame lengths.
They run on `stack.SimBus` with a data bit rate (`profiles.sweeps.releases.run_network`) in its
release patterns: independent random jitter, D07's critical instant (every message's first
instance queued at once with its full jitter, a lower-priority frame on the wire one bit
before), jitter alternating between its extremes, and extremes at random. The check is this
file's own (`check`): every instance's time from queuing to the end of its frame must stay within
``bound_ns``, and from its nominal release within ``response_ns``; a simulated deadline miss must
be one the analysis predicts; and a mixed bus sees no error frame (a tolerant node integrates on
FD frames rather than destroy them).

The worst-case FD frame the analysis takes (`profiles.analysis.model`) is checked against the
standard and Bordoloi and Samii in tests/profiles/test_rta_fd.py; here it meets the engine's own
frames and arbitration. At a synchronous release (no jitter, no offset) the highest-priority
message's bound is nearly reached: its worst response is the longest lower-priority frame,
started one bit before the release, and its own frame, measured to the end of EOF (the bound
counts the 3-bit intermission) — within ``TIGHT`` of the bound.
"""

from __future__ import annotations

import random

import pytest

from profiles.analysis.rta import analyse
from profiles.sweeps.networks import Network, random_network
from profiles.sweeps.releases import PATTERNS, Measured, run_network, simulation_duration
from stack.controller.node import FD, TOLERANT

TIGHT = 0.97
"""The least fraction of its bound the highest-priority message reaches at a synchronous release
(what it misses: one nominal bit of the blocker, started a bit early, and its own intermission)."""


def simulate(net: Network, pattern: str, seed: int, blocker: str | None = None) -> dict[str, Measured]:
    """The library's run of ``net``, which must see no error frame: the networks have no error
    model, and on a mixed bus a tolerant node integrates on the FD frames."""
    run = run_network(net, pattern, seed, simulation_duration(net), blocker=blocker)
    assert run.error_frames == 0, (pattern, seed, net)
    return run.measured


def check(net: Network, measured: dict[str, Measured]) -> list[tuple[str, str, float]]:
    """Assert measured <= bound for every bounded message, and that a simulated miss is one the
    analysis predicted; return (name, method, measured/bound from queuing)."""
    res = analyse(net.specs(), net.bitrate, queues=net.queues(), data_bitrate=net.data_bitrate)
    out = []
    for m in net.messages:
        r = res[m.name]
        got = measured[m.name]
        if r.bound_ns is None:
            continue
        assert r.response_ns is not None
        assert got.queued <= r.bound_ns, (m.name, r.method, got.queued, r.bound_ns, net)
        assert got.nominal <= r.response_ns, (m.name, r.method, got.nominal, r.response_ns, net)
        if got.misses:
            assert not r.schedulable, (m.name, net)
        out.append((m.name, r.method, got.queued / r.bound_ns))
    return out


@pytest.mark.parametrize("fd", ["all", "mixed"])
def test_simulation_never_exceeds_the_fd_bounds_on_random_networks(fd):
    rng = random.Random(21 + (fd == "mixed"))
    rows: list[tuple[str, str, float]] = []
    fd_brs = fd_plain = classical = tolerant = 0
    for i in range(20):
        net = random_network(rng, fd=fd)
        assert net.data_bitrate is not None and net.bitrate <= net.data_bitrate <= 8 * net.bitrate
        fd_brs += sum(m.brs for m in net.messages)
        fd_plain += sum(m.fd and not m.brs for m in net.messages)
        classical += sum(not m.fd for m in net.messages)
        tolerant += sum(n.fd == TOLERANT for n in net.nodes)
        # a tolerant node sends classical frames only (only an FD-enabled controller sends FD ones)
        kinds = {n.name: n.fd for n in net.nodes}
        assert all(kinds[m.node] == FD for m in net.messages if m.fd)
        rows += check(net, simulate(net, list(PATTERNS)[i % len(PATTERNS)], 1_000 * (fd == "mixed") + i))
    methods = {method for _, method, _ in rows}
    assert {"davis2007", "fifo", "mailbox"} <= methods, methods  # every kind of bound exercised
    assert len(rows) >= 60 and fd_brs >= 10 and fd_plain >= 5
    if fd == "mixed":
        assert classical >= 5 and tolerant >= 2
    else:
        assert classical == tolerant == 0


@pytest.mark.parametrize("seed", range(6))
def test_a_synchronous_release_comes_close_to_the_bound_of_the_highest_priority_message(seed):
    """Jitter 0, offsets 0, priority queues, exact lengths: every message released at once, the
    longest lower-priority frame one bit earlier. The highest-priority message waits for that
    frame and then goes: its bound (B + C) is reached but for one nominal bit and its own
    intermission, both in the bound (TIGHT); every other bound holds."""
    rng = random.Random(100 + seed)
    net = random_network(rng, max_util=0.6, fd="mixed" if seed % 2 else "all", drift=False)
    for n in net.nodes:
        n.queue, n.mailboxes, n.abort = "priority", None, False
    for m in net.messages:
        m.jitter_ns = 0
    net.exact = True
    top = min(net.messages, key=lambda m: m.frame.key)
    lower = [m for m in net.messages if m is not top]
    blocker = max(lower, key=lambda m: m.frame.bits.duration_ns(net.bitrate, net.data_bitrate)) if lower else None
    got = simulate(net, "critical", seed, blocker=None if blocker is None else blocker.name)
    rows = {name: ratio for name, _, ratio in check(net, got)}
    res = analyse(net.specs(), net.bitrate, queues=net.queues(), data_bitrate=net.data_bitrate)
    if blocker is not None:  # the blocker is the analysis' B
        assert res[top.name].blocking_ns == res[blocker.name].c_ns
    # what is left of the bound: one nominal bit (the blocker started before the release) and
    # top's own intermission
    tau = 10**9 / net.bitrate
    assert res[top.name].bound_ns - got[top.name].queued == pytest.approx(4 * tau, abs=1), net
    assert rows[top.name] >= TIGHT, (rows[top.name], net)


@pytest.mark.campaign
@pytest.mark.parametrize("fd", ["all", "mixed"])
def test_fd_campaign(fd):
    """The longer campaign (-m campaign): 300 networks each; the tightness is printed (-s)."""
    rng = random.Random(2100 + (fd == "mixed"))
    rows: list[tuple[str, str, float]] = []
    for i in range(300):
        net = random_network(rng, fd=fd)
        rows += check(net, simulate(net, list(PATTERNS)[i % len(PATTERNS)], 50_000 + i))
    for method in sorted({m for _, m, _ in rows}):
        ratios = [r for _, m, r in rows if m == method]
        print(
            f"{method}: {len(ratios)} messages, measured/bound max {max(ratios):.3f} mean {sum(ratios) / len(ratios):.3f}"
        )
