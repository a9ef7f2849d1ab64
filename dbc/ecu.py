"""An ECU built from a DBC: the node's messages encoded, scheduled and decoded (sans-IO).

`Ecu(db, "ECM", node)` transmits every message the DBC says node ECM sends, following the
interaction layer (`dbc.interaction`), and decodes every frame of the database it receives.
It acts only through the node (``send``, ``call_at``, ``now``, ``subscribe``), so the same ECU
runs on the simulated bus and on a python-can bus.

CAN FD messages (cantools' ``Message.is_fd``, from the DBC's ``VFrameFormat``) go out as FD
frames, with bit rate switching as the DBC's ``CANFD_BRS`` attribute says (`dbc.transmit.fd_format`)
and their payload padded to the next CAN FD length; the node must be FD enabled (a bus with a data
bit rate), else the ECU refuses to be made (`FdNotCarriedError`, naming the message).

Values are physical (scaled) values, or choice names for signals with a value table. Encoding
and decoding are cantools' ``Message.encode``/``decode``: what goes on the wire is exactly what
cantools gives for the same values.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cantools

from stack import Frame, NodeAPI, Received
from stack.controller.node import FD

from .checks import checks_from_attributes
from .errors import ChoiceError, DbcError, FdNotCarriedError, SignalRangeError, UnknownNameError, load_database
from .interaction import MessageTiming, SendType, message_timing
from .transmit import SignalLimits, TxMessage, fd_format, frame_id_of, frame_of_payload, initial_values

__all__ = [
    "Ecu",
    "MessageReceived",
    "SignalChanged",
    "CheckFailed",
    "node_names",
    "initial_values",
    "frame_id_of",
    "unsupported_reason",
    "SKIP_KINDS",
    "NO_NODE",
    "senderless",
    "j1939_pgn",
]

#: The DBC's placeholder for "no node" (``Vector__XXX``); an `Ecu` of that name sends the
#: messages that no node sends (a rest bus with ``default_cycle_ms``).
NO_NODE = "Vector__XXX"


def senderless(message: Any) -> bool:
    """Whether no node sends a cantools message: no sender, or only ``Vector__XXX``."""
    return all(s == NO_NODE for s in message.senders)


#: Why a database message cannot be a CAN frame, as `unsupported_reason` names it, in the
#: order messages are summarised.
SKIP_KINDS = ("longer than 8 bytes", "longer than 64 bytes", "container")


def unsupported_reason(m: Any) -> tuple[str, str] | None:
    """Why a cantools message cannot be sent or received as one CAN frame (ISO 11898-1:2015: a
    classical frame carries at most 8 data bytes, a CAN FD frame at most 64): (kind,
    explanation), kind one of `SKIP_KINDS`; None when it can."""
    if m.is_container:
        return "container", "container message (AUTOSAR): not one CAN frame"
    if m.is_fd and m.length > 64:
        return "longer than 64 bytes", f"{m.length} bytes: a CAN FD frame carries at most 64"
    if not m.is_fd and m.length > 8:
        return "longer than 8 bytes", f"{m.length} bytes: a classical CAN frame carries at most 8 (CAN FD: 64)"
    return None


@dataclass(frozen=True, slots=True)
class MessageReceived:
    """A database message was received and decoded (physical values, choices as
    `NamedSignalValue`). ``failures`` lists the checks it failed (empty if none)."""

    time: int
    message: str
    signals: dict[str, Any]
    frame: Frame
    failures: tuple[str, ...] = ()


@dataclass(frozen=True, slots=True)
class SignalChanged:
    """A received signal differs from its previous received value (``old`` None at first)."""

    time: int
    message: str
    signal: str
    old: Any
    new: Any


@dataclass(frozen=True, slots=True)
class CheckFailed:
    """A received frame failed a check (alive counter, checksum, E2E, or decoding): ``check``
    names the hook, ``reason`` says what was wrong."""

    time: int
    message: str
    check: str
    reason: str
    frame: Frame


def node_names(db: cantools.database.can.Database) -> list[str]:
    """Names of the nodes of a database, each once, in order: ``BU_`` nodes (a node listed
    twice there, as some real DBCs do, counts once), then senders not declared there
    (``Vector__XXX``, the "no node" placeholder, excluded)."""
    names = list(dict.fromkeys(n.name for n in db.nodes))
    for m in db.messages:
        for s in m.senders:
            if s not in names:
                names.append(s)
    return [n for n in names if n != "Vector__XXX"]


class _RxMessage:
    __slots__ = ("message", "name", "length", "hooks", "values", "decode", "time", "count", "muxed")

    def __init__(self, message: Any, hooks: list[Any]) -> None:
        self.message = message
        self.name = message.name
        self.length = message.length
        self.hooks = hooks
        self.values: dict[str, Any] | None = None
        self.decode = message.decode
        self.time: int | None = None
        self.count = 0
        self.muxed = message.is_multiplexed()


class Ecu:
    """A DBC node on a stack node: transmits the node's messages, decodes what it receives.

    - ``db``: a cantools `Database` or a path (loaded with `load_database`);
    - ``name``: the DBC node (``BU_``) this ECU is; unknown names raise `UnknownNameError` with
      the closest ones;
    - ``node``: a `stack.controller.node.Node` (simulated or python-can driven);
    - ``clamp``: out-of-range writes are clamped to the signal's range instead of raising
      `SignalRangeError` (strict is the default);
    - ``checks``: alive counter / checksum hooks (`dbc.checks`); None takes those declared in
      the DBC (``CanstackCheck`` attribute), ``[]`` none;
    - ``start``: start the interaction layer now (else call `start`);
    - ``default_cycle_ms``: the period of the messages the DBC gives neither a send type nor a
      cycle time (else they are sent on `send` only). ``name`` may be ``"Vector__XXX"``
      (`NO_NODE`): that ECU sends the messages no node sends.

    Transmitted: every message whose DBC senders include ``name``, CAN FD messages as FD frames
    (the node must be FD enabled, else `FdNotCarriedError`); classical messages longer than 8
    bytes and container messages are listed in ``unsupported`` and skipped. Received:
    every other message of the database, matched by identifier and format (J1939 messages
    also by PGN, any source address). A received frame that fails a check is reported
    (`CheckFailed` to `on_check_failed` callbacks, ``check_failures`` counter) and its values are
    not applied unless ``accept_failed``.
    """

    def __init__(
        self,
        db: cantools.database.can.Database | str | Path,
        name: str,
        node: NodeAPI,
        *,
        clamp: bool = False,
        checks: Iterable[Any] | None = None,
        start: bool = True,
        accept_failed: bool = False,
        default_cycle_ms: int | None = None,
    ) -> None:
        if not isinstance(db, cantools.database.can.Database):
            db = load_database(db)
        self.db = db
        names = node_names(db)
        if default_cycle_ms is not None and default_cycle_ms <= 0:
            raise DbcError(f"default cycle {default_cycle_ms} ms: a period must be > 0 ms")
        if name not in names and not (name == NO_NODE and any(senderless(m) for m in db.messages)):
            raise UnknownNameError(
                "node", name, names, "in the database" + (f" (nodes: {', '.join(names)})" if len(names) <= 12 else "")
            )
        self.name = name
        self.node = node
        self.clamp = clamp
        self.accept_failed = accept_failed
        self.tx_overflows = 0
        self.check_failures: dict[tuple[str, str], int] = {}
        self.unsupported: dict[str, str] = {}
        hooks = list(checks_from_attributes(db) if checks is None else checks)
        by_msg: dict[str, list[Any]] = {}
        message_names = {m.name for m in db.messages}
        for h in hooks:
            if h.message not in message_names:
                raise UnknownNameError("message", h.message, [m.name for m in db.messages], f"in hook {h.name}")
            by_msg.setdefault(h.message, []).append(h)
        self._tx: dict[str, TxMessage] = {}
        self._rx: dict[str, _RxMessage] = {}
        self._rx_by_id: dict[tuple[int, bool], _RxMessage] = {}
        self._rx_by_pgn: dict[int, _RxMessage] = {}
        for m in db.messages:
            reason = self._unsupported(m)
            if reason:
                self.unsupported[m.name] = reason
                continue
            specs = by_msg.get(m.name, [])
            if name in m.senders or (name == NO_NODE and senderless(m)):
                timing = message_timing(db, m)
                if default_cycle_ms is not None and timing.on_request_only:
                    timing = dataclasses.replace(timing, send_type=SendType.CYCLIC, cycle_time=default_cycle_ms)
                self._tx[m.name] = TxMessage(self, m, timing, [s.bind(m) for s in specs])
            else:
                rx = _RxMessage(m, [s.bind(m) for s in specs])
                self._rx[m.name] = rx
                self._rx_by_id[frame_id_of(m)] = rx
                if m.protocol == "j1939" and m.is_extended_frame:
                    self._rx_by_pgn.setdefault(j1939_pgn(m.frame_id), rx)
        kind = getattr(node, "fd", FD)  # a node that does not say (a test's stand-in) is not refused
        if kind != FD:
            fd_tx = next((tx for tx in self._tx.values() if tx.fd), None)
            if fd_tx is not None:
                raise FdNotCarriedError(fd_tx.name, getattr(node, "name", "?"), kind, fd_tx.length)
        self._msg_cbs: dict[str, list[Callable[[MessageReceived], Any]]] = {}
        self._sig_cbs: dict[str, dict[str, list[Callable[[SignalChanged], Any]]]] = {}
        self._fail_cbs: list[Callable[[CheckFailed], Any]] = []
        self._any_cbs: list[Callable[[MessageReceived], Any]] = []
        self._sig_index: dict[str, list[str]] = {}
        for m in db.messages:
            for s in m.signals:
                self._sig_index.setdefault(s.name, []).append(m.name)
        self.running = False
        self._sub = node.subscribe(self._on_frame) if self._rx else None
        if start:
            self.start()

    @staticmethod
    def _unsupported(m: Any) -> str | None:
        why = unsupported_reason(m)
        return None if why is None else why[1]

    # ------------------------------------------------------------------ names
    @property
    def tx_messages(self) -> list[str]:
        """Names of the messages this ECU transmits."""
        return list(self._tx)

    @property
    def rx_messages(self) -> list[str]:
        """Names of the messages this ECU decodes."""
        return list(self._rx)

    def _message(self, name: str) -> Any:
        try:
            return self.db.get_message_by_name(name)
        except KeyError:
            raise UnknownNameError("message", name, [m.name for m in self.db.messages]) from None

    def _tx_message(self, name: str) -> TxMessage:
        tx = self._tx.get(name)
        if tx is not None:
            return tx
        m = self._message(name)
        if m.name in self.unsupported:
            raise DbcError(f"message {name} cannot be sent: {self.unsupported[m.name]}")
        raise DbcError(f"ECU {self.name} does not send message {name} (sent by {', '.join(m.senders) or 'no node'})")

    def _resolve(self, signal: str, message: str | None, pool: Mapping[str, Any]) -> tuple[str, str]:
        """(message, signal) for 'Signal', 'Message.Signal' or signal + message."""
        if message is None and "." in signal and signal not in self._sig_index:
            message, signal = signal.split(".", 1)
        if message is not None:
            m = self._message(message)
            names = [s.name for s in m.signals]
            if signal not in names:
                raise UnknownNameError("signal", signal, names, f"in message {message}")
            return message, signal
        owners = self._sig_index.get(signal)
        if not owners:
            raise UnknownNameError("signal", signal, self._sig_index)
        mine = [o for o in owners if o in pool]
        cands = mine or owners
        if len(cands) > 1:
            raise DbcError(f"signal {signal!r} is in messages {', '.join(cands)}: name one, e.g. '{cands[0]}.{signal}'")
        return cands[0], signal

    # ------------------------------------------------------------------ values
    def check_value(self, message: str, signal: str, value: Any, *, clamp: bool | None = None) -> Any:
        """The value ``signal`` of ``message`` would be written with: a choice name must exist
        (`ChoiceError`, with the closest names); a number must be within the signal's range —
        the DBC minimum/maximum and what its raw bits hold — else `SignalRangeError`, or, with
        clamping, the nearest bound."""
        sig = self._message(message).get_signal_by_name(signal)
        if isinstance(value, str):
            choices = sig.choices or {}
            names = [str(v) for v in choices.values()]
            if value in names:
                return value
            if not choices:
                raise DbcError(f"signal {message}.{signal} has no value table: {value!r} is not a number")
            raise ChoiceError(
                "choice",
                value,
                names,
                f"for signal {message}.{signal} (choices: {', '.join(names[:8])}{' ...' if len(names) > 8 else ''})",
            )
        if isinstance(value, bool):
            value = int(value)
        if not isinstance(value, (int, float)):
            num = getattr(value, "value", None)
            if isinstance(num, (int, float)):
                return num  # a NamedSignalValue read back from a decoded frame
            raise DbcError(f"signal {message}.{signal}: value {value!r} is neither a number nor a choice name")
        if isinstance(value, float) and not math.isfinite(value):
            raise SignalRangeError(f"signal {message}.{signal}: {value} is not a finite number")
        lim = self._limits(message, sig)
        if lim.lo <= value <= lim.hi:
            return value
        if self.clamp if clamp is None else clamp:
            return lim.lo if value < lim.lo else lim.hi
        unit = f" {sig.unit}" if sig.unit else ""
        src = "DBC range" if (lim.lo, lim.hi) != (lim.raw_lo, lim.raw_hi) else f"{sig.length}-bit raw range"
        raise SignalRangeError(
            f"signal {message}.{signal}: {value}{unit} is outside its {src} [{_fmt(lim.lo)} .. {_fmt(lim.hi)}]{unit}"
        )

    def _limits(self, message: str, sig: Any) -> SignalLimits:
        tx = self._tx.get(message)
        if tx is not None:
            lim = tx.limits.get(sig.name)
            if lim is None:
                lim = tx.limits[sig.name] = SignalLimits(sig)
            return lim
        return SignalLimits(sig)

    def set(self, signal: str, value: Any, *, message: str | None = None, clamp: bool | None = None) -> None:
        """Write a signal of a transmitted message (physical value or choice name), checked
        against its range; the interaction layer decides whether this sends the message.
        ``signal`` is 'Signal' or 'Message.Signal'.

        Multiplexed messages: every signal keeps its own value, whatever page the multiplexer
        selects. The message sends every page in turn (one page per frame, in the order of the
        multiplexer values, from the page the initial values select), so a value written for a
        signal of any page goes out when its page comes round. Writing a multiplexer signal
        stops the rotation: from then on every frame carries the page the application selected
        (`rotate_pages` starts the rotation again)."""
        msg, sig = self._resolve(signal, message, self._tx)
        tx = self._tx_message(msg)
        v = self.check_value(msg, sig, value, clamp=clamp)
        old = tx.values.get(sig)
        tx.values[sig] = v
        tx.written(sig, old, v)

    def update(self, message: str, values: Mapping[str, Any], *, clamp: bool | None = None) -> None:
        """Write several signals of one transmitted message at once (all checked before any is
        written); one write event per signal, spontaneous sends coalesce per call. Signals of
        multiplexed pages behave as in `set`."""
        tx = self._tx_message(message)
        checked = {}
        for k, v in values.items():
            _, sig = self._resolve(k, message, self._tx)
            checked[sig] = self.check_value(message, sig, v, clamp=clamp)
        old = {k: tx.values.get(k) for k in checked}
        tx.values.update(checked)
        tx.frame = None
        if tx.muxes.intersection(checked):
            tx.rotating = False
        if not tx.running:
            return
        t = tx.timing
        fired = rep = False
        for k, v in checked.items():
            st = tx.sig_timing[k]
            kind = st.send_type or tx.default_trigger
            if kind == "OnWrite" or (kind == "OnChange" and tx.changed(k, old[k], v)):
                fired = True
                rep = rep or st.with_repetition or t.with_repetition
        if t.if_active:
            tx.activity(fired)
        if fired:
            tx.trigger(rep)

    def values(self, message: str) -> dict[str, Any]:
        """Current values of a transmitted message, or the last received values of a received
        one (empty dict if nothing was received yet). For a multiplexed message, each signal's
        last received value, whichever page it came in."""
        tx = self._tx.get(message)
        if tx is not None:
            return dict(tx.values)
        self._message(message)
        rx = self._rx.get(message)
        if rx is None:
            raise DbcError(
                f"message {message} is neither sent nor received by ECU {self.name}: "
                f"{self.unsupported.get(message, '')}"
            )
        return dict(rx.values or {})

    def get(self, signal: str, *, message: str | None = None, default: Any = None) -> Any:
        """Last received value of a signal ('Signal' or 'Message.Signal'); for a signal this ECU
        transmits, its current value. ``default`` if nothing was received yet. A signal of a
        multiplexed page keeps its value while frames of other pages arrive."""
        msg, sig = self._resolve(signal, message, self._rx)
        tx = self._tx.get(msg)
        if tx is not None:
            return tx.values.get(sig, default)
        rx = self._rx.get(msg)
        if rx is None or rx.values is None:
            return default
        return rx.values.get(sig, default)

    def timing(self, message: str) -> MessageTiming:
        """Interaction-layer timing of a message (`dbc.interaction.message_timing`; for a
        transmitted message, as this ECU sends it, ``default_cycle_ms`` applied)."""
        tx = self._tx.get(message)
        if tx is not None:
            return tx.timing
        return message_timing(self.db, self._message(message))

    def would_be_active(self, message: str) -> bool:
        """Whether a CyclicIfActive message's current values make it active (any active
        signal away from its ``GenSigInactiveValue``)."""
        return self._tx_message(message).is_active()

    # ------------------------------------------------------------------ transmit
    def send(self, message: str, values: Mapping[str, Any] | None = None) -> Any:
        """Send a transmitted message now (on-request messages, or an extra copy of any other),
        after writing ``values`` (checked) without triggering the interaction layer; returns the
        node's transmit request."""
        tx = self._tx_message(message)
        if values:
            for k, v in values.items():
                _, sig = self._resolve(k, message, self._tx)
                tx.values[sig] = self.check_value(message, sig, v)
                if sig in tx.muxes:
                    tx.rotating = False
            tx.frame = None
        return tx.transmit()

    def rotate_pages(self, message: str, rotate: bool = True) -> None:
        """Send the pages of a multiplexed message in turn (``rotate``, the default from the
        start), or keep the page its multiplexers select now (what writing a multiplexer
        does); `DbcError` for a message without multiplexer."""
        tx = self._tx_message(message)
        if not tx.pages:
            raise DbcError(f"message {message} is not multiplexed: it has no pages to rotate")
        tx.rotating = rotate
        tx.frame = None

    def encode_frame(self, message: str, values: Mapping[str, Any] | None = None) -> Frame:
        """The frame the ECU path makes for ``message`` with ``values`` (default: its current or
        initial values), hooks of transmitted messages applied, without sending it: nothing
        changes (an alive counter shows the value the next transmission will carry, and that
        transmission still carries it)."""
        tx = self._tx.get(message)
        if tx is None:
            m = self._message(message)
            if m.name in self.unsupported:
                raise DbcError(f"message {message} cannot be encoded: {self.unsupported[m.name]}")
            vals = initial_values(self.db, m) if values is None else dict(values)
            return frame_of_payload(m, m.encode(vals, strict=False), fd_format(self.db, m)[1])
        return tx.preview(values)

    def decode_frame(self, frame: Frame) -> tuple[str, dict[str, Any]] | None:
        """(message name, physical values) of a frame, as the ECU decodes it on reception; None
        for an identifier the database does not know."""
        m = self._lookup(frame)
        if m is None:
            return None
        return m.name, m.decode(_payload(frame.data, m.length), decode_choices=True, scaling=True)

    def _lookup(self, frame: Frame) -> Any:
        rx = self._rx_by_id.get((frame.can_id, frame.extended))
        if rx is not None:
            return rx.message
        for tx in self._tx.values():
            if tx.can_id == frame.can_id and tx.extended == frame.extended:
                return tx.message
        if frame.extended and self._rx_by_pgn:
            rx = self._rx_by_pgn.get(j1939_pgn(frame.can_id))
            if rx is not None:
                return rx.message
        return None

    # ------------------------------------------------------------------ lifecycle
    def start(self, messages: Iterable[str] | None = None) -> None:
        """Start the interaction layer (of ``messages`` only, if given): cyclic messages begin
        after their start delay; messages already running are left alone."""
        txs = list(self._tx.values()) if messages is None else [self._tx_message(m) for m in messages]
        self.running = True
        now = self.node.now()
        for tx in txs:
            if not tx.running:
                tx.start(now)

    def stop(self) -> None:
        """Stop transmitting (timers cancelled); reception goes on."""
        self.running = False
        for tx in self._tx.values():
            tx.stop()

    def sent(self, message: str) -> int:
        """How many times this ECU queued ``message``."""
        return self._tx_message(message).sent

    # ------------------------------------------------------------------ receive
    def on_message(self, message: str | None, callback: Callable[[MessageReceived], Any]) -> None:
        """Call ``callback(MessageReceived)`` for each reception of ``message`` (None: of every
        received database message)."""
        if message is None:
            self._any_cbs.append(callback)
            return
        self._message(message)
        self._msg_cbs.setdefault(message, []).append(callback)

    def on_signal(self, signal: str, callback: Callable[[SignalChanged], Any], *, message: str | None = None) -> None:
        """Call ``callback(SignalChanged)`` when a received signal ('Signal' or
        'Message.Signal') changes value (and at its first reception)."""
        msg, sig = self._resolve(signal, message, self._rx)
        self._sig_cbs.setdefault(msg, {}).setdefault(sig, []).append(callback)

    def on_check_failed(self, callback: Callable[[CheckFailed], Any]) -> None:
        """Call ``callback(CheckFailed)`` for each received frame failing a check."""
        self._fail_cbs.append(callback)

    @property
    def failed_checks(self) -> int:
        """Total number of failed checks on reception."""
        return sum(self.check_failures.values())

    def _fail(self, t: int, rx: _RxMessage, check: str, reason: str, frame: Frame) -> None:
        key = (rx.name, check)
        self.check_failures[key] = self.check_failures.get(key, 0) + 1
        ev = CheckFailed(t, rx.name, check, reason, frame)
        for cb in self._fail_cbs:
            cb(ev)

    def _on_frame(self, ev: Received) -> None:
        frame = ev.frame
        rx = self._rx_by_id.get((frame.can_id, frame.extended))
        if rx is None:
            if not (frame.extended and self._rx_by_pgn):
                return
            rx = self._rx_by_pgn.get(j1939_pgn(frame.can_id))
            if rx is None:
                return
        if frame.remote:
            return
        data = _payload(frame.data, rx.length)
        try:
            decoded = rx.decode(data)
        except Exception as exc:  # short frame, bad multiplexer value ...
            self._fail(ev.time, rx, "decode", " ".join(str(exc).split()), frame)
            return
        failures: tuple[str, ...] = ()
        if rx.hooks:
            bad = []
            for h in rx.hooks:
                reason = h.rx(data, decoded)
                if reason is not None:
                    bad.append(reason)
                    self._fail(ev.time, rx, h.name, reason, frame)
            failures = tuple(bad)
            if bad and not self.accept_failed:
                return
        old = rx.values
        # a multiplexed frame carries one page: every other signal keeps its last received value
        rx.values = decoded if old is None or not rx.muxed else {**old, **decoded}
        rx.time = ev.time
        rx.count += 1
        sig_cbs = self._sig_cbs.get(rx.name)
        if sig_cbs:
            for s, cbs in sig_cbs.items():
                new = decoded.get(s)
                prev = None if old is None else old.get(s)
                if s in decoded and (old is None or prev != new):
                    ch = SignalChanged(ev.time, rx.name, s, prev, new)
                    for sig_cb in cbs:
                        sig_cb(ch)
        msg_cbs = self._msg_cbs.get(rx.name)
        if msg_cbs or self._any_cbs:
            mr = MessageReceived(ev.time, rx.name, decoded, frame, failures)
            for msg_cb in msg_cbs or ():
                msg_cb(mr)
            for any_cb in self._any_cbs:
                any_cb(mr)

    def __repr__(self) -> str:
        return f"<Ecu {self.name} tx={len(self._tx)} rx={len(self._rx)}>"


def j1939_pgn(can_id: int) -> int:
    """The J1939 parameter group number of a 29-bit identifier (SAE J1939-21): bits 8..25, the
    PDU specific byte (the destination address) left out when the PDU format is below 240 (PDU1)."""
    pf = (can_id >> 16) & 0xFF
    pgn = (can_id >> 8) & 0x3FFFF
    if pf < 240:
        pgn &= 0x3FF00
    return pgn


def _payload(data: bytes, length: int) -> bytes:
    """A received frame's data without the padding a CAN FD frame adds after the DBC's length."""
    return data if len(data) <= length else data[:length]


def _fmt(x: float) -> str:
    return f"{x:g}"
