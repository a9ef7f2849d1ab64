"""The transmit side of a DBC ECU: one `TxMessage` per message the ECU sends.

A `TxMessage` keeps the message's current values, encodes them with cantools (checks and alive
counters applied as hooks, `dbc.checks`), and runs the interaction layer (`dbc.interaction`):
cyclic, spontaneous, on change, cyclic if active, delays and repetitions, on the node's timers.
Multiplexed messages send their pages in turn (`dbc.multiplex`) until the application writes a
multiplexer. `Ecu` (``dbc.ecu``) owns them; nothing here reads a clock or sleeps.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from typing import Any

import cantools

from stack import Frame, QueueFull
from stack.wire.frame import FD_LENGTHS, pad_to_fd_length

from .interaction import MessageTiming, attribute, signal_timing
from .multiplex import multiplexer_names, page_of, pages, select_defined_page

__all__ = [
    "TxMessage",
    "SignalLimits",
    "initial_values",
    "frame_id_of",
    "fd_format",
    "frame_of_payload",
    "BRS_ATTRIBUTE",
    "DEFAULT_BRS",
    "FD_PADDING",
]

#: The message attribute Vector's CANdb++ gives CAN FD messages for bit rate switching: an ENUM
#: "0","1" (cantools writes the same definition when it saves an FD database).
BRS_ATTRIBUTE = "CANFD_BRS"

#: Bit rate switching of a CAN FD message whose DBC does not say (no ``CANFD_BRS`` attribute and
#: no default for it): on, the default of CANdb++'s ``CANFD_BRS`` definition ("1").
DEFAULT_BRS = True

#: The byte that pads a CAN FD payload the DBC gives a length between two CAN FD lengths (10
#: bytes go out as 12): ISO 11898-1 leaves the value open; AUTOSAR's CanIf padding default is 0.
FD_PADDING = 0x00

_TRUE_WORDS = {"1", "true", "yes", "on"}
_FALSE_WORDS = {"0", "false", "no", "off"}


def frame_id_of(message: Any) -> tuple[int, bool]:
    """(identifier, extended) of a cantools message as it goes on the wire: the DBC's frame
    id, 29-bit when the DBC marks the message extended (J1939 messages included)."""
    return message.frame_id, bool(message.is_extended_frame)


def fd_format(db: Any, message: Any) -> tuple[bool, bool]:
    """(fd, brs) of a cantools message: ``fd`` as cantools reads it (``Message.is_fd``, from the
    DBC's ``VFrameFormat`` StandardCAN_FD or ExtendedCAN_FD); ``brs`` from the message's
    ``CANFD_BRS`` attribute ("1"/"0", or its ``BA_DEF_DEF_`` default), `DEFAULT_BRS` when the DBC
    has neither; always False for a classical message (BRS exists in CAN FD frames only)."""
    if not message.is_fd:
        return False, False
    value = attribute(db, message, BRS_ATTRIBUTE)
    word = str(value).strip().lower() if value is not None else ""
    if word in _TRUE_WORDS:
        return True, True
    if word in _FALSE_WORDS:
        return True, False
    return True, DEFAULT_BRS


def frame_of_payload(message: Any, data: bytes, brs: bool) -> Frame:
    """The frame carrying a message's encoded payload: a classical frame, or for a CAN FD message
    an FD frame whose data is the payload padded with `FD_PADDING` to the next CAN FD length
    (the DLC's size: a 10-byte message goes out in a 12-byte frame, DLC 9)."""
    can_id, extended = frame_id_of(message)
    if not message.is_fd:
        return Frame(can_id, data, extended=extended)
    if len(data) not in _FD_LENGTH_SET:
        data = pad_to_fd_length(data, FD_PADDING)
    return Frame(can_id, data, extended=extended, fd=True, brs=brs)


_FD_LENGTH_SET = frozenset(FD_LENGTHS)


def initial_values(db: cantools.database.can.Database, message: Any) -> dict[str, Any]:
    """Initial physical value of every signal of ``message``: ``GenSigStartValue`` (raw, through
    the signal's scaling; cantools' ``raw_initial``), else the attribute's default, else raw 0;
    multiplexers that would select an undefined branch select the lowest defined one."""
    values: dict[str, Any] = {}
    for sig in message.signals:
        raw = signal_timing(db, sig).start_raw
        if raw is None:
            raw = 0
        values[sig.name] = sig.conversion.raw_to_scaled(raw, False)
    select_defined_page(message, values)
    return values


class SignalLimits:
    """A signal's allowed physical range: the DBC minimum/maximum intersected with what the
    raw bits can hold (through scale and offset)."""

    __slots__ = ("lo", "hi", "dbc_lo", "dbc_hi", "raw_lo", "raw_hi")

    def __init__(self, sig: Any) -> None:
        conv = sig.conversion
        if sig.is_float:
            raw_lo = -math.inf
            raw_hi = math.inf
        elif sig.is_signed:
            raw_lo, raw_hi = -(1 << (sig.length - 1)), (1 << (sig.length - 1)) - 1
        else:
            raw_lo, raw_hi = 0, (1 << sig.length) - 1
        a = raw_lo * conv.scale + conv.offset if math.isfinite(raw_lo) else -math.inf * (1 if conv.scale > 0 else -1)
        b = raw_hi * conv.scale + conv.offset if math.isfinite(raw_hi) else math.inf * (1 if conv.scale > 0 else -1)
        self.raw_lo, self.raw_hi = min(a, b), max(a, b)
        self.dbc_lo, self.dbc_hi = sig.minimum, sig.maximum
        lo, hi = self.raw_lo, self.raw_hi
        if self.dbc_lo is not None:
            lo = max(lo, self.dbc_lo)
        if self.dbc_hi is not None:
            hi = min(hi, self.dbc_hi)
        if lo > hi:  # DBC range disjoint from the bits: trust the bits
            lo, hi = self.raw_lo, self.raw_hi
        self.lo, self.hi = lo, hi


class TxMessage:
    """State of one transmitted message: values, interaction layer, hooks, timers."""

    def __init__(self, ecu: Any, message: Any, timing: MessageTiming, hooks: list[Any]) -> None:
        db = ecu.db
        self.ecu = ecu
        self.message = message
        self.name = message.name
        self.timing = timing
        self.can_id, self.extended = frame_id_of(message)
        self.length = message.length
        self.fd, self.brs = fd_format(db, message)
        self.values = initial_values(db, message)
        self.signals = {s.name: s for s in message.signals}
        self.sig_timing = {s.name: signal_timing(db, s) for s in message.signals}
        self.limits: dict[str, SignalLimits] = {}
        self.hooks = hooks
        self.value_hooks = [h for h in hooks if getattr(h, "modifies_values", True)]
        self.data_hooks = [h for h in hooks if getattr(h, "modifies_data", True)]
        self.frame: Frame | None = None  # cached while values and hooks do not change it
        self.encode = message.encode
        self.default_trigger = timing.write_trigger()
        active_sigs = [n for n, st in self.sig_timing.items() if st.send_type == "IfActive"]
        if not active_sigs:
            active_sigs = [s.name for s in message.signals if not s.is_multiplexer]
        self.active_signals = active_sigs
        # scheduling state
        self.node = ecu.node
        self.if_active = timing.if_active
        self.running = False
        self.hold_until = 0
        self.last_tx: int | None = None
        self.cycle_timer: Any = None
        self.next_cycle = 0
        self.spont_timer: Any = None
        self.rep_timer: Any = None
        self.reps_left = 0
        self.active = False
        self.sent = 0
        # multiplexed: every page in turn, from the one the initial values select, until the
        # application writes a multiplexer (then that page stays: the application chose it)
        self.pages = pages(message)
        self.muxes = multiplexer_names(message)
        self.rotating = bool(self.pages)
        self.page_index = 0
        if self.pages:
            first = page_of(message, self.values)
            self.page_index = next((i for i, p in enumerate(self.pages) if p == first), 0)

    # ------------------------------------------------------------------ frames
    def build(self) -> Frame:
        """Encode the current values (hooks applied) into a frame."""
        f = self.frame
        if f is not None:
            return f
        values = self.values
        for h in self.value_hooks:  # alive counters write into the values: get() shows the last sent
            h.tx_values(values)
        data = self.encode(values, strict=False)
        for h in self.data_hooks:
            data = h.tx_data(data)
        f = frame_of_payload(self.message, data, self.brs)
        if not self.hooks:
            self.frame = f
        return f

    def preview(self, values: Mapping[str, Any] | None = None) -> Frame:
        """The frame the next transmission would carry with ``values`` merged over the current
        ones, hooks applied to shallow copies of themselves (an alive counter shows its next
        value without advancing): no state of the message or its hooks changes."""
        if values is None and self.frame is not None and not self.rotating:
            return self.frame
        vals = dict(self.values)
        if self.rotating and not (values and self.muxes.intersection(values)):
            for name, raw in self.pages[self.page_index].items():
                vals[name] = self.signals[name].conversion.raw_to_scaled(raw, False)
        if values is not None:
            vals.update(values)
        for h in self.value_hooks:
            copy.copy(h).tx_values(vals)
        data = self.encode(vals, strict=False)
        for h in self.data_hooks:
            data = copy.copy(h).tx_data(data)
        return frame_of_payload(self.message, data, self.brs)

    def next_page(self) -> None:
        """Select the page of the next transmission (rotation): the multiplexers' values of
        page ``page_index``, then advance the index."""
        page = self.pages[self.page_index]
        self.page_index = (self.page_index + 1) % len(self.pages)
        for name, raw in page.items():
            self.values[name] = self.signals[name].conversion.raw_to_scaled(raw, False)
        self.frame = None

    def transmit(self) -> Any:
        node = self.node
        if self.rotating:
            self.next_page()
        frame = self.frame or self.build()
        self.last_tx = node.now()
        self.sent += 1
        try:
            return node.send(frame)
        except QueueFull:
            self.ecu.tx_overflows += 1
            return None

    # ------------------------------------------------------------------ interaction layer
    def start(self, now: int) -> None:
        self.running = True
        t = self.timing
        self.hold_until = now + t.start_delay * 1_000_000
        if t.cyclic:
            self._start_cycle(self.hold_until, t.period_ns)
        elif t.if_active:
            self.active = self.is_active()
            if self.active:
                self._start_cycle(self.hold_until, t.fast_period_ns)

    def stop(self) -> None:
        self.running = False
        for tm in (self.cycle_timer, self.spont_timer, self.rep_timer):
            if tm is not None:
                tm.cancel()
        self.cycle_timer = self.spont_timer = self.rep_timer = None

    def _start_cycle(self, first: int, period: int) -> None:
        self.period = period
        self.next_cycle = first
        self.cycle_timer = self.ecu.node.call_at(first, self._cycle)

    def _cycle(self) -> None:
        # fixed rate: the next period is counted from the schedule, not from when we ran
        self.transmit()
        if self.if_active and not self.active:
            self.cycle_timer = None  # the last transmission carried the inactive values
            return
        self.next_cycle = t = self.next_cycle + self.period
        self.cycle_timer = self.node.call_at(t, self._cycle)

    def written(self, name: str, old: Any, new: Any) -> None:
        """A signal was written by the application: decide whether that triggers a send."""
        self.frame = None
        if name in self.muxes:
            self.rotating = False
        if not self.running:
            return
        st = self.sig_timing[name]
        kind = st.send_type or self.default_trigger
        t = self.timing
        fire = kind == "OnWrite" or (kind == "OnChange" and self.changed(name, old, new))
        if t.if_active and name in self.active_signals:
            self.activity(fire)
        if fire:
            self.trigger(st.with_repetition or t.with_repetition)

    def changed(self, name: str, old: Any, new: Any) -> bool:
        """Whether a write changed the value ('Open' and 1 are the same value of a choice)."""
        if old == new:
            return False
        conv = self.signals[name].conversion
        try:
            a = conv.choice_to_number(old) if isinstance(old, str) else old
            b = conv.choice_to_number(new) if isinstance(new, str) else new
        except Exception:
            return True
        return a != b

    def is_active(self) -> bool:
        for n in self.active_signals:
            inactive = self.sig_timing[n].inactive_raw or 0
            sig = self.signals[n]
            v = self.values[n]
            try:
                raw = sig.conversion.choice_to_number(v) if isinstance(v, str) else sig.conversion.scaled_to_raw(v)
            except Exception:
                return True
            if abs(raw - inactive) > 1e-9:
                return True
        return False

    def activity(self, spontaneous: bool) -> None:
        """Re-evaluate activity after a write; ``spontaneous``: the write also triggers a
        spontaneous transmission (CyclicIfActiveAndSpontaneous, or a signal's own OnWrite or
        OnChange send type), which then is the one frame of
        the event: becoming active, the fast cycle starts one fast period after it (see
        `_spontaneous`); becoming inactive, it carries the inactive values and the cycle stops.
        Without a spontaneous send, the cycle starts now (active) or sends the inactive values
        at its next slot and stops."""
        was = self.active
        self.active = active = self.is_active()
        if active == was:
            return
        if active:
            if self.cycle_timer is None and not spontaneous:
                start = max(self.ecu.node.now(), self.hold_until)
                self._start_cycle(start, self.timing.fast_period_ns)
        elif spontaneous and self.cycle_timer is not None:
            self.cycle_timer.cancel()
            self.cycle_timer = None

    def trigger(self, repeat: bool) -> None:
        """A spontaneous transmission, delayed by the start delay and (WithDelay types) the
        minimum gap; writes during a pending delay are coalesced."""
        if self.spont_timer is not None:
            return
        node = self.ecu.node
        now = node.now()
        t = self.timing
        at = max(now, self.hold_until)
        if t.with_delay and self.last_tx is not None:
            at = max(at, self.last_tx + t.delay_time * 1_000_000)
        self._repeat = repeat
        if at <= now:
            self._spontaneous()
        else:
            self.spont_timer = node.call_at(at, self._spontaneous)

    def _spontaneous(self) -> None:
        self.spont_timer = None
        self.transmit()
        t = self.timing
        last = self.last_tx  # set by transmit
        if last is not None and self.if_active and self.active and self.cycle_timer is None and self.running:
            # the spontaneous frame opened the active phase: the fast cycle follows it
            self._start_cycle(last + t.fast_period_ns, t.fast_period_ns)
        if self._repeat and t.repetitions and t.fast_period_ns:
            if self.rep_timer is not None:
                self.rep_timer.cancel()
            self.reps_left = t.repetitions
            self.rep_timer = self.ecu.node.call_later(t.fast_period_ns, self._repetition)

    def _repetition(self) -> None:
        self.transmit()
        self.reps_left -= 1
        if self.reps_left > 0:
            self.rep_timer = self.ecu.node.call_later(self.timing.fast_period_ns, self._repetition)
        else:
            self.rep_timer = None
