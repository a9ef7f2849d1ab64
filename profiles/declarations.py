"""What a profile is built from: the declarations of a scenario — its nodes, their messages,
the faults to inject — as plain checked values.

These belong to the profile contract (DESIGN.md, "Profiles: the contract"): the protocol packages
read them, and the experiment pipeline (`profiles.pipeline.scenario`) makes them from a TOML file.
Times are integer nanoseconds, the engine's unit.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from stack.wire.frame import data_length

__all__ = ["Scenario", "NodeDecl", "MessageDecl", "FaultDecl", "ms_to_ns"]


def ms_to_ns(ms: float) -> int:
    """Milliseconds (TOML) as integer nanoseconds (the engine's unit)."""
    return round(ms * 1_000_000)


@dataclass
class MessageDecl:
    """A message a node sends: identifier and format, length, and its release pattern —
    periodic (``period_ns``), sporadic (``sporadic_ns`` minimum inter-arrival, ``mean_ns`` mean)
    or none (the profile decides when, e.g. a TDMA window) — with offset, release jitter and
    deadline. ``options`` holds keys a profile adds to messages. ``fd`` marks a CAN FD frame
    (``dlc`` 9..15 then means 12..64 data bytes), ``brs`` its data phase at the bus's
    ``Scenario.data_bitrate``."""

    name: str
    node: str
    can_id: int
    extended: bool
    dlc: int
    data: bytes | None
    remote: bool
    period_ns: int | None
    sporadic_ns: int | None
    mean_ns: int | None
    offset_ns: int
    jitter_ns: int
    deadline_ns: int | None
    options: dict[str, Any] = field(default_factory=dict)
    fd: bool = False
    brs: bool = False

    @property
    def length(self) -> int:
        """Data bytes the frame carries: ``dlc`` for a classical data frame (0..8), the CAN FD
        length of the DLC code for an FD frame (9..15 mean 12..64 bytes), none for a remote frame."""
        return 0 if self.remote else data_length(self.dlc, self.fd)

    @property
    def interval_ns(self) -> int | None:
        """The period, or the minimum inter-arrival time of a sporadic message."""
        return self.period_ns if self.period_ns is not None else self.sporadic_ns

    @property
    def id_text(self) -> str:
        """The identifier as CAN tools print it (0x100, 0x18FEF100)."""
        return f"0x{self.can_id:08X}" if self.extended else f"0x{self.can_id:03X}"


@dataclass
class NodeDecl:
    """A node: its name, profile, controller configuration (queue policy, sizes), oscillator
    (``drift_ppm``, ``clock_offset_ns``), its messages, an optional application hook
    (``app = "module:function"``), the keys its profile adds (``options``) and what its
    controller is towards CAN FD (``fd``: 'fd', 'tolerant' or 'classic' as `stack.controller.node`
    names them; None: as the bus says — FD enabled on a bus with a data bit rate)."""

    name: str
    profile: str
    queue: str
    mailboxes: int | None
    abort: bool
    tx_queue_size: int
    rx_fifo_size: int
    drift_ppm: float
    clock_offset_ns: int
    listen_only: bool
    app: str | None
    messages: list[MessageDecl]
    options: dict[str, Any] = field(default_factory=dict)
    fd: str | None = None

    @property
    def policy(self) -> str:
        """The controller's queue policy as `stack` names it: 'priority', 'fifo' or 'mailbox'."""
        return "mailbox" if self.queue.startswith("mailboxes") else self.queue

    @property
    def priority_queue(self) -> bool:
        """True when the controller sends the highest-priority pending frame first (the
        response-time analysis' assumption)."""
        return self.queue == "priority"


@dataclass
class FaultDecl:
    """A fault to inject (`stack.bus.faults.FaultInjector`): its kind and checked parameters."""

    kind: str
    params: dict[str, Any]
    index: int


@dataclass
class Scenario:
    """A checked scenario. ``tables`` holds what profiles parsed from their own top-level tables
    (e.g. ``tdma``); ``analysis`` and ``plot`` the optional tables of the same names;
    ``data_bitrate`` the bus's CAN FD data bit rate (None: no data phase); ``warnings`` what is
    allowed but likely a mistake (a period shorter than its frame), one line each, naming the
    file, table and key."""

    source: str
    bitrate: int
    duration_ns: int
    seed: int
    nodes: list[NodeDecl]
    faults: list[FaultDecl]
    analysis: dict[str, Any]
    plot: dict[str, Any]
    tables: dict[str, Any] = field(default_factory=dict)
    raw: dict[str, Any] = field(default_factory=dict)
    data_bitrate: int | None = None
    warnings: list[str] = field(default_factory=list)

    @property
    def messages(self) -> list[MessageDecl]:
        """Every declared message, in file order."""
        return [m for n in self.nodes for m in n.messages]

    def node(self, name: str) -> NodeDecl:
        """The node named ``name``."""
        for n in self.nodes:
            if n.name == name:
                return n
        raise KeyError(name)
