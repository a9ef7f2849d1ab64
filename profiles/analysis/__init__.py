"""Analyses that the scheduling experiments print beside simulated results.

``rta``: worst-case response times of CAN messages (Davis, Burns, Bril, Lukkien 2007 for priority
queues; bounds for FIFO queues and transmit mailboxes), classical and CAN FD, on the message model
of ``model`` and the busy windows of ``window``. ``priority``: priority assignment (deadline
monotonic, Audsley's optimal, robust).
"""

from .model import ErrorModel, MessageSpec, NodeQueue, frame_worst
from .rta import RtaResult, analyse, analyse_1994, frame_bits_worst, utilisation

__all__ = [
    "ErrorModel",
    "MessageSpec",
    "NodeQueue",
    "RtaResult",
    "analyse",
    "analyse_1994",
    "frame_bits_worst",
    "frame_worst",
    "utilisation",
]
