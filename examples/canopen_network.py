"""A CANopen network on the simulated bus: a master and five devices, SYNC every 1 ms at
1 Mbit/s, and the SYNC-to-PDO latency the master measures.

    python examples/canopen_network.py [--duration 2] [--json] [--plot latency.png]

Each device (the default EDS, node-IDs 1..5) sends

- TPDO1 at every SYNC (type 1): its cycle counter and digital inputs, 5 bytes;
- TPDO3 synchronously with a type of its own: every 2nd, 3rd, 4th SYNC for devices 1..3,
  acyclic (type 0, at the SYNC after its inputs change) for device 4, every 5th for device 5;
- TPDO2 event-driven (type 255) with an inhibit time of 5 ms: two analog inputs the
  application changes every millisecond, so the inhibit time decides how often it goes.

Synchronous TPDOs must start within 600 µs of the SYNC (0x1007): the ones that cannot are not
sent late (the "late" column). The heartbeat is 50 ms and the master consumes it with 75 ms.
Device 3 dies at 500 ms: its heartbeat stops and the master reports it. examples/canopen.toml is
the scenario-file form (``profile = "canopen"`` / ``"canopen-master"``; the options here are
its ``[nodes.canopen]`` tables), without the application code that changes the inputs.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any

from profiles.canopen import CanopenDevice, CanopenMaster
from stack import SimBus

MS = 1_000_000
US = 1_000

MASTER = {"nodes": [1, 2, 3, 4, 5], "sync_period_us": 1000, "heartbeat_ms": 50, "heartbeat_consumer_ms": 75}
TPDO3_TYPE = {1: 2, 2: 3, 3: 4, 4: 0, 5: 5}
DIES = (3, 500 * MS)


def device_options(node_id: int) -> dict[str, Any]:
    """The device's options (a scenario file's ``[[node]]`` table with ``profile = "canopen"``)."""
    return {
        "sync_window_us": 600,
        "tpdo": {
            1: {"transmission_type": 1, "mapping": ["0x2002:0/32", "0x2000:0/8"]},
            2: {"transmission_type": 255, "inhibit_100us": 50, "mapping": ["0x2001:1/16", "0x2001:2/16"]},
            3: {"transmission_type": TPDO3_TYPE[node_id], "mapping": ["0x2001:3/16", "0x2003:0/16", "0x2000:0/8"]},
            4: {"valid": False},
        },
    }


class Sensors:
    """The application of a device (sans-IO, on the node's timers): a cycle counter and analog
    inputs every 1 ms, digital inputs every 5 ms."""

    def __init__(self, device: CanopenDevice) -> None:
        self.d = device
        self.k = 0
        n = device.node
        n.call_later(1 * MS, self.cycle)
        n.call_later(1 * MS, self.analog)
        n.call_later(5 * MS, self.digital)

    def cycle(self) -> None:
        if self.d.running:
            self.d.write(0x2002, 0, (self.d.read(0x2002) + 1) & 0xFFFF_FFFF)
            self.d.node.call_later(1 * MS, self.cycle)

    def analog(self) -> None:
        if self.d.running:
            self.k += 1
            self.d.write(0x2001, 1, int(1000 * math.sin(self.k / 20)))
            self.d.write(0x2001, 2, int(1000 * math.cos(self.k / 20)))
            self.d.node.call_later(1 * MS, self.analog)

    def digital(self) -> None:
        if self.d.running:
            self.d.write(0x2000, 0, (self.d.read(0x2000) + 1) & 0xFF)
            self.d.node.call_later(5 * MS, self.digital)


def run(duration_s: float = 2.0, seed: int = 1) -> dict[str, Any]:
    """Simulate the network for ``duration_s``; the metrics of the master and of every device."""
    bus = SimBus(1_000_000, seed=seed)
    master = CanopenMaster(bus.node("master"), **MASTER)
    devices = [CanopenDevice(bus.node(f"device{i}"), i, **device_options(i)) for i in MASTER["nodes"]]
    for d in devices:
        d.start()
        Sensors(d)
    master.start()
    nid, t_dies = DIES
    bus.run(until=min(t_dies, int(duration_s * 1e9)))
    if t_dies < duration_s * 1e9:
        devices[nid - 1].stop()
        bus.run(until=int(duration_s * 1e9))
    return {
        "master": master.metrics(),
        "devices": [d.metrics() for d in devices],
        "bus": {"load": round(bus.busy_ns / bus.now(), 4), "frames": bus.frames_ok},
        "latencies_ns": {p.cob_id: list(p.latencies.values) for p in master.pdos.values() if p.latencies.n},
    }


def report(result: dict[str, Any]) -> str:
    """The text summary: nodes, then one line per synchronous PDO."""
    m = result["master"]
    lines = [f"bus load {result['bus']['load']:.1%}, {result['bus']['frames']:,} frames, {m['sync']['sent']:,} SYNCs"]
    late = {(d["node_id"], t["cob_id"]): t["not_in_window"] for d in result["devices"] for t in d["tpdos"]}
    for n in m["nodes"]:
        lines.append(
            f"node {n['node_id']}: {n['nmt_state']:<16} heartbeats {n['heartbeats_received']:>3} received, "
            f"{n['heartbeats_missed']:>2} missed  EMCY {n['emcy_received']}"
        )
    lines.append(
        f"{'PDO':>5} {'node':>4} {'type':>4} {'received':>8} {'late':>4}  "
        f"{'min':>6} {'mean':>6} {'p99':>6} {'max':>6}  SYNC -> reception, ms"
    )
    for p in m["pdos"]:
        s = p["sync_latency_ms"]
        head = f"0x{p['cob_id']:03X} {p['node_id']:>4} {p['transmission_type']:>4} {p['received']:>8}"
        if not s["count"]:
            lines.append(f"{head} {'':>4}  event-driven")
            continue
        lines.append(
            f"{head} {late.get((p['node_id'], p['cob_id']), 0):>4}  "
            f"{s['min']:>6.3f} {s['mean']:>6.3f} {s['p99']:>6.3f} {s['max']:>6.3f}"
        )
    return "\n".join(lines)


def plot(result: dict[str, Any], path: str) -> None:
    """SYNC-to-reception latency per PDO as a box plot (needs the ``plot`` extra: matplotlib)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise SystemExit("--plot needs matplotlib: pip install 'canstack[plot]'") from None
    items = sorted(result["latencies_ns"].items())
    fig, ax = plt.subplots(figsize=(9, 4))
    ax.boxplot([[v / 1e6 for v in lat] for _, lat in items], whis=(0, 99))
    ax.set_xticks(range(1, len(items) + 1), [f"0x{c:03X}" for c, _ in items], rotation=45)
    ax.set_ylabel("SYNC start of frame -> PDO received (ms)")
    ax.set_title("CANopen network, 1 Mbit/s, SYNC every 1 ms (whiskers: min and p99)")
    fig.tight_layout()
    fig.savefig(path)


def main(argv: list[str] | None = None) -> int:
    """Command line of the example."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=2.0, help="simulated seconds (default 2)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", action="store_true", help="every metric as one JSON object")
    ap.add_argument("--plot", metavar="PNG", help="latency box plot (needs matplotlib)")
    args = ap.parse_args(argv)
    result = run(args.duration, args.seed)
    if args.json:
        print(json.dumps(dict(result, latencies_ns={f"0x{k:03X}": v for k, v in result["latencies_ns"].items()})))
    else:
        print(report(result))
    if args.plot:
        plot(result, args.plot)
    return 0


if __name__ == "__main__":
    sys.exit(main())
