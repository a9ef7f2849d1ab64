"""The analysis' bounds against the simulated CAN FD bus: no simulated instance may exceed them.

Random CAN FD and mixed classical/FD networks (seeded) at 125 kbit/s .. 1 Mbit/s nominal and
1 .. 8 times that in the data phase: FD frames of 0..64 bytes with and without BRS beside
classical frames, nodes with priority, FIFO and mailbox queues (with and without abort), some
classical senders ISO 11898-1:2015 tolerant controllers, release jitter up to the period,
drifting clocks, exact or worst-case frame lengths. Releases follow independent random jitter,
D07's critical instant (every message's first instance queued at once with its full jitter, a
lower-priority frame on the wire one bit before), jitter alternating between its extremes, and
extremes at random. Every instance's time from queuing to the end of its frame must stay within
``bound_ns``, and from its nominal release within ``response_ns``.

The worst-case FD frame the analysis takes (`profiles.analysis.model`) is checked against the
standard and Bordoloi and Samii in tests/profiles/test_rta_fd.py; here it meets the engine's own
frames and arbitration. At a synchronous release (no jitter, no offset) the highest-priority
message's bound is nearly reached: its worst response is the longest lower-priority frame,
started one bit before the release, and its own frame, measured to the end of EOF (the bound
counts the 3-bit intermission) — within ``TIGHT`` of the bound.
"""

from __future__ import annotations

import random
from dataclasses import dataclass, field

import pytest

from profiles.analysis.rta import MessageSpec, NodeQueue, analyse, frame_bits_worst
from stack import Frame, LocalClock, Node, RequestState, SimBus
from stack.controller.node import FD, TOLERANT
from stack.wire.fd import FD_LENGTHS

MS = 1_000_000
PATTERNS = ("random", "critical", "alternate", "extremes")
TIGHT = 0.97
"""The least fraction of its bound the highest-priority message reaches at a synchronous release
(what it misses: one nominal bit of the blocker, started a bit early, and its own intermission)."""


@dataclass
class NetNode:
    name: str
    queue: str = "priority"
    mailboxes: int | None = None
    abort: bool = False
    drift_ppm: float = 0.0
    offset_ns: int = 0
    fd: str = FD


@dataclass
class NetMsg:
    name: str
    node: str
    can_id: int
    extended: bool
    data: bytes
    fd: bool
    brs: bool
    period_ns: int
    jitter_ns: int
    deadline_ns: int

    @property
    def frame(self) -> Frame:
        if self.fd:
            return Frame(self.can_id, self.data, extended=self.extended, fd=True, brs=self.brs)
        return Frame(self.can_id, self.data, extended=self.extended)


@dataclass
class Network:
    bitrate: int
    data_bitrate: int
    nodes: list[NetNode]
    messages: list[NetMsg]
    exact: bool = False

    def specs(self) -> list[MessageSpec]:
        drift = {n.name: n.drift_ppm for n in self.nodes}
        out = []
        for m in self.messages:
            f = m.frame
            exact = self.exact
            out.append(
                MessageSpec(
                    m.name,
                    m.can_id,
                    m.extended,
                    f.dlc,
                    m.period_ns,
                    m.deadline_ns,
                    m.jitter_ns,
                    f.bits.length + 3 if exact else None,
                    node=m.node,
                    drift_ppm=drift[m.node],
                    fd=m.fd,
                    brs=m.brs,
                    data_bits=f.bits.data_bits if exact and m.brs else None,
                )
            )
        return out

    def queues(self) -> dict[str, NodeQueue]:
        return {n.name: NodeQueue(n.queue, n.mailboxes, n.abort) for n in self.nodes}


def _uunifast(n: int, total: float, rng: random.Random) -> list[float]:
    out, s = [], total
    for i in range(1, n):
        nxt = s * rng.random() ** (1.0 / (n - i))
        out.append(s - nxt)
        s = nxt
    return out + [s]


def _worst_ns(m: NetMsg, bitrate: int, data_bitrate: int) -> float:
    """A rough worst-case frame time (for choosing periods only): the FD worst case at the data
    rate when BRS, the whole frame at the nominal rate otherwise."""
    dlc = m.frame.dlc
    bits = frame_bits_worst(dlc, m.extended, fd=m.fd, brs=m.brs)
    return bits * 1e9 / (data_bitrate if m.brs else bitrate) + (40 * 1e9 / bitrate if m.brs else 0)


def random_network(rng: random.Random, *, max_util: float = 0.85, mixed: bool = True, drift: bool = True) -> Network:
    """2..5 nodes of random queue kinds, 1..4 messages each, FD (half with BRS) or classical;
    with ``mixed``, some nodes are tolerant classical controllers sending classical frames;
    utilisation 0.15..max_util split by UUniFast; jitter uniform in [0, T] (a quarter exactly T)."""
    bitrate = rng.choice([125_000, 250_000, 500_000, 1_000_000])
    data_bitrate = min(16_000_000, bitrate * rng.choice([1, 2, 4, 5, 8]))
    nodes = []
    for i in range(rng.randint(2, 5)):
        kind = rng.choice(["priority", "fifo", "mailbox", "mailbox"])
        n = NetNode(f"n{i}", kind)
        if kind == "mailbox":
            n.mailboxes = rng.randint(1, 3)
            n.abort = rng.random() < 0.4
        if drift and rng.random() < 0.4:
            n.drift_ppm = rng.choice([1.0, -1.0]) * rng.choice([50.0, 2_000.0, 20_000.0])
            n.offset_ns = rng.randint(0, 10**6)
        if mixed and rng.random() < 0.3:
            n.fd = TOLERANT
        nodes.append(n)
    counts = [rng.randint(1, 4) for _ in nodes]
    ids = rng.sample(range(0x800), sum(counts))
    u = _uunifast(sum(counts), rng.uniform(0.15, max_util), rng)
    msgs = []
    k = 0
    for node, count in zip(nodes, counts):
        for _ in range(count):
            extended = rng.random() < 0.2
            fd = node.fd == FD and (not mixed or rng.random() < 0.7)
            brs = fd and data_bitrate > bitrate and rng.random() < 0.6
            n_bytes = rng.choice(FD_LENGTHS) if fd else rng.randint(0, 8)
            data = bytes(rng.randrange(256) for _ in range(n_bytes))
            m = NetMsg(f"m{k}", node.name, (ids[k] << 18) if extended else ids[k], extended, data, fd, brs, 0, 0, 0)
            c = _worst_ns(m, bitrate, data_bitrate)
            m.period_ns = int(max(2 * c, min(40 * MS, c / max(u[k], 1e-3))))
            m.jitter_ns = m.period_ns if rng.random() < 0.25 else rng.randint(0, m.period_ns)
            m.deadline_ns = m.period_ns
            msgs.append(m)
            k += 1
    return Network(bitrate, data_bitrate, nodes, msgs, exact=rng.random() < 0.5)


@dataclass
class Measured:
    queued: int = 0  # worst queuing -> end of EOF (or still pending at the end)
    nominal: int = 0  # worst nominal release -> end of EOF
    sent: int = 0
    late: list[int] = field(default_factory=list)


class Release:
    """Queues message ``m`` on ``node`` at its nominal releases (node clock) plus a jitter: the
    ``pattern`` list repeated (or ``after`` once it is used up), else uniform in [0, J]; logs
    each request with its nominal release as a bus time."""

    def __init__(self, m: NetMsg, node: Node, log: list, pattern: list[int] | None, after: int | None, rng=None):
        self.m, self.node, self.log = m, node, log
        self.frame = m.frame
        self.pattern, self.after, self.rng = pattern, after, rng
        self.i = 0

    def jitter(self) -> int:
        i, p = self.i, self.pattern
        if p is None:
            return self.rng.randint(0, self.m.jitter_ns)
        if i < len(p) or self.after is None:
            return p[i % len(p)]
        return self.after

    def start(self, nominal: int) -> None:
        self.node.call_at(nominal + self.jitter(), self.fire, nominal)

    def fire(self, nominal: int) -> None:
        req = self.node.send(self.frame)
        self.log.append((req, self.node.to_bus(nominal)))
        self.i += 1
        self.start(nominal + self.m.period_ns)


def simulate(net: Network, pattern: str, seed: int, duration_ns: int, blocker: str | None = None) -> dict:
    """Run ``net`` on an FD bus with releases in ``pattern`` (module docstring); in the critical
    pattern ``blocker`` (default: the longest frame) is queued one nominal bit before the rest."""
    rng = random.Random(seed)
    bus = SimBus(net.bitrate, data_bitrate=net.data_bitrate, seed=seed, record=False)
    nodes: dict[str, Node] = {}
    for n in net.nodes:
        clock = LocalClock(n.offset_ns, n.drift_ppm) if n.drift_ppm else None
        nodes[n.name] = bus.node(n.name, queue=n.queue, mailboxes=n.mailboxes, abort=n.abort, clock=clock, fd=n.fd)
    bus.node("ack")  # an FD-enabled silent receiver: every frame is acknowledged
    log: dict[str, list] = {m.name: [] for m in net.messages}
    tau = 10**9 // net.bitrate
    t0_bus = 2 * MS
    if blocker is None:
        blocker = max(
            net.messages, key=lambda m: (m.frame.bits.duration_ns(net.bitrate, net.data_bitrate), m.can_id)
        ).name
    for m in net.messages:
        node = nodes[m.node]
        if pattern == "critical":
            first = node.to_local(t0_bus - tau if m.name == blocker else t0_bus)
            Release(m, node, log[m.name], [m.jitter_ns], 0).start(first - m.jitter_ns)
        else:
            nominal0 = node.now() + rng.randint(0, m.period_ns)
            r = random.Random(rng.random())
            if pattern == "random":
                extremes = None
            elif pattern == "alternate":
                extremes = [m.jitter_ns, 0]
            else:
                extremes = [m.jitter_ns if r.random() < 0.5 else 0 for _ in range(64)]
            Release(m, node, log[m.name], extremes, None, r).start(nominal0)
    bus.run(until=duration_ns)
    assert bus.error_frames == 0  # a tolerant node integrates: no error frame on a mixed bus
    end = bus.now()
    out: dict[str, Measured] = {}
    for m in net.messages:
        r = out[m.name] = Measured()
        for req, nominal_bus in log[m.name]:
            if req.state is RequestState.SENT:
                q, n = req.t_done - req.t_queued, req.t_done - nominal_bus
                r.sent += 1
            else:
                assert req.state is RequestState.QUEUED, (m.name, req.state)
                q, n = end - req.t_queued, end - nominal_bus
            r.queued = max(r.queued, q)
            r.nominal = max(r.nominal, n)
    return out


def check(net: Network, measured: dict[str, Measured]) -> list[tuple[str, str, float]]:
    """Assert measured <= bound for every bounded message; return (name, method, measured/bound)."""
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
        out.append((m.name, r.method, got.queued / r.bound_ns))
    return out


def _duration(net: Network) -> int:
    return min(200 * MS, 2 * MS + 10 * max(m.period_ns + m.jitter_ns for m in net.messages))


@pytest.mark.parametrize("mixed", [False, True], ids=["fd", "mixed"])
def test_simulation_never_exceeds_the_fd_bounds_on_random_networks(mixed):
    rng = random.Random(21 + mixed)
    rows: list[tuple[str, str, float]] = []
    fd_brs = fd_plain = 0
    for i in range(20):
        net = random_network(rng, mixed=mixed)
        fd_brs += sum(m.brs for m in net.messages)
        fd_plain += sum(m.fd and not m.brs for m in net.messages)
        rows += check(net, simulate(net, PATTERNS[i % len(PATTERNS)], 1_000 * mixed + i, _duration(net)))
    methods = {method for _, method, _ in rows}
    assert {"davis2007", "fifo", "mailbox"} <= methods, methods  # every kind of bound exercised
    assert len(rows) >= 60 and fd_brs >= 10 and fd_plain >= 5


@pytest.mark.parametrize("seed", range(6))
def test_a_synchronous_release_comes_close_to_the_bound_of_the_highest_priority_message(seed):
    """Jitter 0, offsets 0, priority queues, exact lengths: every message released at once, the
    longest lower-priority frame one bit earlier. The highest-priority message waits for that
    frame and then goes: its bound (B + C) is reached but for one nominal bit and its own
    intermission, both in the bound (TIGHT); every other bound holds."""
    rng = random.Random(100 + seed)
    net = random_network(rng, max_util=0.6, mixed=bool(seed % 2), drift=False)
    for n in net.nodes:
        n.queue, n.mailboxes, n.abort = "priority", None, False
    for m in net.messages:
        m.jitter_ns = 0
    net.exact = True
    top = min(net.messages, key=lambda m: m.frame.key)
    lower = [m for m in net.messages if m is not top]
    blocker = max(lower, key=lambda m: m.frame.bits.duration_ns(net.bitrate, net.data_bitrate)) if lower else None
    got = simulate(net, "critical", seed, _duration(net), blocker=None if blocker is None else blocker.name)
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
@pytest.mark.parametrize("mixed", [False, True], ids=["fd", "mixed"])
def test_fd_campaign(mixed):
    """The longer campaign (-m campaign): 300 networks each; the tightness is printed (-s)."""
    rng = random.Random(2100 + mixed)
    rows: list[tuple[str, str, float]] = []
    for i in range(300):
        net = random_network(rng, mixed=mixed)
        rows += check(net, simulate(net, PATTERNS[i % len(PATTERNS)], 50_000 + i, _duration(net)))
    for method in sorted({m for _, m, _ in rows}):
        ratios = [r for _, m, r in rows if m == method]
        print(
            f"{method}: {len(ratios)} messages, measured/bound max {max(ratios):.3f} mean {sum(ratios) / len(ratios):.3f}"
        )
