"""A CANopen device (NMT slave) on a `stack` node, with CANopenNode's behaviour, sans-IO.

`CanopenDevice(node, node_id, eds=None, **options)` puts the object dictionary of an EDS/DCF
(or the small default device) on a node and runs every CiA 301 service of a slave on it: the
NMT state machine with boot-up, heartbeat producer and consumer, node guarding, SYNC consumer
(and producer), TPDOs of every transmission type, RPDOs, the SDO server with block transfer,
EMCY and TIME. It acts only through the node API (send, subscribe/listen, timers, now), so it
runs unchanged on the simulated bus and on any python-can bus through `stack.PyCanDriver`.

A communication error — a heartbeat consumer timeout, a life guarding event, bus off — makes the
device change its NMT state as object 0x1029 sub-index 1 (error behaviour, communication error)
asks (CiA 301 7.5.2.32): 0x00 pre-operational, only from operational; 0x01 no change; 0x02
stopped (from operational or pre-operational). Without the object the state does not change.
(CANopenNode acts only in operational, and also on a heartbeat consumer's "remote reset"; CiA 301
counts only the errors named here.) Recovery from bus off is reported with EMCY 0x8140 and its
error reset, as CANopenNode does once the controller can send again.

What the services do, and which CiA 301 numbers they keep, is in their modules: `nmt`,
`heartbeat`, `guarding`, `sync`, `pdo.tpdo`, `pdo.rpdo`, `sdo.server`, `emcy`, `timestamp`;
the dictionary and its access rules are `dictionary`'s; the options are `options`'s.
"""

from __future__ import annotations

import os
from collections import deque
from collections.abc import Callable
from functools import partial
from typing import Any, NamedTuple

from profiles.canopen import cob
from profiles.canopen._state import NmtState, ResetKind, allows
from profiles.canopen.dictionary import COMMUNICATION_AREA, EdsError, ObjectStore, load_od
from profiles.canopen.emcy import EmcyProducer
from profiles.canopen.guarding import NodeGuardingSlave
from profiles.canopen.heartbeat import (
    HeartbeatConsumer,
    HeartbeatProducer,
    MonitoredNode,
    check_consumer_entry,
    parse_consumer_entry,
)
from profiles.canopen.nmt import NmtSlave
from profiles.canopen.options import DeviceOptions, apply_device_options
from profiles.canopen.pdo.common import Pdo
from profiles.canopen.pdo.rpdo import Rpdo
from profiles.canopen.pdo.tpdo import Tpdo
from profiles.canopen.sdo.server import SdoServer
from profiles.canopen.stats import summary
from profiles.canopen.sync import SyncConsumer, SyncProducer, check_cob_id_sync, check_counter_overflow
from profiles.canopen.timestamp import EPOCH_1984, TimeProducer, check_cob_id_time, decode_time_of_day
from stack import (
    ErrorStateChanged,
    Frame,
    NodeAPI,
    NodeError,
    QueueFull,
    Received,
    TxDone,
    TxFailed,
    TxRequest,
)

__all__ = ["CanopenDevice", "RpdoUpdate"]

MS = 1_000_000
SYNC_ERROR = 0x8100
HEARTBEAT_ERROR = 0x8130
BUS_OFF_RECOVERED = 0x8140
ERROR_BEHAVIOUR = 0x1029
"""Error behaviour: sub-index 1 is the communication error's (CiA 301 7.5.2.32)."""
TO_PRE_OPERATIONAL, NO_CHANGE, TO_STOPPED = 0x00, 0x01, 0x02
SYNC_LENGTH_ERROR = 0x8240
PDO_MAPPING_ERROR = 0x8200


class RpdoUpdate(NamedTuple):
    """What an RPDO wrote: the PDO's number and COB-ID, the objects with their new values, the
    time (node clock) it took effect."""

    n: int
    cob_id: int
    values: dict[tuple[int, int], Any]
    time: int


class CanopenDevice:
    """A CiA 301 device (NMT slave) on ``node`` with node-ID ``node_id`` (1..127).

    ``eds`` is an EDS/DCF path (None: the default device shipped with the package, see
    `profiles.canopen.dictionary.DEFAULT_EDS`). Options (`profiles.canopen.options.DeviceOptions`)
    set objects before boot-up as a DCF would: ``heartbeat_ms`` (0x1017),
    ``heartbeat_consumers`` ({node: ms}, 0x1016), ``guard_time_ms``/``life_time_factor``
    (0x100C/0x100D), ``sync_period_us`` (0x1006), ``sync_window_us`` (0x1007),
    ``sync_producer`` (0x1005 bit 30), ``sync_overflow`` (0x1019), ``emcy_inhibit_100us``
    (0x1015), ``tpdo``/``rpdo`` ({n: {transmission_type, cob_id, inhibit_100us, event_timer_ms,
    sync_start, mapping, valid, rtr}}), ``values`` ({'0x2003': 250}); and behaviour:
    ``start_operational`` (NMT auto start), ``boot_delay_ms``, ``remap_in_operational``,
    ``sdo_timeout_ms``, ``sdo_block_size``, ``time_producer_ms``/``time_epoch_s``.

    `start()` boots the device (boot-up message, pre-operational); `stop()` takes it off the
    bus silently (a crash, as far as the others can tell); `metrics()` gives the figures.
    """

    def __init__(self, node: NodeAPI, node_id: int, eds: str | os.PathLike[str] | None = None, **options: Any) -> None:
        self.node = node
        self.node_id = cob.check_node_id(node_id)
        self.options = DeviceOptions.parse(options)
        self.eds = eds
        self.od = load_od(eds, self.node_id)
        self.store = ObjectStore(self.od)
        self.remap_in_operational = self.options.remap_in_operational
        apply_device_options(self.store, self.options)
        self.store.initial = dict(self.store.values)  # resets restore the configured values
        self.running = False

        self.nmt = NmtSlave(self.node_id, self._state_changed, self._reset)
        send = self._send
        self.emcy = EmcyProducer(
            send,
            node.call_at,
            node.now,
            self._emcy_allowed,
            history_size=max(0, len(self.od.indices[0x1003].subindices) - 1) if 0x1003 in self.od.indices else 0,
        )
        self.heartbeat = HeartbeatProducer(self.node_id, send, node.call_at, node.now, lambda: self.nmt.state)
        self.consumer = HeartbeatConsumer(
            node.call_at,
            node.now,
            on_timeout=self._heartbeat_lost,
            on_resume=self._heartbeat_back,
            on_bootup=self._heartbeat_bootup,
        )
        self.guarding = NodeGuardingSlave(self.node_id, send, node.call_at, lambda: self.nmt.state, self._life_guarding)
        self.sync = SyncConsumer(
            node.call_at, self._on_sync, on_length_error=self._sync_length_error, on_timeout=self._sync_timeout
        )
        self.sync_producer = SyncProducer(send, node.call_at, node.now)
        self.time_producer = TimeProducer(send, node.call_at, node.now)
        self.sdo = SdoServer(
            self.store,
            self._sdo_send,
            node.call_later,
            timeout_ns=self.options.sdo_timeout_ms * MS,
            block_size=self.options.sdo_block_size,
        )
        self.tpdos = [
            Tpdo(self, n, self._transmit, self._sync_info) for n in range(1, 513) if 0x1800 + n - 1 in self.od.indices
        ]
        self.rpdos = [
            Rpdo(self, n, self.emcy.report, self.emcy.clear, self._rpdo_applied)
            for n in range(1, 513)
            if 0x1400 + n - 1 in self.od.indices
        ]
        self._check_pdos()
        self._register_objects()
        self._configure()

        self.routes: dict[tuple[int, bool], Callable[[Received], Any]] = {}
        self._tpdo_ids: dict[int, list[Tpdo]] = {}
        self._rpdo_callbacks: list[Callable[[RpdoUpdate], Any]] = []
        self._state_callbacks: list[Callable[[NmtState, NmtState], Any]] = []
        self._time_callbacks: list[Callable[[int], Any]] = []
        self._subscription: Any = None
        self._listening = False
        self._boot_timer: Any = None
        # counters
        self.boot_ups = 0
        self.heartbeats_sent = 0
        self.resets = {"application": 0, "communication": 0}
        self.tx_refused = 0
        self.late_since_sync = 0
        self._clean_syncs = 0
        self.time_received: int | None = None
        self.state_log: list[tuple[int, str]] = []
        # the latest 1000: a device whose peer is gone reports one every heartbeat period
        self.communication_errors: deque[tuple[int, str]] = deque(maxlen=1000)

    def _check_pdos(self) -> None:
        """A PDO the dictionary makes valid must have a usable mapping: an option naming it is a
        ValueError, the EDS an EdsError (CANopenNode reports it as EMCY 0x8200 and runs without
        the PDO; a device that starts without its PDOs is worse than a clear error here)."""
        for p in (*self.tpdos, *self.rpdos):
            if p.configured_valid and p.mapping_error is not None:
                opts = self.options.tpdo if p.kind == "TPDO" else self.options.rpdo
                if p.n in opts:
                    raise ValueError(f"{p.kind.lower()}.{p.n}: {p.mapping_error}")
                raise EdsError(
                    f"{self.eds or 'default EDS'}: {p.name} is valid but its mapping "
                    f"0x{p.map_index:04X} cannot be used: {p.mapping_error}"
                )

    # ------------------------------------------------------------------ dictionary owners
    def _register_objects(self) -> None:
        s = self.store
        s.readers[0x1001] = lambda sub: bytes([self.emcy.register])
        if 0x1003 in self.od.indices:
            s.readers[0x1003] = self.emcy.read_history
            s.validators[0x1003] = self.emcy.write_history
        s.validators[0x1005] = lambda sub, value, data: check_cob_id_sync(value, self.sync)
        s.validators[0x1019] = lambda sub, value, data: check_counter_overflow(value, s.u(0x1006))
        s.validators[0x1014] = lambda sub, value, data: self.emcy.check_cob_id(value)
        s.validators[0x1012] = lambda sub, value, data: check_cob_id_time(value)
        if 0x1016 in self.od.indices:
            s.validators[0x1016] = lambda sub, value, data: check_consumer_entry(
                sub, value, {k: s.u(0x1016, k) for k in self.od.indices[0x1016].subindices if k}
            )
        for index in (0x1005, 0x1006, 0x1007, 0x1019):
            s.watch(index, None, self._sync_written)
        s.watch(0x1017, None, lambda i, k: self.heartbeat.configure(s.u(0x1017)))
        s.watch(0x1016, None, lambda i, k: self._configure_consumer())
        s.watch(0x100C, None, lambda i, k: self._configure_guarding())
        s.watch(0x100D, None, lambda i, k: self._configure_guarding())
        s.watch(0x1014, None, lambda i, k: self._configure_emcy())
        s.watch(0x1015, None, lambda i, k: self._configure_emcy())
        s.watch(0x1012, None, lambda i, k: self._time_written())

    # ------------------------------------------------------------------ configuration -> services
    def _configure(self) -> None:
        s = self.store
        self.heartbeat.configure(s.u(0x1017))
        self._configure_consumer()
        self._configure_guarding()
        self._configure_emcy()
        self.sync.configure(s.u(0x1005, 0, 0x80), s.u(0x1006), s.u(0x1007), s.u(0x1019))
        word = s.u(0x1012, 0, 0x100)
        self.time_cob_id = word & 0x7FF
        self.time_consumer = bool(word & 0x8000_0000)
        self.time_producing = bool(word & 0x4000_0000)

    def _configure_consumer(self) -> None:
        entries = []
        if 0x1016 in self.od.indices:
            entries = [parse_consumer_entry(self.store.u(0x1016, k)) for k in self.od.indices[0x1016].subindices if k]
        self.consumer.configure(entries)
        if self.running:
            self._rebuild_routes()

    def _configure_guarding(self) -> None:
        self.guarding.configure(self.store.u(0x100C), self.store.u(0x100D))

    def _configure_emcy(self) -> None:
        self.emcy.configure(self.store.u(0x1014, 0, 0x80 + self.node_id), self.store.u(0x1015))

    def _sync_written(self, index: int, sub: int) -> None:
        was_producer = self.sync.producer
        s = self.store
        self.sync.configure(s.u(0x1005, 0, 0x80), s.u(0x1006), s.u(0x1007), s.u(0x1019))
        if self.running and allows(self.nmt.state, "sync"):
            self._start_sync(restart=was_producer != self.sync.producer or index in (0x1005, 0x1006))
            self._rebuild_routes()

    def _time_written(self) -> None:
        self._configure()
        if self.running:
            self._start_time()
            self._rebuild_routes()

    def _sync_info(self) -> tuple[int, int]:
        return self.sync.window_ns, self.sync.overflow

    def pdo_changed(self, pdo: Pdo) -> None:
        """A PDO's configuration changed (`profiles.canopen.pdo.common.PdoHost`)."""
        if self.nmt.state is NmtState.OPERATIONAL:
            pdo.stop()
            pdo.start()
        if self.running:
            self._rebuild_routes()

    def nmt_state(self) -> NmtState:
        """The NMT state (`profiles.canopen.pdo.common.PdoHost`)."""
        return self.nmt.state

    # ------------------------------------------------------------------ life cycle
    def start(self) -> CanopenDevice:
        """Power on (CiA 301 transition 1): subscribe, then after ``boot_delay_ms`` initialise,
        send the boot-up message and enter pre-operational (operational with
        ``start_operational``)."""
        if self.running:
            return self
        self.running = True
        self._subscription = self.node.subscribe(self._on_frame)
        if not self._listening:
            self.node.listen(TxDone, self._on_tx_done)
            self.node.listen(TxFailed, self._on_tx_failed)
            self.node.listen(ErrorStateChanged, self._on_error_state)
            self._listening = True
        delay = int(self.options.boot_delay_ms * MS)
        if delay:
            self._boot_timer = self.node.call_later(delay, self._boot)
        else:
            self._boot()
        return self

    def stop(self) -> None:
        """Power off: unsubscribe, cancel every timer and queued frame, say nothing (the others
        see the heartbeat stop)."""
        if not self.running:
            return
        self.running = False
        if self._boot_timer is not None:
            self._boot_timer.cancel()
            self._boot_timer = None
        self._halt_services()
        if self._subscription is not None:
            self._subscription.unsubscribe()
            self._subscription = None
        for req in list(self.node.pending()):
            self.node.abort(req)
        self.nmt.power_off()
        self.routes = {}

    def _boot(self) -> None:
        """Initialisation finished: boot-up message (0x700 + node-ID, one byte 0), then
        pre-operational (CiA 301 transition 2)."""
        self._boot_timer = None
        self.guarding.reset()
        self._send(Frame(cob.HEARTBEAT + self.node_id, b"\x00"))
        self.boot_ups += 1
        self.nmt.booted(self.options.start_operational)
        self.heartbeat.start()

    def _reset(self, kind: ResetKind) -> None:
        """Reset node (application) or reset communication (CiA 301 7.3.2.2.1): every service
        stops, the objects of the area get their power-on values, the device boots again."""
        self.resets[kind.value] += 1
        self._halt_services()
        for req in list(self.node.pending()):
            self.node.abort(req)
        if kind is ResetKind.APPLICATION:
            self.store.restore()
        else:
            self.store.restore(*COMMUNICATION_AREA)
        if kind is ResetKind.APPLICATION:
            self.emcy.history.clear()  # RAM, as the rest of the application's state
        for p in (*self.tpdos, *self.rpdos):
            p.load()
        self._configure()
        self._rebuild_routes()
        self._boot()

    def _halt_services(self) -> None:
        for p in self.tpdos:
            p.stop()
        for r in self.rpdos:
            r.stop()
        self.heartbeat.stop()
        self.consumer.stop()
        self.guarding.reset()
        self.sync.stop()
        self.sync_producer.stop()
        self.time_producer.stop()
        self.sdo.reset()
        self.emcy.reset()

    def _state_changed(self, old: NmtState, new: NmtState) -> None:
        self.state_log.append((self.node.now(), new.name))
        if old is NmtState.OPERATIONAL:
            for p in self.tpdos:
                p.stop()
            for r in self.rpdos:
                r.stop()
        if not allows(new, "sdo"):
            self.sdo.reset()
        if allows(new, "sync"):
            self._start_sync(restart=False)
        else:
            self.sync.stop()
            self.sync_producer.stop()
        if allows(new, "time"):
            self._start_time()
        else:
            self.time_producer.stop()
        if new is NmtState.OPERATIONAL:
            for r in self.rpdos:
                r.start()
            for p in self.tpdos:
                p.start()
        self._rebuild_routes()
        if allows(new, "emcy"):
            self.emcy.flush()
        if new is not NmtState.INITIALISING:  # a reset's boot-up message reports that one
            self.heartbeat.state_changed()
        for cb in self._state_callbacks:
            cb(old, new)

    def _start_sync(self, restart: bool) -> None:
        p = self.sync_producer
        if self.sync.producer and self.sync.period_ns:
            if restart or not p.running:
                p.configure(self.sync.cob_id, self.sync.period_ns, self.sync.overflow)
                p.start(self.node.now() + self.sync.period_ns)
        else:
            p.stop()

    def _start_time(self) -> None:
        if self.time_producing and self.options.time_producer_ms:
            epoch_s = self.options.time_epoch_s if self.options.time_epoch_s is not None else EPOCH_1984
            self.time_producer.start(self.time_cob_id, self.options.time_producer_ms * MS, int(epoch_s * 1000))
        else:
            self.time_producer.stop()

    def _emcy_allowed(self) -> bool:
        return self.running and allows(self.nmt.state, "emcy")

    # ------------------------------------------------------------------ frames in
    def _rebuild_routes(self) -> None:
        """Which frames reach which service in the present NMT state (CiA 301's table): a
        service not active in the state does not see its frames at all."""
        st = self.nmt.state
        r: dict[tuple[int, bool], Callable[[Received], Any]] = {}
        if not self.running or st is NmtState.INITIALISING:
            self.routes = r
            return
        r[(cob.NMT, False)] = self._on_nmt
        if allows(st, "sdo"):
            r[(cob.SDO_RX + self.node_id, False)] = self._on_sdo
        if allows(st, "sync") and not self.sync.producer:
            r[(self.sync.cob_id, False)] = self._on_sync_frame
        if allows(st, "time") and self.time_consumer:
            r[(self.time_cob_id, False)] = self._on_time
        if allows(st, "error-control"):
            for nid in self.consumer.nodes:
                r[(cob.HEARTBEAT + nid, False)] = partial(self._on_heartbeat, nid)
            if not self.heartbeat.period_ns:
                r[(cob.HEARTBEAT + self.node_id, True)] = self._on_guard
        ids: dict[int, list[Tpdo]] = {}
        if st is NmtState.OPERATIONAL:
            for rp in self.rpdos:
                if rp.valid:
                    r[(rp.can_id, False)] = partial(self._on_rpdo, rp)
            for tp in self.tpdos:
                if tp.valid and tp.rtr_allowed:
                    r[(tp.can_id, True)] = partial(self._on_rtr, tp)
        for tp in self.tpdos:
            ids.setdefault(tp.can_id, []).append(tp)
        self._tpdo_ids = ids
        self.routes = r

    def _on_frame(self, ev: Received) -> None:
        f = ev.frame
        if f.extended:
            return
        if not f.remote and f.can_id == cob.HEARTBEAT + self.node_id:
            # our own boot-up or heartbeat: the bus shows the device its own frames, so each TPDO
            # will see where its frames start on the wire
            for tp in self.tpdos:
                tp.echoes = True
        if not f.remote and f.can_id in self._tpdo_ids and self.nmt.state is NmtState.OPERATIONAL:
            # our own TPDO as the bus shows it (a bus that echoes the node's frames): where it
            # really started, for the inhibit time and the event timer (one sender per COB-ID)
            sof = ev.sof if ev.sof >= 0 else ev.time
            for tp in self._tpdo_ids[f.can_id]:
                if tp.valid:
                    tp.on_wire(sof)
        h = self.routes.get((f.can_id, f.remote))
        if h is not None:
            h(ev)

    def _on_nmt(self, ev: Received) -> None:
        self.nmt.on_command(ev.frame.data)

    def _on_sdo(self, ev: Received) -> None:
        self.sdo.on_request(ev.frame.data)

    def _on_sync_frame(self, ev: Received) -> None:
        self.sync.on_frame(ev.frame.data, ev.time)

    def _on_time(self, ev: Received) -> None:
        try:
            self.time_received = decode_time_of_day(ev.frame.data)
        except ValueError:
            return
        for cb in self._time_callbacks:
            cb(self.time_received)

    def _on_heartbeat(self, nid: int, ev: Received) -> None:
        self.consumer.on_heartbeat(nid, ev.frame.data, ev.time)

    def _on_guard(self, ev: Received) -> None:
        self.guarding.on_request(ev.time)

    def _on_rpdo(self, rp: Rpdo, ev: Received) -> None:
        rp.on_frame(ev.frame.data, ev.time)

    def _on_rtr(self, tp: Tpdo, ev: Received) -> None:
        tp.on_rtr(ev.time)

    # ------------------------------------------------------------------ SYNC
    def _on_sync(self, counter: int | None, t: int) -> None:
        """A SYNC: the synchronous window of the last cycle is judged, synchronous RPDOs take
        effect, then TPDOs sample and go (CANopenNode's order)."""
        if self.late_since_sync:
            self.emcy.report(SYNC_ERROR, b"\x15", key="tpdo-window")
            self._clean_syncs = 0
        else:
            self._clean_syncs += 1
            if self._clean_syncs >= self._window_cycle():
                self.emcy.clear("tpdo-window")
        self.late_since_sync = 0
        for rp in self.rpdos:
            if rp.buffer is not None:
                rp.on_sync(t)
        for tp in self.tpdos:
            tp.on_sync(counter, t)

    def _window_cycle(self) -> int:
        """SYNCs without a late TPDO before the window error is cleared: two whole cycles of the
        synchronous TPDOs (twice the largest type 1..240 in use), at least 10 — so that a PDO
        late now and then does not raise and clear its EMCY over and over (CANopenNode
        re-evaluates the error at every SYNC; the EMCYs of a flapping error would load the
        very bus that made the PDOs late)."""
        return max(
            10,
            2
            * max(
                [tp.transmission_type for tp in self.tpdos if tp.valid and 1 <= tp.transmission_type <= 240], default=1
            ),
        )

    def _sync_length_error(self, dlc: int) -> None:
        self.emcy.report(SYNC_LENGTH_ERROR, bytes([dlc]), key="sync-length")

    def _sync_timeout(self, active: bool) -> None:
        if active:
            self.emcy.report(SYNC_ERROR, b"\x18", key="sync-timeout")
        else:
            self.emcy.clear("sync-timeout")

    # ------------------------------------------------------------------ error control events
    def communication_error(self, event: str) -> None:
        """A communication error (``event``: what it was): the NMT state object 0x1029:1 asks for
        (see the module docstring)."""
        self.communication_errors.append((self.node.now(), event))
        if not self.running:
            return
        behaviour = self.store.u(ERROR_BEHAVIOUR, 1, NO_CHANGE)
        st = self.nmt.state
        if behaviour == TO_PRE_OPERATIONAL and st is NmtState.OPERATIONAL:
            self.nmt.error_behaviour(NmtState.PRE_OPERATIONAL, f"communication error: {event}")
        elif behaviour == TO_STOPPED and st in (NmtState.OPERATIONAL, NmtState.PRE_OPERATIONAL):
            self.nmt.error_behaviour(NmtState.STOPPED, f"communication error: {event}")

    def _on_error_state(self, ev: ErrorStateChanged) -> None:
        if ev.new == "bus-off":
            self.communication_error("bus off")
        elif ev.old == "bus-off" and self.running:
            # CANopenNode reports CO_EM_CAN_TX_BUS_OFF (EMCY 0x8140) while bus off and resets it
            # when the bus is back: both go out once the controller can send again
            self.emcy.report(BUS_OFF_RECOVERED, b"", key="bus-off")
            self.emcy.clear("bus-off")

    def _heartbeat_lost(self, m: MonitoredNode) -> None:
        self.emcy.report(HEARTBEAT_ERROR, bytes([m.node_id]), key=f"heartbeat-{m.node_id}")
        self.communication_error(f"heartbeat of node {m.node_id} lost")

    def _heartbeat_back(self, m: MonitoredNode) -> None:
        self.emcy.clear(f"heartbeat-{m.node_id}")
        self.emcy.clear(f"remote-reset-{m.node_id}")

    def _heartbeat_bootup(self, m: MonitoredNode) -> None:
        """A boot-up from a node that was being monitored: CANopenNode's 'heartbeat consumer
        detected remote node reset', EMCY 0x8130, until its heartbeat comes back."""
        if m.remote_reset:
            if self.emcy.report(HEARTBEAT_ERROR, bytes([m.node_id]), key=f"remote-reset-{m.node_id}"):
                m.lost = True  # cleared with the next heartbeat

    def _life_guarding(self, event: str) -> None:
        if event == "lost":
            self.emcy.report(HEARTBEAT_ERROR, b"\x00", key="life-guarding")
            self.communication_error("life guarding")
        else:
            self.emcy.clear("life-guarding")

    # ------------------------------------------------------------------ frames out
    def _send(self, frame: Frame, *, not_after: int | None = None) -> TxRequest | None:
        try:
            return self.node.send(frame, not_after=not_after) if not_after is not None else self.node.send(frame)
        except (QueueFull, NodeError):
            self.tx_refused += 1
            return None

    def _transmit(self, frame: Frame, *, not_after: int | None = None) -> TxRequest | None:
        return self._send(frame, not_after=not_after)

    def _sdo_send(self, data: bytes) -> None:
        self._send(Frame(cob.SDO_TX + self.node_id, data))

    def _on_tx_done(self, ev: TxDone) -> None:
        can_id = ev.frame.can_id
        if can_id == cob.HEARTBEAT + self.node_id and ev.frame.data[:1] != b"\x00":
            self.heartbeats_sent += 1
            return
        if can_id == self.emcy.cob_id and self.emcy.enabled:
            self.emcy.on_sent(ev.sof if ev.sof >= 0 else ev.time)
            return
        if self.sync.producer and can_id == self.sync.cob_id and self.running:
            d = ev.frame.data
            self.sync.sync(d[0] if d else None, ev.time)
            return
        for tp in self._tpdo_ids.get(can_id, ()):
            if tp.on_done(ev.request, ev.time, ev.sof):
                return

    def _on_tx_failed(self, ev: TxFailed) -> None:
        for tp in self._tpdo_ids.get(ev.frame.can_id, ()):
            if tp.on_failed(ev.request, ev.kind):
                if ev.kind == "expired":
                    self.late_since_sync += 1
                return

    def _rpdo_applied(self, rp: Rpdo, written: list[tuple[int, int]], t: int) -> None:
        if not self._rpdo_callbacks:
            return
        upd = RpdoUpdate(rp.n, rp.can_id, {k: self.store.get(*k) for k in written}, t)
        for cb in self._rpdo_callbacks:
            cb(upd)

    # ------------------------------------------------------------------ the application's API
    @property
    def state(self) -> NmtState:
        """The NMT state (CiA 301 7.3.2.2)."""
        return self.nmt.state

    def read(self, index: int, sub: int = 0) -> Any:
        """An object's value (decoded by its data type)."""
        return self.store.get(index, sub)

    def write(self, index: int, sub: int, value: Any) -> None:
        """Set an object as the application (limits and owner rules apply; raises `SdoAbort`).
        A change of an object mapped into an event-driven TPDO triggers it (CiA 301 7.2.2)."""
        self.store.set(index, sub, value)

    def on_write(self, index: int, sub: int | None, callback: Callable[[int, int], Any]) -> None:
        """Call ``callback(index, sub)`` after each write of the object (SDO, RPDO or local)."""
        self.store.watch(index, sub, callback)

    def on_rpdo(self, callback: Callable[[RpdoUpdate], Any]) -> None:
        """Call ``callback(RpdoUpdate)`` each time an RPDO has written its objects."""
        self._rpdo_callbacks.append(callback)

    def on_state(self, callback: Callable[[NmtState, NmtState], Any]) -> None:
        """Call ``callback(old, new)`` after each NMT state change."""
        self._state_callbacks.append(callback)

    def on_time(self, callback: Callable[[int], Any]) -> None:
        """Call ``callback(unix_ms)`` for each TIME message consumed."""
        self._time_callbacks.append(callback)

    def request_tpdo(self, n: int) -> None:
        """The application's event for TPDO ``n`` (types 0, 254, 255; CiA 301 7.2.2)."""
        self.tpdo(n).request()

    def tpdo(self, n: int) -> Tpdo:
        """TPDO ``n`` (1-based)."""
        for tp in self.tpdos:
            if tp.n == n:
                return tp
        raise KeyError(f"the device has no TPDO{n}")

    def rpdo(self, n: int) -> Rpdo:
        """RPDO ``n`` (1-based)."""
        for rp in self.rpdos:
            if rp.n == n:
                return rp
        raise KeyError(f"the device has no RPDO{n}")

    def report_error(self, code: int, info: bytes = b"") -> bool:
        """Raise an application error: EMCY ``code`` (CiA 301 7.2.7), error register, 0x1003."""
        return self.emcy.report(code, info)

    def clear_error(self, code: int) -> bool:
        """The application error ``code`` went away (EMCY error reset after the last one)."""
        return self.emcy.clear(code)

    # ------------------------------------------------------------------ metrics
    def metrics(self) -> dict[str, Any]:
        """JSON-ready figures: NMT state, heartbeats, SYNC, EMCY, SDO, and per PDO the counts,
        the SYNC-to-transmission latency (ms) and the PDOs not sent inside the synchronous
        window."""
        return {
            "profile": "canopen",
            "node": self.node.name,
            "node_id": self.node_id,
            "nmt_state": self.nmt.state.name,
            "boot_ups": self.boot_ups,
            "resets": dict(self.resets),
            "heartbeat_ms": self.heartbeat.period_ns // MS,
            "heartbeats_sent": self.heartbeats_sent,
            "sync_received": self.sync.received,
            "sync_timeouts": self.sync.timeouts,
            "sync_length_errors": self.sync.length_errors,
            "emcy_sent": self.emcy.sent,
            "error_register": self.emcy.register,
            "errors_active": sorted(self.emcy.active.values()),
            "tx_refused": self.tx_refused,
            "communication_errors": [[t / 1e6, what] for t, what in self.communication_errors],
            "sdo": {
                "requests": self.sdo.requests,
                "aborts_sent": self.sdo.aborts_sent,
                "aborts_received": self.sdo.aborts_received,
                "completed": dict(self.sdo.completed),
            },
            "tpdos": [
                dict(
                    tp.info(),
                    queued=tp.queued,
                    sent=tp.sent,
                    not_in_window=tp.late,
                    refused=tp.refused,
                    sync_to_tx_ms=summary(tp.sync_latencies),
                )
                for tp in self.tpdos
                if tp.valid or tp.queued
            ],
            "rpdos": [
                dict(
                    rp.info(),
                    received=rp.received,
                    applied=rp.applied_count,
                    length_errors=rp.length_errors,
                    timeouts=rp.timeouts,
                )
                for rp in self.rpdos
                if rp.valid or rp.received
            ],
            "heartbeat_consumer": [
                {
                    "node_id": m.node_id,
                    "status": m.status,
                    "nmt_state": m.state_name,
                    "received": m.received,
                    "missed": m.missed,
                    "timeouts": m.timeouts,
                }
                for m in self.consumer.nodes.values()
            ],
        }

    def __repr__(self) -> str:
        return f"<CanopenDevice node-ID {self.node_id} on {self.node.name!r} {self.nmt.state.name}>"
