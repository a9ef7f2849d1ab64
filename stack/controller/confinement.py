"""Fault confinement of CAN 2.0 (ISO 11898-1 §12): the error counters, the states and their rules,
written once.

A pure transition table in the manner of h11's ``_state.py``: the node applies it to its own
counters, the bit-level attempt (`stack.bus.attempt`) to each node's view of an attempt, the bus
to recovery; nothing here holds state or imports another layer.

The twelve rules:

1. a receiver that detects an error: REC += 1 (`RULE_1_REC`), except a bit error while sending an
   active error flag or an overload flag (rule 5);
2. a receiver that reads dominant as the first bit after sending its error flag: REC += 8;
3. a transmitter that sends an error flag: TEC += 8 — except (1) an error-passive transmitter
   with an ACK error that reads no dominant bit while sending its passive flag, and (2) a stuff
   error during arbitration on a stuff bit sent recessive and read dominant;
4. a transmitter with a bit error while sending an active error flag or overload flag: TEC += 8;
5. a receiver in the same situation: REC += 8;
6. after an active error flag or an overload flag the 14th consecutive dominant bit, after a
   passive error flag the 8th, and each further 8: every transmitter TEC += 8, every receiver
   REC += 8 (`DOMINANT_BITS_TOLERATED` counts from the end of the 6-bit flag);
7. a successful transmission: TEC −= 1, not below 0 (`after_tx_success`);
8. a successful reception: REC −= 1 if 1..127; above 127 it is set to a value in 119..127 — this
   implementation sets 127 (`after_rx_success`);
9. error passive when TEC ≥ 128 or REC ≥ 128;
10. bus off when TEC ≥ 256;
11. error active again when TEC ≤ 127 and REC ≤ 127 (`state_for`);
12. bus off → error active with both counters 0 after 128 occurrences of 11 consecutive
    recessive bits (`RECOVERY_OCCURRENCES` × `RECOVERY_RECESSIVE_BITS`).

Error warning (TEC or REC ≥ 96) is not a state of the specification; Linux and most controllers
report it, and so does this one (`ErrorState.WARNING`).
"""

from __future__ import annotations

from enum import Enum

__all__ = [
    "ErrorState",
    "ACTIVE",
    "WARNING",
    "PASSIVE",
    "BUS_OFF",
    "WARNING_LIMIT",
    "PASSIVE_LIMIT",
    "BUS_OFF_LIMIT",
    "RULE_1_REC",
    "RULE_2_REC",
    "RULE_3_TEC",
    "RULE_4_TEC",
    "RULE_5_REC",
    "RULE_6_STEP",
    "DOMINANT_BITS_TOLERATED",
    "RECOVERY_OCCURRENCES",
    "RECOVERY_RECESSIVE_BITS",
    "RULE_8_ABOVE_PASSIVE",
    "state_for",
    "after_tx_success",
    "after_rx_success",
]


class ErrorState(str, Enum):
    """Fault confinement states (rules 9-12; WARNING at TEC or REC >= 96)."""

    ACTIVE = "error-active"
    WARNING = "error-warning"
    PASSIVE = "error-passive"
    BUS_OFF = "bus-off"

    def __str__(self) -> str:
        return self.value


# the states as module constants: reading a member off an Enum class is a descriptor call, a
# global is not, and the engine compares states on every frame
ACTIVE = ErrorState.ACTIVE
WARNING = ErrorState.WARNING
PASSIVE = ErrorState.PASSIVE
BUS_OFF = ErrorState.BUS_OFF

WARNING_LIMIT = 96
PASSIVE_LIMIT = 128  # rule 9
BUS_OFF_LIMIT = 256  # rule 10

RULE_1_REC = 1
RULE_2_REC = 8
RULE_3_TEC = 8
RULE_4_TEC = 8
RULE_5_REC = 8
RULE_6_STEP = 8
DOMINANT_BITS_TOLERATED = 8
"""Rule 6 counts the 14th dominant bit from the start of an active error or overload flag (6 flag
bits + 8) and the 8th after a passive flag: both are the 8th bit after the flag."""

RULE_8_ABOVE_PASSIVE = 127  # rule 8 allows 119..127 for a REC above 127
RECOVERY_OCCURRENCES = 128  # rule 12
RECOVERY_RECESSIVE_BITS = 11


def state_for(tec: int, rec: int) -> ErrorState:
    """Rules 9-11 and the warning level: bus off at TEC >= 256, error passive at TEC or REC >= 128,
    error warning at >= 96, else error active. (Leaving bus off is rule 12's, not this.)"""
    if tec >= BUS_OFF_LIMIT:
        return BUS_OFF
    if tec >= PASSIVE_LIMIT or rec >= PASSIVE_LIMIT:
        return PASSIVE
    if tec >= WARNING_LIMIT or rec >= WARNING_LIMIT:
        return WARNING
    return ACTIVE


def after_tx_success(tec: int) -> int:
    """Rule 7: a successful transmission decrements TEC, not below 0."""
    return tec - 1 if tec > 0 else 0


def after_rx_success(rec: int) -> int:
    """Rule 8: a successful reception decrements REC if it is 1..127 and sets it to 127 (a value
    in 119..127) if it is above."""
    if rec > RULE_8_ABOVE_PASSIVE:
        return RULE_8_ABOVE_PASSIVE
    return rec - 1 if rec > 0 else 0
