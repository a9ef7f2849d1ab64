"""A message set of the profiles study (`profiles.sweeps.comparison`) as a TDMA schedule.

The basic cycle is the set's shortest period; each message gets an exclusive window repeating
every 2^k basic cycles, the largest power of two whose time does not exceed its period (so it is
sent at least as often as the set asks, never less). Windows are packed into columns of the
basic cycle: a message joins a column where its cycles of the matrix are free (another base
cycle), else opens a new one; a column is as long as its longest window (Tx_Enable + the
worst-case frame). A node ``time_master`` sends the reference message (the lowest free
identifier block of 8: its 3 low bits are the master's priority). A set whose columns do not fit
in one basic cycle after the reference message cannot be scheduled this way: ValueError.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from profiles.tdma.schedule import frame_ns_worst

if TYPE_CHECKING:  # pragma: no cover
    from profiles.message_set import MessageSet

__all__ = ["express_message_set"]

TX_ENABLE_BITS = 16
MAX_MATRIX = 64


def express_message_set(mset: MessageSet) -> dict[str, Any]:
    """The set as a TDMA scenario (see the module docstring). Every time is a whole number of NTU
    (level 1: bit times), as the schedule's time marks are. A set with a CAN FD message is refused
    (ValueError naming it: the study lists the profile as skipped)."""
    fd = [m.name for m in mset.messages if m.fd]
    if fd:
        raise ValueError(
            f"CAN FD message {fd[0]!r}: TDMA sends classical CAN frames only (its windows are sized for them)"
        )
    bit_ns = 1e9 / mset.bitrate
    ntu_us = bit_ns / 1000

    def _us_up(ns: float) -> float:
        return _ntus(math.ceil(ns / bit_ns - 1e-9))

    def _ntus(n: int) -> float:
        return round(n * ntu_us, 6)

    cycle_us = _ntus(int(min(m.period_ns for m in mset.messages) // bit_ns))
    tx_enable_us = _ntus(TX_ENABLE_BITS)
    used = {m.can_id for m in mset.messages}
    ref_id = next(i for i in range(0, 0x800, 8) if all(j not in used for j in range(i, i + 8)))
    ref_us = _us_up(frame_ns_worst(1, False, False, bit_ns))
    repeats = {}
    for m in mset.messages:
        r = 1
        while r * 2 <= MAX_MATRIX and r * 2 * cycle_us * 1000 <= m.period_ns:
            r *= 2
        repeats[m.name] = r
    matrix = max(repeats.values())
    columns: list[dict[str, Any]] = []  # {"length": µs, "busy": set of cycles, "windows": [...]}
    for m in sorted(mset.messages, key=lambda m: (repeats[m.name], m.can_id)):
        r = repeats[m.name]
        length = round(tx_enable_us + _us_up(frame_ns_worst(m.dlc, m.extended, False, bit_ns)), 6)
        placed = False
        for col in columns:
            for base in range(r):
                cycles = set(range(base, matrix, r))
                if not cycles & col["busy"]:
                    col["busy"] |= cycles
                    col["length"] = max(col["length"], length)
                    col["windows"].append((m.name, base, r))
                    placed = True
                    break
            if placed:
                break
        if not placed:
            columns.append({"length": length, "busy": set(range(0, matrix, r)), "windows": [(m.name, 0, r)]})
    start = ref_us
    windows = []
    for col in columns:
        for name, base, r in col["windows"]:
            windows.append(
                {
                    "start_us": start,
                    "length_us": col["length"],
                    "kind": "exclusive",
                    "messages": [name],
                    "base_cycle": base,
                    "repeat": r,
                }
            )
        start = round(start + col["length"], 6)
    if start > cycle_us:
        raise ValueError(
            f"the set does not fit a TDMA schedule: its windows need {start:g} µs of a {cycle_us:g} µs "
            f"basic cycle (after a {ref_us} µs reference message)"
        )
    nodes: list[dict[str, Any]] = [{"name": "time_master", "profile": "tdma"}]
    for node in mset.nodes:
        nodes.append(
            {
                "name": node,
                "profile": "tdma",
                "messages": [
                    {"name": m.name, "id": m.can_id, "dlc": m.dlc, "deadline_ms": m.deadline_ns / 1e6}
                    for m in mset.messages
                    if m.node == node
                ],
            }
        )
    return {
        "bus": {"bitrate": mset.bitrate, "duration": mset.duration_s, "seed": mset.seed},
        "nodes": nodes,
        "tdma": {
            "reference_id": ref_id,
            "time_masters": ["time_master"],
            "basic_cycle_us": cycle_us,
            "matrix_cycles": matrix,
            "tx_enable_us": tx_enable_us,
            "level": 1,
            "windows": windows,
        },
    }
