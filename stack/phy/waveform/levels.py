"""The CAN_RX level convention and the limits the waveform modules share.

On the CAN_RX pin 0 is dominant and 1 recessive (as in `stack.wire.coding`); a waveform is held
as a bytes object of one such byte per sample, so that edges are found with ``bytes.find``.
"""

from __future__ import annotations

__all__ = ["DOMINANT", "RECESSIVE", "IDLE_BITS", "MAX_RENDER_SAMPLES", "MAX_SAMPLES_PER_BIT"]

#: One dominant sample (the byte searched for with ``bytes.find``).
DOMINANT = b"\x00"
#: One recessive sample.
RECESSIVE = b"\x01"

#: Recessive bits that make the bus idle for a receiver that has lost track of the traffic:
#: 8 bits error/overload delimiter + 3 bits intermission (also the bus-integration rule).
IDLE_BITS = 11

#: Samples a rendered waveform may have: it is built in memory, one byte a sample.
MAX_RENDER_SAMPLES = 400_000_000
#: Longest bit, in samples, the receiver and the renderer accept: the two options are checked
#: one by one (positive, finite), but their ratio can still overflow (1e300 samples/s at
#: 1e-10 bit/s); a frame of bits this long would span 4.4e10 samples, far beyond any capture.
MAX_SAMPLES_PER_BIT = 1e9
