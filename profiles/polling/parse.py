"""Reading the master/slave network of a scenario (the keys are in `profiles.polling.config`):
the slaves' messages, the masters' poll lists entry by entry, then the checks across nodes —
unique MAC IDs, a master for every slave, a role for every message of a slave, no response
timeout below its transaction's worst case. The checks of one entry alone are in
`profiles.polling.entries`."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import profiles.polling.plan as ids
from profiles.base import frame_of
from profiles.declarations import MessageDecl, ms_to_ns
from profiles.polling.analysis import transaction_bound_ns
from profiles.polling.config import (
    NETWORK_TABLE,
    POLL_KEYS,
    WATCHDOG_EPRS,
    CosLink,
    MasterConfig,
    Network,
    SlaveConfig,
    Transaction,
)
from profiles.polling.entries import check_entry_keys, dup_mac, eprs, io_message, request_payload, timing
from profiles.schema import ScenarioError, identifier_rule, read_table, where

if TYPE_CHECKING:  # pragma: no cover
    from profiles.declarations import NodeDecl, Scenario

__all__ = ["parse_network"]


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
            io_message(m, mloc)
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
            dup_mac=dup_mac(d, self.loc(d)),
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
            dup_mac=dup_mac(d, self.loc(d)),
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
            check_entry_keys(raw, style, loc)
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
                dlc, data, _ = request_payload(e, loc, default)
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
            timeout, retries = timing(e, d, loc, style)
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
            dlc, data, io = request_payload(e, loc, b"", fragmented=True)
            extra = {} if io is None else {"io_data": io}
            req = self.new_message(d, loc, name, req_id, ext, dlc, data, False, poll=j, style=style, **extra)
            s.answers[frame_of(req).key] = resp
        s.requests.add(frame_of(req).key)
        s.polls.add(frame_of(req).key)
        timeout, retries = timing(e, d, loc, style)
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
        link = CosLink(j, s.name, tuple(timed), ack, eprs(timed, e, loc))
        s.cos_link = link
        return link

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
