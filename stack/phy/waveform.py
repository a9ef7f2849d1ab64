"""CAN_RX waveforms: render frames as a logic signal, and decode recorded signals into frames.

Level convention on the CAN_RX pin: 0 = dominant, 1 = recessive (as in `stack.bits`).

Rendering (`render_samples`, `write_vcd`, `write_raw`): each frame's exact bit stream
(`Frame.bits`, SOF..EOF with the ACK slot dominant) is laid out at the bit rate, frames separated
by the 3-bit intermission (back to back) or placed at given start times, with bus idle before the
first frame and after the last. Optional clock drift (the transmitter's oscillator error) and edge
jitter exercise a receiver's resynchronisation.

Decoding (`decode_samples`, `decode_file`) is a bit-level receiver working in the sample domain
(ISO 11898-1 bit timing, see `BitReceiver`):
- hard synchronisation on the recessive->dominant edge that starts a frame after bus idle
  (11 recessive bits, or the 3-bit intermission after a valid EOF);
- resynchronisation on recessive->dominant edges inside the frame: phase error e > 0 (edge before
  the sample point) lengthens Phase_Seg1 by min(e, SJW), e < 0 (edge after the sample point)
  shortens Phase_Seg2 by min(|e|, SJW); at most one synchronisation between two sample points, and
  only when the bit sampled before the edge was recessive;
- one sample per bit at the sample point (default 87.5 %), destuffing and the frame checks of
  `stack.bits.BitDecoder` (stuff, form, CRC), error flags (6+ dominant bits where the frame should
  continue) reported as error records, a frame cut by the end of the capture as a 'truncated'
  error record.

Speed: a Python loop over every sample is far too slow for a 12 M sample capture, so the channel
is first reduced to a bytes object of 0/1 (one `bytes.translate`), edges are found with
`bytes.find` (memchr) and the Python loop runs once per *bit*, only inside frames. Bus idle is
skipped in C. See `benchmark()` for the figure against sigrok-cli.

Inputs: sigrok session files (.sr, zip with `metadata` + `logic-1` or `logic-1-N` chunks), VCD
(read with pyvcd's tokenizer) and raw one-byte-per-sample files.
"""

from __future__ import annotations

import configparser
import itertools
import json
import math
import random
import re
import zipfile
import zlib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any

from stack.wire.coding import INTERMISSION_BITS
from stack.wire.decoder import BitDecoder, BitError, DecodedFrame
from stack.wire.frame import Frame

__all__ = [
    "Capture",
    "RxRecord",
    "BitReceiver",
    "render_samples",
    "render_edges",
    "write_vcd",
    "write_raw",
    "runs_to_raw",
    "read_capture",
    "read_sigrok",
    "read_vcd",
    "read_raw",
    "decode_samples",
    "decode_file",
    "frames_from_jsonl",
    "record_to_json",
    "IDLE_BITS",
    "missing_input",
]

#: Recessive bits that make the bus idle for a receiver that has lost track of the traffic:
#: 8 bits error/overload delimiter + 3 bits intermission (also the bus-integration rule).
IDLE_BITS = 11

MAX_RENDER_SAMPLES = 400_000_000  # a rendered waveform is built in memory: one byte a sample
#: Longest bit, in samples, the receiver and the renderer accept: the two options are checked
#: one by one (positive, finite), but their ratio can still overflow (1e300 samples/s at
#: 1e-10 bit/s); a frame of bits this long would span 4.4e10 samples, far beyond any capture.
MAX_SAMPLES_PER_BIT = 1e9
_DOMINANT = b"\x00"
_RECESSIVE = b"\x01"


# ---------------------------------------------------------------------------------------------
# Captures


@dataclass(frozen=True)
class Capture:
    """One logic channel of a recording: ``samples`` holds one byte per sample, 0 (dominant) or
    1 (recessive); ``samplerate`` in Hz; ``channel`` the channel's name; ``source`` the file."""

    samples: bytes
    samplerate: float
    channel: str
    source: str = ""
    # the rate the recording was made at, when the samples were subdivided for the receiver
    # (a VCD's edge grid): the decoder's rescue for coarse captures goes by this one
    native_rate: float | None = None

    @property
    def duration(self) -> float:
        """Length of the recording in seconds."""
        return len(self.samples) / self.samplerate


def _bit_table(bit: int) -> bytes:
    return bytes((x >> bit) & 1 for x in range(256))


_UNITS = {"": 1, "hz": 1, "khz": 1e3, "mhz": 1e6, "ghz": 1e9}


def _parse_samplerate(text: str) -> float:
    m = re.fullmatch(r"\s*([0-9.]+)\s*([kMG]?Hz)?\s*", text, re.IGNORECASE)
    if not m:
        raise ValueError(f"samplerate {text!r} in sigrok metadata is not a frequency like '4 MHz'")
    return float(m.group(1)) * _UNITS[(m.group(2) or "").lower()]


def _select_channel(names: list[str], channel: str | int | None, what: str) -> int:
    """Index of the channel chosen by name or by 0-based index (``#N`` forces an index); a
    number that is one channel's name and another's index is refused as ambiguous; a message
    lists the channels."""
    listing = ", ".join(f"{i}={n!r}" for i, n in enumerate(names) if n is not None)
    if channel is None:
        if "CAN_RX" in names:
            return names.index("CAN_RX")
        present = [i for i, n in enumerate(names) if n is not None]
        if len(present) == 1:
            return present[0]
        raise ValueError(f"{what} has several channels ({listing}): choose one with --channel")
    text = str(channel)
    if text.startswith("#"):  # explicitly an index
        try:
            idx = int(text[1:])
        except ValueError:
            idx = -1
        if 0 <= idx < len(names) and names[idx] is not None:
            return idx
        raise ValueError(f"channel index {text!r} not in {what}: available channels are {listing}")
    try:
        idx = int(text) if not isinstance(channel, bool) else -1
    except ValueError:
        idx = -1
    by_index = idx if 0 <= idx < len(names) and names[idx] is not None else None
    if text in names:
        by_name = names.index(text)
        if by_index is not None and by_index != by_name:
            raise ValueError(
                f"channel {text!r} is ambiguous in {what}: the channel named {text!r} is index "
                f"{by_name}, index {idx} is {names[idx]!r}; say --channel {names[idx]} or "
                f"--channel '#{idx}' (channels: {listing})"
            )
        return by_name
    if by_index is not None:
        return by_index
    raise ValueError(f"channel {text!r} not found in {what}: available channels are {listing}")


def read_sigrok(path: str | Path, channel: str | int | None = None) -> Capture:
    """Read one channel of a sigrok session file (.sr).

    Format: a zip with an ini file ``metadata`` ([device 1]: ``capturefile``, ``unitsize`` bytes a
    sample, ``samplerate``, ``probe{k+1}`` the name of bit k) and the samples in ``logic-1`` or in
    chunks ``logic-1-1``, ``logic-1-2``, ... (concatenated in numeric order). The channel is chosen
    by name, else by 0-based bit index; default CAN_RX, or the only channel.
    """
    path = Path(path)
    try:
        zf = zipfile.ZipFile(path)
    except zipfile.BadZipFile:
        raise ValueError(f"{path}: not a sigrok session file (not a zip archive)") from None
    with zf:
        names = zf.namelist()
        if "metadata" not in names:
            raise ValueError(f"{path}: not a sigrok session file (zip without 'metadata')")
        cp = configparser.ConfigParser(interpolation=None)
        try:
            cp.read_string(_read_member(zf, path, "metadata").decode("utf-8", "replace"))
        except configparser.Error as exc:
            first = str(exc).splitlines()[0]
            raise ValueError(f"{path}: sigrok metadata is not an ini file ({first})") from None
        dev = next((s for s in cp.sections() if s.startswith("device")), None)
        if dev is None:
            raise ValueError(f"{path}: sigrok metadata has no [device N] section")
        sec = cp[dev]
        base = sec.get("capturefile", "logic-1")
        try:
            unitsize = int(sec.get("unitsize", "1"))
        except ValueError as exc:
            raise ValueError(f"{path}: sigrok metadata: {exc}") from None
        if not 1 <= unitsize <= 8:
            raise ValueError(f"{path}: sigrok metadata: unitsize {unitsize} outside 1..8 bytes a sample")
        if "samplerate" not in sec:
            raise ValueError(f"{path}: sigrok metadata gives no samplerate")
        rate = _parse_samplerate(sec["samplerate"])
        # a sample of ``unitsize`` bytes holds 8 x unitsize channels: a probe numbered beyond
        # that has no data in the file, and sizing the channel list by it would let one
        # metadata line allocate gigabytes ('probe999999999')
        width = 8 * unitsize
        probes: dict[int, str] = {}
        for key, value in sec.items():
            m = re.fullmatch(r"probe(\d+)", key)
            if m:
                num = int(m.group(1))
                if not 1 <= num <= width:
                    raise ValueError(
                        f"{path}: sigrok metadata names {key!r}, but a sample of unitsize {unitsize} "
                        f"holds {width} channels (probe1..probe{width})"
                    )
                probes[num - 1] = value
        chan_names: list[Any] = [probes.get(i) for i in range(width)]
        bit = _select_channel(chan_names, channel, str(path))
        if base in names:
            parts = [base]
        else:
            chunk = re.compile(re.escape(base) + r"-(\d+)$")
            nums = sorted((int(m.group(1)), n) for n in names if (m := chunk.match(n)))
            parts = [n for _, n in nums]
        if not parts:
            raise ValueError(f"{path}: sigrok session without sample data ('{base}' or '{base}-N')")
        raw = b"".join(_read_member(zf, path, p) for p in parts)
    if unitsize > 1:
        raw = raw[bit // 8 :: unitsize]
    return Capture(raw.translate(_bit_table(bit % 8)), rate, chan_names[bit], str(path))


def _read_member(zf: zipfile.ZipFile, path: Path, member: str) -> bytes:
    """One member of a session archive; a damaged member (CRC mismatch, bad deflate data, cut
    short) is a ValueError naming the file and the member, since the archive's directory being
    intact says nothing about the data behind it."""
    try:
        return zf.read(member)
    except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError) as exc:
        raise ValueError(f"{path}: sigrok session member {member!r} is damaged ({exc})") from None


def read_raw(path: str | Path, samplerate: float | None, channel: str | int | None = None) -> Capture:
    """Read a raw file of one byte per sample; the channel is a bit index 0..7.

    A samplerate must be given (the file carries none). Default channel: the one bit that
    changes in the file; if several do, they are listed and one must be chosen.
    """
    if not samplerate or samplerate <= 0:
        raise ValueError(f"{path}: a raw sample file carries no samplerate: give --samplerate")
    data = Path(path).read_bytes()
    if not data:
        raise ValueError(f"{path}: empty file, no samples")
    if channel is None:
        all_or = 0
        all_and = 0xFF
        for v in set(data):
            all_or |= v
            all_and &= v
        seen = all_or & ~all_and
        bits = [b for b in range(8) if seen >> b & 1]
        if len(bits) > 1:
            raise ValueError(
                f"{path}: bits {', '.join(map(str, bits))} change in this raw file: choose one with --channel"
            )
        bit = bits[0] if bits else 0
    else:
        try:
            bit = int(str(channel))
        except ValueError:
            bit = -1
        if not 0 <= bit <= 7:
            raise ValueError(f"channel {channel!r} of a raw file must be a bit index 0..7")
    return Capture(data.translate(_bit_table(bit)), float(samplerate), str(bit), str(path))


class _ChannelError(ValueError):
    """A complete message about the file (a channel that is not in it, times that go
    backwards), raised through the VCD reader's error wrapping unchanged."""


def _approx(x: float | int | Fraction) -> str:
    """A number for a message, 3 significant digits, also beyond the range of a float (a VCD
    time is an integer of any size, its rate a fraction that may underflow)."""
    q = Fraction(x)
    if q == 0 or Fraction(1, 10**300) < abs(q) < 10**300:
        return f"{float(q):.3g}"
    return f"about 1e{len(str(abs(q.numerator))) - len(str(q.denominator))}"


def _vcd_time(t: int) -> str:
    """A VCD time stamp as written (#t), shortened when it has more digits than a message can
    usefully show."""
    digits = str(t)
    return f"#{t}" if len(digits) <= 15 else f"#{digits[:6]}... ({len(digits)} digits)"


_TS_EXP = {"s": 0, "ms": -3, "us": -6, "ns": -9, "ps": -12, "fs": -15}


def read_vcd(
    path: str | Path,
    channel: str | int | None = None,
    samplerate: float | None = None,
    bitrate: float | None = None,
) -> Capture:
    """Read one 1-bit signal of a VCD file (pyvcd's tokenizer) into samples.

    The signal is chosen by reference name (or scope.name), else by 0-based index in declaration
    order; default CAN_RX or the only signal. Values x/z count as recessive (an undriven bus).
    Without ``samplerate`` the signal is sampled exactly: the sample period is the greatest common
    divisor of the change times, divided further (still exact) until a bit of ``bitrate`` spans
    at least 16 samples, so every edge lands on a sample boundary.
    """
    from vcd.reader import TokenKind, VCDParseError, tokenize

    path = Path(path)
    decls: list[tuple[str, str, int]] = []  # (name, id_code, size)
    scope: list[str] = []
    timescale = Fraction(1, 10**9)
    changes: list[tuple[int, int]] = []
    want: str | None = None
    now = 0
    now_line = 0
    level = 1
    try:
        with open(path, "rb") as fh:
            for tok in tokenize(fh):
                kind = tok.kind
                if kind is TokenKind.CHANGE_TIME:
                    # IEEE 1364 dumps times in increasing order; a reader that accepted a step
                    # back would silently draw the changes after it at the wrong place
                    if tok.data < now:
                        raise _ChannelError(
                            f"{path} line {tok.span.start.line}: time {_vcd_time(tok.data)} is earlier than {_vcd_time(now)} "
                            f"(line {now_line}): VCD times must not decrease"
                        )
                    now = tok.data
                    now_line = tok.span.start.line
                elif kind is TokenKind.CHANGE_SCALAR:
                    if tok.data.id_code == want:
                        v = 0 if tok.data.value == "0" else 1
                        if v != level or not changes:
                            changes.append((now, v))
                            level = v
                elif kind is TokenKind.CHANGE_VECTOR:
                    if tok.data.id_code == want:
                        v = 0 if tok.data.value == 0 else 1
                        if v != level or not changes:
                            changes.append((now, v))
                            level = v
                elif kind is TokenKind.SCOPE:
                    scope.append(tok.data.ident)
                elif kind is TokenKind.UPSCOPE:
                    if scope:
                        scope.pop()
                elif kind is TokenKind.VAR:
                    var = tok.data
                    decls.append((".".join(scope + [var.reference]), var.id_code, var.size))
                elif kind is TokenKind.TIMESCALE:
                    ts = tok.data
                    timescale = Fraction(ts.magnitude) * Fraction(10) ** _TS_EXP[ts.unit.value]
                elif kind is TokenKind.ENDDEFINITIONS:
                    if not decls:
                        raise ValueError(f"{path}: VCD file declares no signals")
                    short = [d[0].rsplit(".", 1)[-1] for d in decls]
                    text = None if channel is None else str(channel)
                    if text is not None and text in [d[0] for d in decls]:
                        idx = [d[0] for d in decls].index(text)
                    else:
                        try:
                            idx = _select_channel(short, channel, str(path))
                        except ValueError as exc:
                            raise _ChannelError(str(exc)) from None
                    want = decls[idx][1]
                    chan_name = short[idx]
    except _ChannelError:
        raise
    except (VCDParseError, ValueError, KeyError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not a readable VCD file ({exc})") from None
    if want is None:
        raise ValueError(f"{path}: not a VCD file (no $enddefinitions)")
    if not changes:
        raise ValueError(f"{path}: signal {chan_name!r} has no value changes")
    end = max(now, changes[-1][0])
    # exact arithmetic until the sample count is known to be sane: a change time of 1e309
    # units is a valid VCD integer, but as a float its rate underflows to 0 (or its ratio to
    # the bitrate overflows)
    native: float | None = None
    if samplerate:
        rate_q = Fraction(samplerate).limit_denominator(10**6)
        step = 1 / (rate_q * timescale)
    else:
        g = end
        for t, _ in changes:
            g = math.gcd(g, t)
        step = Fraction(g or 1)
        rate_q = 1 / (step * timescale)
        native_q = rate_q
        if bitrate and rate_q < 16 * Fraction(bitrate):
            # an edge-exact signal stays exact at any integer multiple of its rate
            k = math.ceil(16 * Fraction(bitrate) / rate_q)
            step /= k
            rate_q *= k
    total = math.ceil(end / step)
    if total > 400_000_000:
        raise ValueError(
            f"{path}: the signal runs to time {_vcd_time(end)} ({_approx(end * timescale)} s): {_approx(total)} samples at "
            f"{_approx(rate_q)} Hz, more than 400,000,000 (cut the recording, or give a lower --samplerate)"
        )
    rate = float(rate_q)
    if not 0 < rate < math.inf:
        raise ValueError(
            f"{path}: the change times give a sample period of {_approx(step * timescale)} s, "
            f"{_approx(rate_q)} samples/s, which is no usable rate: give --samplerate"
        )
    if not samplerate:
        native = float(native_q)
    parts: list[bytes] = []
    pos = 0
    level = 1  # before the first value change the bus counts as idle (recessive)
    for t, v in changes:
        idx = math.ceil(t / step)
        if idx > pos:
            parts.append((_RECESSIVE if level else _DOMINANT) * (idx - pos))
            pos = idx
        level = v
    parts.append((_RECESSIVE if level else _DOMINANT) * max(1, total - pos))
    return Capture(b"".join(parts), rate, chan_name, str(path), native)


def missing_input(path: str | Path, what: str = "file") -> str:
    """Why an input file cannot be opened, in words: a directory, a path through a file, or no
    such file (the OS's own message says 'Not a directory' without saying which part)."""
    p = Path(path)
    if p.is_dir():
        return f"{p}: is a directory, not a {what}"
    parent = p.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if parent.exists() and not parent.is_dir():
        return f"{p}: {str(parent)!r} is a file, not a directory"
    return f"{p}: no such {what}"


def read_capture(
    path: str | Path,
    channel: str | int | None = None,
    samplerate: float | None = None,
    bitrate: float | None = None,
) -> Capture:
    """Read a capture, recognising the format by content: a zip is a sigrok session, text that
    starts with a VCD keyword is VCD, anything else is raw samples (which need a samplerate)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(missing_input(path, "capture file"))
    with open(path, "rb") as fh:
        head = fh.read(4096)
    if head[:4] == b"PK\x03\x04":
        return read_sigrok(path, channel)
    stripped = head.lstrip()
    if stripped[:1] == b"$" and re.match(rb"\$(date|version|timescale|comment|scope|var)\b", stripped):
        return read_vcd(path, channel, samplerate, bitrate)
    if path.suffix.lower() in (".sr", ".vcd"):
        raise ValueError(f"{path}: not a capture: the content is neither a sigrok session (zip) nor VCD")
    if not samplerate:
        raise ValueError(
            f"{path}: not a capture: neither a sigrok session (.sr zip) nor VCD; "
            "a raw one-byte-per-sample file needs --samplerate"
        )
    return read_raw(path, samplerate, channel)


# ---------------------------------------------------------------------------------------------
# Rendering


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
    one = _RECESSIVE if bit is None else bytes([1 << _check_bit(bit)])
    return b"".join((one if lvl else _DOMINANT) * n for lvl, n in runs)


def _check_bit(bit: int) -> int:
    if not 0 <= bit <= 7:
        raise ValueError(f"bit {bit}: a raw sample byte has bits 0..7")
    return bit


def runs_to_raw(runs: Sequence[tuple[int, int]], bit: int | None = None) -> bytes:
    """Raw sample bytes of a run list (level, samples): bytes 0/1, or with ``bit`` the level on
    that bit of each byte (a logic analyser's channel), dominant as 0."""
    one = _RECESSIVE if bit is None else bytes([1 << _check_bit(bit)])
    return b"".join((one if lvl else _DOMINANT) * n for lvl, n in runs)


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
        nxt = samples.find(_DOMINANT if lvl else _RECESSIVE, pos)
        if nxt < 0:
            nxt = n
        runs.append((1 if lvl else 0, nxt - pos))
        pos = nxt
    return runs


# ---------------------------------------------------------------------------------------------
# Decoding


@dataclass(frozen=True)
class RxRecord:
    """One frame (or error record) seen on the waveform.

    ``t`` is the time of its SOF edge in seconds from the start of the capture, ``sample`` that
    edge's sample index. The header fields are None where the frame did not get that far.
    ``error`` is None for a valid frame; otherwise its kind is 'stuff', 'form', 'crc' (from
    `BitDecoder`) or 'truncated' (the capture ended inside the frame). ``error_flag`` is True when
    the error shows as an error flag on the bus: 6 or more dominant bits where the frame should
    have continued.
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
        return Frame(self.can_id, self.data, extended=self.extended, remote=self.remote, dlc=self.dlc)


def record_to_json(rec: RxRecord) -> dict[str, Any]:
    """The JSON-lines form of a record: t, id, extended, remote, dlc, data (hex), crc, crc_ok,
    ack; error records add ``error`` {kind, field, bit (index in the field), position (bit from
    SOF), flag (error flag seen)}."""
    out: dict[str, Any] = {
        "t": rec.t,
        "id": rec.can_id,
        "extended": rec.extended,
        "remote": rec.remote,
        "dlc": rec.dlc,
        "data": rec.data.hex(),
        "crc": rec.crc,
        "crc_ok": rec.crc_ok,
        "ack": rec.ack,
    }
    if rec.error is not None:
        out["error"] = {
            "kind": rec.error.kind,
            "field": rec.error.field.value,
            "bit": rec.error.index,
            "position": rec.error.position,
            "flag": rec.error_flag,
        }
    return out


class BitReceiver:
    """Bit timing of a receiver in the sample domain (ISO 11898-1, 'Bit timing' and
    'Synchronisation').

    The nominal bit time is ``samplerate / bitrate`` samples, divided into ``tq_per_bit`` time
    quanta; the sample point is at ``sample_point`` % of the bit (end of Phase_Seg1), so
    Phase_Seg2 is the rest. ``sjw`` (time quanta, 1..4, at most Phase_Seg2; default
    min(4, Phase_Seg2)) bounds each resynchronisation. A sample at index i is the bus level during
    [i, i+1); an edge at index i (sample i differs from sample i-1) happens at time i.
    """

    def __init__(
        self,
        bitrate: float,
        samplerate: float,
        *,
        sample_point: float = 87.5,
        sjw: float | None = None,
        tq_per_bit: int = 16,
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
        return line.find(_DOMINANT, after + 1)
    r = line.find(_RECESSIVE, after + 1)
    return -1 if r < 0 else line.find(_DOMINANT, r + 1)


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
        res = feed(v)
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
        start = line.find(_DOMINANT, start)
        if start < 0 or start - sample > rx.bit_time:
            return 0.0
    else:
        r = line.rfind(_RECESSIVE, 0, start)
        start = r + 1
    end = line.find(_RECESSIVE, start)
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
    r = line.rfind(_DOMINANT, 0, pos) + 1 if line[pos] else line.find(_RECESSIVE, pos)
    while r >= 0:
        f = line.find(_DOMINANT, r)
        if f < 0:
            return -1
        if f - r >= need:
            return f
        r = line.find(_RECESSIVE, f)
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
        nxt = line.find(_DOMINANT if lvl else _RECESSIVE, pos)
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
    """
    rx = BitReceiver(bitrate, samplerate, sample_point=sample_point, sjw=sjw, tq_per_bit=tq_per_bit)
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
                    BitReceiver(bitrate, samplerate, sample_point=spv, sjw=min(4.0, ps2), tq_per_bit=tq_per_bit)
                )
    line = bytes(samples)
    n = len(line)
    if n == 0:
        return []
    # bus idle: 11 recessive bits, but a node may start in the third intermission bit after an
    # error or overload delimiter (8 + 2 bits); half a bit of tolerance for the edge positions
    idle_need = (IDLE_BITS - 1.5) * T
    dec = BitDecoder()
    out: list[RxRecord] = []
    pos = 0
    need = idle_need
    # a capture triggered just before a frame has less than 11 bits of idle ahead of its SOF:
    # the bus before the capture is unknown, so that first frame is taken when it decodes
    # cleanly (a capture that starts inside a frame gives no such frame, and no false error)
    if line[0]:
        f = line.find(_DOMINANT)
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
                if T < 8 or (native_rate is not None and native_rate / bitrate < 8):
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
                if line.find(_DOMINANT, min(n, int(end) + 1), pos) >= 0:
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
) -> list[RxRecord]:
    """Read a capture (`read_capture`) and decode it (`decode_samples`)."""
    cap = read_capture(path, channel, samplerate, bitrate)
    return decode_samples(
        cap.samples,
        cap.samplerate,
        bitrate,
        sample_point=sample_point,
        sjw=sjw,
        retry=retry,
        native_rate=cap.native_rate,
    )


# ---------------------------------------------------------------------------------------------
# Frames lists (JSON lines)


def frames_from_jsonl(lines: Iterable[str], source: str = "input") -> list[tuple[float | None, Frame]]:
    """Parse JSON lines with decode's keys (id, extended, remote, dlc, data hex; t optional, crc
    optional and checked against the frame's CRC-15 when given) into (t, Frame) pairs.

    Error records (with an ``error`` key) are skipped: they are not frames a node sends.
    """
    out: list[tuple[float | None, Frame]] = []
    for lineno, text in enumerate(lines, 1):
        text = text.strip()
        if not text:
            continue
        where = f"{source} line {lineno}"
        try:
            obj = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{where}: not JSON ({exc.msg})") from None
        if not isinstance(obj, dict):
            raise ValueError(f"{where}: expected a JSON object per line, got {type(obj).__name__}")
        if "error" in obj:
            continue
        if "id" not in obj or not isinstance(obj["id"], int) or isinstance(obj["id"], bool):
            raise ValueError(f"{where}: 'id' must be an integer identifier")
        data_hex = obj.get("data", "") or ""
        try:
            data = bytes.fromhex(data_hex)
        except (ValueError, TypeError):
            raise ValueError(f"{where}: 'data' {data_hex!r} is not a hex string") from None
        remote = bool(obj.get("remote", False))
        try:
            frame = Frame(
                obj["id"],
                b"" if remote else data,
                extended=bool(obj.get("extended", False)),
                remote=remote,
                dlc=obj.get("dlc"),
            )
        except (ValueError, TypeError) as exc:
            raise ValueError(f"{where}: {exc}") from None
        crc = obj.get("crc")
        if crc is not None and crc != frame.bits.crc:
            raise ValueError(
                f"{where}: crc {crc} (0x{crc:04X}) does not match the frame's CRC-15 0x{frame.bits.crc:04X}"
            )
        t = obj.get("t")
        if t is not None and (not isinstance(t, (int, float)) or isinstance(t, bool) or not 0 <= t < math.inf):
            raise ValueError(f"{where}: 't' {t!r} must be a time in seconds >= 0")
        out.append((None if t is None else float(t), frame))
    return out
