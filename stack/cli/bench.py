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
- ``fd_vs_classical_10_nodes``: the same 10 nodes on a CAN FD bus (2 Mbit/s data phase), half of
  the frames 64-byte FD frames with BRS (`bench_fd_mixed`): frames per second divided by the
  classical 10-node figure, both measured in this figure, one run of each in turn.
- ``campaign_realtime_factor_500k``: the reliability campaign (5 nodes, random traffic,
  bit-error rate 1e-4 global and local) at 500 kbit/s, against the same traffic fault-free
  (``campaign_vs_fault_free``).
- ``unacked_fast_vs_bitlevel``: one node alone on a 1 Mbit/s bus retransmitting a frame nobody
  acknowledges (error passive after its first 16 ACK errors): CPU seconds per simulated second
  with the replay of the identical attempt reused (`SimBus.reuse_unacked`, the serve fast path)
  and replaying every attempt bit by bit, the ratio of the two.
- ``decode_vs_sigrok`` (when the corpus and sigrok-cli are present): see `stack.cli.bench_io.decode_benchmark`;
  without the corpus (``--corpus``, default ``../shared/corpus``) the figure is skipped with a note.
- ``pycan``: the python-can integration (`stack.cli.bench_io.benchmark`): 10 ms periodic jitter against
  python-can's virtual bus, plugin and ``canstack serve`` throughput as fractions of the wire.
- figures that packages above stack register under the ``canstack.bench`` entry point group
  (``dbc_ecu``: DBC ECU encode + scheduling against cantools' encode).

Each engine figure and its reference is the best of ``--repeat`` runs (3 by default), as
`timeit` does: the machine's noise only ever slows a run down.

``--json`` prints one JSON object; ``--quick`` runs smaller counts; ``--only`` names the figures to
measure (`FIGURES`, then the entry points). A figure whose data is missing is skipped with a note
(``skipped`` in the JSON), one that fails is noted (``failed``): neither loses the other figures.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import can

from stack.bus.sim import SimBus
from stack.cli.bench_io import CORPUS
from stack.controller.events import TxDone
from stack.wire.frame import Frame

__all__ = [
    "bench_python_can_virtual",
    "bench_canstack_pair",
    "bench_saturated",
    "bench_fd_mixed",
    "bench_campaign",
    "bench_unacked",
    "Figure",
    "FIGURES",
    "Settings",
    "figures",
    "run_figures",
    "main",
]


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


def _alternate(node: Any, a: Frame, b: Frame) -> Callable[[TxDone], None]:
    send = node.send
    return lambda ev: send(b if ev.frame is a else a)


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


def bench_fd_mixed(nodes: int, n: int) -> tuple[float, float]:
    """(frames per second, real-time factor) for ``nodes`` saturating senders on a CAN FD bus at
    1 Mbit/s with a 2 Mbit/s data phase, as `bench_saturated` without filters, each sender sending
    an 8-byte classical frame and a 64-byte FD frame with BRS of one identifier in turn (the other
    one when the last is done): half of the traffic is FD."""
    bus = SimBus(1_000_000, data_bitrate=2_000_000, record=False)
    for i in range(nodes):
        cid = (0x100 + i) & 0x7FF
        node = bus.node(f"n{i}")
        classical = Frame(cid, bytes([i & 0xFF]) * 8)
        node.listen(TxDone, _alternate(node, classical, Frame(cid, bytes([i & 0xFF]) * 64, fd=True, brs=True)))
        node.send(classical)
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


def bench_unacked(sim_s: float, reuse: bool) -> float:
    """CPU seconds per simulated second of a node alone on a 1 Mbit/s bus whose frame nobody
    acknowledges (it retransmits at once, rule 3 and its exception 1 in error passive), with the
    replay of an identical unacknowledged attempt reused or not (`SimBus.reuse_unacked`); timed
    from error passive on, trace recording off."""
    bus = SimBus(1_000_000, record=False)
    bus.reuse_unacked = reuse
    bus.node("alone").send(Frame(0x123, bytes(8)))
    bus.run(until=10_000_000)  # 16 ACK errors (rule 3) take it to error passive in about 3 ms
    start = bus.now()
    t0 = time.process_time()
    bus.run(until=start + int(sim_s * 1e9))
    return (time.process_time() - t0) / ((bus.now() - start) / 1e9)


@dataclass(frozen=True)
class Settings:
    """What every figure is measured with: ``repeat`` runs each (the best counts), counts scaled
    by ``scale`` (``--quick``: 0.2), the corpus directory of the capture-decoding figure."""

    repeat: int = 3
    scale: float = 1.0
    corpus: Path = CORPUS


def _engine(s: Settings) -> dict[str, Any]:
    _progress("python-can virtual: 1 sender -> 1 receiver")
    ref = max(bench_python_can_virtual(int(50_000 * s.scale)) for _ in range(s.repeat))
    _progress("canstack SimBus: 1 sender -> 1 receiver")
    ours = max(bench_canstack_pair(int(200_000 * s.scale)) for _ in range(s.repeat))
    return {"python_can_virtual_fps": ref, "canstack_pair_fps": ours, "vs_python_can_virtual": ours / ref}


def _engine_lines(r: dict[str, Any]) -> list[str]:
    return [
        f"frames/s 1 sender -> 1 receiver: {r['canstack_pair_fps']:,.0f} vs python-can virtual "
        f"{r['python_can_virtual_fps']:,.0f}: {r['vs_python_can_virtual']:.2f}x (target >= 3)"
    ]


def _nodes(s: Settings) -> dict[str, Any]:
    _progress("10 nodes, 1 Mbit/s, 100 % load")
    fps10, rtf10 = max(bench_saturated(10, int(300_000 * s.scale), False) for _ in range(s.repeat))
    _progress("1000 nodes, 1 Mbit/s, 100 % load")
    fps1000, _rtf1000 = max(bench_saturated(1000, int(300_000 * s.scale), True) for _ in range(s.repeat))
    return {
        "fps_10_nodes": fps10,
        "realtime_factor_10_nodes": rtf10,
        "fps_1000_nodes": fps1000,
        "scale_1000_vs_10_nodes": fps1000 / fps10,
    }


def _nodes_lines(r: dict[str, Any]) -> list[str]:
    return [
        f"10 nodes @ 1 Mbit/s, 100 % load: {r['fps_10_nodes']:,.0f} frames/s, real-time factor "
        f"{r['realtime_factor_10_nodes']:.1f}x the wire (target >= 50)",
        f"1000 nodes: {r['fps_1000_nodes']:,.0f} frames/s = {r['scale_1000_vs_10_nodes']:.2f} of the 10-node "
        f"figure (target >= 0.5)",
    ]


def _fd(s: Settings) -> dict[str, Any]:
    n = int(300_000 * s.scale)
    classical: list[tuple[float, float]] = []
    fd: list[tuple[float, float]] = []
    for i in range(s.repeat):  # in turn, so that the machine's load weighs on both alike
        _progress(f"10 nodes, half of the frames CAN FD (64 bytes, BRS, 2 Mbit/s), and classical: run {i + 1}")
        fd.append(bench_fd_mixed(10, n))
        classical.append(bench_saturated(10, n, False))
    fps_fd, rtf_fd = max(fd)
    fps, _ = max(classical)
    return {
        "fps_10_nodes_fd_half": fps_fd,
        "realtime_factor_10_nodes_fd_half": rtf_fd,
        "fps_10_nodes_classical": fps,
        "fd_vs_classical_10_nodes": fps_fd / fps,
    }


def _fd_lines(r: dict[str, Any]) -> list[str]:
    return [
        f"10 nodes @ 1 Mbit/s, 2 Mbit/s data phase, half of the frames CAN FD (64 bytes, BRS): "
        f"{r['fps_10_nodes_fd_half']:,.0f} frames/s, real-time factor {r['realtime_factor_10_nodes_fd_half']:.1f}x "
        f"= {r['fd_vs_classical_10_nodes']:.2f} of the classical 10-node frames/s "
        f"({r['fps_10_nodes_classical']:,.0f}) (target >= 0.8)"
    ]


def _campaign(s: Settings) -> dict[str, Any]:
    n = int(1_000_000 * s.scale)
    _progress(f"reliability campaign, {n:,} frames fault-free")
    rtf_clean, _ = bench_campaign(n, 0.0)
    _progress(f"reliability campaign, {n:,} frames at bit-error rate 1e-4 (global + local)")
    rtf_faulty, errors = bench_campaign(n, 1e-4)
    return {
        "campaign_frames": n,
        "campaign_error_frames": errors,
        "campaign_realtime_factor_500k": rtf_faulty,
        "campaign_realtime_factor_fault_free": rtf_clean,
        "campaign_vs_fault_free": rtf_faulty / rtf_clean,
    }


def _campaign_lines(r: dict[str, Any]) -> list[str]:
    return [
        f"reliability campaign, {r['campaign_frames']:,} frames, 5 nodes @ 500 kbit/s, BER 1e-4: real-time "
        f"factor {r['campaign_realtime_factor_500k']:.1f}x ({r['campaign_error_frames']:,} error frames) vs "
        f"{r['campaign_realtime_factor_fault_free']:.1f}x fault-free: {r['campaign_vs_fault_free']:.2f}"
    ]


def _unacked(s: Settings) -> dict[str, Any]:
    fast: list[float] = []
    slow: list[float] = []
    for i in range(s.repeat):  # in turn, so that the machine's load weighs on both alike
        _progress(f"a lone node, unacknowledged frame, 1 Mbit/s: fast path and bit by bit, run {i + 1}")
        fast.append(bench_unacked(2.0 * s.scale, True))
        slow.append(bench_unacked(0.2 * s.scale, False))
    return {
        "unacked_cpu_per_sim_s_fast": min(fast),
        "unacked_cpu_per_sim_s_bitlevel": min(slow),
        "unacked_fast_vs_bitlevel": min(slow) / min(fast),
    }


def _unacked_lines(r: dict[str, Any]) -> list[str]:
    return [
        f"a lone node @ 1 Mbit/s retransmitting an unacknowledged frame: {r['unacked_cpu_per_sim_s_fast']:.3f} CPU s "
        f"per simulated s with the fast path vs {r['unacked_cpu_per_sim_s_bitlevel']:.3f} bit by bit: "
        f"{r['unacked_fast_vs_bitlevel']:.1f}x"
    ]


def _decode(s: Settings) -> dict[str, Any]:
    from stack.cli.bench_io import decode_benchmark

    _progress("decoding a 12 M-sample capture")
    w = decode_benchmark(corpus=s.corpus)
    return {
        "decode_s": w["decode_s"],
        "decode_cli_s": w["decode_cli_s"],
        "sigrok_s": w["sigrok_s"],
        "decode_vs_sigrok": w["vs_sigrok"],
        "decode_cli_vs_sigrok": w["cli_vs_sigrok"],
    }


def _decode_lines(r: dict[str, Any]) -> list[str]:
    if r.get("decode_vs_sigrok") is None:
        return [f"capture decode: {r['decode_s']:.2f} s (sigrok-cli not installed)"]
    return [
        f"capture decode vs sigrok-cli ({r['sigrok_s']:.3f} s, a whole process): canstack decode as a "
        f"process {r['decode_cli_s']:.3f} s: {r['decode_cli_vs_sigrok']:.2f}x (target >= 1); "
        f"in-process decode_file {r['decode_s']:.3f} s: {r['decode_vs_sigrok']:.2f}x"
    ]


def _pycan(s: Settings) -> dict[str, Any]:
    from stack.cli.bench_io import benchmark as pycan_benchmark

    _progress("python-can integration: periodic jitter, plugin and serve throughput")
    return {"pycan": pycan_benchmark(3.0 * max(s.scale, 0.5))}


def _pycan_lines(r: dict[str, Any]) -> list[str]:
    p = r["pycan"]
    per = p["periodic"]
    ours, ref = per["canstack"], per["python_can_virtual"]
    return [
        f"10 ms periodic, p99 period deviation: canstack {ours['p99_timestamp_s'] * 1e6:.1f} us "
        f"(bus timestamps; {ours['p99_arrival_s'] * 1e6:.0f} us at recv) vs python-can virtual "
        f"{ref['p99_timestamp_s'] * 1e6:.0f} us ({ref['p99_arrival_s'] * 1e6:.0f} us): "
        f"{per['ratio_timestamp']:.3f}x / {per['ratio_arrival']:.2f}x (target <= 1; median of "
        f"{per.get('rounds', 1)} rounds)",
        f"python-can plugin, 2 nodes @ 1 Mbit/s back to back: {p['plugin_throughput']['fps']:,.0f} frames/s = "
        f"{p['plugin_throughput']['fraction']:.3f} of the wire (target >= 0.9)",
        f"canstack serve, 3 client processes @ 500 kbit/s: {p['serve_throughput']['fps']:,.0f} frames/s = "
        f"{p['serve_throughput']['fraction']:.3f} of the wire",
    ]


class Figure(NamedTuple):
    """One figure of the benchmark: ``measure`` returns its JSON keys, ``lines`` says them."""

    name: str
    what: str
    measure: Callable[[Settings], dict[str, Any]]
    lines: Callable[[dict[str, Any]], list[str]]


#: The engine's figures, in the order they run; the packages above stack add theirs through the
#: ``canstack.bench`` entry point group.
FIGURES: tuple[Figure, ...] = (
    Figure("engine", "1 sender -> 1 receiver against python-can's virtual bus", _engine, _engine_lines),
    Figure("nodes", "10 and 1000 saturating nodes", _nodes, _nodes_lines),
    Figure("fd", "10 saturating nodes, half of the frames CAN FD, against the classical 10", _fd, _fd_lines),
    Figure("campaign", "the reliability campaign against the same traffic fault-free", _campaign, _campaign_lines),
    Figure("unacked", "a lone node's unacknowledged frame: the fast path against bit by bit", _unacked, _unacked_lines),
    Figure("decode", "capture decoding against sigrok-cli (needs the corpus)", _decode, _decode_lines),
    Figure("pycan", "python-can integration: periodic jitter, plugin and serve throughput", _pycan, _pycan_lines),
)


def _plugin_figure(ep: Any) -> Figure:
    def measure(s: Settings) -> dict[str, Any]:
        _progress(f"{ep.name} (entry point {ep.value})")
        return {ep.name: ep.load()(seconds=3 * s.scale)}

    def lines(r: dict[str, Any]) -> list[str]:
        out = r[ep.name]
        if ep.name == "dbc_ecu":
            return [
                f"DBC ECU encode + scheduling: {out['ecu_us_per_msg']:.2f} us/message vs cantools encode "
                f"{out['cantools_us_per_msg']:.2f} us: {out['ratio']:.2f}x (target <= 1.5)"
            ]
        return list(out.get("lines", ())) if isinstance(out, dict) else []

    return Figure(ep.name, f"entry point {ep.value}", measure, lines)


def figures() -> list[Figure]:
    """The engine's figures and those the ``canstack.bench`` entry points register (by name)."""
    from importlib.metadata import entry_points

    # found through entry points so that stack does not import the packages above it
    plugins = sorted(entry_points(group="canstack.bench"), key=lambda e: e.name)
    return [*FIGURES, *(_plugin_figure(ep) for ep in plugins)]


def run_figures(chosen: Sequence[Figure], settings: Settings) -> tuple[dict[str, Any], list[str]]:
    """Measure each figure in turn: (the JSON object, the lines of the report).

    A figure whose data is missing (FileNotFoundError: a plain clone has no ``../shared/corpus``)
    is skipped with a note under ``skipped``; one that fails for any other reason is noted under
    ``failed``; neither loses the figures measured before or after it. Ctrl-C (or SIGTERM) stops
    the run and keeps what was measured, noted under ``interrupted``.
    """
    res: dict[str, Any] = {}
    lines: list[str] = []
    skipped: dict[str, str] = {}
    failed: dict[str, str] = {}
    for i, fig in enumerate(chosen):
        try:
            got = fig.measure(settings)
        except KeyboardInterrupt:
            res["interrupted"] = [f.name for f in chosen[i:]]
            lines.append("interrupted: not measured: " + ", ".join(res["interrupted"]))
            _progress("interrupted")
            break
        except FileNotFoundError as exc:
            skipped[fig.name] = str(exc)
            lines.append(f"{fig.name}: skipped ({exc})")
            _progress(f"  skipped: {exc}")
            continue
        except Exception as exc:  # one broken figure must not lose the others
            failed[fig.name] = f"{type(exc).__name__}: {exc}"
            lines.append(f"{fig.name}: failed ({failed[fig.name]})")
            _progress(f"  failed: {failed[fig.name]}")
            continue
        res.update(got)
        lines.extend(fig.lines(got))
    if skipped:
        res["skipped"] = skipped
    if failed:
        res["failed"] = failed
    return res, lines


def main(argv: list[str] | None = None) -> int:
    """Run the benchmarks and print each figure as a ratio against its reference."""
    everything = figures()
    names = [f.name for f in everything]
    ap = argparse.ArgumentParser(
        prog="python -m stack.bench",
        epilog="figures: " + "; ".join(f"{f.name}: {f.what}" for f in everything),
    )
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--quick", action="store_true", help="smaller counts (a quick look)")
    ap.add_argument("--no-waveform", action="store_true", help="skip the capture-decoding figure")
    ap.add_argument("--repeat", type=int, default=3, help="best of this many runs per figure (default 3)")
    ap.add_argument(
        "--only",
        metavar="NAMES",
        help=f"measure only these figures, comma-separated ({', '.join(names)})",
    )
    ap.add_argument(
        "--corpus",
        type=Path,
        default=CORPUS,
        help="the shared corpus directory with the captures (default: ../shared/corpus beside the checkout)",
    )
    args = ap.parse_args(argv)
    chosen = everything
    if args.only is not None:
        wanted = [n.strip() for n in args.only.split(",") if n.strip()]
        unknown = [n for n in wanted if n not in names]
        if unknown or not wanted:
            ap.error(f"--only {args.only!r}: choose among {', '.join(names)}")
        chosen = [f for f in everything if f.name in wanted]
    if args.no_waveform:
        chosen = [f for f in chosen if f.name != "decode"]
    settings = Settings(repeat=max(1, args.repeat), scale=0.2 if args.quick else 1.0, corpus=args.corpus)
    res, lines = run_figures(chosen, settings)
    if args.json:
        print(json.dumps(res))
    else:
        for line in lines:
            print(line)
    return 130 if "interrupted" in res else 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
