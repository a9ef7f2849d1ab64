"""A CAN FD frame on a bus with CAN 2.0 nodes, computed at once instead of bit by bit.

A CAN 2.0 controller (a node of kind `stack.controller.node.CLASSIC`) takes an FD frame's FDF bit
for its reserved bit r0 (r1 in an extended frame) and cannot receive the bits that follow: it
answers with an error frame. Where a real one finds the error depends on how it samples the FD
bits at its nominal rate (the data phase of a frame with BRS is a blur to it); the engine puts it
at FDF, the first bit where the frame is no longer a classical one, as a form error — what Vector's
CAN FD course teaches ("a recessive bit in the position of the dominant r-bit is regarded as
irregularity") and what ISO 11898-1:2015 makes of a recessive FDF at a node without the protocol
exception. A flipped r0 in a classical frame stays a reserved bit, accepted either way as CAN 2.0
says: the form error belongs to the FD frame that follows it.

With no fault on the bus and one transmitter, what happens next is fully determined by the nodes'
kinds, states and counters, and `classic_fd_attempt` computes it — the same `AttemptResult` the
bit-level replay (`stack.bus.attempt.simulate_attempt`) gives, at about the cost of a frame instead
of one step per node per bit. ``p`` below is FDF's position from SOF.

- At ``p`` every CAN 2.0 node detects the form error (rule 1). The tolerant nodes go bus
  integrating (the protocol exception); the FD-enabled nodes read FDF and go on.
- **Some CAN 2.0 node sends an active error flag** (bits p+1..p+6, dominant): the transmitter, which
  sends res (dominant) at p+1, reads dominant at its first recessive bit — BRS, ESI, a DLC bit or
  the stuff bit after five dominant bits, so by p+6 — a bit error (rule 3), and sends its flag
  after it. The FD-enabled receivers read six dominant bits from res on: a stuff error at p+6
  (rule 1), their flags from p+7. The wire is dominant from p+1 to the end of the last active flag
  (superposition), recessive after it; each node then waits for recessive (rule 2 for a receiver
  that reads dominant first), sends its 8-bit delimiter and intermission. No data phase: the
  transmitter's error comes at or before BRS.
- **Every CAN 2.0 node sends a passive flag** (error passive, or listen-only): nobody drives the bus,
  the frame goes through for the FD-enabled nodes, and each CAN 2.0 node's passive flag completes
  at the sixth equal bit — the sixth recessive bit from the ACK delimiter, since stuffing allows no
  six equal bits before it — then its delimiter and intermission end the attempt 6 bits after EOF.

Anything else (an FD frame nobody can acknowledge, a count of dominant bits that would reach rule
6) is left to the bit-level replay: the function returns None. A differential test runs random
mixed networks both ways and compares every trace record and counter.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from stack.bus.attempt import INTEGRATION_BITS, AttemptResult, NodeOutcome, brs_position, fdf_position
from stack.controller.confinement import (
    BUS_OFF,
    PASSIVE,
    RULE_1_REC,
    RULE_2_REC,
    RULE_3_TEC,
    after_rx_success,
    after_tx_success,
    state_for,
)
from stack.controller.node import CLASSIC, FD

if TYPE_CHECKING:  # pragma: no cover
    from stack.controller.node import Node
    from stack.controller.queues import TxRequest
    from stack.wire.frame import Frame

__all__ = ["classic_fd_attempt"]

FLAG_BITS = 6
DELIMITER_BITS = 8
INTERMISSION_BITS = 3
# the transmitter's bits after FDF, by offset from it: res, BRS, ESI, DLC3, DLC2, and the stuff
# bit after five dominant ones (reported in the field of the bit before it)
_AFTER_FDF = {2: ("BRS", 0), 3: ("ESI", 0), 4: ("DLC", 0), 5: ("DLC", 1), 6: ("DLC", 0)}


class _Node:
    """One node's counters through the attempt: `stack.bus.attempt._bump`'s bookkeeping."""

    __slots__ = ("out", "tx", "passive", "off", "flag_start", "active_flag")

    def __init__(self, node: Node, tx: bool) -> None:
        self.out = NodeOutcome(node.name, "tx" if tx else "rx")
        self.out.tec0 = node.tec
        self.out.rec0 = node.rec
        self.tx = tx
        self.passive = node.state is PASSIVE
        self.off = False
        self.flag_start = -1
        self.active_flag = False

    def bump(self, bit: int, amount: int, rule: str) -> None:
        out = self.out
        before = state_for(out.tec0 + out.tec_delta, out.rec0 + out.rec_delta)
        if self.tx:
            out.tec_delta += amount
        else:
            out.rec_delta += amount
        out.rules.append(rule)
        after = state_for(out.tec0 + out.tec_delta, out.rec0 + out.rec_delta)
        if after is not before:
            out.trail.append((bit, out.tec_delta, out.rec_delta))
        if after is BUS_OFF:
            self.off = True
        elif after is PASSIVE:
            self.passive = True

    def detect(self, bit: int, det: tuple[str, str, int, int], listen_only: bool) -> None:
        """Rules 1 and 3 at ``bit``, and the flag from the next bit (none when bus off)."""
        self.out.detected = det
        if self.tx:
            self.bump(bit, RULE_3_TEC, "rule 3")
        else:
            self.bump(bit, RULE_1_REC, "rule 1")
        if self.off:
            return
        self.out.detect_bit = bit
        self.flag_start = bit + 1
        self.active_flag = not (self.passive or listen_only)


def classic_fd_attempt(req: TxRequest, frame: Frame, nodes: list[Node]) -> AttemptResult | None:
    """The attempt of ``frame`` (an FD frame as ``req``'s node sends it, `sent_frame`) on a bus
    whose on-bus ``nodes`` (in bus order) include CAN 2.0 ones, with no fault and no other
    transmitter: the `AttemptResult` of `simulate_attempt`, or None where the module docstring
    says the bit-level replay must decide."""
    sender = req.node
    fb = frame.encoded or frame.bits
    bits = fb.bits
    p = fdf_position(frame)
    views: dict[str, _Node] = {}
    classic: list[tuple[_Node, bool]] = []
    fd_rx: list[tuple[_Node, bool]] = []
    tolerant: list[_Node] = []
    acker = False
    for n in nodes:
        v = views[n.name] = _Node(n, n is sender)
        if n is sender:
            tx = v
        elif n.fd == CLASSIC:
            classic.append((v, n.listen_only))
        elif n.fd == FD:
            fd_rx.append((v, n.listen_only))
            acker = acker or not n.listen_only
        else:
            tolerant.append(v)
    field = "r1" if frame.extended else "r0"
    form = ("form", field, 0, p)
    for v, listen_only in classic:
        v.detect(p, form, listen_only)
    for v in tolerant:
        v.out.integrating_bit = p
    if not any(v.active_flag for v, _ in classic):
        return _passive_flags(req, frame, views, tx, classic, fd_rx, form) if acker else None
    # the transmitter's first recessive bit after FDF, read dominant: its bit error
    e = next(k for k in range(p + 2, p + 7) if bits[k] == "1")
    name, index = _AFTER_FDF[e - p]
    tx.detect(e, ("bit", name, index, e), False)
    for v, listen_only in fd_rx:
        v.detect(p + 6, ("stuff", "DLC", 2, p + 6), listen_only)
    flaggers = [v for v, _ in classic] + [v for v, _ in fd_rx] + ([] if tx.off else [tx])
    # the wire is dominant from p+1 to the end of the last active flag (they overlap or touch)
    last_dominant = max(v.flag_start + FLAG_BITS - 1 for v in flaggers if v.active_flag)
    idle = last_dominant  # the last bit before every node is idle
    for v in flaggers:
        start = v.flag_start
        if v.active_flag or start + FLAG_BITS - 1 <= last_dominant:
            done = start + FLAG_BITS - 1  # six dominant bits: active, or a passive flag superposed
        else:
            done = last_dominant + FLAG_BITS  # a passive flag completes on six recessive bits
        dominant_after = last_dominant - done
        if dominant_after >= 8:
            return None  # rule 6 (never, for the flags above): the bit-level replay counts it
        if dominant_after > 0 and not v.tx:
            v.bump(done + 1, RULE_2_REC, "rule 2")
        delimiter = max(done, last_dominant) + 1
        idle = max(idle, delimiter + DELIMITER_BITS - 1 + INTERMISSION_BITS)
    if tolerant:  # bus integration: 11 recessive bits from the end of the flags
        idle = max(idle, last_dominant + INTEGRATION_BITS)
    end = idle + 1 if tx.off else idle - 2  # the replay leaves out the last intermission when all idle
    return _result(
        end,
        bits[: p + 1] + "0" * (last_dominant - p) + "1" * (idle - last_dominant),
        form,
        views,
        None,
        None,
    )


def _passive_flags(
    req: TxRequest,
    frame: Frame,
    views: dict[str, _Node],
    tx: _Node,
    classic: list[tuple[_Node, bool]],
    fd_rx: list[tuple[_Node, bool]],
    form: tuple[str, str, int, int],
) -> AttemptResult:
    """Every CAN 2.0 node flags passively: the frame goes through for the FD-enabled nodes (rules
    7 and 8 where the replay applies them, at the last EOF bit and the reception)."""
    fb = frame.encoded or frame.bits
    length = len(fb.bits)
    out = tx.out
    out.success = True
    out.tec0 = after_tx_success(out.tec0)
    for v, _ in fd_rx:
        o = v.out
        o.accepted = True
        o.accept_bit = length - 2  # valid at the last-but-one EOF bit
        o.rec0 = after_rx_success(o.rec0)
        o.frame = frame
    # a passive flag completes at the sixth recessive bit from the ACK delimiter (EOF bit 4), the
    # delimiter starts at EOF bit 5: the last node is idle 9 bits after EOF
    phase = (brs_position(frame) + 1, fb.crc_delim) if frame.brs else None
    return _result(length + 6, fb.bits + "1" * 9, form, views, req, phase)


def _result(
    bits: int,
    wire: str,
    first: tuple[str, str, int, int],
    views: dict[str, _Node],
    winner: TxRequest | None,
    data_phase: tuple[int, int] | None,
) -> AttemptResult:
    outcomes = {name: v.out for name, v in views.items()}
    first_bit = min((o.detect_bit for o in outcomes.values() if o.detect_bit >= 0), default=-1)
    for o in outcomes.values():
        o.primary = o.detect_bit >= 0 and o.detect_bit == first_bit
    return AttemptResult(bits, wire, first, outcomes, winner, data_phase=data_phase)
