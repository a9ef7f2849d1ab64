"""A plain message set: a bus's bit rate and its messages (name, sending node, identifier, DLC,
period and deadline), with how long and with which seed to run it.

It belongs to the profile contract (DESIGN.md, "Profiles: the contract"): a profile expresses a
message set in its own terms with a converter (``express_message_set(mset) -> dict`` in the
module of its ``ProfileKind.build``), and the studies of `profiles.sweeps` generate the sets and
run them.
"""

from __future__ import annotations

from dataclasses import dataclass

from profiles.analysis.rta import MessageSpec, frame_bits_worst

__all__ = ["StudyMessage", "MessageSet"]


@dataclass(frozen=True)
class StudyMessage:
    """One message of a study's set: name, sending node, identifier, DLC, period and deadline
    (integer ns)."""

    name: str
    node: str
    can_id: int
    dlc: int
    period_ns: int
    deadline_ns: int
    extended: bool = False


@dataclass(frozen=True)
class MessageSet:
    """A message set on one bus: bit rate, messages, and how long and with which seed a converter
    should run it."""

    bitrate: int
    messages: tuple[StudyMessage, ...]
    duration_s: float
    seed: int = 0

    @property
    def nodes(self) -> list[str]:
        """The sending nodes, in the order their first message appears."""
        return list(dict.fromkeys(m.node for m in self.messages))

    def specs(self) -> list[MessageSpec]:
        """The set as the response-time analysis models it (worst-case stuffing)."""
        return [MessageSpec(m.name, m.can_id, m.extended, m.dlc, m.period_ns, m.deadline_ns) for m in self.messages]

    def utilisation(self) -> float:
        """Σ C_i / T_i with worst-case frames (eq. 1 of Davis et al. 2007)."""
        return sum(frame_bits_worst(m.dlc, m.extended) * 1e9 / self.bitrate / m.period_ns for m in self.messages)
