"""Error detection, error signalling and fault confinement, bit by bit.

A clean transmission is handled at frame granularity by `stack.bus.sim`. Any attempt that can go
wrong — a bit flipped by fault injection, a transmitter nobody acknowledges, two nodes sending
different frames with the same arbitration field, a stuck or deaf node — is replayed here one
bit at a time for every node on the bus. Each node drives a level (0 dominant, 1 recessive), the
wire is the wired-AND of all drivers, and each node perceives the wire through its own faults
(a flipped bit can be global or local to some nodes). Each node runs its own receiver state
machine (`BitDecoder`), so detection happens where ISO 11898-1 puts it:

- bit error: a transmitter reads a level other than the one it sent, except a recessive bit
  read dominant in the arbitration field (lost arbitration) or in the ACK slot;
- stuff error: a sixth equal bit in SOF..CRC (a recessive stuff bit of the transmitter read
  dominant during arbitration is a stuff error: rule 3, exception 2);
- CRC error: signalled after the ACK delimiter; form error: dominant CRC delimiter, ACK
  delimiter, or EOF bits 1..6; ACK error: a transmitter reads the ACK slot recessive.

Error flags (6 dominant, or 6 recessive when error passive), their superposition, the error
delimiter (8 recessive), overload frames (dominant at the last EOF bit or the first two
intermission bits) and intermission all take their real bit times.

Fault confinement applies the 12 rules of the CAN 2.0 specification
(`stack.controller.confinement`, where each is written once) to each node's view of the attempt:
rules 1-6 where the bits happen (which node saw what, when), rules 7 and 8 at the bit of
success, and the state changes of rules 9 and 10 at once for the rest of the attempt.

Data consistency: receivers accept a frame at the last-but-one EOF bit, the transmitter at the
last. A dominant last EOF bit makes receivers send an overload frame (they keep the frame) and
the transmitter an error frame (it retransmits): double reception. A local error at the
last-but-one bit seen by some receivers only makes those drop the frame while the others have it
already: inconsistent omission if the transmitter then fails before retransmitting.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from functools import lru_cache
from typing import TYPE_CHECKING, Any

from stack.controller.confinement import (
    BUS_OFF,
    DOMINANT_BITS_TOLERATED,
    PASSIVE,
    RULE_1_REC,
    RULE_2_REC,
    RULE_3_TEC,
    RULE_4_TEC,
    RULE_5_REC,
    RULE_6_STEP,
    after_rx_success,
    after_tx_success,
    state_for,
)
from stack.controller.node import CLASSIC, FD, Node
from stack.wire.coding import Field
from stack.wire.decoder import BitDecoder
from stack.wire.frame import Frame

if TYPE_CHECKING:  # pragma: no cover
    from stack.controller.queues import TxRequest

#: Stuck faults of an attempt by node: (level, the bit where the fault ends or None[, the bit where
#: it begins]) — see `simulate_attempt`.
StuckFaults = dict[Node, tuple[int, int | None] | tuple[int, int | None, int]]

__all__ = [
    "StuckFaults",
    "AttemptResult",
    "NodeOutcome",
    "simulate_attempt",
    "sent_frame",
    "brs_position",
    "fdf_position",
    "MAX_ATTEMPT_BITS",
    "INTEGRATION_BITS",
]

MAX_ATTEMPT_BITS = 1 << 20
INTEGRATION_BITS = 11  # bus integration: 11 consecutive recessive bits (ISO 11898-1:2015)

# node phases
FRAME, FLAG, AFTER_FLAG, DELIM, INTERMISSION, IDLE, OFF, INTEGRATING = range(8)

# unstuffed index of FDF and BRS from SOF: standard SOF ID(11) RRS IDE FDF res BRS, extended SOF
# ID(11) SRR IDE ID(18) RRS FDF res BRS
_FDF_AT = {False: 14, True: 33}
_BRS_AT = {False: 16, True: 35}


def _stuffed(fb: Any, unstuffed: int) -> int:
    pos = unstuffed
    for s in fb.stuff_positions:
        if s > pos:
            break
        pos += 1
    return pos


def fdf_position(frame: Frame) -> int:
    """The position from SOF (stuff bits counted) of an FD frame's FDF bit, the bit where a
    classical frame has r0 (standard) or r1 (extended)."""
    return _stuffed(frame.encoded or frame.bits, _FDF_AT[frame.extended])


def brs_position(frame: Frame) -> int:
    """The position from SOF of an FD frame's BRS bit (as ``frame.bits.position(Field.BRS)``,
    without building the frame's field table: the engine asks once per FD frame)."""
    return _stuffed(frame.encoded or frame.bits, _BRS_AT[frame.extended])


@lru_cache(maxsize=1024)
def _with_esi(frame: Frame, esi: bool) -> Frame:
    return Frame(frame.can_id, frame.data, extended=frame.extended, fd=True, brs=frame.brs, esi=esi)


def sent_frame(frame: Frame, passive: bool) -> Frame:
    """The frame as its transmitter puts it on the wire: an FD frame's ESI is the transmitter's
    error state at the start of the frame, recessive when it is error passive (ISO 11898-1:2015),
    whatever the queued frame says; a classical frame as queued."""
    if not frame.fd or frame.esi is passive:
        return frame
    return _with_esi(frame, passive)


@dataclass
class NodeOutcome:
    """What one node made of an attempt."""

    name: str
    role: str  # 'tx' (still transmitting at the end) or 'rx' (including arbitration losers)
    detected: tuple[str, str, int, int] | None = None  # (kind, field, index in field, bit from SOF)
    primary: bool = False  # detected on its own, before any error flag reached it
    accepted: bool = False  # receiver: frame valid (at the last-but-one EOF bit)
    accept_bit: int = -1
    success: bool = False  # transmitter: no error up to the end of EOF
    lost_arbitration: bool = False
    detect_bit: int = -1
    frame: Any = None  # receiver: the frame it accepted
    tec_delta: int = 0
    rec_delta: int = 0
    rules: list[str] = field(default_factory=list)
    overload_flags: int = 0
    integrating_bit: int = -1  # the protocol exception event: bus integration from this bit
    tec0: int = 0  # the counters the deltas apply to: at the start of the attempt, with rule 7
    rec0: int = 0  # (transmitter's success) or rule 8 (reception) applied when they happened
    # (bit, tec_delta, rec_delta) wherever the counters cross a state boundary (warning 96,
    # passive 128, bus off 256) inside the attempt: the engine applies them at their bit times,
    # so a long episode (a stuck-dominant node) changes states when it should, not at its end
    trail: list[tuple[int, int, int]] = field(default_factory=list)


@dataclass
class AttemptResult:
    """One attempt on the wire, bit by bit: its length, the first error and each node's view."""

    bits: int  # from SOF to the end of the last delimiter (intermission not included)
    wire: str
    first_error: tuple[str, str, int, int] | None
    outcomes: dict[str, NodeOutcome]
    winner: TxRequest | None
    accepted_frame: Any = None
    data_phase: tuple[int, int] | None = None
    """The first and last bit sent at the data bit rate (an FD frame with BRS: after BRS up to the
    CRC delimiter, or up to the bit where the transmitter detected an error or a node started an
    active error flag, at whose sample point the nominal rate resumes), or None."""
    collision: bool = False  # several transmitters whose frames differ (set by the bus)
    before: dict[str, Any] | None = None  # the nodes' states when the attempt started (set by the bus)


class _View:
    __slots__ = (
        "node",
        "out",
        "role",
        "req",
        "bits",
        "arb_end",
        "stuff",
        "dec",
        "phase",
        "flag_kind",
        "flag_n",
        "flag_levels",
        "dom_run",
        "first_after",
        "delim_n",
        "im_n",
        "overloads",
        "passive",
        "listen_only",
        "stuck",
        "deaf_ack",
        "ack_slot",
        "eof_last",
        "frame_done",
        "flag_had_dominant",
        "tec0",
        "rec0",
        "want_overloads",
        "bit",
        "kind",
        "frame",
        "integrating",
        "switch_bit",
        "fd_wire",
    )

    def __init__(
        self, node: Node, req: TxRequest | None, stuck: int | None, deaf_ack: bool, frame: Frame | None = None
    ) -> None:
        self.node = node
        self.out = NodeOutcome(node.name, "tx" if req is not None else "rx")
        self.role = "tx" if req is not None else "rx"
        self.req = req
        self.kind = node.fd
        self.frame = frame  # a transmitter's frame as it sends it (`sent_frame`)
        if frame is not None:
            fb = frame.encoded or frame.bits
            self.bits = fb.bits
            self.stuff = set(fb.stuff_positions)
            self.arb_end = fb.arbitration_end
            self.ack_slot = fb.fields[Field.ACK_SLOT][0]
            self.eof_last = fb.fields[Field.EOF][-1]
        self.dec = BitDecoder(self.kind)
        self.phase = FRAME
        self.flag_kind = ""
        self.flag_n = 0
        self.flag_levels: list[int] = []
        self.dom_run = 0
        self.first_after = True
        self.delim_n = 0
        self.im_n = 0
        self.overloads = 0
        self.passive = node.state is PASSIVE
        self.listen_only = node.listen_only
        self.stuck = stuck
        self.deaf_ack = deaf_ack
        self.frame_done = False
        self.flag_had_dominant = False
        self.tec0 = node.tec
        self.rec0 = node.rec
        self.out.tec0 = node.tec
        self.out.rec0 = node.rec
        self.bit = 0  # the bit being processed (for the trail of state changes)
        self.want_overloads = 0
        self.integrating = 0  # recessive bits counted in bus integration
        self.switch_bit = -1  # the bit of its first error, when it ends an FD data phase there
        self.fd_wire = False  # an FD frame is on the wire (a CAN 2.0 node cannot receive it)

    def intended(self, b: int) -> int:
        """The level this node means to send (its transmitter may be stuck)."""
        ph = self.phase
        if ph == FRAME:
            if self.role == "tx":
                if b == self.ack_slot:
                    return 1
                return 0 if self.bits[b] == "0" else 1
            dec = self.dec
            if (
                dec.in_frame
                and dec.field == Field.ACK_SLOT
                and dec.crc_matches
                and not self.deaf_ack
                and not self.listen_only
            ):
                return 0
            return 1
        if ph == FLAG:
            return 1 if self.flag_kind == "passive" else 0
        return 1


def simulate_attempt(
    txs: Iterable[TxRequest],
    nodes: Iterable[Node],
    flips: dict[int, Any],
    stuck: StuckFaults | None = None,
    deaf_ack: Iterable[Node] = (),
    overload: dict[Node, int] | None = None,
    leave: dict[Node, int] | None = None,
) -> AttemptResult:
    """Replay one attempt bit by bit for every node on the bus.

    ``flips`` maps a bit position (from SOF) to the nodes that perceive that bit inverted (a set
    of nodes, or None for every node: a global error). ``stuck`` maps nodes to (level, release):
    the level they force (0: stuck dominant, 1: stuck recessive / transmitter disconnected) until
    bit ``release`` of the attempt (for good if None; an attempt then ends after
    MAX_ATTEMPT_BITS), optionally (level, release, onset) for a fault that starts at bit
    ``onset`` of the attempt; ``deaf_ack`` nodes never acknowledge; ``leave`` maps nodes to the
    bit at which they are disconnected from the bus (they neither drive nor receive from then
    on: a transmitter's frame is cut off there).
    ``overload`` maps receivers that need a delay to the number of overload frames (1 or 2)
    they send after the frame, starting at the first intermission bit.
    Counter changes are returned per node (``tec_delta``/``rec_delta``), not applied.
    """
    stuck = stuck or {}
    deaf = set(deaf_ack)
    txs = list(txs)
    tx_nodes = {q.node: q for q in txs}
    sent = {q.node: sent_frame(q.frame, q.node.state is PASSIVE) for q in txs}
    onset_of = {n: (spec[2] if len(spec) > 2 else 0) for n, spec in stuck.items()}
    views = [
        _View(n, tx_nodes.get(n), stuck[n][0] if n in stuck and onset_of[n] <= 0 else None, n in deaf, sent.get(n))
        for n in nodes
    ]
    first_frame = sent[txs[0].node] if txs else None
    fd_on_wire = any(f.fd for f in sent.values())
    release = {v: stuck[v.node][1] for v in views if v.node in stuck}
    # faults that begin inside the attempt: (bit, view, what)
    pending = sorted(
        [(onset_of[v.node], i, "stuck") for i, v in enumerate(views) if v.node in stuck and onset_of[v.node] > 0]
        + [(leave[v.node], i, "leave") for i, v in enumerate(views) if leave and v.node in leave]
    )
    for v in views:
        v.want_overloads = (overload or {}).get(v.node, 0)
    wire_bits: list[str] = []
    first_error: tuple[str, str, int, int] | None = None
    first_flag_bit: int | None = None
    winner_view = None
    b = _common_prefix([sent[q.node] for q in txs], flips, stuck)
    if pending:
        b = min(b, pending[0][0])  # the views part from the bit a fault begins
    if fd_on_wire and first_frame is not None and any(v.kind != FD for v in views):
        b = min(b, fdf_position(first_frame))  # a node that is not FD enabled reacts to FDF
    if b:
        # every node saw the same clean bits so far: decode them once per kind of receiver and
        # share the state
        prefix = first_frame.bits.bits[:b] if first_frame is not None else ""
        shared: dict[str, BitDecoder] = {}
        for v in views:
            dec = shared.get(v.kind)
            if dec is None:
                dec = shared[v.kind] = BitDecoder(v.kind)
                for c in prefix:
                    dec.feed(1 if c == "1" else 0)
            v.dec = dec.clone()
        wire_bits.append(prefix)
    for v in views:
        v.fd_wire = fd_on_wire
    while b < MAX_ATTEMPT_BITS:
        while pending and pending[0][0] <= b:
            _, i, what = pending.pop(0)
            v = views[i]
            if what == "stuck":
                v.stuck = stuck[v.node][0]
            else:  # disconnected: off the wire from this bit, its frame unfinished
                v.phase = OFF
                v.stuck = None
                release.pop(v, None)
        if release:
            for v, end_bit in list(release.items()):
                if end_bit is not None and b >= end_bit:
                    v.stuck = None  # this node's fault is over
                    del release[v]
        intended = [v.intended(b) for v in views]
        wire = 1
        for v, d in zip(views, intended):
            a = 1 if (v.listen_only or v.phase == OFF) else (d if v.stuck is None else v.stuck)
            if a == 0:
                wire = 0
        wire_bits.append(str(wire))
        holders = [release[v] for v in views if v.stuck == 0]
        if wire == 0 and holders and all(v.phase in (AFTER_FLAG, OFF, INTEGRATING) or v.listen_only for v in views):
            # a stuck-dominant node holds the wire: fast-forward rule 6 in steps of 8 bits, to
            # the first release (or to the end of the attempt for a fault that never ends)
            horizon = min([h for h in holders if h is not None] + [p[0] for p in pending[:1]], default=MAX_ATTEMPT_BITS)
            skip = max(1, min(horizon, MAX_ATTEMPT_BITS) - b)
            for v in views:
                if v.phase == AFTER_FLAG:
                    v.bit = b
                    _fast_dominant(v, skip)
                elif v.phase == INTEGRATING:
                    v.integrating = 0
            wire_bits.append("0" * (skip - 1))
            b += skip
            continue
        fl = flips.get(b, ())
        for v, d in zip(views, intended):
            v.bit = b
            p = wire
            if fl is None or (fl and v.node in fl):
                p ^= 1
            ev = _step(v, b, d, p)
            if ev is not None and first_error is None:
                first_error = ev
        if first_error is not None and first_flag_bit is None:
            first_flag_bit = b + 1
        if all(v.phase in (IDLE, OFF) or (v.phase == FRAME and v.role == "rx" and not v.dec.in_frame) for v in views):
            # every node is idle: the attempt is over (a node stuck dominant from here on is
            # the SOF of an episode of its own, started by the fault injector when the bus is
            # idle)
            b += 1
            break
        b += 1
    first_bit = min((v.out.detect_bit for v in views if v.out.detect_bit >= 0), default=-1)
    for v in views:
        v.out.primary = v.out.detect_bit >= 0 and v.out.detect_bit == first_bit
        if v.role == "tx" and v.out.success:
            winner_view = v
    # the last 3 bits were everyone's intermission: the attempt proper ends before them
    if all(v.phase == IDLE for v in views) and b >= 3:
        b -= 3
    res = AttemptResult(
        b,
        "".join(wire_bits),
        first_error,
        {v.node.name: v.out for v in views},
        winner_view.req if winner_view else None,
        data_phase=_data_phase(first_frame, views),
    )
    return res


def _data_phase(frame: Frame | None, views: list[_View]) -> tuple[int, int] | None:
    """Bits at the data bit rate (see `AttemptResult.data_phase`): ISO 11898-1:2015 switches to the
    data bit timing at the sample point of BRS and back at the sample point of the CRC delimiter,
    or of the bit where an error is detected (error flags go at the nominal rate). The simulated
    bus has one bit clock for every node: it resumes the nominal rate at the first error that
    ends the data phase for the wire — the transmitter's, or a node's whose error flag is active
    (dominant); a passive flag leaves the transmitter sending at the data rate."""
    if frame is None or not frame.brs:
        return None
    fb = frame.encoded or frame.bits
    first = brs_position(frame) + 1
    last = fb.crc_delim
    for v in views:
        if 0 <= v.switch_bit < last:
            last = v.switch_bit
    return (first, last) if last >= first else None


def _common_prefix(frames: list[Frame], flips: dict[int, Any], stuck: StuckFaults) -> int:
    """Bits from SOF that every node sees exactly as the transmitters sent them: before the
    first flip, the first difference between transmitters, the ACK slot, and only when no node
    is stuck or listen-only-silent matters (listen-only nodes never drive, so they do not)."""
    if not frames or stuck:
        return 0
    fb = frames[0].encoded or frames[0].bits
    end = fb.fields[Field.ACK_SLOT][0]
    if flips:
        end = min(end, min(flips))
    b0 = fb.bits
    for f in frames[1:]:
        b1 = f.bits.bits
        if b1 != b0:
            end = min(end, next(i for i, (x, y) in enumerate(zip(b0, b1)) if x != y))
    return max(0, end)


def _bump(v: _View, amount: int, rule: str) -> None:
    """Add to TEC (transmitter) or REC (receiver); error passive and bus off take effect at once
    for the rest of the attempt (rules 9 and 10)."""
    out = v.out
    before = state_for(v.tec0 + out.tec_delta, v.rec0 + out.rec_delta)
    if v.role == "tx":
        out.tec_delta += amount
    else:
        out.rec_delta += amount
    out.rules.append(rule)
    after = state_for(v.tec0 + out.tec_delta, v.rec0 + out.rec_delta)
    if after is not before:
        out.trail.append((v.bit, out.tec_delta, out.rec_delta))
    if after is BUS_OFF:
        v.phase = OFF
    elif after is PASSIVE:
        v.passive = True


def _fast_dominant(v: _View, skip: int) -> None:
    limit = DOMINANT_BITS_TOLERATED
    if v.first_after and v.role == "rx" and v.flag_kind != "overload":
        _bump(v, RULE_2_REC, "rule 2")
    v.first_after = False
    start = v.dom_run
    end = start + skip
    n = start + 1
    if n < limit:
        n = limit
    else:
        n = limit + -(-(n - limit) // RULE_6_STEP) * RULE_6_STEP
    b0 = v.bit - start - 1  # the bit at which the dominant run would have been 0 long
    while n <= end and v.phase != OFF:
        v.bit = b0 + n
        _bump(v, RULE_6_STEP, "rule 6")
        n += RULE_6_STEP
    v.dom_run = end


def _error_detected(
    v: _View, b: int, kind: str, fld: Field | str, idx: int, pos: int, primary: bool = True
) -> tuple[str, str, int, int]:
    """Rules 1 and 3 when a node detects an error at bit ``b``; its flag starts at b + 1."""
    out = v.out
    det = (kind, fld.value if isinstance(fld, Field) else str(fld), idx, pos)
    if out.detected is None:
        out.detected = det
        out.primary = primary
    if v.role == "tx":
        exc1 = kind == "ack" and v.passive
        exc2 = kind == "stuff-arbitration"
        if exc2:
            out.rules.append("rule 3 exception 2")
        elif not exc1:  # exception 1 is decided when the passive flag ends
            _bump(v, RULE_3_TEC, "rule 3")
        if v.switch_bit < 0:
            v.switch_bit = b  # a transmitter leaves an FD data phase at its first error
    else:
        _bump(v, RULE_1_REC, "rule 1")
    if v.phase == OFF:
        return det
    v.phase = FLAG
    # a listen-only node never drives the bus: its flag is recessive like a passive one
    v.flag_kind = "passive" if (v.passive or v.listen_only) else "active"
    if v.switch_bit < 0 and v.flag_kind == "active":
        v.switch_bit = b  # its flag, at the nominal rate, ends an FD data phase for everyone
    v.flag_n = 0
    v.flag_levels = []
    v.flag_had_dominant = False
    out.detect_bit = b
    return det


def _start_overload(v: _View) -> None:
    v.phase = FLAG
    v.flag_kind = "passive" if v.listen_only else "overload"
    v.flag_n = 0
    v.flag_levels = []
    v.out.overload_flags += 1
    v.overloads += 1


def _step(v: _View, b: int, driven: int, p: int) -> tuple[str, str, int, int] | None:
    """One bit for one node: it drove ``driven`` and perceives ``p``; the handler of its phase
    decides what that means. Returns the error it detected, if any."""
    handler = _PHASE_STEP.get(v.phase)
    return None if handler is None else handler(v, b, driven, p)


def _step_frame(v: _View, b: int, driven: int, p: int) -> tuple[str, str, int, int] | None:
    """Inside the frame: a transmitter checks what it reads back (bit error, lost arbitration,
    ACK error, success at the last EOF bit); a receiver feeds its decoder (and drives the ACK)."""
    out = v.out
    dec = v.dec
    if v.role == "tx":
        res = dec.feed(p)  # keeps a receiver's view in case arbitration is lost
        if driven != p:
            if b == v.ack_slot and driven == 1 and p == 0:
                pass  # acknowledged
            elif driven == 1 and p == 0 and b <= v.arb_end:
                if b in v.stuff:
                    return _error_detected(v, b, "stuff-arbitration", Field.ID, b, b)
                v.role = "rx"
                out.role = "rx"
                out.lost_arbitration = True
                if res is not None:
                    return _rx_result(v, b, res)
                return None
            else:
                fb = (v.frame.encoded or v.frame.bits) if v.frame is not None else None
                fld, idx = fb.field_at(b) if fb is not None and b < len(v.bits) else (Field.EOF, 0)
                return _error_detected(v, b, "bit", fld, idx if idx is not None else 0, b)
        elif b == v.ack_slot and p == 1:
            return _error_detected(v, b, "ack", Field.ACK_SLOT, 0, b)
        if b == v.eof_last:
            out.success = True
            # rule 7 at this bit: later increments (an overload episode) add to it
            tec = after_tx_success(v.tec0 + out.tec_delta)
            v.tec0 = out.tec0 = tec - out.tec_delta
            v.phase = INTERMISSION
            v.im_n = 0
        return None
    if not dec.in_frame:
        if p == 1:
            return None  # still idle: nothing started
    if driven == 0 and p == 1:
        # a receiver sending its dominant ACK reads recessive: a bit error (only a recessive
        # bit read dominant in the ACK slot is exempt)
        return _error_detected(v, b, "bit", Field.ACK_SLOT, 0, dec.position)
    if p == 1 and v.kind == CLASSIC and v.fd_wire:
        f = dec.field
        if f is Field.R1 or (f is Field.R0 and not dec.extended):
            # an FD frame's FDF, where a CAN 2.0 controller has its reserved bit: it cannot
            # receive what follows and destroys the frame (see `stack.bus.fdnodes`)
            return _error_detected(v, b, "form", f, 0, dec.position)
    res = dec.feed(p)
    if res is None:
        return None
    return _rx_result(v, b, res)


def _step_flag(v: _View, b: int, driven: int, p: int) -> None:
    """Sending an error or overload flag: a passive flag ends after 6 equal bits; a dominant
    flag bit read recessive is rules 4/5 and a new flag."""
    if v.flag_kind == "passive":
        v.flag_levels.append(p)
        if p == 0:
            v.flag_had_dominant = True
        lv = v.flag_levels
        # a passive flag is complete after 6 consecutive bits of equal level
        if len(lv) >= 6 and len(set(lv[-6:])) == 1:
            _flag_done(v)
        return
    if p == 1 and driven == 0:
        # bit error while sending an active error flag or overload flag: rules 4 and 5, and
        # a new error flag from the next bit — a passive one once the counters reached 128
        # (rule 9), so a node whose transmitter cannot drive the bus stops after 16 of them
        if v.role == "tx":
            _bump(v, RULE_4_TEC, "rule 4")
        else:
            _bump(v, RULE_5_REC, "rule 5")
        if v.phase == FLAG:
            v.flag_kind = "passive" if (v.passive or v.listen_only) else "active"
            v.flag_n = 0
            v.flag_levels = []
            v.flag_had_dominant = False
        return
    v.flag_n += 1
    if v.flag_n >= 6:
        _flag_done(v)
    return


def _step_after_flag(v: _View, b: int, driven: int, p: int) -> None:
    """After its flag a node waits for recessive (the superposition of others' flags): rules
    2 and 6 count the dominant bits; the first recessive bit starts the delimiter."""
    if p == 0:
        if v.first_after and v.role == "rx" and v.flag_kind != "overload":
            _bump(v, RULE_2_REC, "rule 2")
        v.first_after = False
        v.dom_run += 1
        if v.dom_run >= DOMINANT_BITS_TOLERATED and (v.dom_run - DOMINANT_BITS_TOLERATED) % RULE_6_STEP == 0:
            _bump(v, RULE_6_STEP, "rule 6")
        return
    v.first_after = False
    v.phase = DELIM
    v.delim_n = 1
    return


def _step_delim(v: _View, b: int, driven: int, p: int) -> tuple[str, str, int, int] | None:
    """The 8-bit delimiter: dominant at its last bit is an overload, before it a form error."""
    if p == 0:
        if v.delim_n == 7:
            _start_overload(v)  # dominant at the last delimiter bit: overload
            return None
        return _error_detected(v, b, "form", "ERROR_DELIM", v.delim_n, b)
    v.delim_n += 1
    if v.delim_n >= 8:
        if v.flag_kind == "overload" and v.overloads < v.want_overloads:
            _start_overload(v)  # a second requested overload frame, from the next bit
        else:
            v.phase = INTERMISSION
            v.im_n = 0
    return None


def _step_integrating(v: _View, b: int, driven: int, p: int) -> None:
    """Bus integration after the protocol exception event: idle after 11 consecutive recessive
    bits; no error is detected, no counter moves, nothing is driven (ISO 11898-1:2015)."""
    if p == 0:
        v.integrating = 0
        return
    v.integrating += 1
    if v.integrating >= INTEGRATION_BITS:
        v.phase = IDLE


def _step_intermission(v: _View, b: int, driven: int, p: int) -> None:
    """Intermission: dominant in its first two bits is an overload condition; after 3 the node
    is idle."""
    if p == 0 and v.im_n < 2:
        # dominant in the first two intermission bits: an overload frame (the limit of two
        # applies to the ones a receiver asks for, not to these)
        _start_overload(v)
        return
    v.im_n += 1
    if v.im_n >= 3:
        v.phase = IDLE
    return


_PHASE_STEP = {
    FRAME: _step_frame,
    FLAG: _step_flag,
    AFTER_FLAG: _step_after_flag,
    DELIM: _step_delim,
    INTERMISSION: _step_intermission,
    INTEGRATING: _step_integrating,
}


def _flag_done(v: _View) -> None:
    out = v.out
    if v.role == "tx" and out.detected and out.detected[0] == "ack" and v.flag_kind == "passive":
        if v.flag_had_dominant:
            _bump(v, RULE_3_TEC, "rule 3")
        else:
            out.rules.append("rule 3 exception 1")
    v.phase = AFTER_FLAG
    v.first_after = True
    v.dom_run = 0


def _rx_result(v: _View, b: int, res: Any) -> tuple[str, str, int, int] | None:
    out = v.out
    if res.error is None:
        out.accepted = True
        # rule 8 at acceptance: later increments (an overload episode) add to it
        rec = after_rx_success(v.rec0 + out.rec_delta)
        v.rec0 = out.rec0 = rec - out.rec_delta
        out.frame = res.frame
        out.accept_bit = b - 1  # valid at the last-but-one EOF bit
        v.frame_done = True
        if res.overload or v.want_overloads:
            # dominant last EOF bit (frame kept), or a receiver that needs a delay: the overload
            # flag starts at the first intermission bit
            _start_overload(v)
        else:
            v.phase = INTERMISSION
            v.im_n = 0
        return None
    e = res.error
    if e.kind == "exception":
        # the protocol exception event: a tolerant node at FDF, an FD node at res recessive
        v.phase = INTEGRATING
        v.integrating = 0
        v.out.integrating_bit = b
        return None
    return _error_detected(v, b, e.kind, e.field, e.index, e.position)
