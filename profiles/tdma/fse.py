"""The frame synchronisation entity (FSE) of one TTCAN node: its view of the basic cycle, its
synchronisation and master states, and — on a potential time master — the reference message.

A sans-IO state machine on a node (ISO 11898-4 clauses as the TTCAN model in Pipit quotes them;
the numbers in brackets are those clauses):

- Cycle time restarts at the start of frame of every reference message, as the node saw it
  (the Sync_Mark captured at the sample point of SOF becomes the Ref_Mark; Bosch TTCAN user's
  manual §"Cycle Time and Global Time Synchronisation"): ``ref_mark`` is `Received.sof` /
  `TxDone.sof` on the node's own clock, never the reception time.
- Sync_Mode [9.4.2]: Sync_Off → Synchronising (cycle time zero) → In_Schedule after two
  consecutive reference messages [8.2]; In_Schedule → Sync_Off when the cycle time passes the
  Watch_Trigger without a reference message (Watch_Trigger_Reached, an S3 error [9.3.9]); in
  Synchronising longer than the Init_Watch_Trigger (2^16 - 1 NTU) → Sync_Off. S3 stops the node
  until its host re-initialises it: this model's host does so at once (Synchronising again).
- Until synchronised a node sends nothing but — a potential time master — reference messages;
  a time master that failed waits until it is synchronised before trying again [8.3] (unless it
  hears no reference for a whole Init_Watch_Trigger: the network is silent and someone must
  start it).
- Master_Mode [9.4.3]: Master_Off → time slave (not a potential master) or backup (another
  master's reference) or current (its own reference went out); current → backup on a reference
  of higher priority (TM5).
- Ref_Trigger_Offset [9.5.1]: 0 for the current master; Initial_Ref_Offset after a reference of
  higher priority than the node's own; a backup in schedule that sees a current master of lower
  priority sets it to 0, then lowers it by 1 NTU each basic cycle (to -127) until it wins. Tx_Ref_Trigger is at
  the end of the basic cycle plus the offset, so when the current master falls silent the
  backups start theirs after Initial_Ref_Offset (their watch timeout) and arbitration picks the
  highest priority; a returning primary meets the current master at offset 0 at a cycle boundary
  and wins by arbitration.
- The reference request stays active until any reference message completes (sent or received)
  or the Watch_Trigger: a reference that lost arbitration competes again at the next idle point
  and is withdrawn the moment another master's reference completes — so it never follows the
  winner's (TC1796 §22.5.8: "not retransmitted, but the message on the bus is received"; its
  request flag is cleared by a correct reference message) — and keeps the bus when the winner's
  is destroyed. One disturbed by an error is repeated at once with an updated Master_Ref_Mark
  (sent one-shot and re-queued here, because a frame cannot change while the controller holds
  it).
- Level 2 [global time]: the master's global time is its local time plus a Local_Offset frozen
  when it took over; receivers compute the time unit ratio (TUR, NTU per local ns) from the
  Master_Ref_Marks and their own Ref_Marks of two successive reference messages and measure the
  cycle in the master's NTU, so long basic cycles hold against oscillator drift. Level 1 counts
  the cycle on the local clock and relies on the resynchronisation at every reference message.

Times: local ns of the node's clock (``now``, ``ref_mark``); schedule times are NTU ns of the
time master's clock, converted by `Fse.local`.
"""

from __future__ import annotations

from enum import Enum
from typing import TYPE_CHECKING, Any, Protocol

from profiles.tdma.schedule import CYCLE_TIME_NTU, MARK_MODULUS, NTU_RES_BITS, REF_OFFSET_LIMIT, decode_reference
from stack import ErrorState, ErrorStateChanged, NodeError, QueueFull, Received, TxDone, TxFailed

if TYPE_CHECKING:  # pragma: no cover
    from profiles.tdma.schedule import ReferenceInfo, Schedule
    from stack import NodeAPI, Timer, TxRequest

__all__ = ["Fse", "SyncMode", "MasterMode", "CycleListener", "ERROR_KINDS", "MAX_RATE_DEVIATION"]

ERROR_KINDS = frozenset({"bit", "stuff", "form", "crc", "ack", "error"})
"""`TxFailed.kind` of an attempt destroyed by an error (as opposed to lost arbitration, expired,
aborted)."""
MAX_RATE_DEVIATION = 0.05
"""A time unit ratio further than 5 % from 1 is refused as a measurement error: ISO 11898-1
oscillators are within 1.58 % each, so two of them differ by at most about 3.2 %."""


class SyncMode(str, Enum):
    """Sync_Mode [9.4.2] (In_Gap is not modelled: no gap mode; a reference that announces a gap
    is counted, ``next_is_gap_seen``, and the next one still expected at its time mark)."""

    OFF = "sync_off"
    SYNCHRONISING = "synchronising"
    IN_SCHEDULE = "in_schedule"


class MasterMode(str, Enum):
    """Master_Mode [9.4.3]."""

    OFF = "master_off"
    SLAVE = "time_slave"
    BACKUP = "backup_master"
    CURRENT = "current_master"


class CycleListener(Protocol):
    """What an FSE tells the layer above (the TDMA profile)."""

    def on_cycle(self, fse: Fse) -> None:
        """A basic cycle started and the node is in schedule."""

    def on_lost(self, fse: Fse) -> None:
        """The node left In_Schedule (Watch_Trigger, bus off)."""


class Fse:
    """The FSE of one node (see the module docstring). ``priority`` is the node's time master
    priority (its place in ``time_masters``) or None for a time slave; ``listener`` hears of each
    basic cycle in schedule."""

    def __init__(
        self,
        node: NodeAPI,
        schedule: Schedule,
        *,
        priority: int | None = None,
        listener: CycleListener | None = None,
    ) -> None:
        self.node = node
        self.schedule = schedule
        self.priority = priority
        self.listener = listener
        self.sync = SyncMode.OFF
        self.master = MasterMode.OFF
        self.failed = False
        self.ref_mark = 0
        self.cycle_count: int | None = None
        self.ref_priority: int | None = None
        self.cycle_id = 0
        self.refs = 0
        self.offset = schedule.initial_ref_offset
        self.tur = 1.0
        self.global_ref: float | None = None
        self.local_offset = 0
        self.ref_req: TxRequest | None = None
        self._prev_mark: tuple[int, int] | None = None  # (Ref_Mark, Master_Ref_Mark) of the last reference
        self._timers: dict[str, Timer] = {}
        self._marks: dict[TxRequest, int | None] = {}
        self._bit = schedule.bit_ns
        self._ntu = schedule.ntu_length
        self._init_watch_ns = schedule.ntu(CYCLE_TIME_NTU)
        # counters
        self.references_sent = 0
        self.reference_retransmissions = 0
        self.watch_triggers = 0
        self.init_watch_triggers = 0
        self.restarts = 0
        self.bus_off = 0
        self.took_over = 0
        self.gaps_announced = 0  # references with Next_is_Gap set (from another implementation)

    # ------------------------------------------------------------------ time
    def local(self, ntu_ns: float) -> int:
        """The local time of cycle time ``ntu_ns`` (NTU ns) in the current basic cycle."""
        return self.ref_mark + round(ntu_ns / self.tur)

    def cycle_time(self, now: int) -> float:
        """Cycle_Time at local time ``now``, NTU ns since the last reference message."""
        return (now - self.ref_mark) * self.tur

    def global_time(self, local: int) -> float:
        """The node's view of the global time (level 2) at local time ``local``, ns: the current
        master's (and a master that never heard another's) is its local time plus Local_Offset;
        a receiver's is the last Master_Ref_Mark plus the cycle time in NTU."""
        if self.master is MasterMode.CURRENT or self.global_ref is None:
            return local + self.local_offset
        return self.global_ref + (local - self.ref_mark) * self.tur

    @property
    def in_schedule(self) -> bool:
        """True when the node is synchronised to the schedule (it may send in its windows)."""
        return self.sync is SyncMode.IN_SCHEDULE

    # ------------------------------------------------------------------ life cycle
    def start(self) -> None:
        """Power-up: listen for reference messages and enter Synchronising."""
        s = self.schedule
        top = 0x1FFFFFFF if s.reference_extended else 0x7FF
        self.node.subscribe(
            self._received, [{"can_id": s.reference_id, "can_mask": top & ~7, "extended": s.reference_extended}]
        )
        self.node.listen(TxDone, self._tx_done)
        self.node.listen(TxFailed, self._tx_failed)
        self.node.listen(ErrorStateChanged, self._state_changed)
        self._synchronise()

    def restart(self) -> None:
        """The host re-initialises the node after an S3 error: Synchronising again."""
        self.restarts += 1
        self._synchronise()

    def _synchronise(self) -> None:
        """Enter Synchronising: cycle time zero now, no reference seen; a potential master that
        has not failed requests a reference message at the end of this (first) basic cycle plus
        its Initial_Ref_Offset, like at power-up."""
        self.sync = SyncMode.SYNCHRONISING
        self.master = MasterMode.OFF
        self.refs = 0
        self.ref_mark = self.node.now()
        self.cycle_count = None
        self._prev_mark = None
        self.offset = self.schedule.initial_ref_offset
        self._arm()

    def _severe(self) -> None:
        """An S3 error (Watch_Trigger reached, bus off): all CAN operation of the schedule stops."""
        was = self.sync
        self.sync = SyncMode.OFF
        self.master = MasterMode.OFF
        if self.priority is not None:
            self.failed = True
        self._cancel()
        self._withdraw()
        if was is SyncMode.IN_SCHEDULE and self.listener is not None:
            self.listener.on_lost(self)

    # ------------------------------------------------------------------ timers
    def _cancel(self) -> None:
        for t in self._timers.values():
            t.cancel()
        self._timers.clear()

    def _arm(self) -> None:
        """Time marks of the basic cycle that just started: Tx_Ref_Trigger (+ Ref_Trigger_Offset)
        of a potential master that may send, Watch_Trigger in schedule, Init_Watch_Trigger while
        synchronising."""
        self._cancel()
        s = self.schedule
        if self.priority is not None and (self.sync is SyncMode.IN_SCHEDULE or not self.failed):
            t = self.local(s.basic_cycle_ns + s.ntu(self.offset))
            self._timers["ref"] = self.node.call_at(t, self._tx_ref_trigger)
        if self.sync is SyncMode.IN_SCHEDULE:
            self._timers["watch"] = self.node.call_at(self.local(s.watch_ns), self._watch)
        else:
            self._timers["init"] = self.node.call_at(self.local(self._init_watch_ns), self._init_watch)

    def _watch(self) -> None:
        self._timers.pop("watch", None)
        self.watch_triggers += 1
        self._severe()
        self.restart()

    def _init_watch(self) -> None:
        self._timers.pop("init", None)
        self.init_watch_triggers += 1
        # a whole Init_Watch_Trigger without any reference message: the network is silent, so
        # even a master that failed may start it again
        self.failed = False
        self.restart()

    # ------------------------------------------------------------------ reference message out
    def _tx_ref_trigger(self) -> None:
        self._timers.pop("ref", None)
        if self.ref_req is None:
            self._send_reference(self.node.now())

    def _send_reference(self, sof_guess: int) -> None:
        """Request a reference message opening the next basic cycle; at level 2 it carries the
        global time at ``sof_guess``, when it is expected to start."""
        s = self.schedule
        not_after = self.local(s.watch_ns)
        if self.priority is None or not_after < self.node.now():
            return
        cc = 0 if self.cycle_count is None else (self.cycle_count + 1) % s.matrix_cycles
        mark = None
        if s.level == 2:
            mark = round(self.global_time(sof_guess) * (1 << NTU_RES_BITS) / self._ntu) % MARK_MODULUS
        frame = s.reference_frame(self.priority, cc, mark=mark)
        try:
            req = self.node.send(frame, one_shot=True, not_after=not_after)
        except (QueueFull, NodeError):
            return
        self.ref_req = req
        self._marks[req] = mark

    def _withdraw(self) -> None:
        req = self.ref_req
        self.ref_req = None
        if req is not None:
            self._marks.pop(req, None)
            self.node.abort(req)

    # ------------------------------------------------------------------ events in
    def _received(self, ev: Received) -> None:
        f = ev.frame
        prio = None if f.remote else self.schedule.priority_of(f.can_id, f.extended)
        if prio is None:
            return
        info = decode_reference(f.data, self.schedule.level)
        if info is None:
            return
        sof = ev.sof if ev.sof >= 0 else ev.time - round(f.bits.length * self._bit)
        self._reference(sof, prio, info, own=False)

    def _tx_done(self, ev: TxDone) -> None:
        if ev.request is not self.ref_req:
            return
        self.ref_req = None
        self.references_sent += 1
        mark = self._marks.pop(ev.request, None)
        info = decode_reference(ev.frame.data, self.schedule.level)
        if info is not None and self.priority is not None:
            info = info._replace(mark=mark)
            self._reference(ev.sof, self.priority, info, own=True)

    def _tx_failed(self, ev: TxFailed) -> None:
        if ev.request is not self.ref_req:
            return
        self.ref_req = None
        self._marks.pop(ev.request, None)
        if (ev.kind in ERROR_KINDS or ev.kind == "arbitration") and self.sync is not SyncMode.OFF:
            # the request stays active: repeated as soon as possible with an updated
            # Master_Ref_Mark — the bus is idle after the 3-bit intermission (and 8 bits of
            # suspend transmission when error passive). After a lost arbitration the winner's
            # frame is usually still on the wire: if it is a reference message, its completion
            # withdraws this request before the next arbitration.
            bits = 3 + (8 if self.node.state is ErrorState.PASSIVE else 0)
            if ev.kind != "arbitration":
                self.reference_retransmissions += 1
            self._send_reference(self.node.now() + self.schedule.bits(bits))

    def _state_changed(self, ev: ErrorStateChanged) -> None:
        if ev.new == ErrorState.BUS_OFF.value:
            self.bus_off += 1
            self._severe()  # CAN_Bus_Off, S3: the node is off the bus until it recovers
        elif ev.old == ErrorState.BUS_OFF.value:
            self.restart()

    def _reference(self, sof: int, prio: int, info: ReferenceInfo, *, own: bool) -> None:
        """A reference message completed (received, or sent by this node): a new basic cycle."""
        if self.sync is SyncMode.OFF:
            return
        if not own and self.ref_req is not None:
            self._withdraw()  # the request ends with any completed reference message
        s = self.schedule
        if info.next_is_gap:
            # gap mode is not modelled: the next reference is still expected at its time mark,
            # so a gap longer than the Watch_Trigger ends in Sync_Off (counted and reported)
            self.gaps_announced += 1
        if s.level == 2:
            self._time_base(sof, info, own)
        self.ref_mark = sof
        self.cycle_count = info.cycle_count
        self.ref_priority = prio
        self.cycle_id += 1
        if self.sync is SyncMode.SYNCHRONISING:
            self.refs += 1
            if self.refs >= 2:
                self.sync = SyncMode.IN_SCHEDULE
                self.failed = False
        self._master_mode(prio, own)
        self._arm()
        if self.sync is SyncMode.IN_SCHEDULE and self.listener is not None:
            self.listener.on_cycle(self)

    def _time_base(self, sof: int, info: ReferenceInfo, own: bool) -> None:
        """Level 2: the global time at this reference and, on a receiver, the time unit ratio
        from the last two (Master_Ref_Mark against Ref_Mark)."""
        mark = info.mark
        if mark is None:
            return
        if own:
            g = self.global_time(sof)
            if self.master is not MasterMode.CURRENT:
                self.local_offset = round(g) - sof  # frozen when the node becomes time master
            self.global_ref = g
            self.tur = 1.0  # the current master's clock defines the NTU
            self._prev_mark = (sof, mark)
            return
        prev = self._prev_mark
        step = None
        if prev is not None and not info.disc:
            step = ((mark - prev[1]) % MARK_MODULUS) * self._ntu / (1 << NTU_RES_BITS)
            d_local = sof - prev[0]
            if d_local > 0 and abs(step / d_local - 1) < MAX_RATE_DEVIATION:
                self.tur = step / d_local
        if step is not None and self.global_ref is not None:
            self.global_ref += step
        else:
            self.global_ref = mark * self._ntu / (1 << NTU_RES_BITS)
        self._prev_mark = (sof, mark)

    def _master_mode(self, prio: int, own: bool) -> None:
        """Master_Mode [9.4.3] and Ref_Trigger_Offset [9.5.1] after a reference of ``prio``."""
        if self.priority is None:
            self.master = MasterMode.SLAVE
            return
        mine = self.priority
        if own:
            if self.master is not MasterMode.CURRENT:
                self.took_over += 1
            self.master = MasterMode.CURRENT
            self.offset = 0
        elif prio < mine:
            self.master = MasterMode.BACKUP
            self.offset = self.schedule.initial_ref_offset
        elif prio > mine:
            if self.master is MasterMode.OFF:
                self.master = MasterMode.BACKUP
            if self.master is MasterMode.BACKUP and self.sync is SyncMode.IN_SCHEDULE:
                # a current master of lower priority: meet it at the next cycle boundary (offset
                # 0, arbitration decides), then start earlier each cycle until this node wins.
                # Only in schedule: a returning master first synchronises [8.3], so it does not
                # count down while it cannot send.
                self.offset = 0 if self.offset > 0 else max(-REF_OFFSET_LIMIT, self.offset - 1)

    def state(self) -> dict[str, Any]:
        """The node's TTCAN state and counters (JSON-ready)."""
        out: dict[str, Any] = {
            "sync_mode": self.sync.value,
            "master_mode": self.master.value,
            "watch_triggers": self.watch_triggers,
            "restarts": self.restarts,
        }
        if self.priority is not None:
            out.update(
                priority=self.priority,
                references_sent=self.references_sent,
                reference_retransmissions=self.reference_retransmissions,
                took_over=self.took_over,
                ref_trigger_offset=self.offset,
            )
        if self.bus_off:
            out["bus_off"] = self.bus_off
        if self.gaps_announced:
            out["next_is_gap_seen"] = self.gaps_announced
        if self.schedule.level == 2:
            out["tur"] = round(self.tur, 9)
        return out
