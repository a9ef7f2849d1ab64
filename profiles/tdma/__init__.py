"""TDMA: time-triggered CAN in the manner of TTCAN (ISO 11898-4), levels 1 and 2.

Every node with ``profile = "tdma"`` follows one schedule, the ``[tdma]`` table of the scenario:
a reference message from the current time master starts each basic cycle, and every message
has its own time window in a system matrix of 1..64 basic cycles. Potential time masters (up to
8, by priority) take over from each other when a reference message does not come; level 2 adds
the global time and the drift correction. CSMA nodes on the same bus are gated into the
arbitrating windows unless ``tdma_gated = false``.

- `profiles.tdma.schedule` — the schedule (system matrix) and the reference message layout;
- `profiles.tdma.parse` — the ``[tdma]`` table and its checks;
- `profiles.tdma.fse` — a node's frame synchronisation entity (cycle time, sync and master
  states, reference messages, level 2 time unit ratio);
- `profiles.tdma.profile` — the profile on a node (messages in their windows) and the gate of a
  CSMA node;
- `profiles.tdma.monitor` — the schedule as the bus shows it, the ``tdma`` results;
- `profiles.tdma.plots` — the timeline with the windows behind the frames;
- `profiles.tdma.kind` — what it adds to scenario files (``profile = "tdma"``, ``[tdma]``).

Not modelled: gap mode (Next_is_Gap, an event-synchronised cycle), message status counters and
the S1/S2 error levels, external clock synchronisation.
"""

from profiles.tdma.profile import TdmaProfile

__all__ = ["TdmaProfile"]
