"""The FD-intolerant node: one CAN 2.0 controller on a CAN FD network.

Run:  python examples/fd_intolerant.py
A 500 kbit/s bus with a 2 Mbit/s data phase: a gateway and a camera send CAN FD frames (with bit
rate switch), a body controller classical ones, a dashboard listens. The same network runs twice,
its legacy node first a CAN 2.0 controller ("classic": it destroys every FD frame with an error
frame until it is error passive), then a classical controller with ISO 11898-1:2015's protocol
exception ("tolerant": it ignores FD frames and sees the classical ones).
"""

from stack.bus.sim import SimBus
from stack.controller.events import ErrorStateChanged
from stack.wire.frame import Frame

MS = 1_000_000


def run(kind: str) -> None:
    bus = SimBus(500_000, data_bitrate=2_000_000, seed=1)
    gateway, camera, dash = bus.node("gateway"), bus.node("camera"), bus.node("dash")
    body = bus.node("body")  # FD enabled, sending classical frames
    legacy = bus.node("legacy", fd=kind)
    gateway.send_periodic(Frame(0x120, bytes(range(32)), fd=True, brs=True), 10 * MS)
    camera.send_periodic(Frame(0x200, bytes(64), fd=True, brs=True), 20 * MS, offset=2 * MS)
    body.send_periodic(Frame(0x300, bytes(8)), 10 * MS, offset=5 * MS)
    changes: list[ErrorStateChanged] = []
    legacy.listen(ErrorStateChanged, changes.append)
    bus.run(until=200 * MS)

    print(f"legacy is {kind!r}:")
    for rec in bus.trace[:3]:
        d = rec.detail or {}
        what = f"{d['error']} error in {d['field']} seen by {d['seen_by']}" if "error" in d else ""
        f = rec.frame
        frame = f"0x{f.can_id:03X} {'FD ' if f.fd else ''}{len(f.data)} bytes"
        print(f"  {rec.start / 1e3:7.1f} us  {rec.kind:<5} {rec.sender:<7} {frame:<16} {what}".rstrip())
    fd = sum(r.kind == "frame" and r.frame.fd for r in bus.trace)
    classical = sum(r.kind == "frame" and not r.frame.fd for r in bus.trace)
    print(f"  in 200 ms: {fd} FD frames and {classical} classical frames through, {bus.error_frames} error frames")
    print(f"  dash received {dash.rx_frames} frames, legacy {legacy.rx_frames} (classical only)")
    print(f"  gateway TEC {gateway.tec}, camera TEC {camera.tec}; legacy REC {legacy.rec}, {legacy.state}")
    for ev in changes[:3]:
        print(f"  {ev.time / 1e3:7.1f} us  legacy {ev.old} -> {ev.new} (REC {ev.rec})")
    if len(changes) > 3:
        print(f"  ... {len(changes)} state changes of legacy in all")


run("classic")
run("tolerant")
