"""`python -m stack.bench`: speed figures, each as a ratio against a reference measured in the
same run (so the figures compare across machines).

- ``vs_python_can_virtual``: frames delivered per second from one sender to one receiver on a
  canstack `SimBus` (bursts of 64 queued, carried, read from the receive FIFO), divided by the
  same on python-can's ``virtual`` interface (send + recv in one process, the better of one at a
  time and bursts of 64). canstack does arbitration and exact timing; the virtual bus neither.
- ``realtime_factor_10_nodes``: 10 nodes at 1 Mbit/s sending 8-byte frames back to back (100 %
  bus load), every node receiving everything through its filters into its FIFO, counters on,
  trace recording off: simulated time divided by wall time (the wire is the reference).
- ``scale_1000_vs_10_nodes``: frames per second with 1000 such nodes (each filtering the 16
  identifiers of its group) divided by the 10-node figure.
- ``campaign_realtime_factor_500k``: the reliability campaign (5 nodes, random traffic,
  bit-error rate 1e-4 global and local) at 500 kbit/s, against the same traffic fault-free
  (``campaign_vs_fault_free``).
- ``decode_vs_sigrok`` (when the corpus and sigrok-cli are present): see `stack.cli.bench_io.decode_benchmark`.
- ``pycan``: the python-can integration (`stack.cli.bench_io.benchmark`): 10 ms periodic jitter against
  python-can's virtual bus, plugin and ``canstack serve`` throughput as fractions of the wire.
- figures that packages above stack register under the ``canstack.bench`` entry point group
  (``dbc_ecu``: DBC ECU encode + scheduling against cantools' encode).

Each engine figure and its reference is the best of ``--repeat`` runs (3 by default), as
`timeit` does: the machine's noise only ever slows a run down.

``--json`` prints one JSON object; ``--quick`` runs smaller counts.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from typing import Any

import can

from stack.bus.sim import SimBus
from stack.controller.events import TxDone
from stack.wire.frame import Frame

__all__ = ["bench_python_can_virtual", "bench_canstack_pair", "bench_saturated", "main"]


def _progress(msg: str) -> None:
    print(f"[bench] {msg}", file=sys.stderr, flush=True)


BURST = 64  # frames the sender queues at a time in the 1 -> 1 figures


def bench_python_can_virtual(n: int) -> float:
    """Frames per second through python-can's virtual interface, one sender, one receiver in one
    process: the better of sending and receiving one frame at a time and in bursts of 64 (the
    reference gets its best case)."""
    tx = can.Bus(interface="virtual", channel="bench", receive_own_messages=False)
    rx = can.Bus(interface="virtual", channel="bench", receive_own_messages=False)
    msg = can.Message(arbitration_id=0x123, data=bytes(8), is_extended_id=False)
    best = 0.0
    try:
        for burst in (1, BURST):
            got = 0
            t0 = time.perf_counter()
            for _ in range(n // burst):
                for _ in range(burst):
                    tx.send(msg)
                for _ in range(burst):
                    if rx.recv(timeout=1.0) is not None:
                        got += 1
            best = max(best, got / (time.perf_counter() - t0))
    finally:
        tx.shutdown()
        rx.shutdown()
    return best


def bench_canstack_pair(n: int) -> float:
    """Frames per second delivered from one sender to one receiver on a SimBus at 1 Mbit/s: the
    sender queues 64 frames, the bus carries them (arbitration, exact stuffed lengths, ACK,
    counters, per-ID statistics), the receiver reads them from its FIFO; repeated."""
    bus = SimBus(1_000_000, record=False)
    tx = bus.node("tx")
    rx = bus.node("rx", rx_fifo_size=BURST)
    frame = Frame(0x123, bytes(8))
    send, recv, run = tx.send, rx.recv, bus.run
    got = 0
    t0 = time.perf_counter()
    for _ in range(n // BURST):
        for _ in range(BURST):
            send(frame)
        run(frames=BURST)
        while recv() is not None:
            got += 1
    dt = time.perf_counter() - t0
    assert rx.rx_overruns == 0 and got == (n // BURST) * BURST
    return got / dt


def _resend(node: Any) -> Callable[[TxDone], None]:
    send = node.send
    return lambda ev: send(ev.frame)


def bench_saturated(nodes: int, n: int, group_filters: bool) -> tuple[float, float]:
    """(frames per second, real-time factor) for ``nodes`` saturating senders at 1 Mbit/s."""
    bus = SimBus(1_000_000, record=False)
    for i in range(nodes):
        cid = (0x100 + i) & 0x7FF
        kw: dict[str, Any] = {}
        if group_filters:
            kw["filters"] = [{"can_id": cid & 0x7F0, "can_mask": 0x7F0, "extended": False}]
        node = bus.node(f"n{i}", **kw)
        node.listen(TxDone, _resend(node))
        node.send(Frame(cid, bytes([i & 0xFF]) * 8))
    t0 = time.perf_counter()
    bus.run(frames=n)
    dt = time.perf_counter() - t0
    return n / dt, bus.now() / 1e9 / dt


def bench_campaign(frames: int, ber: float, seed: int = 1) -> tuple[float, int]:
    """(real-time factor, error frames) of the reliability campaign: 5 nodes with random traffic
    at 500 kbit/s, global and per-node local bit errors at ``ber``, trace recording off."""
    import random

    from stack.bus.faults import FaultInjector

    bus = SimBus(500_000, seed=seed, record=False)
    nodes = [bus.node(f"n{i}", rx_fifo_size=256) for i in range(5)]
    if ber:
        fi = FaultInjector(bus)
        fi.bit_errors(ber)
        fi.bit_errors(ber, nodes=[n.name for n in nodes])
    rng = random.Random(seed)
    for i, n in enumerate(nodes):
        count = [0]

        def again(ev: Any = None, n: Any = n, i: int = i, count: list[int] = count) -> None:
            count[0] += 1
            n.send(Frame(0x100 * (i + 1) + rng.randrange(0x100), count[0].to_bytes(4, "big") + bytes([i])))

        n.listen(TxDone, again)
        again()
    step = max(1, frames // 10)
    t0 = time.perf_counter()
    done = 0
    while done < frames:
        bus.run(frames=min(step, frames - done))
        done = min(frames, done + step)
        _progress(f"  campaign ber={ber:g}: {done:,}/{frames:,} frames")
    dt = time.perf_counter() - t0
    return bus.now() / 1e9 / dt, bus.error_frames


def main(argv: list[str] | None = None) -> int:
    """Run the benchmarks and print each figure as a ratio against its reference."""
    ap = argparse.ArgumentParser(prog="python -m stack.bench")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--quick", action="store_true", help="smaller counts (a quick look)")
    ap.add_argument("--no-waveform", action="store_true", help="skip the capture-decoding figure")
    ap.add_argument("--repeat", type=int, default=3, help="best of this many runs per figure (default 3)")
    args = ap.parse_args(argv)
    rep = max(1, args.repeat)
    scale = 0.2 if args.quick else 1.0
    res: dict[str, Any] = {}

    _progress("python-can virtual: 1 sender -> 1 receiver")
    ref = max(bench_python_can_virtual(int(50_000 * scale)) for _ in range(rep))
    _progress("canstack SimBus: 1 sender -> 1 receiver")
    ours = max(bench_canstack_pair(int(200_000 * scale)) for _ in range(rep))
    res["python_can_virtual_fps"] = ref
    res["canstack_pair_fps"] = ours
    res["vs_python_can_virtual"] = ours / ref

    _progress("10 nodes, 1 Mbit/s, 100 % load")
    fps10, rtf10 = max(bench_saturated(10, int(300_000 * scale), False) for _ in range(rep))
    res["fps_10_nodes"] = fps10
    res["realtime_factor_10_nodes"] = rtf10
    _progress("1000 nodes, 1 Mbit/s, 100 % load")
    fps1000, _rtf1000 = max(bench_saturated(1000, int(300_000 * scale), True) for _ in range(rep))
    res["fps_1000_nodes"] = fps1000
    res["scale_1000_vs_10_nodes"] = fps1000 / fps10

    n_campaign = int(1_000_000 * scale)
    _progress(f"reliability campaign, {n_campaign:,} frames fault-free")
    rtf_clean, _ = bench_campaign(n_campaign, 0.0)
    _progress(f"reliability campaign, {n_campaign:,} frames at bit-error rate 1e-4 (global + local)")
    rtf_faulty, errors = bench_campaign(n_campaign, 1e-4)
    res["campaign_frames"] = n_campaign
    res["campaign_error_frames"] = errors
    res["campaign_realtime_factor_500k"] = rtf_faulty
    res["campaign_realtime_factor_fault_free"] = rtf_clean
    res["campaign_vs_fault_free"] = rtf_faulty / rtf_clean

    if not args.no_waveform:
        from stack.cli.bench_io import decode_benchmark

        _progress("decoding a 12 M-sample capture")
        try:
            w = decode_benchmark()
        except FileNotFoundError as exc:
            _progress(f"skipped: {exc}")
        else:
            res["decode_s"] = w.get("decode_s")
            res["decode_cli_s"] = w.get("decode_cli_s")
            res["sigrok_s"] = w.get("sigrok_s")
            res["decode_vs_sigrok"] = w.get("vs_sigrok")
            res["decode_cli_vs_sigrok"] = w.get("cli_vs_sigrok")

    _progress("python-can integration: periodic jitter, plugin and serve throughput")
    try:
        from stack.cli.bench_io import benchmark as pycan_benchmark

        res["pycan"] = pycan_benchmark(3.0 * max(scale, 0.5))
    except Exception as exc:  # pragma: no cover - reported, not fatal
        _progress(f"  failed: {exc}")

    # figures of the packages above stack (dbc, profiles), found through entry points so that
    # stack does not import them
    from importlib.metadata import entry_points

    for ep in sorted(entry_points(group="canstack.bench"), key=lambda e: e.name):
        _progress(f"{ep.name} (entry point {ep.value})")
        try:
            out = ep.load()(seconds=3 * scale)
        except Exception as exc:  # a broken plug-in must not hide the other figures
            _progress(f"  failed: {exc}")
            continue
        res[ep.name] = out

    if args.json:
        print(json.dumps(res))
        return 0
    print(
        f"frames/s 1 sender -> 1 receiver: {ours:,.0f} vs python-can virtual {ref:,.0f}: "
        f"{res['vs_python_can_virtual']:.2f}x (target >= 3)"
    )
    print(
        f"10 nodes @ 1 Mbit/s, 100 % load: {fps10:,.0f} frames/s, real-time factor {rtf10:.1f}x the wire (target >= 50)"
    )
    print(
        f"1000 nodes: {fps1000:,.0f} frames/s = {res['scale_1000_vs_10_nodes']:.2f} of the 10-node "
        f"figure (target >= 0.5)"
    )
    print(
        f"reliability campaign, {n_campaign:,} frames, 5 nodes @ 500 kbit/s, BER 1e-4: real-time "
        f"factor {rtf_faulty:.1f}x ({errors:,} error frames) vs {rtf_clean:.1f}x fault-free: "
        f"{res['campaign_vs_fault_free']:.2f}"
    )
    if res.get("decode_vs_sigrok") is not None:
        print(
            f"capture decode vs sigrok-cli ({res['sigrok_s']:.3f} s, a whole process): canstack decode as a "
            f"process {res['decode_cli_s']:.3f} s: {res['decode_cli_vs_sigrok']:.2f}x (target >= 1); "
            f"in-process decode_file {res['decode_s']:.3f} s: {res['decode_vs_sigrok']:.2f}x"
        )
    elif "decode_s" in res:
        print(f"capture decode: {res['decode_s']:.2f} s (sigrok-cli not installed)")
    if "pycan" in res:
        p = res["pycan"]
        per = p["periodic"]
        print(
            f"10 ms periodic, p99 period deviation: canstack {per['canstack']['p99_timestamp_s'] * 1e6:.1f} us "
            f"(bus timestamps; {per['canstack']['p99_arrival_s'] * 1e6:.0f} us at recv) vs python-can virtual "
            f"{per['python_can_virtual']['p99_timestamp_s'] * 1e6:.0f} us "
            f"({per['python_can_virtual']['p99_arrival_s'] * 1e6:.0f} us): {per['ratio_timestamp']:.3f}x / "
            f"{per['ratio_arrival']:.2f}x (target <= 1; median of {per.get('rounds', 1)} rounds)"
        )
        print(
            f"python-can plugin, 2 nodes @ 1 Mbit/s back to back: {p['plugin_throughput']['fps']:,.0f} frames/s = "
            f"{p['plugin_throughput']['fraction']:.3f} of the wire (target >= 0.9)"
        )
        print(
            f"canstack serve, 3 client processes @ 500 kbit/s: {p['serve_throughput']['fps']:,.0f} frames/s = "
            f"{p['serve_throughput']['fraction']:.3f} of the wire"
        )
    if "dbc_ecu" in res:
        d = res["dbc_ecu"]
        print(
            f"DBC ECU encode + scheduling: {d['ecu_us_per_msg']:.2f} us/message vs cantools encode "
            f"{d['cantools_us_per_msg']:.2f} us: {d['ratio']:.2f}x (target <= 1.5)"
        )
    for name, out in res.items():  # other plug-ins say their figures in lines of their own
        if isinstance(out, dict) and name != "dbc_ecu":
            for line in out.get("lines", ()):
                print(line)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
