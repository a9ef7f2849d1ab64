"""Alive counters and checksums: hooks applied at each transmission, checked at each reception.

A hook is a specification (`AliveCounter`, `Checksum`, `E2E`) naming a message and a signal; an
`Ecu` binds it to the cantools message once per direction (``bind``), so each ECU keeps its own
counter state. A bound hook has three steps:

- ``tx_values(values)`` before encoding (an alive counter writes its next value);
- ``tx_data(data) -> bytes`` after encoding (a checksum writes itself into the payload);
- ``rx(data, decoded) -> str | None`` at reception: None if the check passes, else the reason.

Checksum input: the payload with the checksum signal's bits cleared, leaving out the bytes the
checksum signal covers completely (an 8-bit checksum in byte 7 covers bytes 0..6). The value
is the algorithm's result masked to the signal's length.

Hooks can also come from the DBC: a signal attribute ``CanstackCheck`` (STRING) with the value
``counter``, ``xor``, ``sum``, ``crc8_sae_j1850``, ``crc8_autosar``, ``e2e_p2:<data id>`` or
``e2e_p5:<data id>`` (see `checks_from_attributes`).
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import Any, Protocol

import cantools

from .errors import DbcError, UnknownNameError
from .interaction import attribute

__all__ = [
    "AliveCounter",
    "Checksum",
    "E2E",
    "BoundHook",
    "ALGORITHMS",
    "xor8",
    "sum8",
    "crc8_sae_j1850",
    "crc8_autosar",
    "checks_from_attributes",
    "hook_from_spec",
]


def _crc8_table(poly: int) -> list[int]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return table


_J1850 = _crc8_table(0x1D)
_AUTOSAR = _crc8_table(0x2F)


def xor8(data: bytes) -> int:
    """XOR of all bytes."""
    x = 0
    for b in data:
        x ^= b
    return x


def sum8(data: bytes) -> int:
    """Additive checksum: sum of all bytes modulo 256."""
    return sum(data) & 0xFF


def crc8_sae_j1850(data: bytes) -> int:
    """CRC-8 SAE J1850: poly 0x1D, init 0xFF, final XOR 0xFF, no reflection (check 0x4B).

    Table-driven by hand because crccheck's generic engine costs much more per byte on the
    transmit path of every protected message (the figure is on the benchmarks page)."""
    crc = 0xFF
    t = _J1850
    for b in data:
        crc = t[crc ^ b]
    return crc ^ 0xFF


def crc8_autosar(data: bytes) -> int:
    """CRC-8H2F (AUTOSAR): poly 0x2F, init 0xFF, final XOR 0xFF, no reflection (check 0xDF)."""
    crc = 0xFF
    t = _AUTOSAR
    for b in data:
        crc = t[crc ^ b]
    return crc ^ 0xFF


ALGORITHMS: dict[str, Callable[[bytes], int]] = {
    "xor": xor8,
    "sum": sum8,
    "additive": sum8,
    "crc8_sae_j1850": crc8_sae_j1850,
    "crc8": crc8_sae_j1850,
    "crc8_autosar": crc8_autosar,
}


class BoundHook(Protocol):
    """A hook bound to one message of one ECU (see the module docstring)."""

    name: str
    modifies_values: bool
    modifies_data: bool

    def tx_values(self, values: dict[str, Any]) -> None: ...

    def tx_data(self, data: bytes) -> bytes: ...

    def rx(self, data: bytes, decoded: dict[str, Any]) -> str | None: ...


def _signal(message: Any, name: str) -> Any:
    for s in message.signals:
        if s.name == name:
            return s
    raise UnknownNameError("signal", name, [s.name for s in message.signals], f"in message {message.name}")


def _raw_range(sig: Any) -> tuple[int, int]:
    if sig.is_signed:
        lo, hi = -(1 << (sig.length - 1)), (1 << (sig.length - 1)) - 1
    else:
        lo, hi = 0, (1 << sig.length) - 1
    conv = sig.conversion
    for bound, pick in ((sig.minimum, max), (sig.maximum, min)):
        if bound is None:
            continue
        try:
            raw = conv.scaled_to_raw(bound)
        except Exception:  # pragma: no cover - exotic conversions
            continue
        raw = round(raw)
        if pick is max:
            lo = max(lo, raw) if conv.scale > 0 else lo
        else:
            hi = min(hi, raw) if conv.scale > 0 else hi
    return (lo, hi) if lo <= hi else (0, (1 << sig.length) - 1)


class AliveCounter:
    """An alive (rolling) counter in ``signal`` of ``message``: each transmission sends the
    next raw value, wrapping from the top of the signal's range (its DBC minimum/maximum, else
    its bit range) to the bottom; each reception expects the previous value + 1 (wrapped) and
    reports a repeated or skipped value. The first reception is accepted as is."""

    def __init__(self, message: str, signal: str) -> None:
        self.message = message
        self.signal = signal
        self.name = f"counter {signal}"

    def bind(self, message: Any) -> _BoundCounter:
        """Counter state for one message of one ECU."""
        return _BoundCounter(self, message)


class _BoundCounter:
    modifies_values = True
    modifies_data = False

    def __init__(self, spec: AliveCounter, message: Any) -> None:
        sig = _signal(message, spec.signal)
        self.name = spec.name
        self.signal = sig.name
        self.lo, self.hi = _raw_range(sig)
        self.conv = sig.conversion
        init = sig.raw_initial
        self.next = int(init) if init is not None and self.lo <= init <= self.hi else self.lo
        self.last: int | None = None
        self.identity = self.conv.scale == 1 and self.conv.offset == 0

    def _wrap(self, v: int) -> int:
        return self.lo if v > self.hi else v

    def tx_values(self, values: dict[str, Any]) -> None:
        raw = self.next
        values[self.signal] = raw if self.identity else self.conv.raw_to_scaled(raw, False)
        self.next = self._wrap(raw + 1)

    def tx_data(self, data: bytes) -> bytes:
        return data

    def rx(self, data: bytes, decoded: dict[str, Any]) -> str | None:
        v = decoded.get(self.signal)
        if v is None:
            return None  # not in this multiplexed variant
        raw = round(self.conv.scaled_to_raw(float(getattr(v, "value", v))))
        last, self.last = self.last, raw
        if last is None:
            return None
        expected = self._wrap(last + 1)
        if raw != expected:
            return f"alive counter {self.signal} = {raw}, expected {expected}" + (" (repeated)" if raw == last else "")
        return None


class _Placement:
    """Where a signal's bits are in the payload: a mask and a function placing a raw value."""

    def __init__(self, message: Any, sig: Any) -> None:
        s = copy.copy(sig)
        s.multiplexer_ids = None
        s.multiplexer_signal = None
        s.is_multiplexer = False
        self.msg = cantools.database.can.Message(
            frame_id=message.frame_id,
            name="_placement",
            length=message.length,
            signals=[s],
            is_extended_frame=message.is_extended_frame,
            strict=False,
        )
        self.sig_name = s.name
        all_ones = -1 if s.is_signed else (1 << s.length) - 1
        mask = self.msg.encode({s.name: all_ones}, scaling=False, strict=False)
        self.mask = int.from_bytes(mask, "big")
        self.length = message.length
        self.value_mask = (1 << s.length) - 1
        self.signed = s.is_signed
        full = [i for i, b in enumerate(mask) if b == 0xFF]
        self.skip = set(full)
        # fast path: the signal is exactly one byte
        self.byte = full[0] if s.length == 8 and len(full) == 1 else None

    def input(self, data: bytes) -> bytes:
        """Payload with the signal's bits cleared, without the bytes it covers completely."""
        if self.byte is not None:
            b = self.byte
            return data[:b] + data[b + 1 :]
        cleared = (int.from_bytes(data, "big") & ~self.mask).to_bytes(self.length, "big")
        return bytes(c for i, c in enumerate(cleared) if i not in self.skip)

    def place(self, data: bytes, raw: int) -> bytes:
        """Payload with the signal's bits set to ``raw``."""
        raw &= self.value_mask
        if self.byte is not None:
            b = self.byte
            return data[:b] + bytes((raw,)) + data[b + 1 :]
        if self.signed and raw >> (self.value_mask.bit_length() - 1):
            raw -= self.value_mask + 1
        bits = int.from_bytes(self.msg.encode({self.sig_name: raw}, scaling=False, strict=False), "big")
        return ((int.from_bytes(data, "big") & ~self.mask) | bits).to_bytes(self.length, "big")

    def read(self, data: bytes) -> int:
        """The signal's raw bits as an unsigned number."""
        if self.byte is not None:
            return data[self.byte]
        v = self.msg.decode(data, decode_choices=False, scaling=False, allow_truncated=True)[self.sig_name]
        if not isinstance(v, (int, float)):  # without choices and scaling cantools gives raw numbers
            raise DbcError(f"signal {self.sig_name}: raw value {v!r} is not a number")
        return int(v) & self.value_mask


class Checksum:
    """A checksum in ``signal`` of ``message`` computed with ``algorithm`` (a name in
    `ALGORITHMS` — 'xor', 'sum'/'additive', 'crc8_sae_j1850', 'crc8_autosar' — or a function
    bytes -> int) over the payload without the checksum (see the module docstring); written at
    each transmission after every other hook, verified at each reception."""

    def __init__(self, message: str, signal: str, algorithm: str | Callable[[bytes], int] = "xor") -> None:
        if isinstance(algorithm, str):
            if algorithm not in ALGORITHMS:
                raise UnknownNameError("checksum algorithm", algorithm, ALGORITHMS)
            self.function = ALGORITHMS[algorithm]
            self.algorithm = algorithm
        elif callable(algorithm):
            self.function = algorithm
            self.algorithm = getattr(algorithm, "__name__", "custom")
        else:
            raise TypeError(f"algorithm must be a name or a function, not {type(algorithm).__name__}")
        self.message = message
        self.signal = signal
        self.name = f"checksum {signal} ({self.algorithm})"

    def bind(self, message: Any) -> _BoundChecksum:
        """The checksum placed in one message."""
        return _BoundChecksum(self, message)


class _BoundChecksum:
    modifies_values = False
    modifies_data = True

    def __init__(self, spec: Checksum, message: Any) -> None:
        sig = _signal(message, spec.signal)
        self.name = spec.name
        self.signal = sig.name
        self.fn = spec.function
        self.where = _Placement(message, sig)

    def tx_values(self, values: dict[str, Any]) -> None:
        pass

    def tx_data(self, data: bytes) -> bytes:
        w = self.where
        return w.place(data, self.fn(w.input(data)))

    def rx(self, data: bytes, decoded: dict[str, Any]) -> str | None:
        w = self.where
        want = self.fn(w.input(data)) & w.value_mask
        got = w.read(data)
        if got != want:
            return f"checksum {self.signal} = 0x{got:02X}, expected 0x{want:02X}"
        return None


class E2E:
    """AUTOSAR end-to-end protection through cantools (``cantools.autosar``): profile 2 (CRC-8H2F
    in byte 0, counter in the low nibble of byte 1, data ID appended) or profile 5 (CRC-16 in
    bytes 0-1). ``data_id`` may be omitted when the message carries its E2E properties
    (ARXML databases). Pair profile 2 with an `AliveCounter` on its counter signal."""

    def __init__(self, message: str, profile: int = 2, data_id: int | None = None) -> None:
        if profile not in (2, 5):
            raise DbcError(f"AUTOSAR E2E profile {profile}: cantools provides profiles 2 and 5")
        self.message = message
        self.profile = profile
        self.data_id = data_id
        self.name = f"E2E profile {profile}"

    def bind(self, message: Any) -> _BoundE2E:
        """E2E protection of one message."""
        return _BoundE2E(self, message)


class _BoundE2E:
    modifies_values = False
    modifies_data = True

    def __init__(self, spec: E2E, message: Any) -> None:
        from cantools import autosar

        self.name = spec.name
        ref = spec.data_id if spec.data_id is not None else message
        if spec.profile == 2:
            self._apply, self._check = autosar.apply_profile2_crc, autosar.check_profile2_crc
        else:
            self._apply, self._check = autosar.apply_profile5_crc, autosar.check_profile5_crc
        self.ref = ref
        if self._apply(bytes(message.length), ref) is None:
            raise DbcError(
                f"message {message.name}: no AUTOSAR E2E profile {spec.profile} properties "
                f"(and {message.length} bytes); give data_id"
            )

    def tx_values(self, values: dict[str, Any]) -> None:
        pass

    def tx_data(self, data: bytes) -> bytes:
        protected = self._apply(data, self.ref)
        if protected is None:  # cantools gives None where it cannot protect the payload
            raise DbcError(f"{self.name}: cantools cannot protect a payload of {len(data)} bytes")
        return bytes(protected)

    def rx(self, data: bytes, decoded: dict[str, Any]) -> str | None:
        ok = self._check(data, self.ref)
        return None if ok else f"{self.name} CRC mismatch"


def checks_from_attributes(db: Any) -> list[Any]:
    """Hooks declared in the DBC by the signal attribute ``CanstackCheck``: 'counter' gives an
    `AliveCounter`, an algorithm name a `Checksum`, 'e2e_p2:<id>'/'e2e_p5:<id>' an `E2E`."""
    hooks: list[Any] = []
    for msg in db.messages:
        for sig in msg.signals:
            spec = attribute(db, sig, "CanstackCheck")
            if spec:
                hooks.append(hook_from_spec(msg.name, sig.name, str(spec)))
    return hooks


def hook_from_spec(message: str, signal: str, spec: str) -> Any:
    """The hook a ``CanstackCheck`` value declares on ``message.signal``; `DbcError` naming the
    message and signal when the value names no check."""
    spec = spec.strip()
    try:
        if spec.lower() in ("counter", "alive", "alive_counter"):
            return AliveCounter(message, signal)
        if spec.lower().startswith("e2e_p"):
            prof, _, did = spec[5:].partition(":")
            return E2E(message, int(prof), int(did, 0) if did else None)
        return Checksum(message, signal, spec.lower())
    except (DbcError, ValueError) as exc:
        raise DbcError(f"message {message} signal {signal}: CanstackCheck {spec!r}: {exc}") from None
