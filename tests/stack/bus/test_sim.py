"""The simulated bus: arbitration, exact timing, ACK, collisions, determinism, statistics, traces."""

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stack.bus.sim import SimBus
from stack.cli.demo import build_demo
from stack.io.tracefile import load_messages, save_trace
from stack.wire.coding import Field
from stack.wire.frame import Frame


def bitwise_winner(frames):
    """Independent arbitration: wired-AND over the bits; a node sending recessive (1) that reads
    dominant (0) drops out. Runs over the arbitration field of the encoded bit strings."""
    alive = list(range(len(frames)))
    bits = [f.bits.bits for f in frames]
    for i in range(40):  # arbitration ends within SOF + 32 stuffed bits + stuff bits
        wire = min(bits[j][i] for j in alive)
        alive = [j for j in alive if bits[j][i] == wire]
        if len(alive) == 1:
            break
    return alive


def frame_strategy():
    return st.one_of(
        st.builds(
            lambda i, r: Frame(i, remote=True, dlc=1) if r else Frame(i, b"\x01"), st.integers(0, 0x7FF), st.booleans()
        ),
        st.builds(
            lambda i, r: Frame(i, extended=True, remote=True, dlc=1) if r else Frame(i, b"\x01", extended=True),
            st.integers(0, 0x1FFFFFFF),
            st.booleans(),
        ),
    )


@settings(max_examples=60, deadline=None)
@given(st.lists(frame_strategy(), min_size=2, max_size=8, unique_by=lambda f: f.key))
def test_arbitration_winner_is_minimum_key_and_matches_bitwise_wired_and(frames):
    bus = SimBus(500_000)
    rx = bus.node("rx")
    for i, f in enumerate(frames):
        bus.node(f"n{i}").send(f)
    bus.run(frames=1)
    won = bus.trace[0].frame
    assert won.key == min(f.key for f in frames)
    assert [frames[j] for j in bitwise_winner(frames)] == [won]


def test_documented_priority_rules():
    bus = SimBus(500_000)
    bus.node("rx")
    ext = Frame(0x100 << 18, b"\x01", extended=True)
    rem = Frame(0x100, remote=True, dlc=1)
    dat = Frame(0x100, b"\x01")
    for i, f in enumerate([ext, rem, dat]):
        bus.node(f"n{i}").send(f)
    bus.run()
    assert [r.frame for r in bus.trace] == [dat, rem, ext]
    assert [r.losses for r in bus.trace] == [0, 1, 2]


def test_frame_occupies_exact_stuffed_length_then_intermission():
    bus = SimBus(250_000)
    a, b = bus.node("a"), bus.node("b")
    f1, f2 = Frame(0x0C1, bytes.fromhex("4001087500000000")), Frame(0x222, bytes.fromhex("0011223344"))
    a.send(f1)
    a.send(f2)
    bus.run()
    r1, r2 = bus.trace
    assert r1.end - r1.start == 118 * 4000  # 118 bits at 4 us
    assert r1.bits == f1.bits.length == 118
    assert r2.start == r1.end + 3 * 4000  # next SOF after 3 bits intermission
    assert r2.end - r2.start == f2.bits.length * 4000


def test_lone_transmitter_gets_no_ack_and_keeps_retransmitting():
    bus = SimBus(500_000)
    a = bus.node("a")
    req = a.send(Frame(0x10, b"\x01"))
    bus.run(duration=2_000_000)
    errs = [r for r in bus.trace if r.kind == "error"]
    assert len(errs) >= 10 and all(r.detail["error"] == "ack" and r.detail["field"] == "ACK_SLOT" for r in errs)
    assert req.state == "queued" and req.retries == len(errs) == a.retransmissions
    # ACK error at the ACK slot, flag from the ACK delimiter: 6 flag + 8 delimiter bits
    assert errs[0].end - errs[0].start == (Frame(0x10, b"\x01").bits.position(Field.ACK_SLOT) + 1 + 6 + 8) * 2000
    # once a second node is on the bus, the frame goes through
    bus.node("b")
    bus.run(duration=1_000_000)
    assert req.state == "sent" and bus.trace[-1].kind == "frame"


def test_listen_only_node_does_not_acknowledge():
    bus = SimBus(500_000)
    a = bus.node("a")
    bus.node("spy", listen_only=True)
    a.send(Frame(0x10))
    bus.run(duration=500_000)
    assert bus.frames_ok == 0 and bus.error_frames > 0


def test_remote_frames_same_id_different_dlc_collide_and_are_reported():
    bus = SimBus(500_000)
    a, b = bus.node("a"), bus.node("b")
    bus.node("c")
    a.send(Frame(0x55, remote=True, dlc=1))
    b.send(Frame(0x55, remote=True, dlc=2))
    bus.run(duration=200_000)
    assert bus.collisions >= 1
    rec = bus.trace[0]
    assert rec.kind == "collision" and rec.detail["field"] == "DLC"
    # DLC 0001 vs 0010: b sends recessive first (bit 2 of DLC) and sees the bit error
    assert rec.detail["seen_by"] == "b" and rec.detail["bit"] == Frame(0x55, remote=True, dlc=1).bits.position(
        Field.DLC, 2
    )
    # both count +8 per collision (rule 3); at 128 b is error passive, its passive flag no
    # longer destroys a's frame: that attempt is a's frame alone, recorded with a as sender
    bus.run(duration=5_000_000)
    first = next(r for r in bus.trace if r.kind == "frame")
    assert first.sender == "a" and first.frame == Frame(0x55, remote=True, dlc=1)
    assert first.detail["states"] == "b:error-warning->error-passive"


def test_identical_frames_from_two_nodes_both_succeed():
    bus = SimBus(500_000)
    a, b, c = bus.node("a"), bus.node("b"), bus.node("c")
    ra, rb = a.send(Frame(0x55, b"\x01")), b.send(Frame(0x55, b"\x01"))
    bus.run()
    assert ra.state == rb.state == "sent" and bus.frames_ok == 1 and c.rx_frames == 1


def test_run_bounded_by_time_and_by_frames():
    bus = SimBus(500_000)
    build_demo(bus)
    bus.run(frames=25)
    assert bus.frames_ok == 25
    bus.run(until=100_000_000)
    assert bus.now() == 100_000_000
    assert all(r.end <= 100_000_000 for r in bus.trace)


def _demo_trace(seed):
    bus = SimBus(500_000, seed=seed)
    build_demo(bus)
    bus.run(until=300_000_000)
    return [r.as_tuple() for r in bus.trace]


def test_deterministic_same_scenario_same_trace():
    assert _demo_trace(7) == _demo_trace(7)


def test_statistics_agree_with_the_trace():
    bus = SimBus(500_000)
    build_demo(bus)
    bus.run(until=200_000_000)
    busy = sum(r.end - r.start + 3 * 2000 for r in bus.trace)
    assert bus.bus_load() == pytest.approx(busy / 200_000_000, rel=1e-3)
    by_id = {}
    for r in bus.trace:
        by_id.setdefault(r.frame.key, []).append(r.end - r.queued)
    for key, st_ in bus.id_stats.items():
        lat = by_id[key]
        assert (st_.count, st_.min, st_.max) == (len(lat), min(lat), max(lat))
        assert st_.mean == pytest.approx(sum(lat) / len(lat))


@pytest.mark.parametrize("suffix", [".asc", ".blf", ".log", ".csv"])
def test_trace_export_read_back_with_python_can(tmp_path, suffix):
    bus = SimBus(500_000)
    build_demo(bus)
    bus.run(until=50_000_000)
    path = tmp_path / f"t{suffix}"
    n = save_trace(bus, path)
    msgs = [m for m in load_messages(path) if not m.is_error_frame]
    assert n == len(bus.trace) == len(msgs)
    for rec, m in zip(bus.trace, msgs):
        assert m.arbitration_id == rec.frame.can_id and m.is_extended_id == rec.frame.extended
        assert m.is_remote_frame == rec.frame.remote
        if not rec.frame.remote:
            assert bytes(m.data) == rec.frame.data
        # formats differ in their time origin (ASC is relative to the first record): compare offsets
        assert m.timestamp - msgs[0].timestamp == pytest.approx((rec.end - bus.trace[0].end) / 1e9, abs=1e-5)


def test_error_attempts_exported_as_error_frames(tmp_path):
    bus = SimBus(500_000)
    bus.node("a").send(Frame(1))
    bus.run(duration=300_000)
    path = tmp_path / "e.asc"
    save_trace(bus, path)
    msgs = load_messages(path)
    assert msgs and all(m.is_error_frame for m in msgs)


def test_bad_bitrate_and_duplicate_node_names():
    with pytest.raises(ValueError, match="bitrate 2000000"):
        SimBus(2_000_000)
    bus = SimBus()
    bus.node("a")
    with pytest.raises(ValueError, match="already on bus"):
        bus.node("a")
    with pytest.raises(KeyError, match="no node named 'zz'"):
        bus["zz"]


def test_unbounded_run_with_lone_transmitter_refuses():
    bus = SimBus()
    bus.node("a").send(Frame(1))
    with pytest.raises(ValueError, match="never end"):
        bus.run()


@pytest.mark.parametrize("scenario", ["demo", "saturated"])
def test_fast_loop_gives_the_same_trace_as_the_general_path(monkeypatch, scenario):
    from stack.controller.events import TxDone

    def run(fast):
        monkeypatch.setattr(SimBus, "fast", fast)
        bus = SimBus(500_000)
        if scenario == "demo":
            build_demo(bus)
            bus.run(until=300_000_000)
        else:
            for i in range(5):
                n = bus.node(f"n{i}", rx_fifo_size=8)
                n.listen(TxDone, lambda ev, n=n: n.send(ev.frame))
                n.send(Frame(0x100 + i, bytes([i]) * 8))
            bus.run(frames=3000)
        return [r.as_tuple() for r in bus.trace], {n.name: n.counters() for n in bus.nodes}, bus.now()

    assert run(True) == run(False)


@pytest.mark.parametrize("fast", [True, False])
def test_a_callback_that_queues_a_higher_priority_frame_for_the_sender(fast, monkeypatch):
    # b's receive callback queues 0x100 at a while a still has a second 0x200 waiting: the
    # priority queue sends 0x100 next, on the fast path as on the general one
    monkeypatch.setattr(SimBus, "fast", fast)
    bus = SimBus(500_000)
    a, b = bus.node("a"), bus.node("b")
    fired = []

    def cb(ev):
        if not fired:
            fired.append(1)
            a.send(Frame(0x100))

    b.subscribe(cb)
    a.send(Frame(0x200, b"\x01"))
    a.send(Frame(0x200, b"\x02"))
    bus.run()
    assert [(r.frame.can_id, r.frame.data) for r in bus.trace] == [(0x200, b"\x01"), (0x100, b""), (0x200, b"\x02")]


def _random_network(seed: int) -> tuple:
    """A seeded random scenario: queue policies, filters, self-reception, remote replies,
    callbacks that send (on reception and on TxDone), periodic tasks, an abort and reads from
    the FIFOs in the middle of the run. Returns everything observable."""
    import random

    from stack.controller.events import ArbitrationLost, TxDone

    rng = random.Random(seed)
    bus = SimBus(rng.choice([125_000, 500_000, 1_000_000]), seed=seed, record=rng.random() < 0.8)
    ids = [rng.choice([0x100, 0x101, 0x180, 0x200, 0x201, 0x300, 0x7FF]) for _ in range(6)]

    def frame(r):
        if r.random() < 0.15:
            return Frame(r.choice(ids), remote=True, dlc=r.randint(0, 8))
        return Frame(r.choice(ids), bytes(r.randrange(256) for _ in range(r.randint(0, 8))))

    nodes, log = [], []
    for i in range(rng.randint(2, 5)):
        policy = rng.choice(["priority", "priority", "fifo", "mailbox"])
        kw = {"queue": policy, "rx_fifo_size": rng.choice([1, 4, 64]), "receive_own_messages": rng.random() < 0.3}
        if policy == "mailbox":
            kw.update(mailboxes=rng.randint(1, 3), abort=rng.random() < 0.5)
        if rng.random() < 0.3:
            kw["filters"] = [{"can_id": rng.choice([0x100, 0x200]), "can_mask": 0x700}]
        nodes.append(bus.node(f"n{i}", **kw))
    for n in nodes:
        if rng.random() < 0.3:
            n.set_remote_reply(Frame(rng.choice(ids), b"\xaa"))
        own = random.Random(seed * 31 + len(log))
        budget = [rng.randint(5, 60)]

        def send_some(target, own=own, budget=budget):
            if budget[0] > 0:
                budget[0] -= 1
                try:
                    target.send(frame(own))
                except Exception as exc:  # queue full, bus off: part of what is compared
                    log.append(("refused", type(exc).__name__))

        kind, target = rng.random(), rng.choice(nodes)
        if kind < 0.3:
            n.subscribe(lambda ev, t=target, s=send_some: (log.append(("rx", ev.time, ev.frame.key)), s(t)))
        elif kind < 0.5:
            n.listen(TxDone, lambda ev, t=target, s=send_some: s(t))
        elif kind < 0.6:
            n.listen(ArbitrationLost, lambda ev: log.append(("lost", ev.time, ev.frame.key)))
        if rng.random() < 0.3:
            n.send_periodic(
                frame(rng),
                rng.choice([200_000, 333_333, 1_000_000]),
                offset=rng.randint(0, 100_000),
                count=rng.randint(1, 20),
            )
        for _ in range(rng.randint(0, 15)):
            try:
                n.send(frame(rng))
            except Exception as exc:
                log.append(("refused", type(exc).__name__))
    victim = rng.choice(nodes)
    bus.call_at(
        rng.randint(0, 2_000_000),
        lambda: log.append(
            ("abort", bool(victim.pending()) and victim.abort(max(victim.pending(), key=lambda r: r.seq)))
        ),
    )
    for _ in range(3):
        bus.call_at(rng.randint(0, 5_000_000), lambda: log.extend(("recv", n.name, n.recv()) for n in nodes))
    bus.run(until=rng.choice([2_000_000, 10_000_000, 40_000_000]))
    return (
        [r.as_tuple() for r in bus.trace],
        {n.name: n.counters() for n in nodes},
        {n.name: [(t, f, s.name) for t, f, s in n.rx_fifo] for n in nodes},
        {n.name: sorted((r.frame.key, r.seq) for r in n.pending()) for n in nodes},
        bus.now(),
        bus.frames_ok,
        bus.rounds,
        bus.busy_ns,
        log,
        {k: (v.count, v.total, v.losses, v.min, v.max) for k, v in bus.id_stats.items()},
    )


@pytest.mark.parametrize("seed", range(300))
def test_fast_loop_matches_the_general_path_on_random_networks(monkeypatch, seed):
    monkeypatch.setattr(SimBus, "fast", True)
    fast = _random_network(seed)
    monkeypatch.setattr(SimBus, "fast", False)
    assert fast == _random_network(seed)


def test_removed_node_leaves_the_bus_and_frees_its_name():
    from stack.controller.events import TxFailed

    bus = SimBus(500_000)
    a = bus.node("a")
    b = bus.node("b")
    failed = []
    b.listen(TxFailed, failed.append)
    b.send(Frame(0x200, b"\x01"))
    b.send(Frame(0x201, b"\x02"))
    bus.remove(b)
    assert [n.name for n in bus.nodes] == ["a"] and b.bus is None
    assert [ev.reason for ev in failed] == ["aborted", "aborted"]
    bus.node("b")  # the name is free again
    a.send(Frame(0x100))
    bus.run(duration=1_000_000)
    assert bus.frames_ok == 1 and bus["b"].rx_frames == 1


def test_node_removed_while_its_frame_is_on_the_wire_finishes_that_frame_first():
    bus = SimBus(500_000)
    a = bus.node("a")
    b = bus.node("b")
    a.send(Frame(0x100, bytes(8)))
    bus.run(until=bus.bits_to_ns(20))  # inside the frame
    bus.remove(a)
    assert a in bus.nodes  # still transmitting
    bus.run(duration=1_000_000)
    assert a not in bus.nodes and a.tx_frames == 1 and b.rx_frames == 1


def test_many_nodes_joining_and_leaving_leave_no_trace():
    bus = SimBus(500_000)
    keep = bus.node("keep", rx_fifo_size=1000)
    for i in range(500):
        n = bus.node(f"client{i % 3}")
        n.send(Frame(0x300 + i % 3))
        bus.run(duration=200_000)
        bus.remove(n)
    assert bus.nodes == [keep] and keep.rx_frames == 500


@pytest.mark.parametrize("fast", [True, False])
@pytest.mark.parametrize("slack", [-0.5, 0, 0.5, 1])
def test_a_frame_completes_in_a_run_only_when_it_ends_by_the_time_bound(fast, slack, monkeypatch):
    # run(until=T) carries a frame that ends at or before T (T may be fractional ns), on the
    # fast loop as on the general path: the second of two frames back to back ends after both
    # frames and the 3-bit intermission between them (1 us a bit at 1 Mbit/s)
    monkeypatch.setattr(SimBus, "fast", fast)
    bus = SimBus(1_000_000, record=False)
    a, b = bus.node("a"), bus.node("b")
    frame = Frame(0x7FF, bytes(8))
    a.send(frame)
    a.send(frame)
    end = (2 * frame.wire_bits + 3) * 1000
    bus.run(until=end + slack)
    assert a.tx_frames == (2 if slack >= 0 else 1)
    assert b.recv() is not None


def _random_fd_network(seed: int) -> tuple:
    """A seeded random CAN FD network: nodes FD enabled, tolerant or classic (CAN 2.0), some of
    them near the error-passive limit or listen-only; classical and FD frames (any length, with or
    without BRS, ESI asked or not) from callbacks and periodic tasks; sometimes random bit errors.
    Returns everything observable, as `_random_network` does."""
    import random

    from stack.bus.faults import FaultInjector
    from stack.controller.events import TxDone
    from stack.wire.frame import FD_LENGTHS

    rng = random.Random(seed)
    rate = rng.choice([125_000, 500_000, 1_000_000])
    bus = SimBus(
        rate, data_bitrate=rng.choice([rate, 2 * rate, 2_000_000, 5_000_000]), seed=seed, record=rng.random() < 0.8
    )
    ids = [rng.choice([0x000, 0x100, 0x101, 0x1FF, 0x200, 0x7FF]) for _ in range(6)]

    def frame(r, kind):
        ext = r.random() < 0.2
        cid = r.choice(ids) | ((r.randrange(1 << 18)) << 11 if ext else 0)
        cid = (cid & 0x7FF) << 18 | (cid >> 11) if ext else cid
        if kind == "fd" and r.random() < 0.6:
            n = r.choice(FD_LENGTHS)
            fill = r.choice([0x00, 0xFF, None])
            data = bytes(r.randrange(256) if fill is None else fill for _ in range(n))
            return Frame(cid, data, extended=ext, fd=True, brs=r.random() < 0.7, esi=r.random() < 0.1)
        if r.random() < 0.1:
            return Frame(cid, remote=True, dlc=r.randint(0, 8), extended=ext)
        return Frame(cid, bytes(r.randrange(256) for _ in range(r.randint(0, 8))), extended=ext)

    nodes, log = [], []
    kinds = ["fd"] + [rng.choice(["fd", "fd", "tolerant", "classic"]) for _ in range(rng.randint(1, 5))]
    for i, kind in enumerate(kinds):
        n = bus.node(f"n{i}", fd=kind, rx_fifo_size=rng.choice([4, 64]), listen_only=i > 1 and rng.random() < 0.1)
        if rng.random() < 0.3:
            n.set_counters(rng.choice([0, 120, 127, 130, 250]), rng.choice([0, 95, 127, 130]), 0)
        nodes.append(n)
    talkers = [n for n in nodes if not n.listen_only]
    for n in talkers:
        own = random.Random(seed * 31 + len(log))
        budget = [rng.randint(3, 30)]

        def send_some(target, own=own, budget=budget):
            if budget[0] > 0:
                budget[0] -= 1
                try:
                    target.send(frame(own, target.fd))
                except Exception as exc:  # bus off: part of what is compared
                    log.append(("refused", type(exc).__name__))

        target = rng.choice(talkers)
        if rng.random() < 0.4:
            n.subscribe(
                lambda ev, t=target, s=send_some: (log.append(("rx", ev.time, ev.frame.key, ev.frame.esi)), s(t))
            )
        elif rng.random() < 0.5:
            n.listen(TxDone, lambda ev, t=target, s=send_some: s(t))
        if rng.random() < 0.4:
            n.send_periodic(
                frame(rng, n.fd),
                rng.choice([300_000, 1_000_000]),
                offset=rng.randint(0, 100_000),
                count=rng.randint(1, 8),
            )
        for _ in range(rng.randint(0, 6)):
            try:
                n.send(frame(rng, n.fd))
            except Exception as exc:
                log.append(("refused", type(exc).__name__))
    if rng.random() < 0.15:
        FaultInjector(bus).bit_errors(rng.choice([1e-4, 1e-3]))
    bus.call_at(rng.randint(0, 3_000_000), lambda: log.extend(("recv", n.name, n.recv()) for n in nodes))
    bus.run(until=rng.choice([2_000_000, 6_000_000]))
    return (
        [r.as_tuple() + (r.frame.fd, r.frame.brs, r.frame.esi) for r in bus.trace],
        {n.name: (n.counters(), n.state) for n in nodes},
        {n.name: [(t, f, f.esi, s.name) for t, f, s in n.rx_fifo] for n in nodes},
        {n.name: sorted((r.frame.key, r.seq) for r in n.pending()) for n in nodes},
        bus.now(),
        bus.frames_ok,
        bus.error_frames,
        bus.rounds,
        bus.busy_ns,
        log,
    )


@pytest.mark.parametrize("seed", range(120))
def test_fast_loop_matches_the_general_path_on_random_fd_networks(monkeypatch, seed):
    monkeypatch.setattr(SimBus, "fast", True)
    fast = _random_fd_network(seed)
    monkeypatch.setattr(SimBus, "fast", False)
    assert fast == _random_fd_network(seed)


@pytest.mark.parametrize("seed", range(120))
def test_fd_attempts_with_can_2_nodes_match_the_bit_level_replay_on_random_networks(monkeypatch, seed):
    # `stack.bus.fdnodes` computes an FD frame's attempt on a bus with CAN 2.0 nodes at once: the
    # same trace, counters and receptions as replaying it bit by bit for every node
    monkeypatch.setattr(SimBus, "fast_fd_attempts", True)
    computed = _random_fd_network(seed)
    monkeypatch.setattr(SimBus, "fast_fd_attempts", False)
    assert computed == _random_fd_network(seed)


def test_the_bus_tells_a_fault_injector_when_it_is_busy_idle_or_about_to_arbitrate():
    bus = SimBus(250_000)
    a, b = bus.node("a"), bus.node("b")
    a.send(Frame(0x0C1, bytes.fromhex("4001087500000000")))  # 118 bits on the wire
    assert not bus.transmitting and bus.arbitration_due(0)  # offered at 0: arbitration starts then
    bus.run(until=100 * 4000)
    assert bus.transmitting and not bus.arbitration_due(bus.now())
    assert bus.idle_at == (118 + 3) * 4000  # the end of the frame's intermission (3 bits)
    bus.run()
    assert not bus.transmitting and bus.idle_at == (118 + 3) * 4000 and not bus.arbitration_due(bus.now())
