"""The fast path of a frame nobody acknowledges (`SimBus.reuse_unacked`): the replay of an
attempt that ends in an ACK error is reused while the frame and every node's state and counters
are the same, so a lone transmitter retransmitting for ever costs little. It must change
nothing: the same trace, counters and states as replaying every attempt bit by bit, and the
numbers fault confinement gives (rule 3: TEC += 8 per ACK error while error active, exception 1
keeps it at 128 once error passive; rule 12 does not apply: never bus off)."""

import pytest

from stack.bus.sim import SimBus
from stack.wire.frame import Frame


def _run(reuse: bool, listeners: int, frames: list[Frame], until_ns: int) -> tuple:
    saved = SimBus.reuse_unacked
    SimBus.reuse_unacked = reuse
    try:
        bus = SimBus(1_000_000, record=True)
        tx = bus.node("tx")
        others = [bus.node(f"m{i}", listen_only=True) for i in range(listeners)]
        for f in frames:
            tx.send(f)
        bus.run(until=until_ns)
    finally:
        SimBus.reuse_unacked = saved
    nodes = [tx, *others]
    return (
        [r.as_tuple() for r in bus.trace],
        [(n.tec, n.rec, n.state, n.retransmissions, n.tx_frames) for n in nodes],
        bus.error_frames,
        bus.frames_ok,
        bus.busy_ns,
    )


@pytest.mark.parametrize("listeners", [0, 1, 2])
@pytest.mark.parametrize(
    "frames",
    [
        [Frame(0x123, bytes(8))],
        [Frame(0x7FF, b""), Frame(0x1ABCDEF0, b"\xff" * 5, extended=True)],
        [Frame(0x0C1, bytes.fromhex("4001087500000000")), Frame(0x100, remote=True, dlc=2)],
    ],
)
def test_reusing_unacknowledged_attempts_changes_nothing(listeners, frames):
    assert _run(True, listeners, frames, 30_000_000) == _run(False, listeners, frames, 30_000_000)


def test_a_lone_transmitter_follows_rule_3_and_its_exception_1():
    trace, counters, errors, ok, _ = _run(True, 0, [Frame(0x123, bytes(8))], 30_000_000)
    tec, rec, state, retransmissions, sent = counters[0]
    # 16 ACK errors as error active take TEC from 0 to 128 (rule 3: +8 each); from then on it is
    # error passive and an ACK error without a dominant bit in its passive flag leaves TEC as it is
    assert (tec, rec, state.value, sent, ok) == (128, 0, "error-passive", 0, 0)
    assert errors == len(trace) == retransmissions > 16
    assert all(kind == "error" and ("error", "ack") in detail for kind, *_, detail in trace)
