"""The master/slave network of a scenario: the masters' poll lists (DeviceNet calls them scan
lists), each slave's connections, and the frames they use — read from ``[[nodes]]`` tables with
``profile = "master"`` / ``"slave"`` and checked before anything runs.

    [[nodes]]
    name = "scanner"
    profile = "master"
    mac_id = 0                # DeviceNet MAC ID (the bit-strobe command carries it)
    plan = "devicenet"        # devicenet (identifiers from the MAC IDs) | custom (given below)
    cycle_ms = 5              # a cycle starts every 5 ms, or when the previous one ends if later
    timeout_ms = 1            # default response timeout of the entries (request SOF -> response end)
    retries = 1               # default retries after a timeout (polled and remote entries)
    lost_after = 3            # a slave that misses this many polls in a row is lost ...
    lost_poll_every = 10      # ... and polled every 10th cycle until it answers
    dup_mac_check = false     # DeviceNet's duplicate MAC ID check at power-up (masters and slaves):
                              # online after two requests 1 s apart (vendor_id, serial_number)

    [[nodes.poll]]            # polled I/O: poll command -> poll response (a data frame)
    slave = "valve1"
    data = "0102"             # the poll command's output data (default: dlc zero bytes); more than
                              # 8 bytes (up to 255) go in DeviceNet fragments (profiles.polling.fragment)

    [[nodes.poll]]            # remote: a remote frame the slave's controller answers itself
    style = "remote"
    slave = "temp2"

    [[nodes.poll]]            # bit-strobe: one broadcast command, every strobed slave answers
    style = "bit_strobe"
    slaves = ["prox5", "prox6"]

    [[nodes.poll]]            # change of state / cyclic: the slave produces on its own
    style = "cos"
    slave = "door9"
    ack = true                # the master acknowledges each one
    epr_ms = 50               # expected packet rate: the slave's heartbeat when nothing changes

    [[nodes]]
    name = "valve1"
    profile = "slave"
    mac_id = 1
    processing_ms = 0.05      # longest time from the request's end to queuing the answer
    processing_min_ms = 0.02  # shortest (default: processing_ms); drawn uniformly, seeded
    watchdog_ms = 20          # loss of master when not polled for this long (default 4 x epr_ms)
    ack_timeout_ms = 16       # an acknowledged COS/cyclic message is sent again after this ...
    retry_limit = 1           # ... at most this many times (DeviceNet's Acknowledge Handler)

    [[nodes.messages]]        # untimed: released by the poll; timed: COS/cyclic production
    name = "valve1_in"
    id = 0x3C1                # DeviceNet: 0x3C0|MAC poll response, 0x380|MAC strobe response,
    dlc = 4                   #            0x340|MAC change of state / cyclic (timed)
    # size = 12               # a poll response above 8 bytes (9..255): DeviceNet fragments of 8-byte
    # io_data = "a0a1..."     # frames (dlc = 8); its data as hex (default zeros)

Connections (DeviceNet's I/O connections, CIP Vol. 3 ch. 3 and the Connection object's attributes
as device manuals reprint them): every connection has an expected packet rate (EPR, attribute 9)
and each end a watchdog of 4 × EPR over what it consumes. The poll and bit-strobe connections'
EPR is the master's ``epr_ms`` (default: ``cycle_ms``); the slave's watchdog over the requests is
``watchdog_ms`` (default 4 × that EPR). A change-of-state connection's EPR is its entry's
``epr_ms`` (required: the slave sends its data at that rate when nothing changes — the heartbeat —
and never faster than the message's ``sporadic_ms``, its production inhibit time); a cyclic
connection's is its message's period. The master's watchdog over a COS/cyclic connection is 4 ×
its EPR; the slave's over the acknowledgements, when the connection is acknowledged, too.

Under the custom plan an entry names its identifiers: ``id`` (the request; a bit-strobe command),
``response_id`` (polled, remote), ``response_ids`` (bit-strobe, one per slave), ``ack_id`` (cos).
Under DeviceNet these follow from the MAC IDs (`profiles.polling.plan`); given anyway, they must
agree. Every error names the file, the node, the entry and the key, on one line
(`profiles.polling.parse` reads and checks the tables, `profiles.polling.entries` one entry).

The master's frames (requests, acknowledgements) become declared messages of the master node,
named ``poll_SLAVE``, ``strobe_MASTER`` and ``ack_SLAVE`` unless an entry gives ``name``, so the
per-message metrics and the response-time analysis cover them like any other.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import profiles.polling.plan as ids
from profiles.declarations import MessageDecl
from profiles.polling.fragment import MAX_IO_SIZE
from profiles.schema import REQUIRED, Key, in_range, non_negative, non_negative_time, one_of, positive, positive_time

__all__ = [
    "Transaction",
    "CosLink",
    "MasterConfig",
    "SlaveConfig",
    "Network",
    "MASTER_KEYS",
    "SLAVE_KEYS",
    "SLAVE_MESSAGE_KEYS",
    "POLL_KEYS",
    "STYLES",
    "NETWORK_TABLE",
    "WATCHDOG_EPRS",
]

STYLES = ("polled", "remote", "bit_strobe", "cos")
WATCHDOG_EPRS = 4
"""A connection times out after 4 × its expected packet rate without a packet (DeviceNet: the
inactivity/watchdog timer; Rockwell 1769-SDN manual, "Expected Packet Rate")."""
NETWORK_TABLE = "master_slave"
"""Where the parsed network lives in ``scenario.tables``."""

DUP_MAC_KEYS = {
    "dup_mac_check": Key(
        bool, False, doc="DeviceNet's duplicate MAC ID check at power-up: online after two requests 1 s apart"
    ),
    "vendor_id": Key(int, 0, in_range(0, 0xFFFF, "a vendor ID (UINT)"), "the Duplicate MAC ID message's vendor ID"),
    "serial_number": Key(
        int,
        None,
        in_range(0, 0xFFFF_FFFF, "a serial number (UDINT)"),
        "the Duplicate MAC ID message's serial number (default: one made from the node's name)",
    ),
}
MASTER_KEYS = {
    "cycle_ms": Key(float, REQUIRED, positive_time("the poll cycle", "ms"), "the poll cycle, ms"),
    "poll": Key(
        list,
        REQUIRED,
        lambda v: None if v else "a master needs at least one [[nodes.poll]] entry",
        "the poll list: [[nodes.poll]] tables",
    ),
    "mac_id": Key(int, 0, in_range(0, ids.MAC_MAX, "a DeviceNet MAC ID")),
    "plan": Key(str, "devicenet", one_of(*ids.PLANS), "identifier plan: devicenet | custom"),
    "offset_ms": Key(float, 0.0, non_negative_time("", "ms"), "start of the first cycle"),
    "timeout_ms": Key(
        float, None, positive_time("a response timeout", "ms"), "default response timeout of the entries"
    ),
    "retries": Key(int, 1, non_negative("retries"), "default retries after a timeout"),
    "lost_after": Key(int, 3, positive("missed polls"), "missed polls in a row that make a slave lost"),
    "lost_poll_every": Key(int, 10, positive("cycles"), "a lost slave is polled every this many cycles"),
    "restart_after_bus_off": Key(bool, True, doc="resume polling when the controller recovers (rule 12)"),
    **DUP_MAC_KEYS,
    "epr_ms": Key(
        float,
        None,
        positive_time("an expected packet rate", "ms"),
        "expected packet rate of the poll and bit-strobe connections (default: cycle_ms)",
    ),
}


SLAVE_MESSAGE_KEYS = {
    "size": Key(
        int,
        None,
        in_range(9, MAX_IO_SIZE, "bytes of a fragmented I/O message (8 or fewer go in one frame: give dlc)"),
        "a poll response longer than 8 bytes: sent in DeviceNet fragments of 8-byte frames",
    ),
    "io_data": Key(str, None, doc="the fragmented message's data as hex (default zeros)"),
}

SLAVE_KEYS = {
    "mac_id": Key(int, None, in_range(0, ids.MAC_MAX, "a DeviceNet MAC ID")),
    "processing_ms": Key(
        float,
        0.0,
        non_negative_time("a processing delay", "ms"),
        "longest delay from the end of a request to queuing the answer",
    ),
    "processing_min_ms": Key(
        float, None, non_negative_time("a processing delay", "ms"), "shortest delay (default: the longest)"
    ),
    "watchdog_ms": Key(
        float,
        None,
        positive_time("a watchdog time", "ms"),
        "loss of master after this long without a request (default: 4 x the master's epr_ms)",
    ),
    "ack_timeout_ms": Key(
        float,
        16.0,
        positive_time("an acknowledge timer", "ms"),
        "an acknowledged COS/cyclic message unacknowledged this long is sent again (DeviceNet default 16 ms)",
    ),
    "retry_limit": Key(
        int,
        1,
        in_range(0, 255, "retries (the Acknowledge Handler's Retry Limit is a USINT)"),
        "times an unacknowledged COS/cyclic message is sent again (DeviceNet default 1)",
    ),
    **DUP_MAC_KEYS,
}

POLL_KEYS = {
    "style": Key(str, "polled", one_of(*STYLES)),
    "slave": Key(str, None),
    "slaves": Key(list, None),
    "name": Key(str, None, lambda v: None if v else "a message needs a name"),
    "dlc": Key(int, None, in_range(0, 8, "a CAN 2.0 data frame carries 0..8 bytes")),
    "data": Key(str, None, doc="the request's data as hex"),
    "id": Key(int, None, non_negative()),
    "extended": Key(bool, False),
    "response_id": Key(int, None, non_negative()),
    "response_ids": Key(list, None),
    "timeout_ms": Key(float, None, positive_time("a response timeout", "ms")),
    "retries": Key(int, None, non_negative("retries")),
    "ack": Key(bool, True, doc="cos: the master acknowledges each COS/cyclic message"),
    "ack_id": Key(int, None, non_negative()),
    "epr_ms": Key(
        float, None, positive_time("an expected packet rate", "ms"), "cos: the connection's expected packet rate"
    ),
}

# keys that mean something only for some styles (the others refuse them)


@dataclass(frozen=True)
class Transaction:
    """One entry of a master's poll list that runs every cycle: ``style`` polled, remote or
    bit_strobe; the slaves it addresses (one, or every strobed slave), the request the master
    sends, the message each slave answers with (same order), the response timeout (request SOF
    to the end of the response) and the retries after a timeout."""

    index: int
    style: str
    slaves: tuple[str, ...]
    request: MessageDecl
    responses: tuple[MessageDecl, ...]
    timeout_ns: int
    retries: int


@dataclass(frozen=True)
class CosLink:
    """A change-of-state / cyclic connection: the slave produces ``messages`` on its own; the
    master consumes them and acknowledges each with ``ack`` (None: no acknowledgement).
    ``epr_ns`` is each message's expected packet rate (a COS message's heartbeat, a cyclic
    message's period); the master's watchdog over the connection is 4 × the longest."""

    index: int
    slave: str
    messages: tuple[MessageDecl, ...]
    ack: MessageDecl | None
    epr_ns: dict[str, int] = field(default_factory=dict)

    @property
    def watchdog_ns(self) -> int:
        """The consumer's inactivity/watchdog timeout: 4 × the connection's EPR."""
        return WATCHDOG_EPRS * max(self.epr_ns.values(), default=0)


@dataclass
class MasterConfig:
    """A master: its MAC ID and plan, the cycle, its poll list (``transactions`` in order, ``cos``
    links) and what it does with a slave that stops answering."""

    name: str
    mac_id: int
    plan: str
    cycle_ns: int
    offset_ns: int
    epr_ns: int
    lost_after: int
    lost_poll_every: int
    restart_after_bus_off: bool
    transactions: list[Transaction] = field(default_factory=list)
    dup_mac: tuple[int, int] | None = None
    """(vendor ID, serial number) of the duplicate MAC ID check at power-up, None without one."""
    cos: list[CosLink] = field(default_factory=list)

    @property
    def slaves(self) -> list[str]:
        """Every slave of the poll list, in the order the list first names it."""
        out: dict[str, None] = {}
        for t in self.transactions:
            out.update(dict.fromkeys(t.slaves))
        for c in self.cos:
            out[c.slave] = None
        return list(out)


@dataclass
class SlaveConfig:
    """A slave: its master, MAC ID, processing delays and watchdog, and its connections —
    ``answers`` (request arbitration key -> the message it queues after its processing delay),
    ``mailbox`` (messages its controller answers remote frames with), ``cos`` (produced on its
    own), ``polls`` (the keys of its master's requests to it: the poll connection's watchdog,
    ``watchdog_ns``), ``acks`` (the key of the acknowledgement of its COS/cyclic connection) and
    ``requests`` (every key of a frame of its master addressed to it). ``cos_link`` is its
    COS/cyclic connection; an acknowledged one is sent again ``retry_limit`` times after
    ``ack_timeout_ns`` without an acknowledgement."""

    name: str
    master: str
    mac_id: int | None
    processing_min_ns: int
    processing_max_ns: int
    watchdog_ns: int
    ack_timeout_ns: int = 16_000_000
    retry_limit: int = 1
    answers: dict[int, MessageDecl] = field(default_factory=dict)
    mailbox: list[MessageDecl] = field(default_factory=list)
    cos: list[MessageDecl] = field(default_factory=list)
    polls: set[int] = field(default_factory=set)
    acks: set[int] = field(default_factory=set)
    requests: set[int] = field(default_factory=set)
    cos_link: CosLink | None = None
    dup_mac: tuple[int, int] | None = None
    """(vendor ID, serial number) of the duplicate MAC ID check at power-up, None without one."""


@dataclass
class Network:
    """Every master and slave of a scenario; ``cache`` keeps analyses computed from it."""

    masters: dict[str, MasterConfig]
    slaves: dict[str, SlaveConfig]
    cache: dict[Any, Any] = field(default_factory=dict)
