"""canstack's software CAN controller and bus (see DESIGN.md)."""

from .frame import Frame, arbitration_key, data_length

__all__ = ["Frame", "arbitration_key", "data_length"]
