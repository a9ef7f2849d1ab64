"""Master/slave polling: a master runs a poll list as a cycle and is the only node that starts a
transaction, so its traffic never contends and its cycle is known in advance — DeviceNet's
Predefined Master/Slave Connection Set, many industrial I/O systems, home-grown ECU networks.

Two profiles: ``profile = "master"`` (`profiles.polling.master`: the poll list, timeouts and
retries, lost slaves, cycle overruns, bus off) and ``profile = "slave"``
(`profiles.polling.slave`: answers after its processing delay or from its controller's
remote-reply mailbox, change-of-state / cyclic production, the watchdogs). The identifier plans
are in `profiles.polling.plan` (DeviceNet, checked against its sources, or user-given), the
scenario keys in `profiles.polling.config` (read and checked by `profiles.polling.parse` and
`profiles.polling.entries`), DeviceNet's connection timers (expected packet rate, heartbeat,
watchdogs, acknowledge handler) in `profiles.polling.connection`, its duplicate MAC ID check in
`profiles.polling.dupmac`, its I/O fragmentation in `profiles.polling.fragment`, the analysis —
the cycle's worst case from frame lengths, and the holistic response-time model of a shared bus
— in `profiles.polling.analysis`, the poll-cycle plot in `profiles.polling.plots`, and what the
profiles add to scenario files and results in `profiles.polling.kind`.

Where canstack's policy differs from DeviceNet's Predefined Master/Slave Connection Set:

- A polled or strobed slave is lost to the master after ``lost_after`` missed polls (each with
  ``retries`` repetitions), not when 4 × the connection's EPR pass without its answer; it is then
  polled every ``lost_poll_every`` cycles and taken back by its next answer. DeviceNet's scanner
  drops the connection and opens it again through explicit messages (Allocate_Master/Slave_
  Connection_Set, the EPR set again); explicit messaging is not modelled. A COS/cyclic connection
  does time out at the master after 4 × EPR (`SlaveLost` with ``connection = "cos"``) and comes
  back with its next message.
- A slave whose watchdog expired reports `MasterLost` but keeps answering; DeviceNet's connection
  would stay timed out (watchdog timeout action "transition to timed out") until the master
  allocates it again.
- A polled request is repeated after a timeout (``retries``); DeviceNet polls once per scan.
- The duplicate MAC ID check runs only with ``dup_mac_check = true`` (otherwise I/O starts at
  0 s rather than 2 s); communication fault is left only by a new run.
- Fragmentation covers polled I/O (up to 255 bytes); bit-strobe answers, COS/cyclic messages and
  explicit messages stay single frames.
"""

from profiles.polling.master import Master
from profiles.polling.slave import Slave

__all__ = ["Master", "Slave"]
