"""Render frames as a CAN_RX waveform, and write waveforms as VCD or raw samples.

Each frame's exact bit stream (`Frame.bits`, SOF..EOF with the ACK slot dominant) is laid out at
the bit rate, frames separated by the 3-bit intermission (back to back) or placed at given start
times, with bus idle before the first frame and after the last. Optional clock drift (the
transmitter's oscillator error) and edge jitter exercise a receiver's resynchronisation.

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
) -> tuple[list[tuple[int, int]], int, list[int]]:
    """The waveform as runs: ([(level, n_samples), ...], total samples, SOF sample of each frame).

    Bus idle of ``idle_bits`` recessive bits comes first and last. A frame without a time follows
    the previous one after the 3-bit intermission (its SOF is the bit after it); a time (seconds
    from the start of the waveform) places its SOF edge at that sample, and must leave the
    intermission after the previous frame, or ``idle_bits`` of bus idle before the first.
    ``drift`` scales the transmitter's bit time (0.01 = bits 1 % longer); ``jitter`` moves every
    edge by a uniform random amount of up to +-jitter bit times (seeded: the same seed gives the
    same waveform). Sample i holds the level during [i, i+1), so an edge at time x first shows in
    sample ceil(x).
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
        k = 0
        while k < nb:
            lvl = bits[k]
            j = k
            while j < nb and bits[j] == lvl:
                j += 1
            edge = start + j * tb
            if jitter and j < nb:
                edge += rng.uniform(-jitter, jitter) * tbit
            emit(1 if lvl == "1" else 0, max(pos + 1, math.ceil(edge - 1e-9)))
            k = j
        eof_end = start + nb * tb
        earliest = eof_end + INTERMISSION_BITS * tb
    emit(1, max(pos + 1, math.ceil(earliest - INTERMISSION_BITS * tb + idle_bits * tbit)))
    return runs, pos, sofs


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
) -> bytes:
    """The CAN_RX waveform of ``frames`` as one byte per sample (see `render_edges` for timing).

    Values are 0 (dominant) / 1 (recessive), or 0 / 1 << ``bit`` when a bit position is chosen
    (so the file looks like one channel of a multi-channel logic analyzer).
    """
    runs, _, _ = render_edges(
        frames, bitrate, samplerate, times=times, idle_bits=idle_bits, drift=drift, jitter=jitter, seed=seed
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
