"""Decode a CAN_RX signal into frames: a bit-level receiver in the sample domain (ISO 11898-1 bit
timing, see `BitReceiver`).

- hard synchronisation on the recessive->dominant edge that starts a frame after bus idle
  (11 recessive bits, or the 3-bit intermission after a valid EOF);
- resynchronisation on recessive->dominant edges inside the frame: phase error e > 0 (edge before
  the sample point) lengthens Phase_Seg1 by min(e, SJW), e < 0 (edge after the sample point)
  shortens Phase_Seg2 by min(|e|, SJW); at most one synchronisation between two sample points, and
  only when the bit sampled before the edge was recessive;
- one sample per bit at the sample point (default 87.5 %), destuffing and the frame checks of
  `stack.wire.decoder.BitDecoder` (stuff, form, CRC), error flags (6+ dominant bits where the
  frame should continue) reported as error records, a frame cut by the end of the capture as a
  'truncated' error record.
- CAN FD (with a data bit rate): an ISO CAN FD receiver (`BitDecoder` mode 'fd'); at the sample
  point of a recessive BRS the bit timing switches to the data bit rate (the rest of BRS is the
  data phase's Phase_Seg2) and back at the sample point of the CRC delimiter (ISO 11898-1:2015),
  resynchronising with the data phase's SJW in between.

Speed: a Python loop over every sample is far too slow for a 12 M sample capture, so the channel
is first reduced to a bytes object of 0/1 (one `bytes.translate`, see `stack.phy.waveform.capture`),
edges are found with `bytes.find` (memchr) and the Python loop runs once per *bit*, only inside
frames. Bus idle is skipped in C. `python -m stack.bench` measures it against sigrok-cli.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from stack.phy.waveform.capture import read_capture
from stack.phy.waveform.levels import DOMINANT, IDLE_BITS, MAX_SAMPLES_PER_BIT, RECESSIVE
from stack.wire.coding import Field
from stack.wire.decoder import BitDecoder, BitError, DecodedFrame
from stack.wire.frame import Frame

__all__ = ["RxRecord", "BitReceiver", "decode_samples", "decode_file"]

_BRS, _CRC_DELIM = Field.BRS, Field.CRC_DELIM


@dataclass(frozen=True)
class RxRecord:
    """One frame (or error record) seen on the waveform.

    ``t`` is the time of its SOF edge in seconds from the start of the capture, ``sample`` that
    edge's sample index. The header fields are None where the frame did not get that far.
    ``error`` is None for a valid frame; otherwise its kind is 'stuff', 'form', 'crc' (from
    `BitDecoder`) or 'truncated' (the capture ended inside the frame). ``error_flag`` is True when
    the error shows as an error flag on the bus: 6 or more dominant bits where the frame should
    have continued. ``fd``, ``brs`` and ``esi`` are a CAN FD frame's flags as received (decoding
    with a data bit rate).
    """

    t: float
    sample: int
    can_id: int | None
    extended: bool
    remote: bool
    dlc: int | None
    data: bytes
    crc: int | None
    crc_ok: bool
    ack: bool
    error: BitError | None
    error_flag: bool = False
    overload: bool = False
    via: str = "receiver"
    fd: bool = False
    brs: bool = False
    esi: bool = False

    @property
    def ok(self) -> bool:
        """True for a frame a receiver accepts (no stuff, form or CRC error, not truncated)."""
        return self.error is None

    @property
    def stuff_ok(self) -> bool:
        """No stuff error (six equal bits in SOF..CRC)."""
        return self.error is None or self.error.kind != "stuff"

    @property
    def form_ok(self) -> bool:
        """No form error (dominant CRC delimiter, ACK delimiter or EOF bit)."""
        return self.error is None or self.error.kind != "form"

    def to_frame(self) -> Frame | None:
        """The received `Frame`, or None for an error record."""
        if self.error is not None or self.can_id is None or self.dlc is None:
            return None
        return Frame(
            self.can_id,
            self.data,
            extended=self.extended,
            remote=self.remote,
            dlc=self.dlc,
            fd=self.fd,
            brs=self.brs,
            esi=self.esi,
        )


class BitReceiver:
    """Bit timing of a receiver in the sample domain (ISO 11898-1, 'Bit timing' and
    'Synchronisation').

    The nominal bit time is ``samplerate / bitrate`` samples, divided into ``tq_per_bit`` time
    quanta; the sample point is at ``sample_point`` % of the bit (end of Phase_Seg1), so
    Phase_Seg2 is the rest. ``sjw`` (time quanta, 1..4, at most Phase_Seg2; default
    min(4, Phase_Seg2)) bounds each resynchronisation. A sample at index i is the bus level during
    [i, i+1); an edge at index i (sample i differs from sample i-1) happens at time i.

    With ``data_bitrate`` the receiver is a CAN FD one: ``data`` is the data phase's receiver
    (``data_sample_point``, default 75 %, and ``data_sjw``, in tq of ``tq_per_bit``).
    """

    def __init__(
        self,
        bitrate: float,
        samplerate: float,
        *,
        sample_point: float = 87.5,
        sjw: float | None = None,
        tq_per_bit: int = 16,
        data_bitrate: float | None = None,
        data_sample_point: float = 75.0,
        data_sjw: float | None = None,
    ) -> None:
        if not bitrate or bitrate <= 0:
            raise ValueError(f"bitrate {bitrate!r}: must be a positive number of bit/s")
        if not samplerate or samplerate <= 0:
            raise ValueError(f"samplerate {samplerate!r}: must be a positive number of samples/s")
        spb = samplerate / bitrate
        if spb < 2:
            raise ValueError(
                f"bitrate {bitrate:.10g} bit/s with samplerate {samplerate:.10g} Hz gives {spb:.9g} samples "
                "per bit: at least 2 are needed to decode"
            )
        if not spb <= MAX_SAMPLES_PER_BIT:
            raise ValueError(
                f"bitrate {bitrate:.10g} bit/s with samplerate {samplerate:.10g} Hz gives {spb:.3g} samples "
                f"per bit: at most {MAX_SAMPLES_PER_BIT:.0e} can be decoded (check the two rates)"
            )
        if not 50 <= sample_point < 100:
            raise ValueError(f"sample point {sample_point:g} %: must be 50 <= sample point < 100")
        if not 8 <= tq_per_bit <= 25:
            raise ValueError(f"{tq_per_bit} time quanta per bit: a CAN bit time has 8..25")
        phase_seg2 = tq_per_bit * (100 - sample_point) / 100
        if sjw is None:
            # a late sample point leaves less than 1 tq of Phase_Seg2: the jump width is all of it
            sjw = min(4.0, phase_seg2)
        elif not 1 <= sjw <= 4 or sjw > phase_seg2 + 1e-9:
            raise ValueError(
                f"SJW {sjw} tq: must be 1..4 tq and at most Phase_Seg2 ({phase_seg2:g} tq at a "
                f"{sample_point:g} % sample point with {tq_per_bit} tq per bit)"
            )
        self.bitrate = float(bitrate)
        self.samplerate = float(samplerate)
        self.sample_point = float(sample_point)
        self.tq_per_bit = tq_per_bit
        self.sjw = float(sjw)
        self.bit_time = spb  # samples
        self.sp_offset = spb * sample_point / 100  # samples from bit start to the sample point
        self.sjw_samples = spb * sjw / tq_per_bit
        self.data: BitReceiver | None = None
        if data_bitrate is not None:
            if not data_bitrate > 0 or data_bitrate < bitrate:
                raise ValueError(
                    f"data bit rate {data_bitrate:.10g} bit/s: must be at least the nominal {bitrate:.10g} bit/s"
                )
            self.data = BitReceiver(
                data_bitrate, samplerate, sample_point=data_sample_point, sjw=data_sjw, tq_per_bit=tq_per_bit
            )

    def phase_correction(self, bit_start: float, edge: float) -> tuple[float, float]:
        """Resynchronisation for an edge at ``edge`` in the bit starting at ``bit_start``.

        Returns (lengthen Phase_Seg1, shorten Phase_Seg2) in samples: phase error e = edge -
        bit_start; e > 0 before the sample point lengthens Phase_Seg1 by min(e, SJW); an edge
        after the sample point belongs to the next bit, e = edge - (bit_start + bit time) < 0,
        and shortens Phase_Seg2 by min(|e|, SJW).
        """
        e = edge - bit_start
        if e < 0:
            raise ValueError("edge before the bit start")
        if e < self.sp_offset:
            return min(e, self.sjw_samples), 0.0
        e = edge - (bit_start + self.bit_time)
        return 0.0, min(-e, self.sjw_samples) if e < 0 else 0.0


def _next_fall(line: bytes, after: int) -> int:
    """Index of the first recessive->dominant edge at an index > ``after`` (-1 if none)."""
    if line[after]:
        return line.find(DOMINANT, after + 1)
    r = line.find(RECESSIVE, after + 1)
    return -1 if r < 0 else line.find(DOMINANT, r + 1)


def _receive(line: bytes, sof: int, rx: BitReceiver, dec: BitDecoder) -> tuple[DecodedFrame | None, float, int]:
    """Receive one frame whose SOF edge is at sample ``sof`` (hard synchronisation).

    Returns (the decoder's result or None if the capture ended, end of the last bit in samples,
    index of the last sample point). Runs once per bit; edges come from `_next_fall`.
    """
    n = len(line)
    T = rx.bit_time
    spo = rx.sp_offset
    sjw = rx.sjw_samples
    feed = dec.feed
    data = rx.data
    fast = False  # in the data phase of a frame with BRS
    dec.reset()
    b = float(sof)  # hard synchronisation: the bit time restarts with the edge
    fe = _next_fall(line, sof)  # SOF's own edge may not resynchronise it
    prev = 0  # SOF is dominant
    si = sof
    first = True
    while True:
        s = b + spo
        end = b + T
        if not first and prev and fe >= 0:
            # one resynchronisation between two sample points, on a rec->dom edge, only when the
            # previous sample was recessive (a dominant sample before the edge means a glitch)
            if fe < b:
                e = b - fe
                d = e if e < sjw else sjw
                b -= d
                s -= d
                end -= d
            elif fe < s:
                e = fe - b
                d = e if e < sjw else sjw
                s += d
                end += d
        first = False
        si = int(s)
        if si >= n:
            return None, b, si
        v = line[si]
        if data is None:
            res = feed(v)
        else:
            was = dec.field
            res = feed(v)
            # a field's last bit (a stuff bit leaves the field as it was): BRS recessive switches
            # to the data bit timing at its sample point, the CRC delimiter back to the nominal
            if res is None and was is not dec.field:
                if was is _BRS and dec.brs:
                    T, spo, sjw, fast = data.bit_time, data.sp_offset, data.sjw_samples, True
                    end = s + T - spo
                elif was is _CRC_DELIM and fast:
                    T, spo, sjw, fast = rx.bit_time, rx.sp_offset, rx.sjw_samples, False
                    end = s + T - spo
        if res is not None:
            return res, end, si
        prev = v
        if fe >= 0 and fe <= si:
            fe = _next_fall(line, si)
        b = end


def _dominant_bits_at(line: bytes, sample: int, rx: BitReceiver) -> float:
    """Length in bits of the dominant run that contains (or starts right after) ``sample``."""
    n = len(line)
    if sample >= n:
        return 0.0
    start = sample
    if line[start]:
        start = line.find(DOMINANT, start)
        if start < 0 or start - sample > rx.bit_time:
            return 0.0
    else:
        r = line.rfind(RECESSIVE, 0, start)
        start = r + 1
    end = line.find(RECESSIVE, start)
    if end < 0:
        end = n
    return (end - start) / rx.bit_time


def _find_sof_after_idle(line: bytes, pos: int, need: float) -> int:
    """The first rec->dom edge at index >= pos preceded by at least ``need`` recessive samples
    (the whole recessive run counts, also the part before ``pos``); -1 if none. Skips idle and
    unusable traffic with bytes.find only."""
    n = len(line)
    if pos >= n:
        return -1
    if not line[pos] and pos and line[pos - 1] and need <= 0:
        return pos
    r = line.rfind(DOMINANT, 0, pos) + 1 if line[pos] else line.find(RECESSIVE, pos)
    while r >= 0:
        f = line.find(DOMINANT, r)
        if f < 0:
            return -1
        if f - r >= need:
            return f
        r = line.find(RECESSIVE, f)
    return -1


def _run_length_retry(
    line: bytes, sof: int, bit_time: float, max_changes: int = 3, max_attempts: int = 256
) -> tuple[DecodedFrame, float] | None:
    """Receive the frame at ``sof`` again, taking *every* edge as a bit boundary.

    Each run of equal samples is L / bit_time bits, rounded. A run whose length is within a
    quarter bit of a half-integer is ambiguous; it is first read as transceivers distort CAN_RX
    (dominant runs come out longer, recessive runs shorter: dominant rounds down, recessive up),
    then with the other rounding, trying the fewest changes first (up to ``max_changes`` runs,
    ``max_attempts`` attempts). Only a frame with a valid CRC, valid stuffing and a well-formed
    CRC delimiter, ACK delimiter and EOF is returned, with the sample where its last bit ends.
    """
    n = len(line)
    limit = min(n, sof + int(200 * bit_time))
    runs: list[tuple[int, int, int]] = []  # (level, start, length)
    pos = sof
    while pos < limit:
        lvl = line[pos]
        nxt = line.find(DOMINANT if lvl else RECESSIVE, pos)
        if nxt < 0:
            nxt = n
        runs.append((lvl, pos, nxt - pos))
        pos = nxt
    options: list[tuple[int, ...]] = []
    ambiguous: list[int] = []
    for i, (lvl, _, length) in enumerate(runs):
        x = length / bit_time
        lo = int(x)
        frac = x - lo
        if frac < 0.25:
            opt: tuple[int, ...] = (max(1, lo),)
        elif frac > 0.75:
            opt = (lo + 1,)
        else:
            pair = (lo + 1, lo) if lvl else (lo, lo + 1)
            opt = tuple(c for c in pair if c >= 1)
        if len(opt) > 1:
            ambiguous.append(i)
        options.append(opt)
    dec = BitDecoder()
    attempts = 0
    for changes in range(max_changes + 1):
        for combo in itertools.combinations(ambiguous, changes):
            attempts += 1
            if attempts > max_attempts:
                return None
            flip = set(combo)
            dec.reset()
            res = None
            for i, (lvl, rstart, _) in enumerate(runs):
                opt = options[i]
                count = opt[1] if i in flip else opt[0]
                for k in range(count):  # noqa: B007 - read after the loop
                    res = dec.feed(lvl)
                    if res is not None:
                        break
                if res is not None:
                    if res.ok:
                        return res, rstart + (k + 1) * bit_time
                    break
    return None


def decode_samples(
    samples: bytes,
    samplerate: float,
    bitrate: float,
    *,
    sample_point: float = 87.5,
    sjw: float | None = None,
    tq_per_bit: int = 16,
    retry: bool = True,
    native_rate: float | None = None,
    data_bitrate: float | None = None,
    data_sample_point: float = 75.0,
    data_sjw: float | None = None,
) -> list[RxRecord]:
    """Decode a CAN_RX signal (one byte per sample, 0 dominant / 1 recessive) into records.
    (``native_rate``: the rate the signal was recorded at when ``samples`` were subdivided from
    it; below 8 samples a bit the run-length rescue applies, as for a coarse capture.)

    The receiver (see `BitReceiver`) waits for bus idle (11 recessive bits), hard-synchronises on
    the SOF edge, samples one bit per bit time with resynchronisation, and feeds `BitDecoder`.
    After a valid frame, the next SOF may come from the third intermission bit on; a dominant bit
    in the first two is an overload condition; after an error or an overload it waits for 11
    recessive bits again (delimiter + intermission).

    With ``retry`` (the default), a frame that fails its checks is received again: with other
    sample points (50..81.25 %), and below 8 samples a bit with `_run_length_retry`, because
    there a capture's quantisation (1 sample = up to half a bit) and the transceiver's asymmetric
    delays defeat any fixed sample point. Only a frame with a valid CRC, stuffing and form replaces
    the error record (``RxRecord.via`` says how it was received); CRC-15 lets a wrong frame through
    with probability 2^-15 per attempt.

    With ``data_bitrate`` it is a CAN FD receiver (`BitReceiver`'s data phase; ``data_sample_point``
    and ``data_sjw`` time it): classical frames decode as before, FD frames with their CRC-17/21
    and stuff count; the retries move the nominal sample point only (no run-length rescue: an FD
    frame's bits are not all one length).
    """
    fd_kw: dict[str, Any] = dict(data_bitrate=data_bitrate, data_sample_point=data_sample_point, data_sjw=data_sjw)
    rx = BitReceiver(bitrate, samplerate, sample_point=sample_point, sjw=sjw, tq_per_bit=tq_per_bit, **fd_kw)
    alternates: list[BitReceiver] = []
    T = rx.bit_time
    if retry:
        for spv in (75.0, 62.5, 50.0, 81.25, 68.75, 56.25):
            spo = math.floor(T * spv / 100)
            # at low oversampling several sample points read the same sample: try each once
            if (
                spv != sample_point
                and spo != math.floor(rx.sp_offset)
                and all(math.floor(a.sp_offset) != spo for a in alternates)
            ):
                ps2 = tq_per_bit * (100 - spv) / 100
                alternates.append(
                    BitReceiver(
                        bitrate, samplerate, sample_point=spv, sjw=min(4.0, ps2), tq_per_bit=tq_per_bit, **fd_kw
                    )
                )
    line = bytes(samples)
    n = len(line)
    if n == 0:
        return []
    # bus idle: 11 recessive bits, but a node may start in the third intermission bit after an
    # error or overload delimiter (8 + 2 bits); half a bit of tolerance for the edge positions
    idle_need = (IDLE_BITS - 1.5) * T
    dec = BitDecoder("classic" if data_bitrate is None else "fd")
    out: list[RxRecord] = []
    pos = 0
    need = idle_need
    # a capture triggered just before a frame has less than 11 bits of idle ahead of its SOF:
    # the bus before the capture is unknown, so that first frame is taken when it decodes
    # cleanly (a capture that starts inside a frame gives no such frame, and no false error)
    if line[0]:
        f = line.find(DOMINANT)
        if T <= f < idle_need:
            res, end, _ = _receive(line, f, rx, dec)
            if res is not None and res.ok:
                need = 0
                pos = f
    while True:
        sof = _find_sof_after_idle(line, pos, need)
        if sof < 0:
            break
        res, end, last_si = _receive(line, sof, rx, dec)
        via = "receiver"
        t = sof / samplerate
        if res is None:
            # the capture ended inside the frame
            err = BitError("truncated", dec.field, dec.field_index, dec.position)
            out.append(_record(t, sof, None, err, dec))
            break
        if not res.ok and retry:
            for alt in alternates:
                r2, e2, s2 = _receive(line, sof, alt, dec)
                if r2 is not None and r2.ok:
                    res, end, last_si, via = r2, e2, s2, f"sample point {alt.sample_point:g} %"
                    break
            else:
                if rx.data is None and (T < 8 or (native_rate is not None and native_rate / bitrate < 8)):
                    found = _run_length_retry(line, sof, T)
                    if found is not None:
                        res, end = found
                        last_si, via = int(end), "run lengths"
        if res.error is None:
            out.append(_record(t, sof, res, None, None, via=via))
            if res.overload:
                pos, need = int(end), idle_need
            else:
                # intermission: a dominant bit in its first two bits is an overload condition,
                # from the third on it is the next SOF
                pos = min(n, int(end + 1.5 * T))
                if line.find(DOMINANT, min(n, int(end) + 1), pos) >= 0:
                    pos, need = int(end), idle_need
                else:
                    need = 0
            continue
        flag = _dominant_bits_at(line, last_si, rx) >= 5.5
        out.append(_record(t, sof, res, res.error, None, flag))
        pos, need = min(last_si, n - 1), idle_need
    return out


def _record(
    t: float,
    sof: int,
    res: DecodedFrame | None,
    error: BitError | None,
    dec: BitDecoder | None,
    flag: bool = False,
    via: str = "receiver",
) -> RxRecord:
    if res is None:
        # truncated: what the decoder had collected when the samples ran out
        assert dec is not None
        return RxRecord(
            t,
            sof,
            dec.can_id,
            dec.extended,
            dec.remote,
            dec.dlc,
            dec.received_data,
            dec.received_crc,
            False,
            False,
            error,
            False,
            fd=dec.fd,
            brs=dec.brs,
            esi=dec.esi,
        )
    return RxRecord(
        t=t,
        sample=sof,
        can_id=res.can_id,
        extended=res.extended,
        remote=res.remote,
        dlc=res.dlc,
        data=res.data,
        crc=res.crc,
        crc_ok=res.crc_ok,
        ack=res.ack,
        error=error,
        error_flag=flag,
        overload=res.overload,
        via=via,
        fd=res.fd,
        brs=res.brs,
        esi=res.esi,
    )


def decode_file(
    path: str | Path,
    bitrate: float,
    *,
    channel: str | int | None = None,
    samplerate: float | None = None,
    sample_point: float = 87.5,
    sjw: float | None = None,
    retry: bool = True,
    data_bitrate: float | None = None,
    data_sample_point: float = 75.0,
) -> list[RxRecord]:
    """Read a capture (`read_capture`, a VCD resampled finely enough for the faster bit rate) and
    decode it (`decode_samples`; CAN FD with ``data_bitrate``)."""
    cap = read_capture(path, channel, samplerate, max(bitrate, data_bitrate or 0))
    return decode_samples(
        cap.samples,
        cap.samplerate,
        bitrate,
        sample_point=sample_point,
        sjw=sjw,
        retry=retry,
        native_rate=cap.native_rate,
        data_bitrate=data_bitrate,
        data_sample_point=data_sample_point,
    )
