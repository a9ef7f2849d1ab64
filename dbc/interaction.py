"""The interaction layer: how a message is transmitted, read from the DBC's attributes.

cantools reads the attributes; this module only interprets them (``Message.cycle_time``,
``Message.send_type``, and ``.dbc.attributes`` of the database, messages and signals, falling
back to the ``BA_DEF_DEF_`` default of each definition).

Mapping (Vector interaction-layer attribute names):

==============================  ===============================================================
attribute                       meaning here
==============================  ===============================================================
``GenMsgSendType``              the message's send type, normalised to `SendType`:
                                ``Cyclic``/``FixedPeriodic`` → CYCLIC;
                                ``Spontaneous``/``OnWrite``/``Event`` → SPONTANEOUS;
                                ``OnChange`` → ON_CHANGE;
                                ``CyclicIfActive``/``IfActive``/``EnabledPeriodic`` → CYCLIC_IF_ACTIVE;
                                ``CyclicAndSpontaneous``/``EventPeriodic`` → CYCLIC_AND_SPONTANEOUS;
                                ``CyclicIfActiveAndSpontaneous`` → CYCLIC_IF_ACTIVE_AND_SPONTANEOUS;
                                a ``...WithDelay`` suffix sets ``with_delay``, a
                                ``...WithRepetition`` suffix ``with_repetition``;
                                ``NoMsgSendType``, ``NotUsed``, empty or unknown → NONE.
``GenMsgCycleTime`` (ms)        period of CYCLIC / CYCLIC_AND_SPONTANEOUS. A message whose send
                                type is NONE but has a cycle time > 0 is CYCLIC (many DBCs give
                                only the cycle time). No send type and no cycle time: the message
                                is sent on request only (`Ecu.send`).
``GenMsgCycleTimeFast`` (ms)    period while a CYCLIC_IF_ACTIVE message is active (falls back to
                                ``GenMsgCycleTime``), and the spacing of repetitions.
``GenMsgStartDelayTime`` (ms)   nothing of the message is sent before start + this delay; the
                                first cyclic transmission is at start + delay.
``GenMsgDelayTime`` (ms)        WithDelay types: minimum gap between two transmissions; writes
                                inside the gap are coalesced into one transmission at its end.
``GenMsgNrOfRepetition``        WithRepetition (message or signal send type): after a triggered
                                transmission, this many more copies, ``GenMsgCycleTimeFast`` apart.
``GenSigSendType``              what a write of the signal does: ``Cyclic`` nothing (wait for the
                                cycle); ``OnWrite`` send; ``OnChange`` send if the value changed;
                                ``IfActive`` re-evaluate activity; ``...WithRepetition`` adds
                                repetitions; ``NoSigSendType``/absent: follow the message
                                (SPONTANEOUS, the "...AndSpontaneous" types → OnWrite;
                                ON_CHANGE → OnChange; others → nothing).
``GenSigInactiveValue`` (raw)   CYCLIC_IF_ACTIVE: the message is active while any ``IfActive``
                                signal (or, if none is marked, any signal) differs from its
                                inactive value; it is sent once more when it becomes inactive.
                                When the write that changes activity also sends the message
                                spontaneously (CYCLIC_IF_ACTIVE_AND_SPONTANEOUS, or an OnWrite/
                                OnChange signal), that frame is the only one of the event:
                                becoming active, the fast cycle starts one
                                ``GenMsgCycleTimeFast`` after it; becoming inactive, it carries
                                the inactive values and the cycle stops. Otherwise the cycle
                                starts at the write, or sends the inactive values at its next
                                slot and stops.
``GenSigStartValue`` (raw)      the signal's initial value (raw → physical through its scaling);
                                cantools exposes it as ``Signal.raw_initial``; default 0 raw.
==============================  ===============================================================
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import Any

__all__ = [
    "SendType",
    "MessageTiming",
    "SignalTiming",
    "attribute",
    "message_timing",
    "signal_timing",
    "MS",
]

MS = 1_000_000


class SendType(str, Enum):
    """Normalised message send types (see the module docstring for the DBC names)."""

    CYCLIC = "Cyclic"
    SPONTANEOUS = "Spontaneous"
    ON_CHANGE = "OnChange"
    CYCLIC_IF_ACTIVE = "CyclicIfActive"
    CYCLIC_AND_SPONTANEOUS = "CyclicAndSpontaneous"
    CYCLIC_IF_ACTIVE_AND_SPONTANEOUS = "CyclicIfActiveAndSpontaneous"
    NONE = "NoMsgSendType"

    def __str__(self) -> str:
        return self.value


_BASE_TYPES: dict[str, SendType] = {
    "cyclic": SendType.CYCLIC,
    "fixedperiodic": SendType.CYCLIC,
    "periodic": SendType.CYCLIC,
    "spontaneous": SendType.SPONTANEOUS,
    "onwrite": SendType.SPONTANEOUS,
    "event": SendType.SPONTANEOUS,
    "onchange": SendType.ON_CHANGE,
    "cyclicifactive": SendType.CYCLIC_IF_ACTIVE,
    "ifactive": SendType.CYCLIC_IF_ACTIVE,
    "enabledperiodic": SendType.CYCLIC_IF_ACTIVE,
    "cyclicandspontaneous": SendType.CYCLIC_AND_SPONTANEOUS,
    "eventperiodic": SendType.CYCLIC_AND_SPONTANEOUS,
    "cyclicifactiveandspontaneous": SendType.CYCLIC_IF_ACTIVE_AND_SPONTANEOUS,
}

_CYCLIC = {SendType.CYCLIC, SendType.CYCLIC_AND_SPONTANEOUS}
_IF_ACTIVE = {SendType.CYCLIC_IF_ACTIVE, SendType.CYCLIC_IF_ACTIVE_AND_SPONTANEOUS}
_ON_WRITE = {SendType.SPONTANEOUS, SendType.CYCLIC_AND_SPONTANEOUS, SendType.CYCLIC_IF_ACTIVE_AND_SPONTANEOUS}


def _parse_send_type(name: str | None) -> tuple[SendType, bool, bool]:
    if not name:
        return SendType.NONE, False, False
    key = str(name).replace("_", "").replace(" ", "").lower()
    delay = rep = False
    if key.endswith("withdelay"):
        key, delay = key[: -len("withdelay")], True
    if key.endswith("withrepetition"):
        key, rep = key[: -len("withrepetition")], True
    return _BASE_TYPES.get(key, SendType.NONE), delay, rep


def attribute(db: Any, owner: Any, name: str) -> Any:
    """Value of DBC attribute ``name`` on ``owner`` (a cantools Message or Signal, or the
    Database): the ``BA_`` value if set, else the ``BA_DEF_DEF_`` default, else None.
    ENUM values are returned as their names."""
    own = getattr(owner, "dbc", None)
    attr = own.attributes.get(name) if own is not None and own.attributes else None
    dbc = getattr(db, "dbc", None)
    defs = dbc.attribute_definitions if dbc is not None and dbc.attribute_definitions else {}
    definition = attr.definition if attr is not None else defs.get(name)
    if attr is not None:
        value = attr.value
    elif definition is not None:
        value = definition.default_value
    else:
        return None
    if definition is not None and definition.type_name == "ENUM" and definition.choices:
        if isinstance(value, str) and value.strip().lstrip("-").isdigit() and value not in definition.choices:
            value = int(value)
        if isinstance(value, int) and 0 <= value < len(definition.choices):
            value = definition.choices[value]
    elif definition is not None and definition.type_name in ("INT", "HEX", "FLOAT") and isinstance(value, str):
        try:
            value = float(value) if definition.type_name == "FLOAT" else int(value, 0)
        except ValueError:
            value = None
    return value


def _ms(value: Any) -> int:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return 0
    return int(v) if v > 0 else 0


@dataclass(frozen=True)
class MessageTiming:
    """How a message is transmitted, from its interaction-layer attributes (times in ms).

    ``declared`` is the ``GenMsgSendType`` name as written in the DBC (None if absent).
    """

    send_type: SendType
    declared: str | None
    cycle_time: int = 0
    cycle_time_fast: int = 0
    delay_time: int = 0
    start_delay: int = 0
    repetitions: int = 0
    with_delay: bool = False
    with_repetition: bool = False

    @property
    def cyclic(self) -> bool:
        """Sent every ``cycle_time`` ms regardless of writes."""
        return self.send_type in _CYCLIC

    @property
    def if_active(self) -> bool:
        """Sent cyclically only while active (CyclicIfActive types)."""
        return self.send_type in _IF_ACTIVE

    @property
    def on_request_only(self) -> bool:
        """No send type and no cycle time: sent only when the application asks."""
        return self.send_type is SendType.NONE

    @property
    def period_ns(self) -> int:
        """Cyclic period in ns (0 if none)."""
        return self.cycle_time * MS

    @property
    def fast_period_ns(self) -> int:
        """Period while active and between repetitions in ns: ``GenMsgCycleTimeFast``, else
        ``GenMsgCycleTime``, else ``GenMsgDelayTime``."""
        return (self.cycle_time_fast or self.cycle_time or self.delay_time) * MS

    def write_trigger(self) -> str:
        """What a write of a signal with no own send type does: 'OnWrite', 'OnChange' or ''."""
        if self.send_type in _ON_WRITE:
            return "OnWrite"
        if self.send_type is SendType.ON_CHANGE:
            return "OnChange"
        return ""


@dataclass(frozen=True)
class SignalTiming:
    """A signal's interaction-layer attributes: ``send_type`` normalised to 'Cyclic', 'OnWrite',
    'OnChange', 'IfActive' or '' (none), ``with_repetition``, ``inactive_raw`` and
    ``start_raw`` (None when the DBC gives no start value)."""

    send_type: str
    with_repetition: bool
    inactive_raw: float | int | None
    start_raw: float | int | None


_SIG_TYPES = {
    "cyclic": "Cyclic",
    "onwrite": "OnWrite",
    "onchange": "OnChange",
    "ifactive": "IfActive",
    "spontaneous": "OnWrite",
    "event": "OnWrite",
}


def message_timing(db: Any, message: Any) -> MessageTiming:
    """The `MessageTiming` of a cantools message (see the module docstring for the mapping)."""
    declared = attribute(db, message, "GenMsgSendType")
    if declared is None:
        declared = message.send_type
    st, delay, rep = _parse_send_type(declared)
    cycle = _ms(attribute(db, message, "GenMsgCycleTime"))
    if not cycle and message.cycle_time:
        cycle = _ms(message.cycle_time)
    fast = _ms(attribute(db, message, "GenMsgCycleTimeFast"))
    if st is SendType.NONE and cycle:
        st = SendType.CYCLIC
    if st in _CYCLIC and not cycle:
        # a cyclic type without a period cannot cycle: its spontaneous part (if any) remains
        st = SendType.SPONTANEOUS if st is SendType.CYCLIC_AND_SPONTANEOUS else SendType.NONE
    if st in _IF_ACTIVE and not (fast or cycle):
        st = SendType.SPONTANEOUS if st is SendType.CYCLIC_IF_ACTIVE_AND_SPONTANEOUS else SendType.NONE
    reps = _ms(attribute(db, message, "GenMsgNrOfRepetition"))
    return MessageTiming(
        send_type=st,
        declared=None if declared is None else str(declared),
        cycle_time=cycle,
        cycle_time_fast=fast,
        delay_time=_ms(attribute(db, message, "GenMsgDelayTime")),
        start_delay=_ms(attribute(db, message, "GenMsgStartDelayTime")),
        repetitions=reps,
        with_delay=delay,
        with_repetition=rep,
    )


def signal_timing(db: Any, signal: Any) -> SignalTiming:
    """The `SignalTiming` of a cantools signal (``GenSigSendType``, ``GenSigInactiveValue``,
    ``GenSigStartValue``)."""
    name = attribute(db, signal, "GenSigSendType")
    key = str(name or "").replace("_", "").lower()
    rep = key.endswith("withrepetition")
    if rep:
        key = key[: -len("withrepetition")]
    inactive = attribute(db, signal, "GenSigInactiveValue")
    start = signal.raw_initial
    if start is None:
        start = attribute(db, signal, "GenSigStartValue")
    try:
        inactive = None if inactive is None else (float(inactive) if signal.is_float else int(float(inactive)))
    except (TypeError, ValueError):
        inactive = None
    try:
        start = None if start is None else (float(start) if signal.is_float else int(float(start)))
    except (TypeError, ValueError):
        start = None
    return SignalTiming(_SIG_TYPES.get(key, ""), rep, inactive, start)
