"""A CANopen master (NMT master, SYNC producer, heartbeat consumer) on a `stack` node, sans-IO.

`CanopenMaster(node, nodes=[...], **options)` boots a network the way CiA 302's simplified
boot-up does it:

1. reset communication of every node (NMT 0x82 to node 0), unless ``reset_nodes`` is off;
2. for each boot-up message (0x700 + node-ID, data 00) of a node it manages: configure it by
   SDO — the producer heartbeat time 0x1017 (``heartbeat_ms``), then the writes of
   ``configure`` (an integer is written with the size the node reports for the object on an
   upload first; a string as its ASCII bytes) — and read its TPDO communication parameters
   0x1800..0x1803 sub-indices 1 and 2 (``read_pdo_config``), so that it knows which PDOs are
   synchronous; then start it (NMT 0x01, ``start_nodes``) and monitor its heartbeat
   (consumer time ``heartbeat_consumer_ms``, default 1.5 × ``heartbeat_ms``) or guard it
   (``node_guarding_ms``);
3. when every node is started, or ``boot_timeout_ms`` after `start` at the latest, produce
   SYNC every ``sync_period_us`` (counter with ``sync_overflow``).

A node that boots again later (a reset, a power cycle) is configured and started again.

What it measures (`metrics`): per node the state it reported last, heartbeats received and
missed, timeouts, boots, EMCY received; per PDO the SYNC-to-reception latency — from the start of
frame of the SYNC the master sent (`TxDone.sof`) to the end of the PDO's frame (`Received.time`)
— for the PDOs the node reported as synchronous (types 0..240, 252).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from profiles.canopen import cob
from profiles.canopen._state import NmtCommand, NmtState, state_name
from profiles.canopen.emcy import Emcy, decode_emcy
from profiles.canopen.guarding import GuardedNode, NodeGuardingMaster
from profiles.canopen.heartbeat import HeartbeatConsumer, MonitoredNode
from profiles.canopen.nmt import nmt_command
from profiles.canopen.options import MasterOptions
from profiles.canopen.sdo.client import SdoClient, SdoResult
from profiles.canopen.stats import summary
from profiles.canopen.sync import SyncProducer
from profiles.responses import ResponseStats
from stack import Frame, NodeAPI, NodeError, QueueFull, Received, TxDone, TxRequest

__all__ = ["CanopenMaster", "ManagedNode", "PdoStats", "EVENTS_KEPT"]

EVENTS_KEPT = 1000
"""Events and EMCY messages per node the master keeps (the latest; EMCY are all counted)."""

MS = 1_000_000
US = 1_000


@dataclass
class ManagedNode:
    """The master's record of one node."""

    node_id: int
    status: str = "waiting"  # waiting -> configuring -> started; missing (no boot-up in time)
    boots: int = 0
    boot_time: int | None = None
    start_time: int | None = None
    config_errors: list[str] = field(default_factory=list)
    # the latest EMCY messages received (all counted in emcy_count, their codes in emcy_codes)
    emcy: deque[tuple[int, Emcy]] = field(default_factory=lambda: deque(maxlen=EVENTS_KEPT))
    emcy_count: int = 0
    emcy_codes: set[int] = field(default_factory=set)
    pdo_types: dict[int, int] = field(default_factory=dict)  # TPDO COB-ID -> transmission type


@dataclass
class PdoStats:
    """What the master saw of one PDO."""

    cob_id: int
    node_id: int
    pdo: str
    transmission_type: int | None = None
    received: int = 0
    latencies: ResponseStats = field(default_factory=ResponseStats)  # ns, SYNC SOF -> end of the PDO

    @property
    def synchronous(self) -> bool:
        """Types 0..240 and 252 (unknown types count as synchronous)."""
        tt = self.transmission_type
        return tt is None or tt <= 240 or tt == 252


class CanopenMaster:
    """An NMT master with SYNC producer and heartbeat consumer on ``node`` (see the module
    docstring). Options (`profiles.canopen.options.MasterOptions`): ``nodes`` (node-IDs, required),
    ``sync_period_us``, ``sync_overflow``, ``sync_cob_id``, ``heartbeat_ms``,
    ``heartbeat_consumer_ms``, ``node_guarding_ms``, ``boot_timeout_ms``, ``start_nodes``,
    ``reset_nodes``, ``read_pdo_config``, ``sdo_timeout_ms``, ``configure``
    ({node: {'INDEX:SUB': value}})."""

    def __init__(self, node: NodeAPI, **options: Any) -> None:
        self.node = node
        self.options = o = MasterOptions.parse(options)
        self.nodes = {nid: ManagedNode(nid) for nid in o.nodes}
        self.sdo = {
            nid: SdoClient(self._sdo_sender(nid), node.call_later, timeout_ns=o.sdo_timeout_ms * MS) for nid in o.nodes
        }
        self.consumer = HeartbeatConsumer(
            node.call_at,
            node.now,
            on_timeout=self._heartbeat_lost,
            on_bootup=self._bootup,
            on_resume=self._heartbeat_back,
        )
        self.sync = SyncProducer(self._send, node.call_at, node.now)
        self.sync.configure(o.sync_cob_id, o.sync_period_us * US, o.sync_overflow)
        self.guarding = (
            NodeGuardingMaster(self._send, node.call_at, node.now, o.node_guarding_ms, self._guarding_event)
            if o.node_guarding_ms
            else None
        )
        self.pdos: dict[int, PdoStats] = {}
        # (time, node-ID, what): the latest EVENTS_KEPT, so that a long run stays in bounded memory
        self.events: deque[tuple[int, int, str]] = deque(maxlen=EVENTS_KEPT)
        self.last_sync: int | None = None
        self.sync_sent = 0
        self.tx_refused = 0
        self.running = False
        self._subscription: Any = None
        self._listening = False
        self._deadline: Any = None
        self._boot_callbacks: list[Callable[[ManagedNode], Any]] = []
        self._event_callbacks: list[Callable[[int, str], Any]] = []
        for nid in o.nodes:
            for n, base in enumerate(cob.TPDO, start=1):
                self.pdos[base + nid] = PdoStats(base + nid, nid, f"TPDO{n}")
        if o.heartbeat_consumer_ms:
            self.consumer.configure([(nid, o.heartbeat_consumer_ms) for nid in o.nodes])
        else:  # still learn states and boot-ups from 0x700 + node-ID
            self.consumer.observe(o.nodes)

    # ------------------------------------------------------------------ life cycle
    def start(self) -> CanopenMaster:
        """Subscribe, reset the nodes, wait for their boot-up messages (see the module docstring)."""
        if self.running:
            return self
        self.running = True
        self._subscription = self.node.subscribe(self._on_frame)
        if not self._listening:
            self.node.listen(TxDone, self._on_tx_done)
            self._listening = True
        if self.options.reset_nodes:
            self.nmt(NmtCommand.RESET_COMMUNICATION, 0)
        self._deadline = self.node.call_later(int(self.options.boot_timeout_ms * MS), self._boot_deadline)
        return self

    def stop(self) -> None:
        """Stop producing SYNC, monitoring and configuring (the nodes keep their state)."""
        if not self.running:
            return
        self.running = False
        self.sync.stop()
        self.consumer.stop()
        if self.guarding is not None:
            self.guarding.stop()
        for c in self.sdo.values():
            c.cancel_all()
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None
        if self._subscription is not None:
            self._subscription.unsubscribe()
            self._subscription = None

    def nmt(self, command: int, node_id: int = 0) -> TxRequest | None:
        """Send an NMT command (CiA 301 7.2.8.3.1) to ``node_id`` (0: all nodes)."""
        return self._send(nmt_command(command, node_id))

    def on_boot(self, callback: Callable[[ManagedNode], Any]) -> None:
        """Call ``callback(node)`` when a node has been configured and started."""
        self._boot_callbacks.append(callback)

    def on_event(self, callback: Callable[[int, str], Any]) -> None:
        """Call ``callback(node_id, what)`` on error control events ('heartbeat lost',
        'heartbeat back', 'boot-up', 'guarding: no reply', 'guarding: toggle', 'emcy 0xXXXX')."""
        self._event_callbacks.append(callback)

    # ------------------------------------------------------------------ boot
    def _bootup(self, m: MonitoredNode) -> None:
        rec = self.nodes[m.node_id]
        now = self.node.now()
        rec.boots += 1
        rec.boot_time = now
        rec.status = "configuring"
        self._event(m.node_id, "boot-up")
        g = self.guarding.nodes.get(m.node_id) if self.guarding is not None else None
        if g is not None:
            g.expect_toggle = 0  # a booted node starts its toggle bit at 0 again
            g.waiting = False
        client = self.sdo[m.node_id]
        client.cancel_all()
        steps: list[Callable[[Callable[[], None]], None]] = []
        if self.options.heartbeat_ms:
            steps.append(self._write_step(m.node_id, 0x1017, 0, self.options.heartbeat_ms.to_bytes(2, "little")))
        for (index, sub), value in self.options.configure.get(m.node_id, {}).items():
            steps.append(self._configure_step(m.node_id, index, sub, value))
        if self.options.read_pdo_config:
            for n in range(4):
                steps.append(self._read_pdo_step(m.node_id, n))
        self._run_steps(m.node_id, steps, rec.boots)

    def _run_steps(self, nid: int, steps: list[Callable[[Callable[[], None]], None]], boot: int) -> None:
        rec = self.nodes[nid]
        if rec.boots != boot:
            return  # the node booted again meanwhile: that boot's sequence runs
        if steps:
            step = steps.pop(0)
            step(lambda: self._run_steps(nid, steps, boot))
            return
        if self.options.start_nodes:
            self.nmt(NmtCommand.START, nid)
        rec.status = "started"
        rec.start_time = self.node.now()
        if self.guarding is not None:
            self.guarding.guard(nid)
        for cb in self._boot_callbacks:
            cb(rec)
        if all(r.status == "started" for r in self.nodes.values()):
            self._start_sync()

    def _write_step(self, nid: int, index: int, sub: int, data: bytes) -> Callable[[Callable[[], None]], None]:
        def step(then: Callable[[], None]) -> None:
            def done(res: SdoResult) -> None:
                if not res.ok:
                    self.nodes[nid].config_errors.append(str(res))
                then()

            self.sdo[nid].download(index, sub, data, done)

        return step

    def _configure_step(self, nid: int, index: int, sub: int, value: Any) -> Callable[[Callable[[], None]], None]:
        if isinstance(value, str):
            return self._write_step(nid, index, sub, value.encode("ascii"))

        def step(then: Callable[[], None]) -> None:
            def sized(res: SdoResult) -> None:
                if not res.ok or res.data is None:
                    self.nodes[nid].config_errors.append(str(res))
                    then()
                    return
                size = len(res.data)
                try:
                    data = int(value).to_bytes(size, "little", signed=int(value) < 0)
                except OverflowError:
                    self.nodes[nid].config_errors.append(f"0x{index:04X}:{sub}: {value} does not fit {size} bytes")
                    then()
                    return
                self._write_step(nid, index, sub, data)(then)

            self.sdo[nid].upload(index, sub, sized)

        return step

    def _read_pdo_step(self, nid: int, n: int) -> Callable[[Callable[[], None]], None]:
        def step(then: Callable[[], None]) -> None:
            def got_cob(res: SdoResult) -> None:
                if not res.ok or res.data is None:
                    then()  # no such TPDO (0x0602 0000): fine
                    return
                word = res.value
                if word & 0x8000_0000:
                    then()
                    return
                can_id = word & 0x7FF

                def got_type(res2: SdoResult) -> None:
                    if res2.ok and res2.data:
                        self.nodes[nid].pdo_types[can_id] = res2.value
                        st = self.pdos.get(can_id)
                        if st is None:
                            st = self.pdos[can_id] = PdoStats(can_id, nid, f"TPDO{n + 1}")
                        st.transmission_type = res2.value
                    then()

                self.sdo[nid].upload(0x1800 + n, 2, got_type)

            self.sdo[nid].upload(0x1800 + n, 1, got_cob)

        return step

    def _boot_deadline(self) -> None:
        self._deadline = None
        for rec in self.nodes.values():
            if rec.status == "waiting":
                rec.status = "missing"
                self._event(rec.node_id, "no boot-up")
        self._start_sync()

    def _start_sync(self) -> None:
        if self.options.sync_period_us and not self.sync.running and self.running:
            self.sync.start()
        if self._deadline is not None and all(r.status == "started" for r in self.nodes.values()):
            self._deadline.cancel()
            self._deadline = None

    # ------------------------------------------------------------------ frames
    def _on_frame(self, ev: Received) -> None:
        f = ev.frame
        if f.extended or f.remote:
            return
        can_id = f.can_id
        fc, nid = can_id & 0x780, can_id & 0x7F
        if nid in self.nodes:
            if fc == cob.HEARTBEAT:
                guarding = self.guarding
                g = None if guarding is None else guarding.nodes.get(nid)
                if guarding is not None and g is not None and g.waiting and f.data != b"\x00":  # 00: a boot-up
                    guarding.on_reply(nid, f.data)
                else:
                    self.consumer.on_heartbeat(nid, f.data, ev.time)
                return
            if fc == cob.SDO_TX:
                self.sdo[nid].on_response(f.data)
                return
            if fc == cob.EMCY and can_id != self.sync.cob_id:
                e = decode_emcy(f.data)
                rec = self.nodes[nid]
                rec.emcy.append((ev.time, e))
                rec.emcy_count += 1
                rec.emcy_codes.add(e.code)
                self._event(nid, f"emcy 0x{e.code:04X}")
                return
        st = self.pdos.get(can_id)
        if st is not None:
            st.received += 1
            if self.last_sync is not None and st.synchronous:
                st.latencies.add(ev.time - self.last_sync)

    def _on_tx_done(self, ev: TxDone) -> None:
        if ev.frame.can_id == self.sync.cob_id and not ev.frame.remote:
            self.last_sync = ev.sof if ev.sof >= 0 else ev.time
            self.sync_sent += 1

    def _send(self, frame: Frame) -> TxRequest | None:
        try:
            return self.node.send(frame)
        except (QueueFull, NodeError):
            self.tx_refused += 1
            return None

    def _sdo_sender(self, nid: int) -> Callable[[bytes], Any]:
        return lambda data: self._send(Frame(cob.SDO_RX + nid, data))

    # ------------------------------------------------------------------ error control
    def _heartbeat_lost(self, m: MonitoredNode) -> None:
        self._event(m.node_id, "heartbeat lost")

    def _heartbeat_back(self, m: MonitoredNode) -> None:
        self._event(m.node_id, "heartbeat back")

    def _guarding_event(self, g: GuardedNode, what: str) -> None:
        self._event(g.node_id, f"guarding: {what}")

    def _event(self, nid: int, what: str) -> None:
        self.events.append((self.node.now(), nid, what))
        for cb in self._event_callbacks:
            cb(nid, what)

    # ------------------------------------------------------------------ results
    def node_state(self, node_id: int) -> str:
        """The node's NMT state as the master knows it: from its last heartbeat (or guarding
        reply); 'UNKNOWN' before one and after a heartbeat timeout."""
        m = self.consumer.nodes.get(node_id)
        g = self.guarding.nodes.get(node_id) if self.guarding is not None else None
        if g is not None and g.state is not None:
            return "UNKNOWN" if g.waiting and g.missed else g.state_name
        if m is None or m.state is None or m.status == "timeout":
            return "UNKNOWN"
        return m.state_name if m.state != NmtState.INITIALISING else state_name(NmtState.INITIALISING)

    def metrics(self) -> dict[str, Any]:
        """JSON-ready figures: per node the state, heartbeats, boots, EMCY; per PDO the
        SYNC-to-reception latency (ms); SYNC and SDO counters."""
        nodes = []
        for nid, rec in self.nodes.items():
            m = self.consumer.nodes.get(nid)
            g = self.guarding.nodes.get(nid) if self.guarding is not None else None
            item: dict[str, Any] = {
                "node_id": nid,
                "status": rec.status,
                "nmt_state": self.node_state(nid),
                "last_state": m.state_name if m is not None else "UNKNOWN",
                "boots": rec.boots,
                "heartbeats_received": m.received if m else 0,
                "heartbeats_missed": m.missed if m and self.options.heartbeat_consumer_ms else 0,
                "heartbeat_timeouts": m.timeouts if m and self.options.heartbeat_consumer_ms else 0,
                "emcy_received": rec.emcy_count,
                "emcy_codes": sorted(rec.emcy_codes),
                "config_errors": list(rec.config_errors),
            }
            if g is not None:
                item["guarding"] = {
                    "requests": g.requests,
                    "replies": g.replies,
                    "missed": g.missed,
                    "toggle_errors": g.toggle_errors,
                }
            nodes.append(item)
        pdos = [
            {
                "cob_id": st.cob_id,
                "node_id": st.node_id,
                "pdo": st.pdo,
                "transmission_type": st.transmission_type,
                "received": st.received,
                "sync_latency_ms": summary(st.latencies),
            }
            for st in sorted(self.pdos.values(), key=lambda s: s.cob_id)
            if st.received
        ]
        return {
            "profile": "canopen-master",
            "node": self.node.name,
            "sync": {"period_us": self.options.sync_period_us, "sent": self.sync_sent},
            "nodes": nodes,
            "pdos": pdos,
            "sdo": {
                "completed": sum(c.completed for c in self.sdo.values()),
                "aborted": sum(c.aborted for c in self.sdo.values()),
                "timeouts": sum(c.timeouts for c in self.sdo.values()),
            },
            "events": [{"t_ms": round(t / MS, 6), "node_id": nid, "event": what} for t, nid, what in self.events],
        }
