"""Master/slave polling: a master runs a poll list as a cycle and is the only node that starts a
transaction, so its traffic never contends and its cycle is known in advance — DeviceNet's
Predefined Master/Slave Connection Set, many industrial I/O systems, home-grown ECU networks.

Two profiles: ``profile = "master"`` (`profiles.polling.master`: the poll list, timeouts and
retries, lost slaves, cycle overruns, bus off) and ``profile = "slave"``
(`profiles.polling.slave`: answers after its processing delay or from its controller's
remote-reply mailbox, change-of-state / cyclic production, the watchdog). The identifier plans
are in `profiles.polling.plan` (DeviceNet, checked against its sources, or user-given), the
scenario keys in `profiles.polling.config`, the analysis — the cycle's worst case from frame
lengths, and the holistic response-time model of a shared bus — in
`profiles.polling.analysis`, the poll-cycle plot in `profiles.polling.plots`, and what the
profiles add to scenario files and results in `profiles.polling.kind`.
"""

from profiles.polling.master import Master
from profiles.polling.slave import Slave

__all__ = ["Master", "Slave"]
