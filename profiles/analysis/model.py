"""What the CAN response-time analyses take: message streams, node queues, the error model, and
their validation into exact integer streams.

Time unit. Every analysis computes in integer *ticks* (`Timebase`): a time of x ns is x × L
ticks with L the least common multiple of the nominal and the data bit rate (the bit rate alone
on a classical bus: one bit time is then 10**9 ticks), so that every bit time at either rate is a
whole number of ticks and a tie — a release exactly at the end of a window — is decided as the
equations say, not by floating-point rounding.

CAN FD (ISO 11898-1:2015). An FD message's worst-case frame is the wire layer's exact worst case
(`stack.wire.fd.worst_case_bits`: the most dynamic stuff bits any identifier, ESI and data of
its length can cause, at the nominal rate up to BRS and at the data rate after it, the stuff
count, the fixed stuff bits and the 17- or 21-bit CRC): with BRS its bits from ESI to the CRC
delimiter go at the data rate, the others (and the 3-bit intermission) at the nominal rate.
C_m = (nominal bits) tau + (data bits) tau_data, rounded up to a whole ns before the
intermission is added (the simulated bus keeps frame times in whole ns). Tests compare it with
Bordoloi and Samii's closed form for CAN FD frames (RTSS 2014), which counts the Bosch
(non-ISO) frame: C = 32 tau + (28 + 5 ceil((p − 16)/64) + 10 p) tau_data for p data bytes.
Arbitration, error signalling and the tau of D07's recurrence stay at the nominal rate.

Drifting clocks. A node whose oscillator runs fast releases its messages on its own clock
(`stack.controller.clock.LocalClock`: local = offset + t + round(t · drift_ppm · 1e-6), t the bus
time; a positive ``drift_ppm`` is a fast clock). A local period T is T / (1 + drift_ppm · 1e-6)
bus ns, shorter for a fast clock, and a local jitter J is J / (1 + drift_ppm · 1e-6) bus ns. The
engine maps a local time N to the first bus time g(N) whose local time has reached N; from the
formula, g(N) = (N − offset)/(1 + d) + e with e in [−0.5/(1 + d), 0.5/(1 + d) + 1), d =
drift_ppm · 1e-6, so the release times on the bus are off the exact ones by less than 2.2 ns
(|d| <= 0.1, `MAX_DRIFT_PPM`). The analysis therefore uses, for a message of a drifting node
(my derivation from that formula, with a margin of 3 ns for the rounding):
T_used = floor(T / (1 + d)) − 3 and J_used = ceil(J / (1 + d)) + 3 — any two queuings i > k of
the message are then at least (i − k) T_used − J_used apart, and each lies within J_used after
its nominal release (the bus time of its nominal local time), which is all the equations use.
A node without drift uses T and J as given.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from fractions import Fraction

from stack import arbitration_key
from stack.wire.fd import worst_case_bits
from stack.wire.frame import data_length, id_text

__all__ = [
    "MessageSpec",
    "ErrorModel",
    "NodeQueue",
    "Stream",
    "Timebase",
    "QUEUE_KINDS",
    "ERROR_FRAME_BITS",
    "HORIZON_FACTOR",
    "NS_PER_S",
    "DRIFT_MARGIN_NS",
    "INTERMISSION_BITS",
    "MAX_DATA_BITRATE",
    "frame_bits_worst",
    "frame_worst",
    "prepare",
    "timebase",
    "used_period_jitter",
]

ERROR_FRAME_BITS = 31
"""Worst-case error signalling overhead in bit times per error, as in Tindell and Burns' model."""

HORIZON_FACTOR = 1000
"""A recurrence past HORIZON_FACTOR x max(D_m, T_m + J_m) is reported as unbounded."""

NS_PER_S = 10**9
DRIFT_MARGIN_NS = 3
"""Rounding margin (ns) on the period and the jitter of a drifting node's messages (see above)."""

INTERMISSION_BITS = 3
"""Bus idle after EOF before the next frame may start, in nominal bit times (C_m counts it)."""

MAX_DATA_BITRATE = 16_000_000
"""Highest CAN FD data bit rate accepted (ISO 11898-1:2015 sets none; transceivers of ISO
11898-2:2016 are specified for 2 and 5 Mbit/s, SIC ones up to 8)."""

QUEUE_KINDS = ("priority", "fifo", "mailbox")
_MIN_BITRATE = 1_000
_MAX_BITRATE = 1_000_000
_MAX_DRIFT_PPM = 100_000.0  # stack.controller.clock.MAX_DRIFT_PPM


@dataclass(frozen=True)
class MessageSpec:
    """One message stream: identifier, format, DLC and timing in integer nanoseconds.

    ``period_ns`` is the period, or the minimum inter-arrival time of a sporadic message, on the
    sending node's clock; ``deadline_ns`` is relative to the nominal release (the initiating
    event, Davis et al. 2007's reference: the release jitter counts against it) and may exceed
    the period; ``jitter_ns`` is the queuing jitter J_m: an instance is queued between its
    nominal release and J_m later. ``frame_bits`` replaces the worst-case length of eq. 1 by a
    frame's exact length in bits (stuff bits and the 3-bit intermission included) when its
    payload is known. ``remote`` marks a remote frame: it arbitrates just after the data frame
    of its identifier (RTR recessive), so the two are distinct streams. ``node`` names the
    sending node (its queue policy comes from ``analyse``'s ``queues``; messages of nodes not
    named there, or with no node, are sent from priority queues); ``drift_ppm`` is that node's
    oscillator drift (`stack.controller.clock.LocalClock`'s sign: positive = fast).

    ``fd`` marks a CAN FD frame (ISO 11898-1:2015): ``dlc`` 9..15 then means 12, 16, 20, 24, 32,
    48 or 64 data bytes (``length``), and ``brs`` sends its data phase at the bus's data bit rate
    (``analyse``'s ``data_bitrate``). For an exact FD frame with BRS, ``frame_bits`` is its whole
    length (intermission included) and ``data_bits`` how many of those bits go at the data rate
    (`stack.wire.coding.FrameBits.data_bits`).
    """

    name: str
    can_id: int
    extended: bool
    dlc: int
    period_ns: int
    deadline_ns: int
    jitter_ns: int = 0
    frame_bits: int | None = None
    remote: bool = False
    node: str = ""
    drift_ppm: float = 0.0
    fd: bool = False
    brs: bool = False
    data_bits: int | None = None

    @property
    def length(self) -> int:
        """Data bytes the frame carries: min(dlc, 8) classical, the FD length of its DLC for FD
        (none for a remote frame)."""
        return 0 if self.remote else data_length(self.dlc, self.fd)


@dataclass(frozen=True)
class ErrorModel:
    """Bus errors: at most ``burst`` errors in any window of ``t_error_ns``.

    ``burst = 1`` is Tindell and Burns' simple model (errors at least T_error apart); a larger
    ``burst`` is the burst form (bursts of up to n errors, T_error between the starts of
    bursts). Each error costs an error frame (31 bit times, worst case) and the retransmission
    of the longest frame it can destroy. See ``profiles.analysis.rta`` for the term.
    """

    t_error_ns: int
    burst: int = 1


@dataclass(frozen=True)
class NodeQueue:
    """How a node's controller offers its frames (`stack.controller.queues`): ``priority`` (the
    pending frame with the lowest arbitration key), ``fifo`` (the oldest pending frame), or
    ``mailbox`` (``mailboxes`` transmit buffers fed in order from a FIFO backlog, the best
    mailbox offered; with ``abort`` the lowest-priority mailbox not on the wire is aborted to
    make room for a better frame)."""

    kind: str = "priority"
    mailboxes: int | None = None
    abort: bool = False


@dataclass(frozen=True)
class Timebase:
    """The integer time unit of one bus (see the module docstring): ``per_ns`` ticks a ns (the
    least common multiple of the bit rates), ``bit`` ticks a nominal bit time (tau), ``data_bit``
    ticks a data-phase bit time."""

    per_ns: int
    bit: int
    data_bit: int

    def frame(self, nominal_bits: int, data_bits: int) -> int:
        """C_m in ticks of a frame of ``nominal_bits`` (intermission included) and ``data_bits``
        bits: exact for a frame at one rate; with data bits, the frame SOF..EOF rounded up to a
        whole ns and the intermission added (see the module docstring)."""
        if not data_bits:
            return nominal_bits * self.bit
        frame = (nominal_bits - INTERMISSION_BITS) * self.bit + data_bits * self.data_bit
        return -(-frame // self.per_ns) * self.per_ns + INTERMISSION_BITS * self.bit


def timebase(bitrate: int, data_bitrate: int | None = None) -> Timebase:
    """The `Timebase` of a bus at ``bitrate`` (and ``data_bitrate`` for CAN FD with BRS); the bit
    rates are checked (1 000..1 000 000 bit/s nominal, data from the nominal up to
    `MAX_DATA_BITRATE`)."""
    _check_bitrate(bitrate)
    if data_bitrate is None:
        return Timebase(bitrate, NS_PER_S, NS_PER_S)
    if (
        isinstance(data_bitrate, bool)
        or not isinstance(data_bitrate, int)
        or not bitrate <= data_bitrate <= MAX_DATA_BITRATE
    ):
        raise ValueError(
            f"data_bitrate {data_bitrate!r}: must be an integer {bitrate}..{MAX_DATA_BITRATE} bit/s "
            "(the data phase is at least as fast as the arbitration phase)"
        )
    per_ns = math.lcm(bitrate, data_bitrate)
    return Timebase(per_ns, NS_PER_S * per_ns // bitrate, NS_PER_S * per_ns // data_bitrate)


@dataclass(frozen=True)
class Stream:
    """A validated message in integer ticks (`Timebase`): arbitration ``key``, transmission time
    ``c`` (C_m), period ``t`` and jitter ``j`` as used (drift applied), deadline ``d``, and the
    sending node's name."""

    spec: MessageSpec
    key: int
    c: int
    t: int
    d: int
    j: int
    node: str

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def horizon(self) -> int:
        """Past this, a recurrence of this message is reported as unbounded (its own values only,
        so that adding other messages never turns an unbounded result bounded)."""
        return HORIZON_FACTOR * max(self.d, self.t + self.j)


def frame_bits_worst(dlc: int, extended: bool, *, fd: bool = False, brs: bool = False) -> int:
    """Worst-case frame length in bits, 3-bit intermission included (Davis et al. 2007, eq. 1).

    g + 8s + 13 + floor((g + 8s - 1) / 4) with g = 34 (standard) or 54 (extended) bits subject to
    stuffing before the data, s = min(dlc, 8) data bytes, 13 = CRC delimiter, ACK slot and
    delimiter, 7 EOF and 3 intermission bits. 135 bits for 8 bytes standard, 160 extended.
    With ``fd``, the CAN FD worst case of ``frame_worst`` at both rates together (its time
    needs the split: `frame_worst`).
    """
    nominal, data = frame_worst(dlc, extended, fd=fd, brs=brs)
    return nominal + data


def frame_worst(dlc: int, extended: bool, *, fd: bool = False, brs: bool = False) -> tuple[int, int]:
    """Worst-case frame length as (bits at the nominal rate, the 3-bit intermission included;
    bits at the data rate): classical frames ``(frame_bits_worst, 0)``; CAN FD the exact worst
    case of `stack.wire.fd.worst_case_bits` for the length of ``dlc`` (data rate bits only with
    ``brs``). ValueError for a DLC outside 0..15, or BRS without FD."""
    if isinstance(dlc, bool) or not isinstance(dlc, int) or not 0 <= dlc <= 15:
        raise ValueError(f"dlc {dlc!r}: must be an integer 0..15 (9..15 mean 8 data bytes, or 12..64 in CAN FD)")
    if not fd:
        if brs:
            raise ValueError("brs: BRS exists only in CAN FD frames (give fd=True)")
        g = 54 if extended else 34
        stuffed = g + 8 * min(dlc, 8)
        return stuffed + 13 + (stuffed - 1) // 4, 0
    wc = worst_case_bits(data_length(dlc, True), extended, fd=True, brs=brs)
    return wc.nominal + INTERMISSION_BITS, wc.data


def used_period_jitter(period_ns: int, jitter_ns: int, drift_ppm: float) -> tuple[int, int]:
    """The period and jitter (bus ns) the analysis uses for a message of a node drifting by
    ``drift_ppm`` (see the module docstring): unchanged without drift, else
    (floor(T / (1 + d)) − 3, ceil(J / (1 + d)) + 3) with d = drift_ppm · 1e-6, exactly."""
    if not drift_ppm:
        return period_ns, jitter_ns
    rate = 1 + Fraction(drift_ppm) / 1_000_000
    return math.floor(period_ns / rate) - DRIFT_MARGIN_NS, math.ceil(jitter_ns / rate) + DRIFT_MARGIN_NS


def _check_int(name: str, field: str, value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"message {name!r}: {field} {value!r} must be an integer number of ns")
    return value


def _check_bitrate(bitrate: object) -> int:
    if isinstance(bitrate, bool) or not isinstance(bitrate, int) or not _MIN_BITRATE <= bitrate <= _MAX_BITRATE:
        raise ValueError(f"bitrate {bitrate!r}: must be an integer {_MIN_BITRATE}..{_MAX_BITRATE} bit/s")
    return bitrate


def check_errors(errors: ErrorModel | None) -> None:
    """Refuse an error model with a non-positive T_error or a burst below 1."""
    if errors is None:
        return
    t_err = errors.t_error_ns
    if isinstance(t_err, bool) or not isinstance(t_err, int) or t_err <= 0:
        raise ValueError(f"error model: t_error_ns {t_err!r} must be an integer > 0 ns")
    n = errors.burst
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"error model: burst {n!r} must be an integer >= 1 (errors per T_error)")


def check_queues(queues: Mapping[str, NodeQueue] | None) -> dict[str, NodeQueue]:
    """Validate the node queue declarations (kind, mailbox count, abort flag)."""
    out: dict[str, NodeQueue] = {}
    for node, q in (queues or {}).items():
        if not isinstance(q, NodeQueue):
            raise ValueError(f"node {node!r}: queue {q!r} must be a NodeQueue")
        if q.kind not in QUEUE_KINDS:
            raise ValueError(f"node {node!r}: queue kind {q.kind!r}: one of {', '.join(QUEUE_KINDS)}")
        if q.kind == "mailbox":
            n = q.mailboxes
            if isinstance(n, bool) or not isinstance(n, int) or n < 1:
                raise ValueError(f"node {node!r}: mailboxes {n!r}: a controller has at least 1 transmit mailbox")
        if not isinstance(q.abort, bool):
            raise ValueError(f"node {node!r}: abort {q.abort!r} must be True or False")
        out[node] = q
    return out


def _check_fd(m: MessageSpec) -> tuple[int, int]:
    """The worst-case (nominal, data) bits of ``m`` (``frame_bits``/``data_bits`` when given),
    after its FD flags are checked."""
    name = m.name
    for flag in ("fd", "brs"):
        if not isinstance(getattr(m, flag), bool):
            raise ValueError(f"message {name!r}: {flag} {getattr(m, flag)!r} must be True or False")
    if m.brs and not m.fd:
        raise ValueError(f"message {name!r}: brs needs fd (BRS exists only in CAN FD frames)")
    if m.fd and m.remote:
        raise ValueError(f"message {name!r}: a CAN FD frame cannot be a remote frame (its RRS bit is always dominant)")
    nominal, data = frame_worst(m.dlc, m.extended, fd=m.fd, brs=m.brs)
    if m.frame_bits is None:
        if m.data_bits is not None:
            raise ValueError(f"message {name!r}: data_bits needs frame_bits (the exact frame's length)")
        return nominal, data
    worst = nominal + data
    if isinstance(m.frame_bits, bool) or not isinstance(m.frame_bits, int) or not 0 < m.frame_bits <= worst:
        raise ValueError(
            f"message {name!r}: frame_bits {m.frame_bits!r} must be 1..{worst} (at most the worst-case length of its DLC)"
        )
    exact_data = 0 if m.data_bits is None else m.data_bits
    if m.data_bits is not None and not m.brs:
        raise ValueError(f"message {name!r}: data_bits is for an FD frame with BRS (the bits at the data rate)")
    if m.brs and m.data_bits is None:
        raise ValueError(f"message {name!r}: an exact FD frame with BRS needs data_bits (its bits at the data rate)")
    if isinstance(exact_data, bool) or not isinstance(exact_data, int) or not 0 <= exact_data <= data:
        raise ValueError(
            f"message {name!r}: data_bits {m.data_bits!r} must be 0..{data} (its worst case at the data rate)"
        )
    if m.frame_bits - exact_data > nominal:
        raise ValueError(
            f"message {name!r}: frame_bits {m.frame_bits} less data_bits {exact_data} leaves "
            f"{m.frame_bits - exact_data} bits at the nominal rate: at most {nominal}"
        )
    return m.frame_bits - exact_data, exact_data


def prepare(
    messages: Sequence[MessageSpec],
    bitrate: int,
    errors: ErrorModel | None = None,
    data_bitrate: int | None = None,
) -> list[Stream]:
    """Validate the inputs and return the streams in priority order (highest first), in ticks of
    ``timebase(bitrate, data_bitrate)``.

    Raises ValueError naming the message and the rule for a non-positive period or deadline,
    negative jitter, a DLC outside 0..15, an identifier out of range, a name or arbitration key
    used twice, a drift outside ±100 000 ppm or a period that drift leaves without room, BRS
    without FD or without a data bit rate, an FD remote frame, a bitrate outside 1 000..1 000 000
    bit/s or a data bit rate outside bitrate..`MAX_DATA_BITRATE`, or a bad error model.
    """
    tb = timebase(bitrate, data_bitrate)
    check_errors(errors)
    out: list[Stream] = []
    names: set[str] = set()
    for m in messages:
        name = m.name
        if name in names:
            raise ValueError(f"message {name!r}: the name is used twice")
        names.add(name)
        can_id = m.can_id
        limit = 0x1FFFFFFF if m.extended else 0x7FF
        if isinstance(can_id, bool) or not isinstance(can_id, int) or not 0 <= can_id <= limit:
            kind = "extended" if m.extended else "standard"
            raise ValueError(f"message {name!r}: can_id {can_id!r} outside 0..0x{limit:X} ({kind})")
        if isinstance(m.dlc, bool) or not isinstance(m.dlc, int) or not 0 <= m.dlc <= 15:
            raise ValueError(f"message {name!r}: dlc {m.dlc!r} outside 0..15")
        period = _check_int(name, "period_ns", m.period_ns)
        deadline = _check_int(name, "deadline_ns", m.deadline_ns)
        jitter = _check_int(name, "jitter_ns", m.jitter_ns)
        if period <= 0:
            raise ValueError(f"message {name!r}: period_ns {period} must be > 0")
        if deadline <= 0:
            raise ValueError(f"message {name!r}: deadline_ns {deadline} must be > 0")
        if jitter < 0:
            raise ValueError(f"message {name!r}: jitter_ns {jitter} must be >= 0")
        drift = m.drift_ppm
        if (
            isinstance(drift, bool)
            or not isinstance(drift, (int, float))
            or not math.isfinite(drift)
            or abs(drift) > _MAX_DRIFT_PPM
        ):
            raise ValueError(
                f"message {name!r}: drift_ppm {drift!r} must be a finite number within ±{_MAX_DRIFT_PPM:g}"
            )
        t_used, j_used = used_period_jitter(period, jitter, drift)
        if t_used <= 0:
            raise ValueError(f"message {name!r}: period_ns {period} is too short for a clock drifting {drift:g} ppm")
        nominal, data = _check_fd(m)
        if m.brs and data_bitrate is None:
            raise ValueError(f"message {name!r}: an FD frame with BRS needs the bus's data bit rate (data_bitrate)")
        if not isinstance(m.node, str):
            raise ValueError(f"message {name!r}: node {m.node!r} must be a string")
        out.append(
            Stream(
                spec=m,
                key=arbitration_key(can_id, m.extended, m.remote),
                c=tb.frame(nominal, data),
                t=t_used * tb.per_ns,
                d=deadline * tb.per_ns,
                j=j_used * tb.per_ns,
                node=m.node,
            )
        )
    out.sort(key=lambda x: x.key)
    for a, b in zip(out, out[1:]):
        if a.key == b.key:
            raise ValueError(
                f"messages {a.spec.name!r} and {b.spec.name!r}: the same arbitration key "
                f"(identifier {id_text(a.spec.can_id, a.spec.extended)}, {'extended' if a.spec.extended else 'standard'}); "
                "two streams may not share an identifier"
            )
    return out
