"""Speed figures of the python-can integration, `canstack serve` and capture decoding, for
`python -m stack.bench`."""

from __future__ import annotations

import math
import os
import shutil
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import can

from stack.io.pycan import CanstackBus, frame_of
from stack.io.serve import BusServer
from stack.phy.waveform import decode_file
from stack.wire.coding import INTERMISSION_BITS
from stack.wire.frame import Frame

__all__ = ["benchmark", "serve_benchmark", "decode_benchmark", "wire_limit_fps", "CORPUS", "BENCH_CAPTURE_NAME"]


def _period_p99(stamps: list[float], period: float) -> float:
    devs = sorted(abs((b - a) - period) for a, b in zip(stamps, stamps[1:]))
    if not devs:
        return float("nan")
    return devs[min(len(devs) - 1, int(0.99 * len(devs)))]


def _measure_periodic(interface: str, channel: str, seconds: float, **kw: Any) -> dict[str, float]:
    tx = can.Bus(interface=interface, channel=channel, **kw)
    rx = can.Bus(interface=interface, channel=channel, **kw)
    stamps: list[float] = []
    arrivals: list[float] = []
    try:
        task = tx.send_periodic(can.Message(arbitration_id=0x100, data=bytes(8), is_extended_id=False), 0.010)
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            m = rx.recv(0.1)
            if m is not None:
                arrivals.append(time.time())
                stamps.append(m.timestamp)
        task.stop()
    finally:
        tx.shutdown()
        rx.shutdown()
    return {
        "p99_timestamp_s": _period_p99(stamps, 0.010),
        "p99_arrival_s": _period_p99(arrivals, 0.010),
        "frames": float(len(stamps)),
    }


def wire_limit_fps(bitrate: int, frame: Frame) -> float:
    """Frames per second the wire carries back to back: bitrate / (stuffed length + 3 bits
    intermission)."""
    return bitrate / (frame.bits.length + INTERMISSION_BITS)


def _measure_throughput(seconds: float) -> dict[str, float]:
    name = f"bench-tp-{time.monotonic_ns()}"
    tx = CanstackBus(name, bitrate=1_000_000, tx_queue_size=256)
    rx = CanstackBus(name)
    msg = can.Message(arbitration_id=0x123, data=bytes.fromhex("0123456789abcdef"), is_extended_id=False)
    got = [0]
    stop = threading.Event()

    def reader() -> None:
        while not stop.is_set():
            if rx.recv(0.05) is not None:
                got[0] += 1

    th = threading.Thread(target=reader, daemon=True)
    th.start()
    try:
        for _ in range(64):
            tx.send(msg)
        time.sleep(0.05)
        g0, t0 = got[0], time.monotonic()
        end = t0 + seconds
        while time.monotonic() < end:
            tx.send(msg, timeout=1.0)
        dt = time.monotonic() - t0
        g1 = got[0]
    finally:
        stop.set()
        th.join(1.0)
        tx.shutdown()
        rx.shutdown()
    fps = (g1 - g0) / dt
    limit = wire_limit_fps(1_000_000, frame_of(msg))
    return {"fps": fps, "wire_limit_fps": limit, "fraction": fps / limit}


def benchmark(seconds: float = 2.0, rounds: int = 3) -> dict[str, Any]:
    """Speed figures of the python-can integration (each a few seconds):

    - ``periodic``: a 10 ms periodic message received by another node: p99 deviation of the
      period from the receive timestamps and from the arrival times at ``recv``, on a canstack
      bus (native periodic task) and on python-can's ``virtual`` bus (its thread-based task),
      the median of ``rounds`` alternating rounds of ``seconds`` each;
    - ``plugin_throughput``: two nodes at 1 Mbit/s, back-to-back 8-byte frames through the
      python-can plugin, frames/s as a fraction of the wire limit (target >= 0.9);
    - ``serve_throughput``: three client processes through ``canstack serve`` at 500 kbit/s,
      frames/s on the wire as a fraction of its limit (see `serve_benchmark`).
    """
    res: dict[str, Any] = {}
    # the p99 of a few hundred periods is the third-worst wake-up of a thread: alternate the two
    # buses over ``rounds`` rounds and keep each side's median round
    ours_r: list[dict[str, float]] = []
    ref_r: list[dict[str, float]] = []
    for _ in range(rounds):
        ours_r.append(_measure_periodic("canstack", f"bench-periodic-{time.monotonic_ns()}", seconds, bitrate=500_000))
        ref_r.append(_measure_periodic("virtual", f"bench-periodic-{time.monotonic_ns()}", seconds))

    def median(rs: list[dict[str, float]]) -> dict[str, float]:
        return {k: statistics.median(r[k] for r in rs) for k in rs[0]}

    ours, ref = median(ours_r), median(ref_r)
    res["periodic"] = {
        "canstack": ours,
        "python_can_virtual": ref,
        "rounds": rounds,
        "ratio_timestamp": ours["p99_timestamp_s"] / max(ref["p99_timestamp_s"], 1e-9),
        "ratio_arrival": ours["p99_arrival_s"] / max(ref["p99_arrival_s"], 1e-9),
    }
    res["plugin_throughput"] = _measure_throughput(seconds)

    res["serve_throughput"] = serve_benchmark(seconds)
    return res


_CLIENT_SCRIPT = r"""
import sys, time, threading, can
import stack.io.pycan
url, can_id, seconds = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
bus = can.Bus(interface="canstack", channel=url, tx_queue_size=64)
msg = can.Message(arbitration_id=can_id, data=bytes([can_id & 0xFF]) * 8, is_extended_id=False)
got = [0]
stop = threading.Event()
def rd():
    while not stop.is_set():
        if bus.recv(0.05) is not None:
            got[0] += 1
threading.Thread(target=rd, daemon=True).start()
print("ready", flush=True)
sys.stdin.readline()
end = time.monotonic() + seconds
sent = 0
while time.monotonic() < end:
    try:
        bus.send(msg, timeout=0.2)
        sent += 1
    except can.CanOperationError:  # a low-priority node starves at 100 % load, as on a real bus
        pass
time.sleep(0.2)
stop.set()
bus.shutdown()
print(sent, got[0], flush=True)
"""


def serve_benchmark(seconds: float = 2.0, clients: int = 3, bitrate: int = 500_000) -> dict[str, Any]:
    """Frames per second through `canstack serve` with ``clients`` processes sending 8-byte
    frames back to back, as a fraction of the wire limit at ``bitrate``."""
    root = str(Path(__file__).resolve().parents[2])  # the checkout holding `stack`
    env = dict(os.environ, PYTHONPATH=root + os.pathsep + os.environ.get("PYTHONPATH", ""))
    ids = [0x100 + i for i in range(clients)]
    with BusServer(bitrate, name="bench", listen=("127.0.0.1", 0)) as server:
        procs = [
            subprocess.Popen(
                [sys.executable, "-c", _CLIENT_SCRIPT, server.url, str(i), str(seconds)],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                text=True,
                env=env,
            )
            for i in ids
        ]
        try:
            for p in procs:
                assert p.stdout is not None and p.stdout.readline().strip() == "ready"
            for p in procs:
                assert p.stdin is not None
                p.stdin.write("go\n")
                p.stdin.flush()
            time.sleep(min(0.5, seconds / 4))
            f0 = server.runner.call(lambda: server.sim.frames_ok)
            t0 = time.monotonic()
            time.sleep(seconds / 2)
            f1 = server.runner.call(lambda: server.sim.frames_ok)
            dt = time.monotonic() - t0
            results = [p.communicate(timeout=seconds + 30)[0].split() for p in procs]
        finally:
            for p in procs:
                if p.poll() is None:
                    p.kill()
    fps = (f1 - f0) / dt
    limit = sum(wire_limit_fps(bitrate, Frame(i, bytes([i & 0xFF]) * 8)) for i in ids) / len(ids)
    return {
        "fps": fps,
        "wire_limit_fps": limit,
        "fraction": fps / limit,
        "server_max_lag_ms": server.runner.max_lag_ns / 1e6,
        "clients": [{"sent": int(r[0]), "received": int(r[1])} for r in results if len(r) == 2],
    }


#: The shared corpus beside the checkout (``../shared/corpus``); a user's clone has none.
CORPUS = Path(__file__).resolve().parents[3] / "shared" / "corpus"
#: The capture the decoding figure is measured on, in the corpus's ``captures`` folder.
BENCH_CAPTURE_NAME = "mcp2515dm-bm-125kbits_bus_load_100percent.sr"


def decode_benchmark(path: str | Path | None = None, *, corpus: str | Path = CORPUS) -> dict[str, Any]:
    """Time `decode_file` on the 12 M sample MCP2515 100 % bus load capture (125 kbit/s, CAN_RX)
    in this process and as a whole `canstack decode` process (interpreter start and imports
    included), and, when sigrok-cli is installed, sigrok's CAN decoder on the same file (a whole
    process too).

    The capture is ``path``, else `BENCH_CAPTURE_NAME` in ``corpus``/captures (default: the
    shared corpus beside the checkout, `CORPUS`); FileNotFoundError, before anything is timed,
    when it is not there (a user's clone has no corpus).

    Returns {"decode_s", "decode_cli_s", "sigrok_s" (None without sigrok-cli), "frames",
    "vs_sigrok" (sigrok_s / decode_s), "cli_vs_sigrok" (sigrok_s / decode_cli_s): > 1 means
    faster than sigrok}; the best of 3 runs each.
    """
    p = Path(path) if path is not None else Path(corpus) / "captures" / BENCH_CAPTURE_NAME
    if not p.is_file():
        raise FileNotFoundError(f"{p}: the benchmark capture is not there (it comes with ../shared/corpus)")
    best = math.inf
    frames = 0
    for _ in range(3):
        t0 = time.perf_counter()
        recs = decode_file(p, 125000, channel="CAN_RX")
        best = min(best, time.perf_counter() - t0)
        frames = sum(1 for r in recs if r.ok)
    # the command line against the command line: a whole `canstack decode` process
    cli = math.inf
    for _ in range(3):
        t0 = time.perf_counter()
        subprocess.run(
            [sys.executable, "-m", "stack.cli", "decode", str(p), "--bitrate", "125000", "--channel", "CAN_RX"],
            check=True,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        cli = min(cli, time.perf_counter() - t0)
    sig: float | None = None
    exe = shutil.which("sigrok-cli")
    if exe:
        sig = math.inf
        for _ in range(3):
            t0 = time.perf_counter()
            subprocess.run(
                [exe, "-i", str(p), "-P", "can:can_rx=CAN_RX:nominal_bitrate=125000", "-A", "can=fields"],
                check=True,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
            sig = min(sig, time.perf_counter() - t0)
    return {
        "decode_s": best,
        "decode_cli_s": cli,
        "sigrok_s": sig,
        "frames": frames,
        "vs_sigrok": (sig / best) if sig else None,
        "cli_vs_sigrok": (sig / cli) if sig else None,
    }


# ---------------------------------------------------------------------------------------------
