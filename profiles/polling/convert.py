"""A message set of the profiles study (`profiles.sweeps.comparison`) as a master/slave network.

The master polls, every cycle, each message whose period is the set's shortest (the control
loop: a poll command, the slave's answer carries the message); messages with a longer period are
produced by their slaves cyclically on their own (DeviceNet's cyclic connection, not
acknowledged) — polling them every cycle would multiply their load. The cycle is the shortest
period. Identifiers: the set's own for the answers and cyclic messages, the lowest free ones for
the poll commands (custom plan), so the answers keep their priorities.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover
    from profiles.message_set import MessageSet

__all__ = ["express_message_set", "free_ids"]


def free_ids(used: set[int], count: int, *, start: int = 0, step: int = 1) -> list[int]:
    """``count`` standard identifiers from ``start`` up, ``step`` apart, none in ``used``."""
    out: list[int] = []
    i = start
    while len(out) < count:
        if i > 0x7FF:
            raise ValueError(f"not enough free 11-bit identifiers for {count} more frames")
        if all(j not in used for j in range(i, i + step)):
            out.append(i)
        i += step
    return out


def express_message_set(mset: MessageSet) -> dict[str, Any]:
    """The set as a scenario: a master ``master`` and one slave per sending node (see the
    module docstring). A set with a CAN FD message is refused
    (ValueError naming it: the study lists the profile as skipped)."""
    fd = [m.name for m in mset.messages if m.fd]
    if fd:
        raise ValueError(f"CAN FD message {fd[0]!r}: master/slave polling sends classical CAN frames only")
    cycle = min(m.period_ns for m in mset.messages)
    polled = [m for m in mset.messages if m.period_ns == cycle]
    cyclic = [m for m in mset.messages if m.period_ns != cycle]
    requests = free_ids({m.can_id for m in mset.messages}, len(polled))
    poll: list[dict[str, Any]] = []
    for m, rid in zip(polled, requests):
        poll.append(
            {"slave": m.node, "name": f"poll_{m.name}", "id": rid, "response_id": m.can_id, "timeout_ms": cycle / 1e6}
        )
    for node in dict.fromkeys(m.node for m in cyclic):
        poll.append({"style": "cos", "slave": node, "ack": False})
    slaves = []
    for node in mset.nodes:
        msgs = []
        for m in mset.messages:
            if m.node != node:
                continue
            msg: dict[str, Any] = {"name": m.name, "id": m.can_id, "dlc": m.dlc, "deadline_ms": m.deadline_ns / 1e6}
            if m.period_ns != cycle:
                msg["period_ms"] = m.period_ns / 1e6
            msgs.append(msg)
        slaves.append({"name": node, "profile": "slave", "messages": msgs})
    return {
        "bus": {"bitrate": mset.bitrate, "duration": mset.duration_s, "seed": mset.seed},
        "nodes": [
            {
                "name": "master",
                "profile": "master",
                "plan": "custom",
                "cycle_ms": cycle / 1e6,
                "retries": 0,
                "poll": poll,
            }
        ]
        + slaves,
    }
