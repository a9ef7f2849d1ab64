"""The CANopen section of `canstack experiment`'s text: every figure the JSON ``canopen`` object
holds, as tables (the shared helpers of `profiles.text`: columns as wide as their widest cell,
identifiers as ``0x181``).

Per device: NMT state (and the state its master saw), boot-ups and resets, heartbeats; SYNC
and EMCY counters, the error register and the active error codes; the SDO server's counts per
transfer kind; each TPDO (queued, sent, not in the synchronous window, refused, SYNC-to-transmit
latency, mapping) and RPDO; its heartbeat consumer; its communication errors. Per master: SYNC
sent, SDO transfers, per node what it saw (status, boots, heartbeats, EMCY, configuration
errors, node guarding), per PDO the SYNC-to-reception latency, and its events (boot-ups, EMCY
codes, heartbeats lost and back) counted per node and kind with the first and last time.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from profiles.text import id_text, table

__all__ = ["canopen_lines", "latency_text", "codes_text", "SDO_KINDS"]

SDO_KINDS = (
    ("expedited download", "exp down"),
    ("expedited upload", "exp up"),
    ("segmented download", "seg down"),
    ("segmented upload", "seg up"),
    ("block download", "block down"),
    ("block upload", "block up"),
)
"""The SDO transfer kinds a device counts (CiA 301 7.2.4.3), with their column headers."""

COMM_ERRORS_SHOWN = 10
"""Communication errors listed per device; the rest are counted (the JSON keeps them all)."""


def latency_text(s: dict[str, Any] | None) -> str:
    """A latency summary as ``min/mean/p99/max`` in ms (3 decimals), the p99 marked ``~`` when
    it comes from the sketch rather than every sample; ``-`` without samples."""
    if not s or not s.get("count"):
        return "-"
    p99 = f"{s['p99']:.3f}" + ("~" if s.get("p99_error") else "")
    return f"{s['min']:.3f}/{s['mean']:.3f}/{p99}/{s['max']:.3f}"


def codes_text(codes: Sequence[int]) -> str:
    """Error codes (CiA 301 EMCY) as ``0x8100,0x0000``; ``-`` for none."""
    return ",".join(f"0x{c:04X}" for c in codes) or "-"


def _yes(v: bool) -> str:
    return "yes" if v else "no"


def _device_lines(devices: list[dict[str, Any]], masters: list[dict[str, Any]]) -> list[str]:
    seen = {n["node_id"]: n for m in masters for n in m["nodes"]}
    rows = []
    for f in devices:
        m = seen.get(f["node_id"])
        rows.append(
            [
                f["node"],
                f["node_id"],
                f["nmt_state"],
                m["nmt_state"] if m else "-",
                f["boot_ups"],
                f["resets"].get("application", 0),
                f["resets"].get("communication", 0),
                f["heartbeat_ms"],
                f["heartbeats_sent"],
                m["heartbeats_missed"] if m else "-",
            ]
        )
    lines = table(
        [
            "CANopen node",
            "id",
            "NMT state",
            "as the master saw it",
            "boot-ups",
            "app resets",
            "comm resets",
            "heartbeat ms",
            "heartbeats sent",
            "missed",
        ],
        rows,
        left={0, 2, 3},
        widest={0: 16},
    )
    rows = [
        [
            f["node"],
            f["sync_received"],
            f["sync_timeouts"],
            f["sync_length_errors"],
            f["emcy_sent"],
            f"0x{f['error_register']:02X}",
            codes_text(f["errors_active"]),
            f["tx_refused"],
            len(f["communication_errors"]),
        ]
        for f in devices
    ]
    lines.append("")
    lines += table(
        [
            "CANopen node",
            "SYNC received",
            "SYNC timeouts",
            "SYNC length errors",
            "EMCY sent",
            "error register",
            "errors active",
            "tx refused",
            "communication errors",
        ],
        rows,
        widest={0: 16},
    )
    rows = [
        [
            f["node"],
            f["sdo"]["requests"],
            f["sdo"]["aborts_sent"],
            f["sdo"]["aborts_received"],
            *(f["sdo"]["completed"].get(k, 0) for k, _ in SDO_KINDS),
        ]
        for f in devices
    ]
    lines.append("")
    lines += table(
        ["SDO server", "requests", "aborts sent", "aborts received", *(h for _, h in SDO_KINDS)],
        rows,
        widest={0: 16},
    )
    rows = [
        [
            tp["pdo"],
            f["node"],
            id_text(tp["cob_id"], False),
            _yes(tp["valid"]),
            tp["transmission_type"],
            tp["queued"],
            tp["sent"],
            tp["not_in_window"],
            tp["refused"],
            (tp["sync_to_tx_ms"] or {}).get("count", 0),
            latency_text(tp["sync_to_tx_ms"]),
            " ".join(tp["mapping"]) or "-",
        ]
        for f in devices
        for tp in f["tpdos"]
    ]
    if rows:
        lines.append("")
        lines += table(
            [
                "TPDO",
                "node",
                "COB-ID",
                "valid",
                "type",
                "queued",
                "sent",
                "not in window",
                "refused",
                "samples",
                "SYNC->tx min/mean/p99/max (ms)",
                "mapping",
            ],
            rows,
            left={0, 1, 11},
            widest={1: 16},
        )
    rows = [
        [
            rp["pdo"],
            f["node"],
            id_text(rp["cob_id"], False),
            _yes(rp["valid"]),
            rp["transmission_type"],
            rp["received"],
            rp["applied"],
            rp["length_errors"],
            rp["timeouts"],
            " ".join(rp["mapping"]) or "-",
        ]
        for f in devices
        for rp in f["rpdos"]
    ]
    if rows:
        lines.append("")
        lines += table(
            ["RPDO", "node", "COB-ID", "valid", "type", "received", "applied", "length errors", "timeouts", "mapping"],
            rows,
            left={0, 1, 9},
            widest={1: 16},
        )
    rows = [
        [f["node"], c["node_id"], c["status"], c["nmt_state"], c["received"], c["missed"], c["timeouts"]]
        for f in devices
        for c in f["heartbeat_consumer"]
    ]
    if rows:
        lines.append("")
        lines += table(
            ["heartbeat consumer", "of node", "status", "NMT state", "received", "missed", "timeouts"],
            rows,
            left={0, 2, 3},
            widest={0: 16},
        )
    for f in devices:
        errs = f["communication_errors"]
        lines += [""] if errs else []
        for t, what in errs[:COMM_ERRORS_SHOWN]:
            lines.append(f"{f['node']}: communication error at {t:.3f} ms: {what}")
        if len(errs) > COMM_ERRORS_SHOWN:
            lines.append(f"{f['node']}: (+{len(errs) - COMM_ERRORS_SHOWN} more communication errors: see --json)")
    return lines


def _master_lines(m: dict[str, Any], names: dict[int, str]) -> list[str]:
    sdo = m["sdo"]
    lines = [
        "",
        f"master {m['node']}: SYNC every {m['sync']['period_us']} us, {m['sync']['sent']} sent; "
        f"SDO {sdo['completed']} completed, {sdo['aborted']} aborted, {sdo['timeouts']} timeouts",
    ]
    guarded = any("guarding" in n for n in m["nodes"])
    rows = []
    for n in m["nodes"]:
        g = n.get("guarding")
        rows.append(
            [
                names.get(n["node_id"], "-"),
                n["node_id"],
                n["status"],
                n["nmt_state"],
                n["last_state"],
                n["boots"],
                n["heartbeats_received"],
                n["heartbeats_missed"],
                n["heartbeat_timeouts"],
                n["emcy_received"],
                codes_text(n["emcy_codes"]),
                "; ".join(n["config_errors"]) or "-",
                *([g["requests"], g["replies"], g["missed"], g["toggle_errors"]] if g else ["-"] * 4)[: 4 * guarded],
            ]
        )
    lines.append("")
    lines += table(
        [
            f"node (master {m['node']})",
            "id",
            "status",
            "NMT state",
            "last heartbeat",
            "boots",
            "heartbeats",
            "missed",
            "timeouts",
            "EMCY",
            "EMCY codes",
            "configuration errors",
            *(["guarding requests", "replies", "missed", "toggle errors"] if guarded else []),
        ],
        rows,
        left={0, 2, 3, 4, 10, 11},
        widest={0: 24},
    )
    prow = [
        [
            p["pdo"],
            names.get(p["node_id"], "-"),
            id_text(p["cob_id"], False),
            p["transmission_type"],
            p["received"],
            (p["sync_latency_ms"] or {}).get("count", 0),
            latency_text(p["sync_latency_ms"]),
        ]
        for p in m["pdos"]
    ]
    if prow:
        lines.append("")
        lines += table(
            [
                f"PDO (master {m['node']})",
                "node",
                "COB-ID",
                "type",
                "received",
                "samples",
                "SYNC->end min/mean/p99/max (ms)",
            ],
            prow,
            left=2,
        )
    kinds: dict[tuple[int, str], list[float]] = {}
    for e in m["events"]:
        kinds.setdefault((e["node_id"], e["event"]), []).append(e["t_ms"])
    erow = [
        [what, names.get(nid, "-"), nid, len(ts), f"{min(ts):.3f}", f"{max(ts):.3f}"]
        for (nid, what), ts in sorted(kinds.items(), key=lambda kv: (min(kv[1]), kv[0]))
    ]
    if erow:
        lines.append("")
        lines += table(
            [f"event (master {m['node']})", "node", "id", "count", "first (ms)", "last (ms)"],
            erow,
            left=2,
        )
    return lines


def canopen_lines(figures: dict[str, Any]) -> list[str]:
    """The CANopen section of the text output: the devices' tables, then each master's (see the
    module docstring for what each holds)."""
    devices = [f for f in figures.values() if f.get("profile") == "canopen"]
    masters = [f for f in figures.values() if f.get("profile") == "canopen-master"]
    names = {f["node_id"]: f["node"] for f in devices}
    lines = _device_lines(devices, masters) if devices else []
    for m in masters:
        lines += _master_lines(m, names)
    return lines
