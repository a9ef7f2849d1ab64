"""A plain message set: a bus's bit rates and its messages (name, sending node, identifier, DLC,
CAN FD flags, period and deadline), with how long and with which seed to run it.

It belongs to the profile contract (DESIGN.md, "Profiles: the contract"): a profile expresses a
message set in its own terms with a converter (``express_message_set(mset) -> dict`` in the
module of its ``ProfileKind.build``), and the studies of `profiles.sweeps` generate the sets and
run them.
"""

from __future__ import annotations

from dataclasses import dataclass

from profiles.analysis.model import timebase
from profiles.analysis.rta import MessageSpec, utilisation
from stack.wire.frame import data_length

__all__ = ["StudyMessage", "MessageSet"]


@dataclass(frozen=True)
class StudyMessage:
    """One message of a study's set: name, sending node, identifier, DLC, period and deadline
    (integer ns). ``fd`` makes it a CAN FD frame (ISO 11898-1:2015: ``dlc`` 9..15 then means
    12..64 data bytes, see ``length``), ``brs`` sends its data phase at the set's
    ``data_bitrate``."""

    name: str
    node: str
    can_id: int
    dlc: int
    period_ns: int
    deadline_ns: int
    extended: bool = False
    fd: bool = False
    brs: bool = False

    @property
    def length(self) -> int:
        """Data bytes: min(dlc, 8) for a classical frame, the FD length of its DLC for FD."""
        return data_length(self.dlc, self.fd)


@dataclass(frozen=True)
class MessageSet:
    """A message set on one bus: bit rate (and the CAN FD data bit rate, for messages with BRS),
    messages, and how long and with which seed a converter should run it.

    ValueError, naming the message, for BRS without FD and for a BRS message on a set without a
    data bit rate; the data bit rate itself is checked as the analysis checks it
    (`profiles.analysis.model.timebase`)."""

    bitrate: int
    messages: tuple[StudyMessage, ...]
    duration_s: float
    seed: int = 0
    data_bitrate: int | None = None

    def __post_init__(self) -> None:
        if self.data_bitrate is not None:
            timebase(self.bitrate, self.data_bitrate)
        for m in self.messages:
            if m.brs and not m.fd:
                raise ValueError(f"message {m.name!r}: brs needs fd (BRS exists only in CAN FD frames)")
            if m.brs and self.data_bitrate is None:
                raise ValueError(
                    f"message {m.name!r}: brs needs the set's data_bitrate (the bit rate of the data phase)"
                )

    @property
    def nodes(self) -> list[str]:
        """The sending nodes, in the order their first message appears."""
        return list(dict.fromkeys(m.node for m in self.messages))

    @property
    def fd(self) -> bool:
        """True when a message is a CAN FD frame."""
        return any(m.fd for m in self.messages)

    def specs(self) -> list[MessageSpec]:
        """The set as the response-time analysis models it (worst-case stuffing; pass
        ``data_bitrate`` to `profiles.analysis.rta.analyse` with them)."""
        return [
            MessageSpec(
                m.name, m.can_id, m.extended, m.dlc, m.period_ns, m.deadline_ns, node=m.node, fd=m.fd, brs=m.brs
            )
            for m in self.messages
        ]

    def utilisation(self) -> float:
        """Σ C_i / T_i with worst-case frames (eq. 1 of Davis et al. 2007; the worst-case CAN FD
        frame at both bit rates for FD messages, `profiles.analysis.model`)."""
        return utilisation(self.specs(), self.bitrate, data_bitrate=self.data_bitrate)
