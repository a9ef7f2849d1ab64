"""Random CAN networks on which the response-time analysis is checked against the simulated bus.

A `Network` is what both sides need: the bit rate (and, for CAN FD, the data bit rate), the
nodes with their transmit queue policy (priority, FIFO, mailboxes with or without abort), clock
drift and, on a CAN FD bus, what their controller is (`stack.Node`'s ``fd``: ``fd``, or
``tolerant`` — classical, with ISO 11898-1:2015's protocol exception), and the messages with
their payload, format (classical or FD, with or without BRS), period, release jitter and
deadline. `Network.specs` and `Network.queues` give the
analysis (`profiles.analysis.rta.analyse`) its inputs; `profiles.sweeps.releases` runs the same
network on `stack.SimBus`.

`random_network` draws one from a `random.Random`, so a seed gives the same network on every
machine:

- 1..``nodes`` nodes (2 at least when ``nodes`` >= 2), each of a queue kind drawn from
  ``queues`` by weight; a mailbox node gets 1..3 mailboxes, with abort 40 % of the time; with
  ``drift``, half the nodes drift by ±50 ppm, ±0.2 %, ±2 % or ±5 % from a random clock offset;
- 1..``per_node`` messages a node, distinct 11-bit identifiers (a fifth of them extended, the
  11 bits shifted to the top of the 29), 0..8 random data bytes;
- the bus utilisation (worst-case frames) uniform in [min(0.15, U/2), U] for ``max_util`` U,
  split by UUniFast (`profiles.sweeps.random_sets.uunifast`); each message's period is its frame's
  share, T = C / u, kept between 2 C and 40 ms; deadline = period;
- release jitter uniform in [0, T], a quarter of the messages exactly T;
- exact frame lengths for the analysis (the real stuffed frame) half the time, else eq. 1's
  worst case.

With ``fd`` (`FD_NETWORKS`) the network is a CAN FD bus (ISO 11898-1:2015), drawn with the same
steps and these more (a classical network draws none of them, so a seed gives the same classical
network as before FD was added):

- a data bit rate of 1, 2, 4, 5 or 8 times the nominal (`DATA_RATIOS`);
- ``mixed``: 30 % of the nodes ``tolerant`` (they send classical frames, and integrate on FD
  frames), and 30 % of the messages of FD-enabled nodes classical; ``all``: every node
  FD-enabled, every message FD;
- an FD message has BRS 60 % of the time (when the data bit rate is above the nominal) and one
  of the FD lengths, 0..64 bytes; its share of the utilisation is its worst-case frame at both
  rates (`profiles.analysis.model.frame_worst`).
"""

from __future__ import annotations

import random
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from profiles.analysis.model import frame_worst
from profiles.analysis.rta import ErrorModel, MessageSpec, NodeQueue, frame_bits_worst
from profiles.sweeps.random_sets import uunifast
from stack import Frame
from stack.controller.node import FD, TOLERANT
from stack.wire.coding import duration_ns
from stack.wire.frame import FD_LENGTHS

__all__ = [
    "NetNode",
    "NetMsg",
    "Network",
    "random_network",
    "parse_queue_mix",
    "queue_mix_text",
    "QUEUE_KINDS",
    "DEFAULT_QUEUES",
    "FD_NETWORKS",
    "DATA_RATIOS",
    "MS",
]

MS = 1_000_000
QUEUE_KINDS = ("priority", "fifo", "mailbox")
DEFAULT_QUEUES: tuple[tuple[str, int], ...] = (("priority", 1), ("fifo", 1), ("mailbox", 2))
"""The default mix of node queue kinds, by weight: mailbox nodes (with and without abort, one
to three mailboxes) are the most varied, so they are drawn twice as often."""

FD_NETWORKS = {
    "mixed": "CAN FD and classical frames: some nodes tolerant classical controllers, some messages of "
    "FD-enabled nodes classical",
    "all": "every node FD-enabled, every message a CAN FD frame",
}
"""The kinds of CAN FD network `random_network` draws (its ``fd``), and what each is."""

DATA_RATIOS = (1, 2, 4, 5, 8)
"""The data bit rate of a CAN FD network, in multiples of its nominal bit rate."""

#: the drifts a drifting node draws from (ppm, either sign)
DRIFTS_PPM = (50.0, 2_000.0, 20_000.0, 50_000.0)
#: the longest period drawn: a nearly idle message would otherwise make the simulation long
MAX_PERIOD_NS = 40 * MS


@dataclass
class NetNode:
    """A node: its queue policy (`profiles.analysis.rta.NodeQueue`'s words), its clock, and what
    its controller is towards CAN FD (`stack.Node`'s ``fd``; None: as the bus says)."""

    name: str
    queue: str = "priority"
    mailboxes: int | None = None
    abort: bool = False
    drift_ppm: float = 0.0
    offset_ns: int = 0
    fd: str | None = None


@dataclass
class NetMsg:
    """A periodic message: identifier, payload, period, release jitter and deadline (ns); ``fd``
    sends it as a CAN FD frame, ``brs`` with its data phase at the bus's data bit rate."""

    name: str
    node: str
    can_id: int
    extended: bool
    data: bytes
    period_ns: int
    jitter_ns: int
    deadline_ns: int
    fd: bool = False
    brs: bool = False

    @property
    def frame(self) -> Frame:
        """The data frame each instance sends."""
        if self.fd:
            return Frame(self.can_id, self.data, extended=self.extended, fd=True, brs=self.brs)
        return Frame(self.can_id, self.data, extended=self.extended)

    @property
    def kind(self) -> str:
        """``classical``, ``FD`` or ``FD with BRS``."""
        return "FD with BRS" if self.brs else "FD" if self.fd else "classical"


@dataclass
class Network:
    """A bus, its nodes and messages; ``exact`` gives the analysis the real frame lengths,
    ``errors`` an error model both the analysis and the simulation keep; ``data_bitrate`` makes
    it a CAN FD bus (`stack.SimBus`'s, and the analysis' ``data_bitrate``)."""

    bitrate: int
    nodes: list[NetNode]
    messages: list[NetMsg]
    exact: bool = False
    errors: ErrorModel | None = None
    data_bitrate: int | None = None
    label: str = field(default="", compare=False)

    def specs(self) -> list[MessageSpec]:
        """The messages as the analysis takes them (drift from their node; for an exact FD frame
        with BRS, also how many of its bits go at the data rate)."""
        drift = {n.name: n.drift_ppm for n in self.nodes}
        out = []
        for m in self.messages:
            f = m.frame
            out.append(
                MessageSpec(
                    m.name,
                    m.can_id,
                    m.extended,
                    f.dlc,
                    m.period_ns,
                    m.deadline_ns,
                    m.jitter_ns,
                    f.wire_bits + 3 if self.exact else None,
                    node=m.node,
                    drift_ppm=drift[m.node],
                    fd=m.fd,
                    brs=m.brs,
                    data_bits=f.bits.data_bits if self.exact and m.brs else None,
                )
            )
        return out

    def queues(self) -> dict[str, NodeQueue]:
        """Each node's queue policy, by node name."""
        return {n.name: NodeQueue(n.queue, n.mailboxes, n.abort) for n in self.nodes}

    def as_dict(self) -> dict[str, Any]:
        """The network as plain data (JSON): enough to build it again. A CAN FD network also has
        ``data_bitrate``, each node its ``fd`` and each message its ``fd`` and ``brs``."""
        fd = self.data_bitrate is not None
        out: dict[str, Any] = {"bitrate": self.bitrate}
        if fd:
            out["data_bitrate"] = self.data_bitrate
        out["exact"] = self.exact
        out["errors"] = (
            None if self.errors is None else {"t_error_ns": self.errors.t_error_ns, "burst": self.errors.burst}
        )
        out["nodes"] = [
            {
                "name": n.name,
                "queue": n.queue,
                "mailboxes": n.mailboxes,
                "abort": n.abort,
                "drift_ppm": n.drift_ppm,
                "offset_ns": n.offset_ns,
                **({"fd": n.fd or FD} if fd else {}),
            }
            for n in self.nodes
        ]
        out["messages"] = [
            {
                "name": m.name,
                "node": m.node,
                "id": m.can_id,
                "extended": m.extended,
                "data": m.data.hex(),
                "period_ns": m.period_ns,
                "jitter_ns": m.jitter_ns,
                "deadline_ns": m.deadline_ns,
                **({"fd": m.fd, "brs": m.brs} if fd else {}),
            }
            for m in self.messages
        ]
        return out

    def describe(self) -> str:
        """The network in lines a person can read and rebuild it from."""
        frames = "exact frame lengths" if self.exact else "worst-case frame lengths (eq. 1)"
        errors = (
            "" if self.errors is None else f", errors: {self.errors.burst} in any {self.errors.t_error_ns / MS:g} ms"
        )
        fd = self.data_bitrate is not None
        rates = f"{self.bitrate} bit/s" + (f", CAN FD data phase {self.data_bitrate} bit/s" if fd else "")
        lines = [f"{self.label or 'network'}: {rates}, {frames}{errors}"]
        for n in self.nodes:
            if n.queue == "mailbox":
                count = n.mailboxes or 1
                queue = f"{count} mailbox{'es' if count > 1 else ''} {'with' if n.abort else 'without'} abort"
            else:
                queue = f"{'FIFO' if n.queue == 'fifo' else n.queue} queue"
            clock = f", drift {n.drift_ppm:+g} ppm from offset {n.offset_ns} ns" if n.drift_ppm else ""
            controller = f", {n.fd or FD} controller" if fd else ""
            lines.append(f"  node {n.name}: {queue}{controller}{clock}")
            for m in self.messages:
                if m.node == n.name:
                    ident = f"0x{m.can_id:08X} (29-bit)" if m.extended else f"0x{m.can_id:03X}"
                    kind = f"{m.kind} ({len(m.data)} bytes), " if fd else ""
                    lines.append(
                        f"    {m.name}: id {ident}, {kind}data {m.data.hex() or '(none)'}, T {m.period_ns} ns, "
                        f"J {m.jitter_ns} ns, D {m.deadline_ns} ns"
                    )
        return "\n".join(lines)


def parse_queue_mix(text: str) -> tuple[tuple[str, int], ...]:
    """``KIND[=WEIGHT],…`` (kinds of `QUEUE_KINDS`, whole weights 1..1000, default 1) as
    (kind, weight) pairs in the order given; ValueError naming the part and the rule."""
    out: list[tuple[str, int]] = []
    for part in text.split(","):
        kind, sep, weight = part.strip().partition("=")
        kind = kind.strip()
        if kind not in QUEUE_KINDS:
            raise ValueError(f"{part.strip()!r}: a queue kind is one of {', '.join(QUEUE_KINDS)} (KIND or KIND=WEIGHT)")
        w = 1
        if sep:
            try:
                w = int(weight)
            except ValueError:
                raise ValueError(f"{part.strip()!r}: the weight of {kind} must be a whole number") from None
            if not 1 <= w <= 1000:
                raise ValueError(f"{part.strip()!r}: the weight of {kind} is from 1 to 1000")
        if any(k == kind for k, _ in out):
            raise ValueError(f"{text!r}: {kind} is given twice")
        out.append((kind, w))
    return tuple(out)


def queue_mix_text(mix: Sequence[tuple[str, int]]) -> str:
    """The mix as ``parse_queue_mix`` reads it."""
    return ",".join(f"{k}={w}" for k, w in mix)


def random_network(
    rng: random.Random,
    *,
    max_util: float = 0.85,
    drift: bool = True,
    per_node: int = 4,
    nodes: int = 5,
    queues: Sequence[tuple[str, int]] = DEFAULT_QUEUES,
    fd: str | None = None,
) -> Network:
    """A random network drawn from ``rng`` (see the module docstring for the distribution): a
    CAN FD one of the kind ``fd`` names (`FD_NETWORKS`), classical when None. ValueError for
    counts below 1, a utilisation not above 0, an empty or unknown queue mix, or an unknown
    ``fd``."""
    if nodes < 1 or per_node < 1:
        raise ValueError(f"nodes {nodes} and per_node {per_node} must be >= 1")
    if not max_util > 0:
        raise ValueError(f"max_util {max_util!r} must be > 0")
    kinds = [k for k, w in queues for _ in range(w)]
    if not kinds or any(k not in QUEUE_KINDS for k in kinds):
        raise ValueError(f"queues {queues!r}: kinds of {', '.join(QUEUE_KINDS)} with weights >= 1")
    if fd is not None and fd not in FD_NETWORKS:
        raise ValueError(f"fd {fd!r}: a CAN FD network is one of {', '.join(FD_NETWORKS)} (None: classical)")
    mixed = fd == "mixed"
    # every draw of the FD features sits behind `fd`: a classical network takes the same draws
    # from rng as before they existed, so a seed keeps its network
    bitrate = rng.choice([125_000, 250_000, 500_000, 1_000_000])
    data_bitrate = bitrate * rng.choice(DATA_RATIOS) if fd else None
    node_list = []
    for i in range(rng.randint(min(2, nodes), nodes)):
        kind = rng.choice(kinds)
        n = NetNode(f"n{i}", kind)
        if kind == "mailbox":
            n.mailboxes = rng.randint(1, 3)
            n.abort = rng.random() < 0.4
        if drift and rng.random() < 0.5:
            n.drift_ppm = rng.choice([1.0, -1.0]) * rng.choice(DRIFTS_PPM)
            n.offset_ns = rng.randint(0, 10**6)
        if fd:
            n.fd = TOLERANT if mixed and rng.random() < 0.3 else FD
        node_list.append(n)
    counts = [rng.randint(1, per_node) for _ in node_list]
    total = sum(counts)
    ids = rng.sample(range(0x800), total)
    u = uunifast(total, rng.uniform(min(0.15, max_util / 2), max_util), rng)
    tau = 10**9 // bitrate
    msgs = []
    k = 0
    for node, count in zip(node_list, counts):
        for _ in range(count):
            extended = rng.random() < 0.2
            is_fd = node.fd == FD and (not mixed or rng.random() < 0.7)
            brs = is_fd and data_bitrate is not None and data_bitrate > bitrate and rng.random() < 0.6
            length = rng.choice(FD_LENGTHS) if is_fd else rng.randint(0, 8)
            data = bytes(rng.randrange(256) for _ in range(length))
            if is_fd:
                nominal_bits, data_bits = frame_worst(Frame(0, data, fd=True).dlc, extended, fd=True, brs=brs)
                c = duration_ns(nominal_bits, data_bits, bitrate, data_bitrate)
            else:
                c = frame_bits_worst(length, extended) * tau
            period = max(2 * c, min(MAX_PERIOD_NS, int(c / max(u[k], 1e-3))))
            jitter = period if rng.random() < 0.25 else rng.randint(0, period)
            can_id = (ids[k] << 18) if extended else ids[k]
            msgs.append(NetMsg(f"m{k}", node.name, can_id, extended, data, period, jitter, period, is_fd, brs))
            k += 1
    return Network(bitrate, node_list, msgs, exact=rng.random() < 0.5, data_bitrate=data_bitrate)
