"""One clock for a frame's release and its end on a canstack bus, in process and over
`canstack serve`: a received frame's timestamp is never before the moment its sender handed it
over plus its time on the wire — also with the CPU loaded by busy-looping processes, where a
preempted bus thread used to stamp frames in the past (negative response times)."""

import contextlib
import subprocess
import sys
import time

import can
import pytest
from hypothesis import given
from hypothesis import strategies as st

from stack.io.clock import ClockOffset
from stack.io.serve import BusServer
from stack.wire.frame import Frame


@given(
    true_offset=st.integers(-(10**15), 10**15),
    exchanges=st.lists(
        st.tuples(st.integers(0, 10**12), st.integers(0, 10**8), st.integers(0, 10**8)), min_size=1, max_size=20
    ),
)
def test_the_offset_is_the_tightest_lower_bound_of_the_answers(true_offset, exchanges):
    """Each answer says: the bus read ``s`` between the question (``c0``) and the answer
    (``c1``); the true offset lies in [s - c1, s - c0]. The estimate is never above it (frames
    never map before they happened) and is as tight as the best answer's return trip."""
    est = ClockOffset(window_ns=10**13)
    t = 0
    for gap, forward, back in exchanges:
        c0 = t + gap
        s = c0 + forward + true_offset
        c1 = c0 + forward + back
        est.sample(c0, s, c1)
        t = c1
    assert est.offset <= true_offset
    assert est.offset == true_offset - min(back for _, _, back in exchanges)


def test_old_answers_leave_the_window():
    est = ClockOffset(window_ns=1_000)
    est.sample(0, 100, 10)  # bound 90
    est.sample(5_000, 5_050, 5_100)  # bound -50: the first is older than the window now
    assert est.offset == -50 and est.round_trip_ns == 100


@contextlib.contextmanager
def _cpu_load(n: int = 2):
    """``n`` busy-looping processes (the machine has two cores), ended on the way out."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
            p.wait()


def _check_causal(tx: can.BusABC, rx: can.BusABC, filler: can.BusABC, n: int = 500) -> list[int]:
    """Send ``n`` frames from ``tx`` one at a time while ``filler`` keeps the bus busy; each
    one's timestamp at ``rx``, read back on the monotonic clock through ``rx``'s own clock pair,
    minus the monotonic time just before it was handed to ``tx``: the frame's response as this
    process sees it (ns). A busy bus keeps the bus thread busy, so that frames are handed to it
    while it is in the middle of simulating (where a preempted thread queued them in the past)."""
    frame = Frame(0x123, bytes(8))
    wire_ns = frame.bits.length * 2_000  # SOF..EOF at 500 kbit/s
    rx.set_filters([{"can_id": 0x123, "can_mask": 0x7FF, "extended": False}])
    task = filler.send_periodic(can.Message(arbitration_id=0x7FF, data=bytes(8), is_extended_id=False), 0.001)
    port = rx._port
    mono0, wall0 = (port.clock.mono0, port.clock.wall0) if hasattr(port, "clock") else (port.runner.t0_ns, port.epoch0)
    out = []
    for i in range(n):
        before = time.monotonic_ns()
        tx.send(can.Message(arbitration_id=0x123, data=bytes(8), is_extended_id=False))
        msg = rx.recv(30.0)
        while msg is not None and msg.arbitration_id != 0x123:  # a filler before the filters applied
            msg = rx.recv(30.0)
        assert msg is not None, f"frame {i} not received"
        end = mono0 + round((msg.timestamp - wall0) * 1e9)
        out.append(end - before)
    task.stop()
    thread = getattr(task, "thread", None)  # python-can's own thread (served bus): ended before shutdown
    if thread is not None:
        thread.join(30.0)
    # a float epoch time holds ~0.2 us: the frame cannot end before its own wire time has passed
    assert min(out) >= wire_ns - 1_000, (min(out), wire_ns)
    return out


@pytest.mark.wallclock
@pytest.mark.subprocess
def test_in_process_frames_end_after_they_were_sent_under_cpu_load():
    ch = "clock-local"
    with (
        _cpu_load(),
        can.Bus(interface="canstack", channel=ch) as tx,
        can.Bus(interface="canstack", channel=ch) as rx,
        can.Bus(interface="canstack", channel=ch, flush_timeout=0) as filler,
    ):
        _check_causal(tx, rx, filler)


@pytest.mark.wallclock
@pytest.mark.subprocess
@pytest.mark.socket
def test_served_frames_end_after_they_were_sent_under_cpu_load():
    with (
        BusServer(500_000, listen=("127.0.0.1", 0)) as srv,
        _cpu_load(),
        can.Bus(interface="canstack", channel=srv.url) as tx,
        can.Bus(interface="canstack", channel=srv.url) as rx,
        can.Bus(interface="canstack", channel=srv.url, flush_timeout=0) as filler,
    ):
        _check_causal(tx, rx, filler)
        assert rx._port.clock.offset.samples >= 3  # every join asks: one clock per server
