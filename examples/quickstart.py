"""A first scenario on the simulated bus: three ECUs, one of them with a faulty receiver.

Run:  python examples/quickstart.py [TRACE_FILE]
It prints the frames of the first 5 ms, the per-identifier latency and arbitration losses, and
what fault confinement made of the noisy node; then writes the trace to TRACE_FILE (any suffix
python-can writes: .asc, .blf, .log, ...), by default quickstart.asc in a new temporary directory,
so that running it leaves nothing behind in the current one.
"""

import sys
import tempfile
from pathlib import Path

from stack.bus.faults import FaultInjector
from stack.bus.sim import SimBus
from stack.controller.events import ErrorStateChanged
from stack.io.tracefile import save_trace
from stack.wire.frame import Frame

MS = 1_000_000

bus = SimBus(500_000, seed=42)
engine = bus.node("engine")
brake = bus.node("brake", queue="mailbox", mailboxes=2)
dash = bus.node("dash", filters=[{"can_id": 0x0C0, "can_mask": 0x7F0}], rx_fifo_size=16)

engine.send_periodic(Frame(0x0C1, bytes.fromhex("4001087500000000")), 10 * MS)
brake.send_periodic(Frame(0x0A0, bytes.fromhex("12345678")), 5 * MS, offset=MS // 2)
dash.listen(ErrorStateChanged, lambda ev: print(f"{ev.time / 1e6:8.3f} ms {ev.node}: {ev.old} -> {ev.new}"))

faults = FaultInjector(bus)
faults.bit_errors(2e-3, nodes=["dash"])  # dash's receiver picks up noise: local errors

bus.run(until=5 * MS)
for rec in bus.trace:
    print(f"{rec.start / 1e3:8.1f} us {rec.kind:<6} {rec.sender:<7} {rec.frame!r} {rec.detail or ''}")

bus.run(until=500 * MS)
summary = bus.summary()
print(f"\nbus load {summary['bus_load']:.1%}, {summary['frames']} frames, {summary['error_frames']} error frames")
for ident, st in summary["ids"].items():
    print(f"{ident}: {st['count']} frames, latency {st['latency_min_us']:.0f}..{st['latency_max_us']:.0f} us")
print("dash:", dash.counters(), dash.state)
print("frames waiting in dash's FIFO:", len(list(iter(dash.recv, None))))
trace = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="canstack-")) / "quickstart.asc"
n = save_trace(bus, trace)
print(f"trace: {n} records written to {trace}")
