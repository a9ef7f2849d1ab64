"""Real DBC files (opendbc and cantools' test set): the ECU path encodes and decodes exactly as
cantools does; rejected files are reported; cyclic messages go out at their cycle time."""

from __future__ import annotations

import os
import random
from pathlib import Path

import pytest

from dbc.ecu import Ecu, initial_values, node_names
from dbc.errors import DbcLoadError, SignalRangeError, load_database
from dbc.interaction import attribute
from dbc.restbus import RestBus
from stack.bus.sim import SimBus

SHARED = Path(os.environ.get("CANSTACK_SHARED") or Path(__file__).resolve().parents[3] / "shared")
CORPUS = SHARED / "corpus" / "dbc"
FILES = sorted(CORPUS.glob("*/*.dbc")) if CORPUS.is_dir() else []
MS = 1_000_000

pytestmark = pytest.mark.skipif(not FILES, reason="../shared/corpus/dbc is absent")


class _Stub:
    """A node that never runs: the ECU is only asked to encode and decode."""

    def now(self) -> int:
        return 0

    def call_at(self, *a):  # pragma: no cover - start=False
        raise AssertionError

    def subscribe(self, cb, filters=None):
        return None


def _random_value(sig, rng: random.Random, ecu: Ecu, message: str):
    if sig.choices and rng.random() < 0.3:
        return str(rng.choice(list(sig.choices.values())))
    lim = ecu._limits(message, sig)
    lo, hi = lim.lo, lim.hi
    if sig.is_float:
        lo = max(lo, -1e6)
        hi = min(hi, 1e6)
        return rng.uniform(lo, hi) if lo < hi else lo
    conv = sig.conversion
    p = rng.uniform(lo, hi)
    raw = round((p - conv.offset) / conv.scale)
    for _ in range(4):
        v = conv.raw_to_scaled(raw, False)
        if lo <= v <= hi:
            return v
        raw += 1 if (v < lo) == (conv.scale > 0) else -1
    return conv.raw_to_scaled(round((lo - conv.offset) / conv.scale), False)


@pytest.fixture(scope="module")
def corpus(corpus_databases):
    """(loaded, rejected): each a list of (path, Database or DbcLoadError) in file order."""
    assert list(corpus_databases) == FILES
    ok = [(f, db) for f, db in corpus_databases.items() if not isinstance(db, DbcLoadError)]
    rejected = [(f, exc) for f, exc in corpus_databases.items() if isinstance(exc, DbcLoadError)]
    return ok, rejected


def test_rejected_files_are_reported_with_reason(corpus):
    ok, rejected = corpus
    assert len(ok) + len(rejected) == len(FILES)
    assert len(ok) > 100
    for f, exc in rejected:
        assert exc.path == str(f) and exc.reason
        print(f"rejected {f.parent.name}/{f.name}: {exc}")
    syntax = [exc for _, exc in rejected if "Invalid syntax" in exc.reason]
    assert syntax and all(exc.line is not None for exc in syntax)


def test_ecu_path_matches_cantools(corpus):
    ok, _ = corpus
    rng = random.Random(6)
    checked = skipped = 0
    for path, db in ok:
        senders = {n: Ecu(db, n, _Stub(), start=False, checks=[]) for n in node_names(db)}
        viewer = (
            Ecu(db, (senders and next(iter(senders))) or node_names(db)[0], _Stub(), start=False, checks=[])
            if senders
            else None
        )
        messages = db.messages if len(db.messages) <= 10 else rng.sample(db.messages, 10)
        for msg in messages:
            ecu = next((senders[s] for s in msg.senders if s in senders), None)
            any_ecu = ecu or viewer
            if any_ecu is None or msg.name in any_ecu.unsupported:
                skipped += 1
                continue
            # 1. initial values
            init = initial_values(db, msg)
            frame = any_ecu.encode_frame(msg.name, init)
            assert frame.data == msg.encode(init, strict=False), (path.name, msg.name)
            assert frame.can_id == msg.frame_id and frame.extended == msg.is_extended_frame
            name, decoded = any_ecu.decode_frame(frame)
            assert name == msg.name and decoded == msg.decode(frame.data), (path.name, msg.name)
            # 2. random in-range values, through the signal API when a node sends it
            for _ in range(3):
                values = dict(init)
                for sig in msg.signals:
                    if not sig.is_multiplexer:
                        values[sig.name] = _random_value(sig, rng, any_ecu, msg.name)
                expected = msg.encode(values, strict=False)
                if ecu is not None:
                    ecu.update(msg.name, values)  # strict range checks accept in-range values
                    frame = ecu.encode_frame(msg.name)
                else:
                    frame = any_ecu.encode_frame(msg.name, values)
                assert frame.data == expected, (path.name, msg.name, values)
                assert any_ecu.decode_frame(frame)[1] == msg.decode(expected), (path.name, msg.name)
            checked += 1
    assert checked > 400
    print(f"{checked} messages checked, {skipped} skipped (CAN FD / no node)")


def test_out_of_range_rejected_on_real_data(corpus):
    ok, _ = corpus
    db = {p.name: d for p, d in ok}["motohawk.dbc"]
    msg = db.get_message_by_name("ExampleMessage")
    ecu = Ecu(db, "PCM1", _Stub(), start=False, checks=[])
    # SG_ Temperature ... [229.52|270.47] "degK" in motohawk.dbc
    with pytest.raises(SignalRangeError, match=r"\[229.52 .. 270.47\] degK"):
        ecu.set("Temperature", 270.48, message=msg.name)
    ecu.set("Temperature", 270.47)


def _periods(bus, can_id):
    ends = [r.end for r in bus.trace if r.kind == "frame" and r.frame.can_id == can_id]
    return [b - a for a, b in zip(ends, ends[1:])]


def _ford():
    return load_database(CORPUS / "opendbc" / "FORD_CADS.dbc")


def test_ford_cads_each_cyclic_message_alone_has_zero_jitter():
    db = _ford()
    cyclic = {m.name: m for m in db.messages if m.cycle_time}
    assert len(cyclic) == 4
    for name, m in cyclic.items():
        bus = SimBus(500_000)
        ecu = Ecu(db, "MRR", bus.node("MRR"), start=False, checks=[])
        bus.node("listener").subscribe(lambda ev: None)
        ecu.start([name])
        bus.run(until=m.cycle_time * MS * 8 + MS)
        periods = _periods(bus, m.frame_id)
        assert len(periods) == 8
        assert set(periods) == {m.cycle_time * MS}


def test_ford_cads_under_load_jitter_bounded_by_blocking():
    db = _ford()
    cyclic = [m for m in db.messages if m.cycle_time]
    bus = SimBus(500_000)
    ecu = Ecu(db, "MRR", bus.node("MRR"), start=False, checks=[])
    bus.node("listener").subscribe(lambda ev: None)
    ecu.start([m.name for m in cyclic])
    bus.run(until=3100 * MS)
    wire = {m.frame_id: bus.bits_to_ns(ecu.encode_frame(m.name).wire_bits + 3) for m in cyclic}
    worst = False
    for m in cyclic:
        # the ECU queues exactly on schedule (release jitter 0) ...
        q = [r.queued for r in bus.trace if r.frame.can_id == m.frame_id]
        assert q == [k * m.cycle_time * MS for k in range(len(q))]
        # ... and a frame is delayed at most by one frame of every other message (periods >> C)
        bound = sum(c for i, c in wire.items() if i != m.frame_id)
        jitter = max(abs(p - m.cycle_time * MS) for p in _periods(bus, m.frame_id))
        assert jitter <= bound
        worst = worst or jitter > 0
    assert worst  # the 30 ms message meets the 1 s ones now and then: blocking is real


def test_timing_dbc_cyclic_foo_only():
    db = load_database(CORPUS / "cantools" / "timing.dbc")
    bus = SimBus(500_000)
    ecu = Ecu(db, "Sender", bus.node("Sender"), checks=[])
    bus.node("Receiver").subscribe(lambda ev: None)
    bus.run(until=1001 * MS)
    foo, bar = db.get_message_by_name("Foo"), db.get_message_by_name("Bar")
    assert ecu.timing("Foo").cycle_time == foo.cycle_time == 200
    assert set(_periods(bus, foo.frame_id)) == {200 * MS}
    assert len(_periods(bus, foo.frame_id)) == 5
    assert _periods(bus, bar.frame_id) == [] and ecu.timing("Bar").on_request_only


def test_restbus_runs_every_loadable_file(corpus):
    """A rest bus of every node of every file cantools loads (some list a node twice in BU_),
    run for 100 ms: every node simulated once, every frame decoded as cantools decodes it and
    credited to a node the DBC names as its sender, periodic messages on the bus."""
    ok, _ = corpus
    ran = checked = 0
    for path, db in ok:
        nodes = [n.name for n in db.nodes] + [s for m in db.messages for s in m.senders]
        expected = set(nodes) - {"Vector__XXX"}
        # a database with CAN FD messages needs an FD bus (its ECUs are refused on a classical one)
        bus = SimBus(500_000, data_bitrate=2_000_000 if any(m.is_fd for m in db.messages) else None)
        rb = RestBus(db, bus)
        assert sorted(rb.ecus) == sorted(expected), path.name
        bus.run(until=100 * MS)
        by_name = {m.name: m for m in db.messages}
        for rec in rb.records:
            m = by_name[rec.name]
            assert rec.sender in m.senders, (path.name, rec.name, rec.sender)
            assert rec.frame.fd == m.is_fd, (path.name, rec.name)
            assert rec.signals == m.decode(rec.frame.data[: m.length]), (path.name, rec.name)
        # every periodic message (a cantools cycle time of at most 100 ms, a periodic send type or
        # none, no start delay; a CAN frame: classical up to 8 bytes, FD up to 64) of a simulated
        # node goes out in the first 100 ms
        periodic = {
            m.name
            for m in db.messages
            if set(m.senders) & expected
            and m.length <= (64 if m.is_fd else 8)
            and not m.is_container
            and m.cycle_time
            and m.cycle_time <= 100
            and m.send_type in (None, "Cyclic", "FixedPeriodic", "EventPeriodic", "CyclicAndSpontaneous")
            and not attribute(db, m, "GenMsgStartDelayTime")
        }
        assert periodic <= {r.name for r in rb.records}, (path.name, periodic - {r.name for r in rb.records})
        checked += len(periodic)
        ran += 1
    assert ran == len(ok) and checked > 30
