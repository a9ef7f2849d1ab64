"""Native CSMA/CR: plain CAN arbitration, each node's frames in its controller's queue order.

- `profiles.csma.profile` — the profile on a node (`CsmaProfile`), the gate a time-triggered
  schedule may put on it, its messages as the response-time analysis models them;
- `profiles.csma.kind` — what it adds to scenario files (``profile = "csma"``).
"""

from profiles.csma.profile import CsmaProfile, Gate, message_specs

__all__ = ["CsmaProfile", "Gate", "message_specs"]
