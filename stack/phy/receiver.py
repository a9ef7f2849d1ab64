"""A CAN receiver's bit timing logic in time quanta: hard synchronisation, resynchronisation and
sampling, for classical CAN and for CAN FD's two bit timings.

Rules (ISO 11898-1 / Bosch CAN 2.0, see DESIGN.md "Bit timing and synchronisation"):
- Hard synchronisation: on the recessive->dominant edge that starts a frame (bus idle) the bit
  time restarts with the quantum holding that edge as Sync_Seg.
- Resynchronisation on recessive->dominant edges inside the frame, phase error e in tq:
  e = 0 in Sync_Seg; e > 0 before the sample point lengthens Phase_Seg1 by min(e, SJW);
  e < 0 after it shortens Phase_Seg2 by min(|e|, SJW) (|e| <= SJW starts the next bit at once).
- One synchronisation between two sample points, and only on an edge whose previous sample
  point was recessive (the value after the edge must differ from the last sampled value).
- The bit is sampled at the end of Phase_Seg1, once or three times (majority of the last three
  quanta of TSEG1), then destuffed and checked by `BitDecoder`.
- CAN FD (ISO 11898-1:2015): at the sample point of a recessive BRS the data bit timing takes
  over (the rest of BRS is the data phase's Phase_Seg2; SJW the data phase's), and at the sample
  point of the CRC delimiter the nominal one again. The data phase samples once.
"""

from __future__ import annotations

import can

from stack.wire.coding import Field
from stack.wire.decoder import BitDecoder, DecodedFrame

__all__ = ["SyncReceiver"]

_BRS, _CRC_DELIM = Field.BRS, Field.CRC_DELIM


def _check(tseg1: int, tseg2: int, sjw: int, phase: str) -> None:
    if tseg1 < 1 or tseg2 < 1:
        raise ValueError(f"{phase}tseg1={tseg1}, tseg2={tseg2}: both segments need at least 1 tq")
    if not 1 <= sjw <= tseg2:
        raise ValueError(f"{phase}sjw={sjw}: needs 1 <= SJW <= Phase_Seg2 ({tseg2})")


class SyncReceiver:
    """A CAN receiver's bit timing logic, advanced one time quantum at a time with `tick`.

    ``tseg1``/``tseg2``/``sjw`` are in tq (Sync_Seg is 1 tq); ``nof_samples`` is 1 or 3. `tick`
    takes the bus level read in that quantum (0 dominant, 1 recessive) and returns the
    `DecodedFrame` when a frame ends (valid or at its first error), else None. Counters
    ``hard_syncs``, ``resyncs`` and ``max_phase_error`` (largest |e| seen, in tq) describe the
    synchronisation work done.

    With ``data`` (the data phase's tseg1, tseg2, sjw in the same quanta) it is an ISO CAN FD
    receiver (`BitDecoder` mode 'fd') switching between the two timings (module docstring);
    `from_timing_fd` builds one from python-can's `can.BitTimingFd`.
    """

    def __init__(
        self, tseg1: int, tseg2: int, sjw: int, nof_samples: int = 1, data: tuple[int, int, int] | None = None
    ) -> None:
        _check(tseg1, tseg2, sjw, "")
        if nof_samples not in (1, 3):
            raise ValueError(f"nof_samples={nof_samples}: a bit is sampled once or three times")
        if nof_samples == 3 and tseg1 < 3:
            raise ValueError(f"tseg1={tseg1}: three samples need TSEG1 >= 3 tq")
        if data is not None:
            _check(*data, "data phase ")
        self.tseg1, self.tseg2, self.sjw, self.nof_samples = tseg1, tseg2, sjw, nof_samples
        self.data = data
        self.decoder = BitDecoder("classic" if data is None else "fd")
        self.hard_syncs = 0
        self.resyncs = 0
        self.max_phase_error = 0
        self._prev = 1
        self._idle = True
        self._reads: list[int] = [1, 1, 1]
        self.sampled: list[int] = []  # bits sampled in the current/last frame, SOF first
        self._synced = True
        self._last_sample = 1
        self._nominal()
        self._new_bit()

    @classmethod
    def from_timing(cls, timing: can.BitTiming) -> SyncReceiver:
        """A receiver for a `can.BitTiming` (its tseg1, tseg2, sjw and nof_samples)."""
        return cls(timing.tseg1, timing.tseg2, timing.sjw, timing.nof_samples)

    @classmethod
    def from_timing_fd(cls, timing: can.BitTimingFd) -> SyncReceiver:
        """A CAN FD receiver for a `can.BitTimingFd`, ticking once a CAN clock period (minimum
        time quantum) so that both phases share the tick whatever their prescalers: a segment of
        n tq is n x brp ticks, Sync_Seg one tick followed by brp - 1 more of TSEG1, so the sample
        point and the bit end where the controller's are (a phase error is resolved to a clock
        period rather than to the controller's tq)."""

        def phase(brp: int, tseg1: int, tseg2: int, sjw: int) -> tuple[int, int, int]:
            return brp * (1 + tseg1) - 1, brp * tseg2, brp * sjw

        t = timing
        n = phase(t.nom_brp, t.nom_tseg1, t.nom_tseg2, t.nom_sjw)
        return cls(*n, data=phase(t.data_brp, t.data_tseg1, t.data_tseg2, t.data_sjw))

    @property
    def idle(self) -> bool:
        """True while waiting for the edge that starts a frame."""
        return self._idle

    @property
    def position(self) -> int:
        """Quantum index within the current bit of the next tick (0 = Sync_Seg)."""
        return self._pos

    @property
    def sample_point(self) -> int:
        """Quantum index of the current bit's sample point: 1 + TSEG1, plus any lengthening."""
        return self._sample_at

    @property
    def bit_length(self) -> int:
        """Quanta in the current bit: NBT, lengthened or shortened by resynchronisation."""
        return self._bit_end

    @property
    def in_data_phase(self) -> bool:
        """True between the sample points of BRS and of the CRC delimiter of an FD frame with BRS."""
        return self._fast

    def _nominal(self) -> None:
        self._seg1, self._seg2, self._jump, self._fast = self.tseg1, self.tseg2, self.sjw, False

    def _new_bit(self) -> None:
        self._pos = 0
        self._sample_at = 1 + self._seg1  # quantum index of the sample point
        self._bit_end = 1 + self._seg1 + self._seg2

    def tick(self, level: int) -> DecodedFrame | None:
        """Advance one time quantum with the bus read as ``level``; see the class docstring."""
        edge = self._prev == 1 and level == 0
        self._prev = level
        reads = self._reads
        reads[0], reads[1], reads[2] = reads[1], reads[2], level
        if self._idle:
            if not edge:
                return None
            # hard synchronisation: this quantum is Sync_Seg of SOF
            self._idle = False
            self.hard_syncs += 1
            self.sampled = []
            self._nominal()
            self._new_bit()
            self._synced = True
            self._last_sample = 1
        elif edge and not self._synced and self._last_sample == 1:
            self._resync()
        result = None
        if self._pos == self._sample_at:
            triple = self.nof_samples == 3 and not self._fast
            bit = int(reads[0] + reads[1] + reads[2] >= 2) if triple else level
            self._synced = False
            self._last_sample = bit
            if self.decoder.position == 0 and bit == 1:
                # a recessive SOF sample: it was a glitch, not a frame (back to bus idle)
                self._idle = True
                return None
            self.sampled.append(bit)
            was = self.decoder.field
            result = self.decoder.feed(bit)
            if result is not None:
                self._idle = True
                return result
            if self.data is not None and was is not self.decoder.field:
                self._switch(was)
        self._pos += 1
        if self._pos >= self._bit_end:
            self._new_bit()
        return result

    def _switch(self, field: Field) -> None:
        """At the sample point of the last bit of ``field`` (a stuff bit leaves the field as it
        was): BRS recessive -> data timing, CRC delimiter -> nominal; the rest of the bit is
        the new timing's Phase_Seg2."""
        if field is _BRS and self.decoder.brs:
            assert self.data is not None
            self._seg1, self._seg2, self._jump = self.data
            self._fast = True
        elif field is _CRC_DELIM and self._fast:
            self._nominal()
        else:
            return
        self._bit_end = self._sample_at + self._seg2

    def _resync(self) -> None:
        """Resynchronisation on an edge at quantum ``_pos`` of the current bit."""
        pos = self._pos
        self._synced = True
        if pos == 0:
            return  # e = 0: the edge is in Sync_Seg
        self.resyncs += 1
        if pos <= self._sample_at:
            # e > 0: the edge is late, lengthen Phase_Seg1
            e = pos
            self._sample_at += min(e, self._jump)
            self._bit_end = self._sample_at + self._seg2
        else:
            # e < 0: the edge is early (it belongs to the next bit), shorten Phase_Seg2
            e = pos - self._bit_end
            if -e <= self._jump:
                self._new_bit()  # the edge quantum becomes Sync_Seg, as a hard sync would
            else:
                self._bit_end -= self._jump
        self.max_phase_error = max(self.max_phase_error, abs(e))
