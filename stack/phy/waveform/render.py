"""Render frames as a CAN_RX waveform, and write waveforms as VCD or raw samples.

Each frame's exact bit stream (`Frame.bits`, SOF..EOF with the ACK slot dominant) is laid out at
the bit rate, frames separated by the 3-bit intermission (back to back) or placed at given start
times, with bus idle before the first frame and after the last. Optional clock drift (the
transmitter's oscillator error) and edge jitter exercise a receiver's resynchronisation.

A CAN FD frame with BRS goes at two bit rates: its transmitter switches to the data bit rate at
the sample point of BRS and back at the sample point of the CRC delimiter (ISO 11898-1:2015), so
those two bits last part of a nominal and part of a data bit (`FrameBits.bit_edges_ns`, with the
transmitter's ``sample_point`` and ``data_sample_point``).

A waveform is a list of runs ``(level, samples)`` (`render_edges`) or one byte per sample
(`render_samples`, `runs_to_raw`), 0 dominant and 1 recessive.
"""

from __future__ import annotations

import math
import random
from collections.abc import Sequence
from fractions import Fraction
from pathlib import Path

from stack.phy.waveform.levels import DOMINANT, IDLE_BITS, MAX_SAMPLES_PER_BIT, RECESSIVE
from stack.wire.coding import INTERMISSION_BITS
from stack.wire.frame import Frame

__all__ = ["render_edges", "render_samples", "runs_to_raw", "write_raw", "write_vcd"]


def render_edges(
    frames: Sequence[Frame],
    bitrate: float,
    samplerate: float,
    *,
    times: Sequence[float | None] | None = None,
    idle_bits: int = IDLE_BITS,
    drift: float = 0.0,
    jitter: float = 0.0,
    seed: int = 0,
    data_bitrate: float | None = None,
    sample_point: float = 87.5,
    data_sample_point: float = 75.0,
) -> tuple[list[tuple[int, int]], int, list[int]]:
    """The waveform as runs: ([(level, n_samples), ...], total samples, SOF sample of each frame).

    Bus idle of ``idle_bits`` recessive bits comes first and last. A frame without a time follows
    the previous one after the 3-bit intermission (its SOF is the bit after it); a time (seconds
    from the start of the waveform) places its SOF edge at that sample, and must leave the
    intermission after the previous frame, or ``idle_bits`` of bus idle before the first.
    ``drift`` scales the transmitter's bit time (0.01 = bits 1 % longer); ``jitter`` moves every
    edge by a uniform random amount of up to +-jitter bit times (seeded: the same seed gives the
    same waveform). Sample i holds the level during [i, i+1), so an edge at time x first shows in
    sample ceil(x). Frames with BRS need ``data_bitrate``; ``sample_point`` and
    ``data_sample_point`` (percent) place the transmitter's switches between the rates, and
    jitter there is a fraction of the data bit.
    """
    if not bitrate or bitrate <= 0 or not samplerate or samplerate <= 0:
        raise ValueError(f"bitrate {bitrate!r} and samplerate {samplerate!r} must be positive")
    if samplerate / bitrate < 2:
        raise ValueError(
            f"samplerate {samplerate:.10g} Hz gives {samplerate / bitrate:.9g} samples per bit at "
            f"{bitrate:.10g} bit/s: at least 2 are needed"
        )
    if not samplerate / bitrate <= MAX_SAMPLES_PER_BIT:
        raise ValueError(
            f"samplerate {samplerate:.10g} Hz gives {samplerate / bitrate:.3g} samples per bit at "
            f"{bitrate:.10g} bit/s: at most {MAX_SAMPLES_PER_BIT:.0e} can be rendered (check the two rates)"
        )
    if not -0.2 < drift < 0.2:
        raise ValueError(f"drift {drift}: must be within +-0.2 (a fraction of the bit time)")
    if not 0 <= jitter < 0.5:
        raise ValueError(f"jitter {jitter}: must be 0 <= jitter < 0.5 bit times")
    if times is not None and len(times) != len(frames):
        raise ValueError(f"{len(times)} times for {len(frames)} frames: give one per frame (or None)")
    if data_bitrate is not None:
        _check_data_rate(data_bitrate, bitrate, samplerate, sample_point, data_sample_point)
    elif any(f.brs for f in frames):
        i = next(i for i, f in enumerate(frames) if f.brs)
        raise ValueError(f"frame {i} ({frames[i]!r}) switches bit rate (BRS): it needs a data bit rate")
    tbit = samplerate / bitrate
    tb = tbit * (1 + drift)
    rng = random.Random(seed)
    runs: list[tuple[int, int]] = []
    sofs: list[int] = []
    pos = 0  # the runs so far cover samples [0, pos)

    def emit(level: int, until: int) -> None:
        nonlocal pos
        n = until - pos
        if n <= 0:
            return
        if runs and runs[-1][0] == level:
            runs[-1] = (level, runs[-1][1] + n)
        else:
            runs.append((level, n))
        pos = until

    earliest = idle_bits * tbit  # earliest SOF time, in samples
    for i, frame in enumerate(frames):
        t = None if times is None else times[i]
        first = math.ceil(earliest - 1e-9)
        if t is None:
            start = max(first, pos)
        else:
            start = round(t * samplerate)
            if start < first:
                what = "the end of the previous frame's intermission" if i else f"{idle_bits} bit times of bus idle"
                raise ValueError(f"frame {i} at t={t:g} s starts before {what} (earliest t={first / samplerate:.9g} s)")
        emit(1, start)
        sofs.append(start)
        bits = frame.bits.bits
        nb = len(bits)
        # where each bit starts, in samples from SOF at the nominal clock: one bit time apart,
        # or for BRS the two rates (a classical frame keeps j * tb: the same floats as always)
        offsets = _bit_offsets(frame, bitrate, data_bitrate, samplerate, sample_point, data_sample_point)
        k = 0
        while k < nb:
            lvl = bits[k]
            j = k
            while j < nb and bits[j] == lvl:
                j += 1
            if offsets is None:
                edge = start + j * tb
                bit_len = tbit
            else:
                edge = start + offsets[j] * (1 + drift)
                bit_len = offsets[j] - offsets[j - 1]
            if jitter and j < nb:
                edge += rng.uniform(-jitter, jitter) * bit_len
            emit(1 if lvl == "1" else 0, max(pos + 1, math.ceil(edge - 1e-9)))
            k = j
        eof_end = start + (nb * tb if offsets is None else offsets[nb] * (1 + drift))
        earliest = eof_end + INTERMISSION_BITS * tb
    emit(1, max(pos + 1, math.ceil(earliest - INTERMISSION_BITS * tb + idle_bits * tbit)))
    return runs, pos, sofs


def _check_data_rate(
    data_bitrate: float, bitrate: float, samplerate: float, sample_point: float, data_sample_point: float
) -> None:
    if not data_bitrate >= bitrate:
        raise ValueError(f"data bit rate {data_bitrate!r}: must be at least the nominal {bitrate:.10g} bit/s")
    if samplerate / data_bitrate < 2:
        raise ValueError(
            f"samplerate {samplerate:.10g} Hz gives {samplerate / data_bitrate:.9g} samples per bit at the data "
            f"bit rate {data_bitrate:.10g} bit/s: at least 2 are needed"
        )
    for name, sp in (("sample point", sample_point), ("data sample point", data_sample_point)):
        if not 0 < sp < 100:
            raise ValueError(f"{name} {sp:g} %: must be 0 < sample point < 100")


def _bit_offsets(
    frame: Frame,
    bitrate: float,
    data_bitrate: float | None,
    samplerate: float,
    sample_point: float,
    data_sample_point: float,
) -> list[float] | None:
    """Start of each bit (and the end of EOF) in samples from SOF for a frame with BRS; None for
    one at a single bit rate."""
    if not frame.brs or data_bitrate is None:
        return None
    edges = frame.bits.bit_edges_ns(bitrate, data_bitrate, sample_point / 100, data_sample_point / 100)  # type: ignore[arg-type]
    scale = samplerate / 1e9
    return [e * scale for e in edges]


def render_samples(
    frames: Sequence[Frame],
    bitrate: float,
    samplerate: float,
    *,
    times: Sequence[float | None] | None = None,
    idle_bits: int = IDLE_BITS,
    drift: float = 0.0,
    jitter: float = 0.0,
    seed: int = 0,
    bit: int | None = None,
    data_bitrate: float | None = None,
    sample_point: float = 87.5,
    data_sample_point: float = 75.0,
) -> bytes:
    """The CAN_RX waveform of ``frames`` as one byte per sample (see `render_edges` for timing).

    Values are 0 (dominant) / 1 (recessive), or 0 / 1 << ``bit`` when a bit position is chosen
    (so the file looks like one channel of a multi-channel logic analyzer).
    """
    runs, _, _ = render_edges(
        frames,
        bitrate,
        samplerate,
        times=times,
        idle_bits=idle_bits,
        drift=drift,
        jitter=jitter,
        seed=seed,
        data_bitrate=data_bitrate,
        sample_point=sample_point,
        data_sample_point=data_sample_point,
    )
    return runs_to_raw(runs, bit)


def _check_bit(bit: int) -> int:
    if not 0 <= bit <= 7:
        raise ValueError(f"bit {bit}: a raw sample byte has bits 0..7")
    return bit


def runs_to_raw(runs: Sequence[tuple[int, int]], bit: int | None = None) -> bytes:
    """Raw sample bytes of a run list (level, samples): bytes 0/1, or with ``bit`` the level on
    that bit of each byte (a logic analyser's channel), dominant as 0."""
    one = RECESSIVE if bit is None else bytes([1 << _check_bit(bit)])
    return b"".join((one if lvl else DOMINANT) * n for lvl, n in runs)


def write_raw(path: str | Path, samples: bytes) -> None:
    """Write samples as a raw file, one byte per sample (sigrok's 'binary' input, PulseView's raw
    import)."""
    Path(path).write_bytes(samples)


def _vcd_timescale(samplerate: float) -> tuple[str, int]:
    """The coarsest standard VCD timescale in which one sample period is a whole number."""
    period = 1 / Fraction(samplerate).limit_denominator(10**9)
    names = {0: "s", -3: "ms", -6: "us", -9: "ns", -12: "ps", -15: "fs"}
    for exp in range(0, -16, -1):
        unit_exp = exp - (exp % 3) if exp % 3 else exp  # s/ms/us/... with magnitude 1, 10, 100
        magnitude = 10 ** (exp - unit_exp)
        scale = Fraction(10) ** exp
        ratio = period / scale
        if ratio.denominator == 1:
            return f"{magnitude} {names[unit_exp]}", int(ratio)
    raise ValueError(f"samplerate {samplerate:g} Hz has no whole sample period in femtoseconds")


def write_vcd(
    path: str | Path,
    samples_or_runs: bytes | list[tuple[int, int]],
    samplerate: float,
    *,
    name: str = "CAN_RX",
    comment: str = "",
) -> None:
    """Write a 1-bit signal ``name`` as VCD with pyvcd (opens in GTKWave and PulseView).

    The timescale is the coarsest standard one in which a sample period is whole, so every value
    change sits exactly on its sample.
    """
    from vcd import VCDWriter

    if isinstance(samples_or_runs, (bytes, bytearray)):
        runs = _runs(bytes(samples_or_runs))
    else:
        runs = samples_or_runs
    timescale, step = _vcd_timescale(samplerate)
    with (
        open(path, "w", encoding="ascii") as fh,
        VCDWriter(fh, timescale=timescale, date="", comment=comment, version="canstack") as w,
    ):
        var = w.register_var("canstack", name, "wire", size=1, init=runs[0][0] if runs else 1)
        t = 0
        for lvl, n in runs:
            if t:
                w.change(var, t * step, lvl)
            t += n
        w.close(t * step)


def _runs(samples: bytes) -> list[tuple[int, int]]:
    """Run-length encode a 0/1 sample string with bytes.find (no per-sample Python loop)."""
    runs: list[tuple[int, int]] = []
    pos, n = 0, len(samples)
    while pos < n:
        lvl = samples[pos]
        nxt = samples.find(DOMINANT if lvl else RECESSIVE, pos)
        if nxt < 0:
            nxt = n
        runs.append((1 if lvl else 0, nxt - pos))
        pos = nxt
    return runs
