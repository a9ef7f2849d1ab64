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
agree. Every error names the file, the node, the entry and the key, on one line.

The master's frames (requests, acknowledgements) become declared messages of the master node,
named ``poll_SLAVE``, ``strobe_MASTER`` and ``ack_SLAVE`` unless an entry gives ``name``, so the
per-message metrics and the response-time analysis cover them like any other.
"""

from __future__ import annotations

import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import profiles.polling.plan as ids
from profiles.base import frame_of
from profiles.declarations import MessageDecl, ms_to_ns
from profiles.polling.analysis import transaction_bound_ns
from profiles.polling.fragment import MAX_IO_SIZE, fragment
from profiles.schema import (
    REQUIRED,
    Key,
    ScenarioError,
    identifier_rule,
    in_range,
    non_negative,
    non_negative_time,
    one_of,
    positive,
    positive_time,
    read_table,
    where,
)

if TYPE_CHECKING:  # pragma: no cover
    from profiles.declarations import NodeDecl, Scenario

__all__ = [
    "Transaction",
    "CosLink",
    "MasterConfig",
    "SlaveConfig",
    "Network",
    "parse_network",
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
_STYLE_KEYS = {
    "polled": {"slave", "name", "dlc", "data", "id", "extended", "response_id", "timeout_ms", "retries"},
    "remote": {"slave", "name", "extended", "response_id", "timeout_ms", "retries"},
    "bit_strobe": {"slaves", "name", "dlc", "data", "id", "extended", "response_ids", "timeout_ms"},
    "cos": {"slave", "name", "extended", "ack", "ack_id", "epr_ms"},
}
_WHY_NOT = {
    ("bit_strobe", "retries"): "a bit-strobe command is a broadcast: repeating it makes every strobed slave answer "
    "again; a missed strobe response waits for the next cycle",
    ("remote", "dlc"): "a remote frame's DLC is the DLC of the data frame it asks for (the slave's response)",
    ("remote", "data"): "a remote frame carries no data",
    ("remote", "id"): "a remote frame has the identifier of the data frame it asks for (give response_id)",
    ("cos", "timeout_ms"): "the master does not poll a cos slave; it consumes what the slave produces",
    ("cos", "retries"): "the master does not poll a cos slave; it consumes what the slave produces",
}


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


# ---------------------------------------------------------------------------------------------- parsing


def _label(i: int, d: NodeDecl) -> str:
    return f"[[nodes]] #{i} {d.name!r}"


class _Parser:
    """Reads the masters' poll lists and the slaves' messages of one scenario."""

    def __init__(self, scenario: Scenario) -> None:
        self.sc = scenario
        self.src = scenario.source
        self.index = {d.name: i for i, d in enumerate(scenario.nodes, 1)}
        self.names = {m.name: m.node for m in scenario.messages}
        self.keys = {frame_of(m).key: m.name for m in scenario.messages}
        self.owner: dict[str, tuple[str, int]] = {}  # slave -> (master, entry)
        self.net = Network({}, {})

    def loc(self, d: NodeDecl, *more: str) -> str:
        return where(self.src, _label(self.index[d.name], d), *more)

    def err(self, loc: str, text: str) -> ScenarioError:
        return ScenarioError(f"{loc}: {text}")

    # -- nodes
    def run(self) -> Network | None:
        masters = [d for d in self.sc.nodes if d.profile == "master"]
        slaves = [d for d in self.sc.nodes if d.profile == "slave"]
        if not masters and not slaves:
            return None
        for d in slaves:
            self.net.slaves[d.name] = self.slave(d)
        self.check_macs(masters, slaves)
        for d in masters:
            self.net.masters[d.name] = self.master(d)
        for d in slaves:
            if d.name not in self.owner:
                raise self.err(
                    self.loc(d),
                    "no master polls this slave: name it in a master's [[nodes.poll]] "
                    "(slave = ...) — a slave answers one master",
                )
        for d in slaves:
            self.classify(d)
        for d in masters:
            self.check_timeouts(d)
        return self.net

    def slave(self, d: NodeDecl) -> SlaveConfig:
        o = d.options
        hi = ms_to_ns(o["processing_ms"])
        lo = hi if o["processing_min_ms"] is None else ms_to_ns(o["processing_min_ms"])
        if lo > hi:
            raise self.err(
                self.loc(d),
                f"processing_min_ms: {o['processing_min_ms']!r} is above processing_ms {o['processing_ms']!r}",
            )
        for j, m in enumerate(d.messages, 1):
            mloc = self.loc(d, f"[[nodes.messages]] #{j} {m.name!r}")
            if m.remote:
                raise self.err(mloc, "remote: a slave answers with data frames (the master sends the remote frames)")
            self.io_message(m, mloc)
        wd = None if o["watchdog_ms"] is None else ms_to_ns(o["watchdog_ms"])
        return SlaveConfig(
            d.name,
            "",
            o["mac_id"],
            lo,
            hi,
            wd or 0,
            ack_timeout_ns=ms_to_ns(o["ack_timeout_ms"]),
            retry_limit=o["retry_limit"],
            dup_mac=self.dup_mac(d),
        )

    def master(self, d: NodeDecl) -> MasterConfig:
        o = d.options
        if d.messages:
            raise self.err(
                self.loc(d, f"[[nodes.messages]] #1 {d.messages[0].name!r}"),
                "a master sends the requests of its poll list only (declare other traffic on a csma node)",
            )
        cfg = MasterConfig(
            name=d.name,
            mac_id=o["mac_id"],
            plan=o["plan"],
            cycle_ns=ms_to_ns(o["cycle_ms"]),
            offset_ns=ms_to_ns(o["offset_ms"]),
            epr_ns=ms_to_ns(o["epr_ms"] if o["epr_ms"] is not None else o["cycle_ms"]),
            lost_after=o["lost_after"],
            lost_poll_every=o["lost_poll_every"],
            restart_after_bus_off=o["restart_after_bus_off"],
            dup_mac=self.dup_mac(d),
        )
        if cfg.dup_mac is not None and cfg.plan != "devicenet":
            raise self.err(
                self.loc(d), 'dup_mac_check: the duplicate MAC ID check is DeviceNet\'s (plan = "devicenet")'
            )
        strobes = 0
        for j, raw in enumerate(o["poll"], 1):
            loc = self.loc(d, f"[[nodes.poll]] #{j}")
            e = read_table(raw, POLL_KEYS, loc)
            style = e["style"]
            for k in POLL_KEYS:
                if k != "style" and k in raw and k not in _STYLE_KEYS[style]:
                    having = ", ".join(sorted(s for s in STYLES if k in _STYLE_KEYS[s]))
                    why = _WHY_NOT.get((style, k), f"only {having} entries have it")
                    raise self.err(loc, f"{k}: not a key of a {style} entry ({why})")
            if e["extended"] and cfg.plan == "devicenet":
                raise self.err(loc, 'extended: the DeviceNet plan uses 11-bit identifiers (plan = "custom" for others)')
            if style == "cos":
                cfg.cos.append(self.cos_link(d, cfg, j, e, loc))
                continue
            if style == "bit_strobe":
                strobes += 1
                if strobes > 1 and cfg.plan == "devicenet":
                    raise self.err(
                        loc,
                        "a DeviceNet master has one bit-strobe command identifier (0x400 | MAC << 3): "
                        "name every strobed slave in one entry",
                    )
            cfg.transactions.append(self.transaction(d, cfg, j, e, loc))
        for t in cfg.transactions:
            d.messages.append(t.request)
        for c in cfg.cos:
            if c.ack is not None:
                d.messages.append(c.ack)
        return cfg

    def io_message(self, m: MessageDecl, loc: str) -> None:
        """A slave's message of ``size`` above 8 bytes goes in DeviceNet fragments: its frames are 8
        bytes long (dlc 8) and its I/O data (``io_data``, zeros by default) is stored in
        ``m.options['io_data']``; a COS/cyclic message is not fragmented here."""
        size, io = m.options.get("size"), m.options.get("io_data")
        if size is None:
            if io is not None:
                raise self.err(
                    loc, "io_data: only a message of size above 8 bytes (size = ...) has I/O data of its own"
                )
            m.options.pop("io_data", None)
            return
        if m.interval_ns is not None:
            raise self.err(loc, f"size: {size}: canstack fragments polled I/O only (a COS/cyclic message is one frame)")
        if m.dlc != 8:
            raise self.err(loc, f"dlc: {m.dlc}: the fragments of a {size}-byte message are 8-byte frames (dlc = 8)")
        if io is None:
            data = bytes(size)
        else:
            try:
                data = bytes.fromhex(io)
            except ValueError:
                raise self.err(loc, f"io_data: {io!r} is not hex bytes") from None
            if len(data) != size:
                raise self.err(loc, f"io_data: {len(data)} bytes given for size {size}")
        m.options["io_data"] = data
        m.data = fragment(data)[0]

    def dup_mac(self, d: NodeDecl) -> tuple[int, int] | None:
        """(vendor ID, serial number) when the node runs the duplicate MAC ID check; the default
        serial number is the CRC-32 of the node's name, so that two nodes differ."""
        o = d.options
        if not o["dup_mac_check"]:
            for k, unset in (("vendor_id", 0), ("serial_number", None)):
                if o[k] != unset:
                    raise self.err(self.loc(d), f"{k}: only the duplicate MAC ID check sends it (dup_mac_check = true)")
            return None
        if o["mac_id"] is None:
            raise self.err(self.loc(d), "dup_mac_check: the duplicate MAC ID check needs the node's mac_id")
        serial = o["serial_number"] if o["serial_number"] is not None else zlib.crc32(d.name.encode())
        return o["vendor_id"], serial

    # -- entries
    def claim(self, master: NodeDecl, slave: Any, j: int, loc: str, key: str) -> SlaveConfig:
        if not isinstance(slave, str):
            raise self.err(loc, f"{key}: {slave!r} is not a node name")
        if slave not in self.index:
            raise self.err(loc, f"{key}: {slave!r} is not a node of this scenario")
        s = self.net.slaves.get(slave)
        if s is None:
            prof = self.sc.node(slave).profile
            raise self.err(loc, f'{key}: {slave!r} is a {prof} node, not a slave (give it profile = "slave")')
        prev = self.owner.get(slave)
        if prev is not None and prev[0] != master.name:
            raise self.err(
                loc, f"{key}: {slave!r} is already polled by master {prev[0]!r} (a slave answers one master)"
            )
        self.owner[slave] = (master.name, j)
        s.master = master.name
        return s

    def response_of(self, s: SlaveConfig, can_id: int, extended: bool, loc: str, what: str, style: str) -> MessageDecl:
        d = self.sc.node(s.name)
        for m in d.messages:
            if m.can_id == can_id and m.extended == extended and not m.remote:
                if m.interval_ns is not None:
                    raise self.err(
                        loc,
                        f"slave {s.name!r} releases {m.name!r} ({m.id_text}) on its own (period_ms or "
                        f"sporadic_ms): the answer to a poll is released by the poll",
                    )
                if "io_data" in m.options and style != "polled":
                    raise self.err(
                        loc,
                        f"slave {s.name!r} answers with {m.name!r} of size {m.options['size']}: canstack "
                        "fragments polled I/O only (a bit-strobe response or a remote frame's answer is one "
                        "frame of at most 8 bytes)",
                    )
                return m
        ident = f"0x{can_id:08X}" if extended else f"0x{can_id:03X}"
        raise self.err(
            loc,
            f"slave {s.name!r} declares no message with identifier {ident} ({what}): add it to its [[nodes.messages]]",
        )

    def plan_id(self, e: dict[str, Any], key: str, cfg: MasterConfig, wanted: int | None, loc: str, what: str) -> int:
        """The identifier of ``key``: the plan's (DeviceNet) or the one given (custom)."""
        given = e[key]
        if cfg.plan == "devicenet":
            if given is not None and given != wanted:
                raise self.err(
                    loc,
                    f"{key}: 0x{given:X} is not the DeviceNet {what} 0x{wanted:03X} "
                    '(leave it out, or set plan = "custom")',
                )
            if wanted is None:  # the slave has no MAC ID (`mac` refuses that first under DeviceNet)
                raise self.err(loc, f"{key}: the DeviceNet {what} needs the slave's mac_id")
            return wanted
        if given is None:
            raise self.err(loc, f'key {key!r} is required with plan = "custom" ({what})')
        rule = identifier_rule(e["extended"])(given)
        if rule is not None:
            raise self.err(loc, f"{key}: {rule}")
        return given

    def mac(self, s: SlaveConfig, cfg: MasterConfig, loc: str) -> int | None:
        if cfg.plan == "devicenet" and s.mac_id is None:
            raise self.err(loc, f"slave {s.name!r} has no mac_id: the DeviceNet plan derives its identifiers from it")
        return s.mac_id

    def request_payload(
        self, e: dict[str, Any], loc: str, default: bytes, *, fragmented: bool = False
    ) -> tuple[int, bytes, bytes | None]:
        """(DLC, data of the frame, the whole I/O message when it is fragmented) of a request."""
        data = default
        if e["data"] is not None:
            try:
                data = bytes.fromhex(e["data"])
            except ValueError:
                raise self.err(loc, f"data: {e['data']!r} is not hex bytes") from None
            if len(data) > 8 and not fragmented:
                raise self.err(loc, f"data: {len(data)} bytes: a CAN 2.0 frame carries at most 8")
            if len(data) > MAX_IO_SIZE:
                raise self.err(loc, f"data: {len(data)} bytes: canstack takes I/O of at most {MAX_IO_SIZE} bytes")
            if len(data) > 8:
                if e["dlc"] is not None:
                    raise self.err(
                        loc,
                        f"dlc: {len(data)} bytes of data go in DeviceNet fragments of 8-byte frames: leave dlc out",
                    )
                return 8, fragment(data)[0], data
        if e["dlc"] is not None:
            if e["data"] is not None and len(data) != e["dlc"]:
                raise self.err(loc, f"data: {len(data)} byte{'s' if len(data) != 1 else ''} given for dlc {e['dlc']}")
            if e["data"] is None:
                data = (default + bytes(8))[: e["dlc"]]
        return len(data), data, None

    def new_message(
        self,
        d: NodeDecl,
        loc: str,
        name: str,
        can_id: int,
        extended: bool,
        dlc: int,
        data: bytes | None,
        remote: bool,
        **options: Any,
    ) -> MessageDecl:
        if name in self.names:
            raise self.err(
                loc,
                f"name: {name!r} is already a message of node {self.names[name]!r} (message names are "
                "unique in a scenario; give this entry a name)",
            )
        m = MessageDecl(
            name=name,
            node=d.name,
            can_id=can_id,
            extended=extended,
            dlc=dlc,
            data=data,
            remote=remote,
            period_ns=None,
            sporadic_ns=None,
            mean_ns=None,
            offset_ns=0,
            jitter_ns=0,
            deadline_ns=None,
            options=options,
        )
        k = frame_of(m).key
        if k in self.keys:
            raise self.err(
                loc,
                f"the request {m.id_text}{' RTR' if remote else ''} is already sent as message "
                f"{self.keys[k]!r}: two senders of one identifier collide on the bus",
            )
        self.names[name] = d.name
        self.keys[k] = name
        return m

    def timing(self, e: dict[str, Any], d: NodeDecl, loc: str, style: str) -> tuple[int, int]:
        timeout = e["timeout_ms"] if e["timeout_ms"] is not None else d.options["timeout_ms"]
        if timeout is None:
            raise self.err(loc, "key 'timeout_ms' is required (on the entry, or on the master for every entry)")
        retries = 0 if style == "bit_strobe" else (e["retries"] if e["retries"] is not None else d.options["retries"])
        return ms_to_ns(timeout), retries

    def transaction(self, d: NodeDecl, cfg: MasterConfig, j: int, e: dict[str, Any], loc: str) -> Transaction:
        style = e["style"]
        ext = e["extended"]
        if style == "bit_strobe":
            names = e["slaves"]
            if not names or not isinstance(names, list):
                raise self.err(loc, "key 'slaves' is required: the slaves the bit-strobe command names")
            if len(set(map(str, names))) != len(names):
                raise self.err(loc, "slaves: a slave is named twice")
            slaves = [self.claim(d, n, j, loc, "slaves") for n in names]
            macs = [self.mac(s, cfg, loc) for s in slaves]
            if cfg.plan == "devicenet":
                # every strobed slave has a MAC ID here: `mac` refuses one without under DeviceNet
                resp_ids = [ids.bit_strobe_response(m) for m in macs if m is not None]
                if e["response_ids"] is not None and list(e["response_ids"]) != resp_ids:
                    raise self.err(
                        loc,
                        "response_ids: not the DeviceNet bit-strobe responses 0x380 | MAC of the "
                        'slaves (leave it out, or set plan = "custom")',
                    )
            else:
                resp_ids = e["response_ids"]
                if resp_ids is None:
                    raise self.err(
                        loc,
                        "key 'response_ids' is required with plan = \"custom\" (one identifier per "
                        "slave, in the order of slaves)",
                    )
                if len(resp_ids) != len(slaves):
                    raise self.err(loc, f"response_ids: {len(resp_ids)} identifiers for {len(slaves)} slaves")
                for r in resp_ids:
                    rule = (
                        identifier_rule(ext)(r)
                        if isinstance(r, int) and not isinstance(r, bool)
                        else f"{r!r} is not an integer identifier"
                    )
                    if rule is not None:
                        raise self.err(loc, f"response_ids: {rule}")
            req_id = self.plan_id(
                e, "id", cfg, ids.bit_strobe_command(cfg.mac_id), loc, f"bit-strobe command of master MAC {cfg.mac_id}"
            )
            default = (
                ids.strobe_data([m for m in macs if m is not None]) if all(m is not None for m in macs) else bytes(8)
            )
            if e["dlc"] is None and e["data"] is None:
                dlc, data = 8, default
            else:
                dlc, data, _ = self.request_payload(e, loc, default)
            if cfg.plan == "devicenet" and dlc != 8:
                raise self.err(
                    loc, f"dlc: {dlc}: the DeviceNet bit-strobe command carries 8 bytes (64 bits, one per MAC ID)"
                )
            responses = [
                self.response_of(s, r, ext, loc, "its bit-strobe response", style) for s, r in zip(slaves, resp_ids)
            ]
            for s, r in zip(slaves, responses):
                self.answer(s, r, loc, j)
            name = e["name"] or f"strobe_{d.name}"
            req = self.new_message(d, loc, name, req_id, ext, dlc, data, False, poll=j, style=style)
            for s in slaves:
                s.answers[frame_of(req).key] = responses[slaves.index(s)]
                s.requests.add(frame_of(req).key)
                s.polls.add(frame_of(req).key)
            timeout, retries = self.timing(e, d, loc, style)
            return Transaction(j, style, tuple(s.name for s in slaves), req, tuple(responses), timeout, retries)
        if e["slave"] is None:
            raise self.err(loc, f"key 'slave' is required: the slave this {style} entry addresses")
        s = self.claim(d, e["slave"], j, loc, "slave")
        mac = self.mac(s, cfg, loc)
        what = f"poll response of MAC {mac}" if cfg.plan == "devicenet" else "the slave's answer"
        resp_id = self.plan_id(e, "response_id", cfg, None if mac is None else ids.poll_response(mac), loc, what)
        resp = self.response_of(s, resp_id, ext, loc, what, style)
        self.answer(s, resp, loc, j)
        name = e["name"] or f"poll_{s.name}"
        if style == "remote":
            req = self.new_message(d, loc, name, resp.can_id, ext, resp.dlc, None, True, poll=j, style=style)
            s.mailbox.append(resp)
        else:
            req_id = self.plan_id(
                e, "id", cfg, None if mac is None else ids.poll_command(mac), loc, f"poll command of MAC {mac}"
            )
            dlc, data, io = self.request_payload(e, loc, b"", fragmented=True)
            extra = {} if io is None else {"io_data": io}
            req = self.new_message(d, loc, name, req_id, ext, dlc, data, False, poll=j, style=style, **extra)
            s.answers[frame_of(req).key] = resp
        s.requests.add(frame_of(req).key)
        s.polls.add(frame_of(req).key)
        timeout, retries = self.timing(e, d, loc, style)
        return Transaction(j, style, (s.name,), req, (resp,), timeout, retries)

    def answer(self, s: SlaveConfig, m: MessageDecl, loc: str, j: int) -> None:
        for known in list(s.answers.values()) + s.mailbox:
            if known is m:
                raise self.err(
                    loc,
                    f"slave {s.name!r}: message {m.name!r} already answers another entry of the poll "
                    "list (one entry per connection)",
                )

    def cos_link(self, d: NodeDecl, cfg: MasterConfig, j: int, e: dict[str, Any], loc: str) -> CosLink:
        if e["slave"] is None:
            raise self.err(
                loc, "key 'slave' is required: the slave whose change-of-state / cyclic messages the master consumes"
            )
        s = self.claim(d, e["slave"], j, loc, "slave")
        mac = self.mac(s, cfg, loc)
        timed = [m for m in self.sc.node(s.name).messages if m.interval_ns is not None]
        cos_id = None if mac is None else ids.cos_message(mac)  # mac is set under DeviceNet (self.mac)
        if cfg.plan == "devicenet":
            timed = [m for m in timed if m.can_id == cos_id]
        if not timed:
            want = f" 0x{cos_id:03X}" if cfg.plan == "devicenet" and cos_id is not None else ""
            raise self.err(
                loc,
                f"slave {s.name!r} produces no change-of-state / cyclic message{want} (a message with "
                "period_ms or sporadic_ms)",
            )
        ack = None
        if e["ack"]:
            if len(timed) > 1:
                raise self.err(
                    loc,
                    f"ack: slave {s.name!r} produces {len(timed)} COS/cyclic messages; an acknowledged "
                    "connection carries one (or set ack = false)",
                )
            ack_id = self.plan_id(
                e, "ack_id", cfg, None if mac is None else ids.cos_ack(mac), loc, f"COS/cyclic acknowledge of MAC {mac}"
            )
            ack = self.new_message(
                d, loc, e["name"] or f"ack_{s.name}", ack_id, e["extended"], 0, b"", False, poll=j, style="cos"
            )
            s.requests.add(frame_of(ack).key)
            s.acks.add(frame_of(ack).key)
        link = CosLink(j, s.name, tuple(timed), ack, self.eprs(timed, e, loc))
        s.cos_link = link
        return link

    def eprs(self, timed: list[MessageDecl], e: dict[str, Any], loc: str) -> dict[str, int]:
        """Each message's expected packet rate: a cyclic message's period (``epr_ms``, when
        given, must be it), a change-of-state message's ``epr_ms`` (required; its heartbeat, no
        faster than its production inhibit time ``sporadic_ms``)."""
        given = None if e["epr_ms"] is None else ms_to_ns(e["epr_ms"])
        out: dict[str, int] = {}
        for m in timed:
            if m.period_ns is not None:
                if given is not None and given != m.period_ns:
                    raise self.err(
                        loc,
                        f"epr_ms: {e['epr_ms']:g} is not the period of the cyclic message {m.name!r} "
                        f"({m.period_ns / 1e6:g} ms): a cyclic connection's expected packet rate is its period "
                        "(leave epr_ms out)",
                    )
                out[m.name] = m.period_ns
                continue
            pit = m.sporadic_ns or 0
            if given is None:
                raise self.err(
                    loc,
                    f"key 'epr_ms' is required for the change-of-state message {m.name!r}: the connection's "
                    "expected packet rate, at which the slave sends its data when nothing changes (the "
                    f"heartbeat; the watchdogs are {WATCHDOG_EPRS} x it), at least its sporadic_ms "
                    f"{pit / 1e6:g} (the production inhibit time)",
                )
            if given < pit:
                raise self.err(
                    loc,
                    f"epr_ms: {e['epr_ms']:g} is below the production inhibit time of {m.name!r} (its "
                    f"sporadic_ms {pit / 1e6:g}): the heartbeat cannot come sooner than new data may",
                )
            out[m.name] = given
        return out

    # -- checks across nodes
    def check_macs(self, masters: list[NodeDecl], slaves: list[NodeDecl]) -> None:
        """MAC IDs are unique on a DeviceNet network (its identifiers are made from them): among
        the DeviceNet masters and every slave that has one."""
        seen: dict[int, str] = {}
        nodes = [d for d in masters if d.options["plan"] == "devicenet"] + slaves
        for d in sorted(nodes, key=lambda x: self.index[x.name]):
            mac = d.options["mac_id"]
            if mac is None:
                continue
            if mac in seen:
                raise self.err(
                    self.loc(d),
                    f"mac_id: {mac} is already the MAC ID of node {seen[mac]!r} (MAC IDs are "
                    "unique on a DeviceNet network)",
                )
            seen[mac] = d.name

    def classify(self, d: NodeDecl) -> None:
        """Every message of a slave has a role: answers a poll, or is produced on its own (COS/cyclic);
        under DeviceNet its identifier must be the one of that role."""
        s = self.net.slaves[d.name]
        master = self.net.masters[s.master]
        if s.watchdog_ns == 0:
            s.watchdog_ns = WATCHDOG_EPRS * master.epr_ns  # DeviceNet: 4 x the connection's EPR
        answering = {id(m) for m in list(s.answers.values()) + s.mailbox}
        for j, m in enumerate(d.messages, 1):
            loc = self.loc(d, f"[[nodes.messages]] #{j} {m.name!r}")
            timed = m.interval_ns is not None
            if master.plan == "devicenet":
                if m.extended:
                    raise self.err(loc, "extended: the DeviceNet plan uses 11-bit identifiers")
                mac = s.mac_id
                if mac is None:  # its master's entry refused a DeviceNet slave without one (`mac`)
                    raise self.err(self.loc(d), "no mac_id: the DeviceNet plan derives its identifiers from it")
                roles = {
                    ids.poll_response(mac): "poll response",
                    ids.bit_strobe_response(mac): "bit-strobe response",
                    ids.cos_message(mac): "change of state / cyclic",
                }
                role = roles.get(m.can_id)
                if role is None:
                    listed = ", ".join(f"{v} 0x{k:03X}" for k, v in roles.items())
                    raise self.err(
                        loc,
                        f"id: 0x{m.can_id:03X} is not an I/O identifier of MAC ID {mac} in the "
                        f"DeviceNet plan ({listed})",
                    )
                if timed and role != "change of state / cyclic":
                    raise self.err(
                        loc, f"the {role} 0x{m.can_id:03X} is released by the poll: remove period_ms / sporadic_ms"
                    )
                if not timed and role == "change of state / cyclic":
                    raise self.err(
                        loc,
                        f"a change of state / cyclic message (0x{m.can_id:03X}) is produced by the "
                        "slave: give it period_ms (cyclic) or sporadic_ms (change of state)",
                    )
            if timed:
                s.cos.append(m)
            elif id(m) not in answering:
                raise self.err(
                    loc,
                    f"no entry of master {s.master!r} asks for {m.name!r} ({m.id_text}): an untimed "
                    "message of a slave answers a poll (or give it period_ms / sporadic_ms)",
                )

    def check_timeouts(self, d: NodeDecl) -> None:
        """A timeout below the transaction's worst case would declare a slave missing that answers
        in time: refused."""
        cfg = self.net.masters[d.name]
        for t in cfg.transactions:
            bound = transaction_bound_ns(t, self.net.slaves, self.sc.bitrate)
            if t.timeout_ns < bound:
                loc = self.loc(d, f"[[nodes.poll]] #{t.index}")
                raise self.err(
                    loc,
                    f"timeout_ms: {t.timeout_ns / 1e6:g} is below the worst case of this transaction, "
                    f"{float(bound) / 1e6:.4f} ms (frames with worst-case stuffing, the processing "
                    "delay and the inter-frame spaces): a slave that answers in time would time out",
                )


def parse_network(scenario: Scenario, tables: Mapping[str, Any]) -> None:
    """The profile kinds' ``parse`` hook: read and check the masters' poll lists and the slaves'
    connections, add the masters' requests to their declared messages, and store the `Network` in
    ``scenario.tables["master_slave"]`` (nothing when the scenario has no master or slave)."""
    net = _Parser(scenario).run()
    if net is not None:
        scenario.tables[NETWORK_TABLE] = net
