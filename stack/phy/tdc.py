"""Transmitter delay compensation: a CAN FD transmitter checking its own data-phase bits at the
secondary sample point, simulated a CAN clock period at a time.

Rules (ISO 11898-1:2015, transmitter delay compensation; Bosch's M_CAN manual describes the same):
- A transmitter reads back every bit it sends; a bit read back other than sent is a bit error
  (not in the ACK slot, where the receivers' ACK overwrites its recessive bit).
- Its own bits reach its RX pin a loop delay later (TX, transceiver, RX). In the nominal phase
  that delay is far shorter than Phase_Seg1; in the data phase it can be longer than a whole
  data bit: read at the sample point, the transmitter would see an earlier bit of its own.
- With TDC the transmitter measures the loop delay once a frame, TDCV in clock periods, at the
  recessive-to-dominant edge that ends FDF, and checks each bit it sends at the data bit rate at
  the secondary sample point SSP = the start of that bit as sent + TDCV + TDCO, keeping the bits
  sent until their SSP comes. A TDCV beyond the controller's range cannot be used.
- The transmitter's bit time is its own: it does not synchronise on its own delayed edges
  (ISO 11898-1: no resynchronisation of a transmitter on a late edge, none in the data phase).
- Receivers need no TDC: they synchronise on the edges they receive (`SyncReceiver`).

`transmit_fd` sends one frame and also lets a receiver elsewhere on the bus decode it;
`max_loop_delay` finds the longest loop delay a transmitter still works with, with and without
TDC.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import can

from stack.phy.boundary import last_working
from stack.phy.receiver import SyncReceiver
from stack.wire.coding import Field
from stack.wire.decoder import DecodedFrame
from stack.wire.frame import Frame

__all__ = ["Transmission", "bit_starts", "transmit_fd", "max_loop_delay", "TDC_FRAMES"]

#: Frames for the loop delay search: CAN FD with BRS, data that changes level every bit (a
#: transmitter reading back an earlier bit is wrong at once) and every few bits.
TDC_FRAMES = (
    Frame(0x0A5, bytes([0x55, 0xAA] * 4), fd=True, brs=True),
    Frame(0x1234567, bytes(range(0, 240, 5)), extended=True, fd=True, brs=True),
)


@dataclass(frozen=True)
class Transmission:
    """What happened when a transmitter sent one FD frame with a loop delay.

    ``ok`` when the transmitter read every bit back as sent and the receiver decoded the frame;
    otherwise ``kind`` is 'bit' (the transmitter's bit error: ``field``/``index``/``position``
    say where, ``detail`` what it read), 'tdcv' (the loop delay measured beyond the controller's
    TDCV range) or the receiver's error. ``tdcv`` is the measured loop delay and ``ssp`` TDCV +
    TDCO (clock periods; None without TDC); ``received`` is the receiver's result.
    """

    ok: bool
    kind: str
    field: Field | None
    index: int | None
    position: int | None
    tdcv: int | None
    ssp: int | None
    received: DecodedFrame | None
    detail: str = ""

    def describe(self) -> str:
        """One line: 'ok' or the failure and where."""
        if self.ok:
            return "ok"
        if self.kind == "bit" and self.field is not None:
            where = f"{self.field.value} bit {self.index}" if self.index is not None else f"after {self.field.value}"
            return f"transmitter's bit error in {where} (bit {self.position} from SOF): {self.detail}"
        return f"{self.kind}: {self.detail}"

    def as_dict(self) -> dict[str, Any]:
        """JSON form."""
        return {
            "ok": self.ok,
            "kind": self.kind,
            "field": self.field.value if self.field else None,
            "bit": self.index,
            "position": self.position,
            "tdcv": self.tdcv,
            "ssp": self.ssp,
            "detail": self.detail,
        }


def bit_starts(frame: Frame, timing: can.BitTimingFd) -> tuple[list[int], list[int]]:
    """Where each bit of ``frame`` starts as its transmitter sends it, in CAN clock periods from
    SOF (``length + 1`` values, the end of EOF last), and the offset of each bit's sample point.

    Nominal bits last brp x NBT clock periods and are sampled after brp x (1 + TSEG1); with BRS the
    data timing runs from the sample point of BRS to that of the CRC delimiter (ISO 11898-1:2015),
    so BRS lasts the nominal sample point plus the data Phase_Seg2, the CRC delimiter the data
    sample point plus the nominal Phase_Seg2."""
    t = timing
    nbt, spn = t.nom_brp * t.nbt, t.nom_brp * (1 + t.nom_tseg1)
    dbt, spd = t.data_brp * t.dbt, t.data_brp * (1 + t.data_tseg1)
    fb = frame.bits
    brs = fb.fields[Field.BRS][0] if fb.brs else fb.length
    delim = fb.crc_delim
    starts, samples = [0], []
    for k in range(fb.length):
        if k < brs or k > delim:
            length, sp = nbt, spn
        elif k == brs:
            length, sp = spn + dbt - spd, spn
        elif k < delim:
            length, sp = dbt, spd
        else:
            length, sp = spd + nbt - spn, spd
        starts.append(starts[-1] + length)
        samples.append(sp)
    return starts, samples


def _receive(
    frame: Frame, timing: can.BitTimingFd, starts_ns: list[float], delay_ns: float, drift_ppm: float, phase: float
) -> DecodedFrame | None:
    """A `SyncReceiver` on its own clock reading the bus ``delay_ns`` after the transmitter."""
    bits = frame.bits.bits
    rx = SyncReceiver.from_timing_fd(timing)
    period = 1e9 / timing.f_clock / (1 + drift_ppm * 1e-6)
    t0 = delay_ns + (phase - 3) * period
    for m in range(int((starts_ns[-1] + 4 * period) / period) + 8):
        k = bisect_right(starts_ns, t0 + m * period - delay_ns) - 1
        res = rx.tick(int(bits[k]) if 0 <= k < len(bits) else 1)
        if res is not None:
            return res
    return None


def transmit_fd(
    frame: Frame,
    timing: can.BitTimingFd,
    loop_delay_ns: float,
    tdco: int | None = None,
    *,
    tdcv_max: int | None = None,
    rx_delay_ns: float = 0.0,
    rx_drift_ppm: float = 0.0,
    phase: float = 0.5,
) -> Transmission:
    """Send ``frame`` (CAN FD) from a transmitter whose RX pin sees its TX ``loop_delay_ns``
    later, with TDC when ``tdco`` (clock periods) is given, and let a receiver ``rx_delay_ns``
    down the bus, its clock off by ``rx_drift_ppm`` (its ticks ``phase`` of a period after the
    SOF edge), decode it. The transmitter ticks once a clock period: it samples its RX at each
    bit's sample point, or for the bits after BRS up to the CRC delimiter at the SSP with TDC
    (module docstring), and reports the first bit read back other than sent."""
    if not frame.fd:
        raise ValueError(f"{frame!r}: transmitter delay compensation is for CAN FD frames")
    if not (math.isfinite(loop_delay_ns) and loop_delay_ns >= 0):
        raise ValueError(f"loop delay {loop_delay_ns!r} ns: must be a finite delay >= 0")
    if tdco is not None and tdco < 0:
        raise ValueError(f"TDCO {tdco}: an offset in clock periods >= 0")
    fb = frame.bits
    bits = fb.bits
    period = 1e9 / timing.f_clock
    starts, samples = bit_starts(frame, timing)
    starts_ns = [s * period for s in starts]

    def rx_level(tick: int) -> int:
        # the transmitter's RX pin at one of its clock ticks: its own TX, loop_delay_ns earlier
        k = bisect_right(starts_ns, tick * period - loop_delay_ns) - 1
        return int(bits[k]) if 0 <= k < len(bits) else 1

    fdf = fb.fields[Field.FDF][0]
    edge = starts[fdf + 1]  # FDF recessive, then res (or a stuff bit) dominant
    tdcv = next(m - edge for m in range(edge, edge + starts[-1]) if rx_level(m) == 0)
    ssp = None if tdco is None else tdcv + tdco
    received = _receive(frame, timing, starts_ns, rx_delay_ns, rx_drift_ppm, phase)
    if ssp is not None and tdcv_max is not None and tdcv > tdcv_max:
        return Transmission(
            False,
            "tdcv",
            None,
            None,
            None,
            tdcv,
            ssp,
            received,
            f"the loop delay measures {tdcv} clock periods, beyond the controller's TDCV range 0..{tdcv_max}",
        )
    brs = fb.fields[Field.BRS][0] if fb.brs else fb.length
    ack = fb.fields[Field.ACK_SLOT][0]
    for k in range(fb.length):
        if k == ack:
            continue
        data_phase = brs < k <= fb.crc_delim
        at = starts[k] + (ssp if ssp is not None and data_phase else samples[k])
        got = rx_level(at)
        if got != int(bits[k]):
            fld, idx = fb.field_at(k)
            how = "at the secondary sample point" if ssp is not None and data_phase else "at its sample point"
            sent, read = ("recessive", "dominant") if bits[k] == "1" else ("dominant", "recessive")
            return Transmission(False, "bit", fld, idx, k, tdcv, ssp, received, f"sent {sent}, read back {read} {how}")
    if received is None or not received.ok or received.frame != frame:
        err = received.error if received is not None else None
        return Transmission(
            False,
            err.kind if err else "lost",
            err.field if err else None,
            err.index if err else None,
            err.position if err else None,
            tdcv,
            ssp,
            received,
            f"the receiver: {err}" if err else "the receiver did not decode the frame",
        )
    return Transmission(True, "ok", None, None, None, tdcv, ssp, received)


def max_loop_delay(
    timing: can.BitTimingFd,
    tdco: int | None = None,
    *,
    tdcv_max: int | None = None,
    frames: Sequence[Frame] = TDC_FRAMES,
    limit_ns: float | None = None,
    resolution_ns: float = 1.0,
) -> tuple[float, Transmission | None]:
    """The longest loop delay (ns, to ``resolution_ns``) at which `transmit_fd` sends every frame
    of ``frames``, and the first failure just beyond it (None when none failed up to
    ``limit_ns``, by default ten data bits). The delays that work are an interval from 0: a
    longer delay moves the bit read back further from the one sent (without TDC), or the
    measured TDCV further up its range (with TDC); bisection finds its end."""

    def failure(delay: float) -> Transmission | None:
        for f in frames:
            r = transmit_fd(f, timing, delay, tdco, tdcv_max=tdcv_max)
            if not r.ok:
                return r
        return None

    hi = limit_ns if limit_ns is not None else 10 * 1e9 / timing.data_bitrate
    bad = failure(hi)
    if bad is None:
        return hi, None
    at_zero = failure(0.0)
    if at_zero is not None:
        return math.nan, at_zero
    lo, _, bad = last_working(failure, 0.0, hi, bad, resolution_ns)
    return lo, bad
