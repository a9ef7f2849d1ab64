"""Worst-case response-time analysis of CAN messages (fixed priority, non-preemptive).

Implements R. I. Davis, A. Burns, R. J. Bril and J. J. Lukkien, "Controller Area Network (CAN)
schedulability analysis: Refuted, revisited and revised", Real-Time Systems 35(3):239-272, 2007
(doi:10.1007/s11241-007-9012-7), and, for comparison, the original analysis it refutes
(K. Tindell, A. Burns, A. Wellings, 1994/1995), which looks only at the first instance of a
message queued at the critical instant and is optimistic.

Model (the paper's): every message m has a priority (its identifier: the lower arbitration key
wins), a worst-case transmission time C_m, a period or minimum inter-arrival time T_m, a deadline
D_m and a queuing (release) jitter J_m; every node enters its highest-priority ready message into
arbitration, so the bus behaves as one priority queue served non-preemptively. Frames have the
worst-case number of stuff bits.

Equations, by the paper's symbols (section numbers as in the journal version; the equation
*numbers* are quoted from memory of that version and were not re-checked against its text; the
formulas themselves are checked by hand-worked examples in tests/profiles/test_rta.py):

- C_m = (g + 8 s_m + 13 + floor((g + 8 s_m - 1) / 4)) tau_bit, g = 34 (11-bit) or 54 (29-bit)
  identifiers, s_m data bytes; includes the 3-bit intermission (Section 3, eq. 1).
  ``frame_bits_worst``.
- B_m = max over k in lp(m) of C_k: one lower-priority frame already on the bus (Section 3).
- The original analysis (Section 3): w_m = B_m + sum over k in hp(m) of
  ceil((w_m + J_k + tau_bit) / T_k) C_k and R_m = J_m + w_m + C_m.  ``analyse_1994``.
- The revised analysis (Section 5): the level-m busy period
  t_m = B_m + sum over k in hep(m) of ceil((t_m + J_k) / T_k) C_k (started from C_m), the number of
  instances in it Q_m = ceil((t_m + J_m) / T_m), for each q = 0..Q_m-1 the queuing delay
  w_m(q) = B_m + q C_m + sum over k in hp(m) of ceil((w_m(q) + J_k + tau_bit) / T_k) C_k, the
  response R_m(q) = J_m + w_m(q) - q T_m + C_m, and R_m = max over q of R_m(q).  ``analyse``.

Why instances after the first matter (Section 4, the paper's Table 1 example): a transmission
cannot be pre-empted, so the busy period can extend past T_m even when the first instance meets
its deadline; a later instance then waits for the push-through of its predecessor and for the
higher-priority frames released meanwhile, and can be later than the first.

Deadlines: the busy-period formulation does not depend on D_m <= T_m (it examines every instance
the busy period holds, however many). As recalled, and not re-checked against the text, the paper
states its exact analysis for arbitrary deadlines and its simpler sufficient tests for
constrained ones (D_m <= T_m). Here D_m may be below, equal to or above T_m.

Errors (optional, ``ErrorModel``): Tindell and Burns' simple model, errors at least T_error apart,
each costing an error frame and the retransmission of the longest frame of priority higher than
or equal to m: E_m(t) = (ceil(t / T_error) + 1) (31 tau_bit + max over k in hep(m) of C_k). It is
added to the busy-period recurrence as E_m(t_m) and to the queuing recurrence as E_m(w_m(q)). The
"+1" counts the error that may strike m's own (re)transmission, which lies outside the window
w_m(q) the recurrence ranges over: at most ceil(w/T_error) errors fall within w and, as long as
the per-error cost is below T_error (a bounded analysis needs that), at most one more within the
following C_m. This is Tindell and Burns' simple single-error form, as this project's issue
states it; the paper's printed form of the error term (including any burst variant) could not be
re-checked when this was written, so treat it as the 1994 model, not as a quotation of the paper.

Termination: no recurrence runs when the utilisation of the messages of higher or equal priority
(with the error overhead 31 tau_bit + max C per T_error) is >= 1, and every recurrence stops with
"unbounded" once its value exceeds a horizon of 1000 x max(D_m, T_m + J_m) of the message under
analysis (its own, so that adding other messages never turns an unbounded result bounded).

Arithmetic is exact: times are integers in units of 1/bitrate ns (one bit time is 10**9 units), so
a tie such as a release exactly at the end of a window is decided as the equations say, not by
floating-point rounding. Results are converted to float nanoseconds at the end.

Pure functions, no I/O; imports only ``stack``'s top-level ``arbitration_key``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from fractions import Fraction

from stack import arbitration_key

__all__ = [
    "MessageSpec",
    "ErrorModel",
    "RtaResult",
    "frame_bits_worst",
    "analyse",
    "analyse_1994",
    "utilisation",
    "ERROR_FRAME_BITS",
    "HORIZON_FACTOR",
]

ERROR_FRAME_BITS = 31
"""Worst-case error signalling overhead in bit times per error, as in Tindell and Burns' model."""

HORIZON_FACTOR = 1000
"""A recurrence past HORIZON_FACTOR x max(D_m, T_m + J_m) is reported as unbounded."""

_NS_PER_S = 10**9
_MIN_BITRATE = 1_000
_MAX_BITRATE = 1_000_000


@dataclass(frozen=True)
class MessageSpec:
    """One message stream: identifier, format, DLC and timing in integer nanoseconds.

    ``period_ns`` is the period, or the minimum inter-arrival time of a sporadic message;
    ``deadline_ns`` is relative to the queuing (release) time and may exceed the period;
    ``jitter_ns`` is the queuing jitter J_m. ``frame_bits`` replaces the worst-case length of
    eq. 1 by a frame's exact length in bits (stuff bits and the 3-bit intermission included) when
    its payload is known — the same analysis with C_m exact, as tight as the bus can be.
    ``remote`` marks a remote frame: it arbitrates just after the data frame of its identifier
    (RTR recessive), so the two are distinct streams.
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


@dataclass(frozen=True)
class ErrorModel:
    """Tindell and Burns' simple error model: bus errors at least ``t_error_ns`` apart."""

    t_error_ns: int


@dataclass(frozen=True)
class RtaResult:
    """The analysis of one message. Times are nanoseconds.

    ``busy_period_ns`` is the level-m busy period t_m (None when it does not converge, and always
    None from ``analyse_1994``, which has no busy period); ``instances`` is Q_m (0 when the busy
    period does not converge; 1 from ``analyse_1994``); ``queuing_delays_ns`` and
    ``responses_ns`` hold w_m(q) and R_m(q) per instance q; ``response_ns`` is R_m, None when
    unbounded (``unbounded_reason`` says why); ``response_1994_ns`` is the first-instance value of
    the original analysis, for comparison; ``priority`` is the rank, 0 = highest;
    ``utilisation_hep`` the utilisation of the messages of higher or equal priority (error
    overhead included when an error model is given).
    """

    name: str
    c_ns: float
    blocking_ns: float
    busy_period_ns: float | None
    instances: int
    response_ns: float | None
    worst_instance: int | None
    schedulable: bool
    deadline_ns: int
    priority: int
    queuing_delays_ns: tuple[float, ...]
    responses_ns: tuple[float, ...]
    response_1994_ns: float | None
    utilisation_hep: float
    unbounded_reason: str | None = None


def frame_bits_worst(dlc: int, extended: bool) -> int:
    """Worst-case frame length in bits, 3-bit intermission included (Section 3, eq. 1).

    g + 8s + 13 + floor((g + 8s - 1) / 4) with g = 34 (standard) or 54 (extended) bits subject to
    stuffing before the data, s = min(dlc, 8) data bytes, 13 = CRC delimiter, ACK slot and
    delimiter, 7 EOF and 3 intermission bits. 135 bits for 8 bytes standard, 160 extended.
    """
    if isinstance(dlc, bool) or not isinstance(dlc, int) or not 0 <= dlc <= 15:
        raise ValueError(f"dlc {dlc!r}: must be an integer 0..15 (9..15 mean 8 data bytes)")
    g = 54 if extended else 34
    stuffed = g + 8 * min(dlc, 8)
    return stuffed + 13 + (stuffed - 1) // 4


@dataclass(frozen=True)
class _Msg:
    """A validated message in integer ticks (1 tick = 1/bitrate ns)."""

    spec: MessageSpec
    key: int
    c: int
    t: int
    d: int
    j: int

    @property
    def horizon(self) -> int:
        return HORIZON_FACTOR * max(self.d, self.t + self.j)


def _ceil_div(a: int, b: int) -> int:
    return -(-a // b)


def _check_int(name: str, field: str, value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"message {name!r}: {field} {value!r} must be an integer number of ns")
    return value


def _prepare(messages: Sequence[MessageSpec], bitrate: int, errors: ErrorModel | None = None) -> list[_Msg]:
    """Validate the inputs and return the messages in priority order, times in ticks."""
    if isinstance(bitrate, bool) or not isinstance(bitrate, int) or not _MIN_BITRATE <= bitrate <= _MAX_BITRATE:
        raise ValueError(f"bitrate {bitrate!r}: must be an integer {_MIN_BITRATE}..{_MAX_BITRATE} bit/s")
    if errors is not None:
        t_err = errors.t_error_ns
        if isinstance(t_err, bool) or not isinstance(t_err, int) or t_err <= 0:
            raise ValueError(f"error model: t_error_ns {t_err!r} must be an integer > 0 ns")
    out: list[_Msg] = []
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
        bits = frame_bits_worst(m.dlc, m.extended)
        if m.frame_bits is not None:
            if isinstance(m.frame_bits, bool) or not isinstance(m.frame_bits, int) or not 0 < m.frame_bits <= bits:
                raise ValueError(
                    f"message {name!r}: frame_bits {m.frame_bits!r} must be 1..{bits} "
                    "(at most the worst-case length of its DLC)"
                )
            bits = m.frame_bits
        out.append(
            _Msg(
                spec=m,
                key=arbitration_key(can_id, m.extended, m.remote),
                c=bits * _NS_PER_S,
                t=period * bitrate,
                d=deadline * bitrate,
                j=jitter * bitrate,
            )
        )
    out.sort(key=lambda x: x.key)
    for a, b in zip(out, out[1:]):
        if a.key == b.key:
            raise ValueError(
                f"messages {a.spec.name!r} and {b.spec.name!r}: the same arbitration key "
                f"(identifier 0x{a.spec.can_id:X}, {'extended' if a.spec.extended else 'standard'}); "
                "two streams may not share an identifier"
            )
    return out


def utilisation(messages: Sequence[MessageSpec], bitrate: int) -> float:
    """Bus utilisation with worst-case frames: sum over m of C_m / T_m."""
    msgs = _prepare(messages, bitrate)
    return float(sum((Fraction(m.c, m.t) for m in msgs), Fraction(0)))


class _Level:
    """The quantities shared by every recurrence of one priority level m."""

    def __init__(self, msgs: list[_Msg], i: int, tau: int, errors: ErrorModel | None, bitrate: int) -> None:
        self.m = msgs[i]
        self.hp = msgs[:i]
        self.hep = msgs[: i + 1]
        self.tau = tau
        self.b = max((k.c for k in msgs[i + 1 :]), default=0)
        if errors is None:
            self.t_err = 0
            self.per_error = 0
        else:
            self.t_err = errors.t_error_ns * bitrate
            self.per_error = ERROR_FRAME_BITS * tau + max(k.c for k in self.hep)
        u = sum((Fraction(k.c, k.t) for k in self.hep), Fraction(0))
        if self.t_err:
            u += Fraction(self.per_error, self.t_err)
        self.u_hep = u

    def errors(self, t: int) -> int:
        """E_m(t) = (ceil(t / T_error) + 1)(31 tau_bit + max over hep(m) of C_k); 0 without a model."""
        if not self.t_err:
            return 0
        return (_ceil_div(t, self.t_err) + 1) * self.per_error

    def busy_period(self) -> int | None:
        """Level-m busy period t_m (Section 5), from t = C_m; None past the horizon."""
        t = self.m.c
        while True:
            nxt = self.b + self.errors(t) + sum(_ceil_div(t + k.j, k.t) * k.c for k in self.hep)
            if nxt == t:
                return t
            if nxt > self.m.horizon:
                return None
            t = nxt

    def queuing_delay(self, q: int, start: int) -> int | None:
        """w_m(q) (Section 5; q = 0 is the original analysis' w_m), iterated up from ``start``.

        ``start`` must not exceed the least fixed point: B_m + q C_m, or w_m(q-1) + C_m.
        None when w + C_m passes the horizon.
        """
        base = self.b + q * self.m.c
        w = start
        while True:
            nxt = base + self.errors(w) + sum(_ceil_div(w + k.j + self.tau, k.t) * k.c for k in self.hp)
            if nxt == w:
                return w
            if nxt + self.m.c > self.m.horizon:
                return None
            w = nxt


def _result(
    msgs: list[_Msg],
    i: int,
    lv: _Level,
    bitrate: int,
    *,
    busy: int | None,
    q_count: int,
    ws: list[int],
    rs: list[int],
    r: int | None,
    worst: int | None,
    r1994: int | None,
    reason: str | None,
) -> RtaResult:
    m = lv.m

    def ns(x: int) -> float:
        return x / bitrate

    return RtaResult(
        name=m.spec.name,
        c_ns=ns(m.c),
        blocking_ns=ns(lv.b),
        busy_period_ns=None if busy is None else ns(busy),
        instances=q_count,
        response_ns=None if r is None else ns(r),
        worst_instance=worst,
        schedulable=r is not None and r <= m.d,
        deadline_ns=m.spec.deadline_ns,
        priority=i,
        queuing_delays_ns=tuple(ns(w) for w in ws),
        responses_ns=tuple(ns(x) for x in rs),
        response_1994_ns=None if r1994 is None else ns(r1994),
        utilisation_hep=float(lv.u_hep),
        unbounded_reason=reason,
    )


_OVERLOAD = "utilisation of the messages of higher or equal priority >= 1"


def _first_instance(lv: _Level) -> int | None:
    """The original analysis' R_m = J_m + w_m + C_m (Section 3), None when unbounded.

    Its own guard is the utilisation of hp(m) (the recurrence ranges over hp(m) only).
    """
    u_hp = sum((Fraction(k.c, k.t) for k in lv.hp), Fraction(0))
    if lv.t_err:
        u_hp += Fraction(lv.per_error, lv.t_err)
    if u_hp >= 1:
        return None
    w = lv.queuing_delay(0, lv.b)
    return None if w is None else lv.m.j + w + lv.m.c


def analyse(messages: Sequence[MessageSpec], bitrate: int, *, errors: ErrorModel | None = None) -> dict[str, RtaResult]:
    """Worst-case response times by the revised analysis (Section 5), keyed by message name.

    Priority is arbitration order (lower ``arbitration_key(can_id, extended, False)`` wins); the
    dict is in priority order, highest first. Raises ValueError naming the message and the rule
    for a non-positive period or deadline, negative jitter, a DLC outside 0..15, an identifier out
    of range, a name or arbitration key used twice, a bitrate outside 1 000..1 000 000 bit/s or
    a non-positive T_error.
    """
    msgs = _prepare(messages, bitrate, errors)
    tau = _NS_PER_S  # one bit time in ticks of 1/bitrate ns
    out: dict[str, RtaResult] = {}
    for i, m in enumerate(msgs):
        lv = _Level(msgs, i, tau, errors, bitrate)
        r1994 = _first_instance(lv)
        if lv.u_hep >= 1:
            out[m.spec.name] = _result(
                msgs,
                i,
                lv,
                bitrate,
                busy=None,
                q_count=0,
                ws=[],
                rs=[],
                r=None,
                worst=None,
                r1994=r1994,
                reason=_OVERLOAD,
            )
            continue
        busy = lv.busy_period()
        if busy is None:
            out[m.spec.name] = _result(
                msgs,
                i,
                lv,
                bitrate,
                busy=None,
                q_count=0,
                ws=[],
                rs=[],
                r=None,
                worst=None,
                r1994=r1994,
                reason=f"busy period beyond the horizon ({HORIZON_FACTOR} x max(D, T + J))",
            )
            continue
        q_count = _ceil_div(busy + m.j, m.t)
        ws: list[int] = []
        rs: list[int] = []
        reason = None
        start = lv.b
        for q in range(q_count):
            w = lv.queuing_delay(q, start)
            if w is None:
                reason = f"queuing delay of instance {q} beyond the horizon ({HORIZON_FACTOR} x max(D, T + J))"
                break
            ws.append(w)
            rs.append(m.j + w - q * m.t + m.c)
            start = w + m.c
        if reason is not None:
            r = worst = None
        else:
            r = max(rs)
            worst = rs.index(r)
        out[m.spec.name] = _result(
            msgs, i, lv, bitrate, busy=busy, q_count=q_count, ws=ws, rs=rs, r=r, worst=worst, r1994=r1994, reason=reason
        )
    return out


def analyse_1994(
    messages: Sequence[MessageSpec], bitrate: int, *, errors: ErrorModel | None = None
) -> dict[str, RtaResult]:
    """The original, optimistic analysis (Section 3): the first instance only.

    For comparison and for the refutation example; do not use it to decide schedulability.
    ``busy_period_ns`` is None (the analysis has none), ``instances`` 1 and ``worst_instance`` 0
    when bounded. Same inputs, order and errors as ``analyse``.
    """
    msgs = _prepare(messages, bitrate, errors)
    tau = _NS_PER_S
    out: dict[str, RtaResult] = {}
    for i, m in enumerate(msgs):
        lv = _Level(msgs, i, tau, errors, bitrate)
        r = _first_instance(lv)
        if r is None:
            out[m.spec.name] = _result(
                msgs,
                i,
                lv,
                bitrate,
                busy=None,
                q_count=1,
                ws=[],
                rs=[],
                r=None,
                worst=None,
                r1994=None,
                reason="higher-priority utilisation >= 1 or queuing delay beyond the horizon",
            )
            continue
        w = r - m.j - m.c
        out[m.spec.name] = _result(
            msgs, i, lv, bitrate, busy=None, q_count=1, ws=[w], rs=[r], r=r, worst=0, r1994=r, reason=None
        )
    return out
