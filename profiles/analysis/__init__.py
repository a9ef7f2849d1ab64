"""Analyses that the scheduling experiments print beside simulated results.

``rta``: worst-case response times of CAN messages (Davis, Burns, Bril, Lukkien 2007).
"""

from .rta import ErrorModel, MessageSpec, RtaResult, analyse, analyse_1994, frame_bits_worst, utilisation

__all__ = ["ErrorModel", "MessageSpec", "RtaResult", "analyse", "analyse_1994", "frame_bits_worst", "utilisation"]
