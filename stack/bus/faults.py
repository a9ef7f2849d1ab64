"""Fault injection on the simulated bus.

Bit flips (targeted by frame, occurrence, field and bit, seen globally or by chosen nodes),
random bit errors at a bit-error rate (seeded, global or per node), and node faults: stuck
dominant, stuck recessive (a disconnected transmitter), disconnect/reconnect, a node that never
acknowledges, and a babbling idiot. Any attempt a fault touches is replayed bit by bit by
`stack.bus.attempt`, so detection, error frames and fault confinement follow from each node's view.

Random bit errors hit the bits of frames (SOF..EOF), not idle time or error frames (CAN FD
frames: the bits as their transmitter sends them, ESI included). A stuck
fault or a disconnect that begins while a frame is on the wire takes effect at its bit of that
frame; a stuck-dominant fault on an idle bus starts an attempt of its own (every node sees a
SOF followed by dominant bits), at once or when the bus goes idle.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from stack.bus.attempt import StuckFaults, brs_position, sent_frame
from stack.controller.confinement import PASSIVE
from stack.controller.events import TxDone
from stack.controller.node import ErrorState, Node
from stack.wire.coding import Field
from stack.wire.fd import worst_case_bits
from stack.wire.frame import Frame

if TYPE_CHECKING:  # pragma: no cover
    from stack.bus.sim import SimBus
    from stack.controller.queues import TxRequest

__all__ = ["FaultInjector", "FIELD_GROUPS", "FlipRule"]

# bits after a frame that an attempt can still take: an error flag with superposition (12),
# the error delimiter (8) and intermission (3), with room to spare
ATTEMPT_MARGIN_BITS = 32

# field groups a user names, in wire order (a frame has the fields of its format: RTR or RRS,
# r1/r0 or FDF/res/BRS/ESI); exact field names are accepted too
FIELD_GROUPS: dict[str, tuple[Field, ...]] = {
    "sof": (Field.SOF,),
    "arbitration": (Field.ID, Field.SRR, Field.IDE, Field.ID_EXT, Field.RTR, Field.RRS),
    "control": (Field.IDE, Field.R1, Field.R0, Field.FDF, Field.RES, Field.BRS, Field.ESI, Field.DLC),
    "data": (Field.DATA,),
    "stuff_count": (Field.STUFF_COUNT, Field.STUFF_PARITY),
    "fixed_stuff": (Field.FIXED_STUFF,),
    "crc": (Field.CRC,),
    "crc_delim": (Field.CRC_DELIM,),
    "ack": (Field.ACK_SLOT,),
    "ack_delim": (Field.ACK_DELIM,),
    "eof": (Field.EOF,),
}
_MAX_BITS = {
    "sof": 1,
    "arbitration": 32,
    "control": 6,
    "data": 64,
    "crc": 15,
    "crc_delim": 1,
    "ack": 1,
    "ack_delim": 1,
    "eof": 7,
    "raw": 160,
}
_FIELD_MAX = {
    Field.SOF: 1,
    Field.ID: 11,
    Field.SRR: 1,
    Field.IDE: 1,
    Field.ID_EXT: 18,
    Field.RTR: 1,
    Field.R1: 1,
    Field.R0: 1,
    Field.DLC: 4,
    Field.DATA: 64,
    Field.CRC: 15,
    Field.CRC_DELIM: 1,
    Field.ACK_SLOT: 1,
    Field.ACK_DELIM: 1,
    Field.EOF: 7,
}
# on a CAN FD bus (a data bit rate): FD frames' fields and lengths (standard FD control field:
# IDE FDF res BRS ESI DLC; 64 data bytes; CRC-21 and its 7 fixed stuff bits; the longest frame)
_FD_MAX_BITS = _MAX_BITS | {
    "control": 9,
    "data": 512,
    "stuff_count": 4,
    "fixed_stuff": 7,
    "crc": 21,
    "raw": worst_case_bits(64, True, fd=True).total,
}
_FD_FIELD_MAX = _FIELD_MAX | {
    Field.RRS: 1,
    Field.FDF: 1,
    Field.RES: 1,
    Field.BRS: 1,
    Field.ESI: 1,
    Field.DATA: 512,
    Field.STUFF_COUNT: 3,
    Field.STUFF_PARITY: 1,
    Field.FIXED_STUFF: 7,
    Field.CRC: 21,
}


def _resolve_field(name: str, fd: bool = False) -> tuple[str, tuple[Field, ...] | None, int]:
    key = str(name).lower()
    groups, fields = (_FD_MAX_BITS, _FD_FIELD_MAX) if fd else (_MAX_BITS, _FIELD_MAX)
    if key == "raw":
        return "raw", None, groups["raw"]
    if key in groups:
        return key, FIELD_GROUPS[key], groups[key]
    for f in fields:
        if f.value.lower() == key or f.name.lower() == key:
            return f.value, (f,), fields[f]
    known = ", ".join([g for g in FIELD_GROUPS if g in groups] + [f.value for f in fields] + ["raw"])
    extra = "" if fd else " (the fields of CAN FD frames on a bus with a data bit rate)"
    raise ValueError(f"unknown field {name!r}: one of {known}{extra}")


def _group_positions(frame: Frame, fields: tuple[Field, ...], group: str) -> list[int]:
    fb = frame.bits
    if group == "arbitration" and not frame.extended:
        fields = (Field.ID, Field.RTR, Field.RRS)
    if group == "control" and frame.extended:
        fields = (Field.R1, Field.R0, Field.FDF, Field.RES, Field.BRS, Field.ESI, Field.DLC)
    out: list[int] = []
    for f in fields:
        out.extend(fb.fields.get(f, ()))
    return out


@dataclass
class FlipRule:
    """Flip one bit of the ``occurrence``-th attempt (1-based) of frames matching ``can_id``
    (any frame if None) that have that bit; ``every`` flips every such attempt from then on.
    Matching frames without the bit are counted in ``skipped`` and warned about once."""

    can_id: int | None
    extended: bool | None
    occurrence: int
    group: str
    fields: tuple[Field, ...] | None
    bit: int
    nodes: frozenset[Node] | None
    every: bool = False
    seen: int = 0
    fired: int = 0
    skipped: int = 0  # matching frames that have no such bit (not counted as occurrences)

    def width(self, frame: Frame) -> int:
        """How many bits of this rule's field ``frame`` has."""
        if self.fields is None:
            return frame.bits.length
        return len(_group_positions(frame, self.fields, self.group))

    def position(self, frame: Frame) -> int | None:
        """The stuffed position (from SOF) this rule flips in ``frame``, or None if the frame
        has no such bit (a data bit beyond its length, say)."""
        if self.fields is None:
            return self.bit if self.bit < frame.bits.length else None
        pos = _group_positions(frame, self.fields, self.group)
        return pos[self.bit] if self.bit < len(pos) else None


@dataclass
class _Stuck:
    node: Node
    level: int
    start: int
    end: int | None


class FaultInjector:
    """Faults for one `SimBus`; create it once per bus (``FaultInjector(bus)``)."""

    def __init__(self, bus: SimBus) -> None:
        bus.attach_faults(self)
        self.bus = bus
        self.rng = bus.rng
        self.flips: list[FlipRule] = []
        self._ber_global: float = 0.0
        self._ber_nodes: dict[Node, float] = {}
        self._countdown: dict[Any, int] = {}
        self._stuck: list[_Stuck] = []
        self._deaf: set[Node] = set()
        self._overload: dict[Node, int] = {}
        self._leaves: list[tuple[Node, int]] = []  # (node, time) of scheduled disconnects
        self.injected = 0

    # ------------------------------------------------------------------ configuration
    def _node(self, node: Node | str) -> Node:
        if isinstance(node, Node):
            if node.bus is not self.bus:
                raise ValueError(f"node {node.name!r} is not on bus {self.bus.name!r}")
            return node
        for n in self.bus.nodes:
            if n.name == node:
                return n
        raise ValueError(
            f"unknown node {node!r}: nodes on bus {self.bus.name!r} are "
            f"{', '.join(n.name for n in self.bus.nodes) or 'none'}"
        )

    def _nodes(self, nodes: Iterable[Node | str] | None) -> frozenset[Node] | None:
        if nodes is None:
            return None
        if isinstance(nodes, (str, Node)):
            nodes = [nodes]
        return frozenset(self._node(n) for n in nodes)

    def flip(
        self,
        *,
        can_id: int | None = None,
        extended: bool | None = None,
        occurrence: int = 1,
        field: str = "data",
        bit: int = 0,
        nodes: Iterable[Node | str] | None = None,
        every: bool = False,
    ) -> FlipRule:
        """Flip bit ``bit`` of ``field`` (a group: sof, arbitration, control, data, crc,
        crc_delim, ack, ack_delim, eof, and for CAN FD frames stuff_count (the stuff count and its
        parity bit) and fixed_stuff (the CRC field's fixed stuff bits); a field name such as DLC,
        ID_EXT, BRS or ESI; or 'raw' for a position from SOF counting stuff bits) in the
        ``occurrence``-th attempt of frames with ``can_id``. ``nodes`` None: every node sees the
        flipped level (a global error); otherwise only those nodes do (a local error). A bus
        with a data bit rate takes the FD fields and lengths (64 data bytes, a 21-bit CRC)."""
        group, fields, width = _resolve_field(field, self.bus.data_bitrate is not None)
        if isinstance(bit, bool) or not isinstance(bit, int) or not 0 <= bit < width:
            raise ValueError(f"bit {bit!r} outside field {group} ({width} bits at most: 0..{width - 1})")
        if isinstance(occurrence, bool) or not isinstance(occurrence, int) or occurrence < 1:
            raise ValueError(f"occurrence {occurrence!r} must be 1 or more")
        rule = FlipRule(can_id, extended, occurrence, group, fields, bit, self._nodes(nodes), every)
        self.flips.append(rule)
        return rule

    def bit_errors(self, rate: float, *, nodes: Iterable[Node | str] | None = None) -> None:
        """Random bit errors at ``rate`` per bit (seeded by the bus seed). ``nodes`` None: global
        errors (everyone sees them); otherwise each listed node sees its own independent local
        errors at that rate."""
        if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not 0.0 <= rate <= 1.0 or math.isnan(rate):
            raise ValueError(f"bit-error rate {rate!r} outside [0, 1]")
        ns = self._nodes(nodes)
        if ns is None:
            self._ber_global = float(rate)
            self._countdown.pop(None, None)
        else:
            for n in sorted(ns, key=lambda n: n.name):
                self._ber_nodes[n] = float(rate)
                self._countdown.pop(n, None)

    def stuck(self, node: Node | str, level: str, *, start: int = 0, end: int | None = None) -> None:
        """Make a node's transmitter stuck 'dominant' (it holds the bus) or 'recessive' (it
        cannot drive the bus: a disconnected transmitter) from ``start`` to ``end`` ns."""
        if level not in ("dominant", "recessive"):
            raise ValueError(f"stuck level {level!r}: 'dominant' or 'recessive'")
        n = self._node(node)
        if end is not None and end <= start:
            raise ValueError(f"stuck fault end {end} ns is not after its start {start} ns")
        s = _Stuck(n, 0 if level == "dominant" else 1, int(start), None if end is None else int(end))
        self._stuck.append(s)
        if s.level == 0:
            self.bus.call_at(s.start, self._disturb, ())

    def never_ack(self, node: Node | str) -> None:
        """The node receives but never drives the ACK slot."""
        self._deaf.add(self._node(node))

    def overload(self, node: Node | str, frames: int = 1) -> None:
        """The node needs a delay after each frame it receives: it sends ``frames`` overload
        frames (1 or 2: the standard allows at most two in a row); 0 stops it."""
        if isinstance(frames, bool) or not isinstance(frames, int) or not 0 <= frames <= 2:
            raise ValueError(f"overload frames {frames!r}: a node sends 0, 1 or 2 in a row")
        n = self._node(node)
        if frames:
            self._overload[n] = frames
        else:
            self._overload.pop(n, None)

    def disconnect(self, node: Node | str, at: int, reconnect_at: int | None = None) -> None:
        """Take the node off the bus at ``at`` ns, and back at ``reconnect_at`` if given."""
        n = self._node(node)
        # an attempt on the wire at ``at`` sees the node vanish at that bit (see attempt)
        self._leaves.append((n, int(at)))
        self.bus.call_at(int(at), self.bus.disconnect, (n,))
        if reconnect_at is not None:
            if reconnect_at <= at:
                raise ValueError(f"reconnect at {reconnect_at} ns is not after disconnect at {at} ns")
            self.bus.call_at(int(reconnect_at), self.bus.reconnect, (n,))

    def babbling_idiot(
        self,
        node: Node | str,
        *,
        can_id: int = 0x000,
        data: bytes = b"\xff" * 8,
        start: int = 0,
        end: int | None = None,
    ) -> None:
        """From ``start`` to ``end`` ns the node floods the bus with a high-priority frame,
        queueing the next copy as soon as one is sent."""
        n = self._node(node)
        frame = Frame(can_id, data)

        def again(ev: TxDone) -> None:
            if ev.frame is frame and (end is None or self.bus.now() < end) and n.state is not ErrorState.BUS_OFF:
                n.send(frame)

        n.listen(TxDone, again)
        self.bus.call_at(int(start), lambda: n.send(frame) if n.state is not ErrorState.BUS_OFF else None, ())

    # ------------------------------------------------------------------ engine side
    def _draw(self, key: Any, rate: float) -> int:
        if rate <= 0.0:
            return 1 << 62
        if rate >= 1.0:
            return 0
        u = self.rng.random()
        return int(math.log1p(-u) / math.log1p(-rate)) if u > 0 else 0

    def _random_positions(self, key: Any, rate: float, length: int) -> list[int]:
        """Positions in the next ``length`` bits of this error stream (geometric gaps)."""
        c = self._countdown.get(key)
        if c is None:
            c = self._draw(key, rate)
        out = []
        while c < length:
            out.append(c)
            c += 1 + self._draw(key, rate)
        self._countdown[key] = c - length
        return out

    def _bits_after(self, now: int, t: int, data_phase: tuple[int, int] | None = None) -> int:
        """The bit of an attempt starting at ``now`` during which time ``t`` falls (rounded up),
        its FD data phase (if any) taken at the data bit rate as sent without error."""
        return self.bus.attempt_bit(t - now, data_phase)

    def _stuck_now(self, now: int, horizon: int = 0, data_phase: tuple[int, int] | None = None) -> StuckFaults:
        """Nodes stuck at ``now``, or from a bit of the attempt starting now within ``horizon``
        ns: (level, the bit where the fault ends or None[, the bit where it starts])."""
        stuck: StuckFaults = {}
        for s in self._stuck:
            if s.start < now + horizon + 1 and (s.end is None or now < s.end) and s.node.connected:
                end = None if s.end is None else self._bits_after(now, s.end, data_phase)
                if s.start <= now:
                    stuck[s.node] = (s.level, end)
                elif s.node not in stuck:
                    stuck[s.node] = (s.level, end, self._bits_after(now, s.start, data_phase))
        return stuck

    def _leaving(self, now: int, horizon: int, data_phase: tuple[int, int] | None = None) -> dict[Node, int]:
        """Nodes `disconnect` takes off the bus during the attempt starting now: the bit.
        Disconnects already past are dropped (every attempt consults this list)."""
        self._leaves = [(n, at) for n, at in self._leaves if at > now]
        return {
            n: self._bits_after(now, at, data_phase) for n, at in self._leaves if at <= now + horizon and n.connected
        }

    def unacknowledging(self, now: int) -> set[Node]:
        """The nodes that cannot drive the ACK slot at ``now`` and from then on: the deaf ones, and
        transmitters stuck recessive for good (a fault with no end that has started)."""
        out = set(self._deaf)
        out.update(s.node for s in self._stuck if s.level == 1 and s.end is None and s.start <= now)
        return out

    def attempt(self, bus: SimBus, now: int, txs: Sequence[TxRequest]) -> dict[str, Any] | None:
        """The faults of one attempt, or None for a clean one (consulted by the engine)."""
        frame = sent_frame(txs[0].frame, txs[0].node.state is PASSIVE)  # the bits on the wire
        flips: dict[int, Any] = {}
        for rule in self.flips:
            if rule.can_id is not None and (
                frame.can_id != rule.can_id or (rule.extended is not None and frame.extended != rule.extended)
            ):
                continue
            pos = rule.position(frame)
            if pos is None:
                # this frame has no such bit (a data bit beyond its length, an ID_EXT bit of a
                # standard frame): not an occurrence; said once per rule, not silently dropped
                rule.skipped += 1
                if rule.skipped == 1:
                    warnings.warn(
                        f"flip of bit {rule.bit} of {rule.group}: frame {frame!r} has only "
                        f"{rule.width(frame)} such bits; frames without it are skipped and do "
                        "not count as occurrences",
                        RuntimeWarning,
                        stacklevel=2,
                    )
                continue
            rule.seen += 1
            if rule.seen == rule.occurrence or (rule.every and rule.seen >= rule.occurrence):
                rule.fired += 1
                _add_flip(flips, pos, rule.nodes)
        length = frame.bits.length
        if self._ber_global:
            for p in self._random_positions(None, self._ber_global, length):
                _add_flip(flips, p, None)
        for n, rate in self._ber_nodes.items():
            if n.on_bus:
                for p in self._random_positions(n, rate, length):
                    _add_flip(flips, p, frozenset((n,)))
        # faults that begin while this attempt is on the wire are part of it: the frame, its
        # error signalling and intermission (a longer attempt misses only faults starting later)
        horizon = bus.bits_to_ns(length + ATTEMPT_MARGIN_BITS)
        phase = (brs_position(frame) + 1, frame.bits.crc_delim) if frame.brs else None
        stuck = self._stuck_now(now, horizon, phase) if self._stuck else {}
        leave = self._leaving(now, horizon, phase) if self._leaves else {}
        deaf = [n for n in self._deaf if n.on_bus]
        overload = {n: k for n, k in self._overload.items() if n.on_bus and all(q.node is not n for q in txs)}
        if not flips and not stuck and not deaf and not overload and not leave:
            return None
        self.injected += len(flips)
        return {
            "flips": flips,
            "stuck": stuck or None,
            "deaf": deaf,
            "overload": overload or None,
            "leave": leave or None,
        }

    def _disturb(self) -> None:
        """A stuck-dominant fault starting on an idle bus: every node sees a SOF. On a busy bus
        the attempt on the wire carries it; if it is still on when the bus is idle again (and
        no frame starts then, which would carry it too), it starts an attempt of its own."""
        bus = self.bus
        now = bus.now()
        if bus.transmitting:
            bus.call_at(max(bus.idle_at, now + 1), self._disturb, ())
            return
        stuck = self._stuck_now(now)
        if not any(spec[0] == 0 for spec in stuck.values()):
            return
        if now < bus.idle_at:
            bus.call_at(bus.idle_at, self._disturb, ())  # in the intermission
            return
        if bus.arbitration_due(now):
            return  # arbitration starts now and carries the fault
        bus.disturbance(now, stuck, deaf=[n for n in self._deaf if n.on_bus])


def _add_flip(flips: dict[int, Any], pos: int, nodes: frozenset[Node] | None) -> None:
    if pos in flips:
        cur = flips[pos]
        if cur is None or nodes is None:
            flips[pos] = None
        else:
            merged = set(cur) ^ set(nodes)  # the same node flipped twice sees the original level
            if merged:
                flips[pos] = frozenset(merged)
            else:
                del flips[pos]
    else:
        flips[pos] = nodes
